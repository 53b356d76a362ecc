//! Validation harnesses for the judge: they run the renderer's stages
//! (BSDF sampling, intersection, first hits) and hold them against the
//! referees in `referee/` and the statistics in `crate::stats`. The judge's
//! ops only wire parameters to these and name the outputs.

use glam::Vec3A;
use serde::Deserialize;
use statrs::distribution::{ContinuousCDF, Normal};

use crate::camera::RealCamera;
use crate::error::{Error, Result};
use crate::pathtrace::bsdf::fresnel_dielectric;
use crate::pathtrace::listed::{unit, HitList, ShapeParam};
use crate::pathtrace::packed::Packed;
use crate::pathtrace::referee::bsdf::fresnel_angles;
use crate::pathtrace::shapes::{intersect, spawn_origin};
use crate::pathtrace::{Material, Quad, Scene, Shape, Sphere};
use crate::rng::rand_f32;
use crate::stats::chi2::{chi2_test, Bins};
use crate::stats::quadrature::{dir, sphere_quad};
use crate::stats::sidak;
use crate::tensor::{Outputs, Tensor};

/// For `n` random camera rays of the scene (pixel and direction from
/// `rand(seed, i, 0, dim)`): at the first hit, spawn one ray on the
/// viewer's side (reflection) and one through the surface (refraction) and
/// count "acne": a reflected ray that hits the same shape (planes and convex
/// spheres cannot), or a transmitted ray into a sphere that meets it again
/// on the entry side instead of the far side. `cam` is the scene's camera
/// at `w` x `h` pixels. Returns (tested, acne).
pub fn self_intersection(
    scene: &Scene,
    cam: &RealCamera<f32>,
    (w, h): (u32, u32),
    n: u32,
    seed: u32,
) -> (u64, u64) {
    let shapes = scene.shapes();
    let (mut tested, mut acne) = (0u64, 0u64);
    for i in 0..n {
        let r = |k| rand_f32(seed, i, 0, k);
        let (o, d) = cam.ray(r(0) * w as f32, r(1) * h as f32);
        let (o, d) = (Vec3A::from_array(o), Vec3A::from_array(d));
        let Some((t, k)) = intersect(shapes, o, d, f32::INFINITY) else {
            continue;
        };
        let (p, nrm) = shapes[k].surface(o, d, t);
        let side = if d.dot(nrm) < 0.0 { nrm } else { -nrm };
        let jitter = Vec3A::new(r(2) - 0.5, r(3) - 0.5, r(4) - 0.5) * 1.9;
        let wr = (side + jitter).normalize();
        if wr.dot(side) > 0.0 {
            tested += 1;
            if matches!(intersect(shapes, spawn_origin(p, nrm, wr), wr, f32::INFINITY), Some((_, k2)) if k2 == k)
            {
                acne += 1;
            }
        }
        if let Shape::Sphere(sph) = shapes[k] {
            let wt = -wr;
            if wt.dot(side) < 0.0 {
                tested += 1;
                let o2 = spawn_origin(p, nrm, wt);
                let far = match Shape::Sphere(sph).hit_t(o2, wt, f32::INFINITY) {
                    Some(t2) => (o2 + t2 * wt - sph.centre).dot(wt) > 0.0,
                    None => false,
                };
                if !far {
                    acne += 1;
                }
            }
        }
    }
    (tested, acne)
}

/// Results of [`bsdf_checks`], one row per (material, `wo`) for the sampled
/// lobes; `chi2_p` has those rows then one per dielectric angle.
#[derive(Clone, Debug)]
pub struct BsdfChecks {
    /// Quadrature of the pdf over the sphere (1 for a complete sampler).
    pub pdf_integral: Vec<f64>,
    /// Quadrature of `f cos` (the directional albedo).
    pub albedo: Vec<f64>,
    /// Largest `|f(wo, wi) - f(wi, wo)|` relative to `f`, over the samples.
    pub reciprocity_err: Vec<f64>,
    /// Largest relative error of the sample weight against `f cos / pdf`.
    pub weight_err: Vec<f64>,
    /// Largest error of the code's Fresnel term against the angle form.
    pub fresnel_err: f64,
    pub chi2_p: Vec<f64>,
    /// The Šidák per-test level for all `chi2_p` tests.
    pub chi2_alpha: f64,
}

impl BsdfChecks {
    /// Tensors named as the fields; counters `tests`, `samples_per_test`.
    pub fn to_outputs(self, samples: u32) -> Result<Outputs> {
        let k = self.chi2_p.len();
        let rows = [self.pdf_integral.len()];
        let mut out = Outputs::default();
        out.tensor("pdf_integral", Tensor::real(&rows, self.pdf_integral)?);
        out.tensor("albedo", Tensor::real(&rows, self.albedo)?);
        out.tensor(
            "reciprocity_err",
            Tensor::real(&rows, self.reciprocity_err)?,
        );
        out.tensor("weight_err", Tensor::real(&rows, self.weight_err)?);
        out.tensor("fresnel_err", Tensor::scalar(self.fresnel_err));
        out.tensor("chi2_p", Tensor::real(&[k], self.chi2_p)?);
        out.tensor("chi2_alpha", Tensor::real(&[k], vec![self.chi2_alpha; k])?);
        out.counter("tests", k as u64)
            .counter("samples_per_test", samples as u64);
        Ok(out)
    }
}

/// Checks every sampled lobe at each `wo` polar angle in `thetas`
/// (degrees, in [0, 90)) with `n` samples: Lambertian (albedo 1) and rough
/// conductor (reflectance 1, alpha `rough`) rows, then one dielectric row
/// per angle (from outside, then from inside the glass). `alpha` is the
/// family-wise level of the chi-square tests.
pub fn bsdf_checks(thetas: &[f64], n: u32, alpha: f64, rough: f32, seed: u32) -> BsdfChecks {
    let mats = [
        Material::Lambertian { albedo: Vec3A::ONE },
        Material::RoughConductor {
            alpha: rough,
            reflectance: Vec3A::ONE,
        },
    ];
    let bins = Bins {
        theta: 90,
        phi: 180,
        sub: 6,
    };
    let (mut pdf_int, mut albedo, mut recip, mut werr, mut chi_p) =
        (vec![], vec![], vec![], vec![], vec![]);
    let mut seed_row = 0u32;
    for m in &mats {
        for &th in thetas {
            seed_row += 1;
            let wo = dir(th.to_radians(), 0.4);
            pdf_int.push(sphere_quad(1000, |wi| m.pdf(wo, wi) as f64));
            albedo.push(sphere_quad(1000, |wi| {
                (m.eval(wo, wi).x * wi.z.abs()) as f64
            }));
            // Reciprocity and weight consistency on random pairs / samples.
            let (mut re, mut we) = (0.0f64, 0.0f64);
            let mut obs = vec![0u64; bins.theta * bins.phi];
            let mut rejected = 0u64;
            for i in 0..n {
                let r = |k| rand_f32(seed ^ seed_row, i, 0, k);
                match m.sample(wo, r(0), [r(1), r(2)]) {
                    Some(s) => {
                        obs[bins.cell(s.wi.to_array().map(|x| x as f64))] += 1;
                        let f = m.eval(wo, s.wi);
                        let back = m.eval(s.wi, wo);
                        let scale = f.max_element().max(1e-3) as f64;
                        re = re.max((f - back).abs().max_element() as f64 / scale);
                        let expect = f * s.wi.z.abs() / s.pdf;
                        we = we.max(
                            (expect - s.weight).abs().max_element() as f64
                                / expect.max_element().max(1e-6) as f64,
                        );
                    }
                    None => rejected += 1,
                }
            }
            // Directions the sampler returns: pdf on wo's side only; the
            // rest of the mass is the rejected cell.
            let masses = bins.masses(|w| {
                let wi = Vec3A::new(w[0] as f32, w[1] as f32, w[2] as f32);
                if wi.z * wo.z > 0.0 {
                    m.pdf(wo, wi) as f64
                } else {
                    0.0
                }
            });
            chi_p.push(chi2_test(&obs, rejected, &masses, n as u64).p_value);
            recip.push(re);
            werr.push(we);
        }
    }
    // Dielectric: the reflect/refract choice against the exact Fresnel
    // reflectance (a two-cell chi-square), from outside and from inside.
    let mut fres_err = 0.0f64;
    let glass = Material::Dielectric { ior: 1.5 };
    for (side, (n1, n2)) in [(1.0f32, (1.0, 1.5)), (-1.0f32, (1.5, 1.0))] {
        for &th in thetas {
            seed_row += 1;
            let mut wo = dir(th.to_radians(), 0.4);
            wo.z *= side;
            let f_ref = fresnel_angles(th.to_radians(), n1, n2);
            let mut refl = 0u64;
            for i in 0..n {
                if let Some(s) = glass.sample(wo, rand_f32(seed ^ seed_row, i, 0, 0), [0.5, 0.5]) {
                    if s.wi.z * wo.z > 0.0 {
                        refl += 1;
                    }
                }
            }
            let f_code = fresnel_dielectric(wo.z.abs(), if side > 0.0 { 1.5 } else { 1.0 / 1.5 }).0;
            fres_err = fres_err.max((f_code as f64 - f_ref).abs());
            let e = [f_ref * n as f64, (1.0 - f_ref) * n as f64];
            let o = [refl as f64, (n as u64 - refl) as f64];
            let p = if e[0] <= 0.0 || e[1] <= 0.0 {
                // A certain outcome: it must happen every time.
                if (e[0] <= 0.0 && o[0] > 0.0) || (e[1] <= 0.0 && o[1] > 0.0) {
                    0.0
                } else {
                    1.0
                }
            } else {
                let x2: f64 = (0..2).map(|k| (o[k] - e[k]).powi(2) / e[k]).sum();
                // chi2 with 1 dof: P(X > x2) = 2 (1 - Phi(sqrt(x2))).
                Normal::standard().sf(x2.sqrt()) * 2.0
            };
            chi_p.push(p);
        }
    }
    let k = chi_p.len();
    BsdfChecks {
        pdf_integral: pdf_int,
        albedo,
        reciprocity_err: recip,
        weight_err: werr,
        fresnel_err: fres_err,
        chi2_p: chi_p,
        chi2_alpha: sidak(alpha, k),
    }
}

/// A region: the pixels whose centre ray first hits shape `shape` at a
/// point within `[r_min, r_max]` of `center` (world space).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Region {
    pub shape: String,
    pub center: [f32; 3],
    #[serde(default)]
    pub r_min: f32,
    pub r_max: f32,
}

/// Sum of the pixel colours of `rgb` whose first hit (`hits`, from
/// `first_hits`) lies on shape `k` within `r` of its centre; the pixel count.
pub fn region_sum(
    rgb: &[[f32; 3]],
    hits: &[(i32, [f32; 3])],
    k: usize,
    r: &Region,
) -> ([f64; 3], u64) {
    let c = Vec3A::from_array(r.center);
    let (mut sum, mut count) = ([0.0f64; 3], 0u64);
    for (i, &(idx, p)) in hits.iter().enumerate() {
        let dist = (Vec3A::from_array(p) - c).length();
        if idx == k as i32 && dist >= r.r_min && dist <= r.r_max {
            for ch in 0..3 {
                sum[ch] += rgb[i][ch] as f64;
            }
            count += 1;
        }
    }
    (sum, count)
}

/// The renderer's intersection of listed rays with listed shapes as
/// rendering runs it (`Packed`, f32). `at` names the shapes for errors (a
/// degenerate quad).
pub fn intersect_listed(rays: &[[f64; 6]], params: &[ShapeParam], at: &str) -> Result<HitList> {
    let v = |a: [f64; 3]| Vec3A::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let mut shapes = Vec::with_capacity(params.len());
    for (i, sp) in params.iter().enumerate() {
        shapes.push(match *sp {
            ShapeParam::Sphere { center, radius } => Shape::Sphere(Sphere {
                centre: v(center),
                radius: radius as f32,
            }),
            ShapeParam::Quad { corner, u, v: e } => Shape::Quad(
                Quad::new(v(corner), v(u), v(e))
                    .ok_or_else(|| Error::invalid(format!("{at}[{i}]"), "degenerate quad"))?,
            ),
        });
    }
    let packed = Packed::new(&shapes);
    let mut hits = HitList::default();
    for r in rays {
        let (o, d) = unit(r);
        let (o, d) = (v(o), v(d).normalize());
        hits.push(packed.intersect(o, d, f32::INFINITY).map(|(th, k)| {
            let (_, n) = shapes[k].surface(o, d, th);
            (th as f64, k, n.to_array().map(|x| x as f64))
        }));
    }
    Ok(hits)
}

/// Whether a rough conductor's reflectance reaches both ways a path uses
/// the material (`eval`, light sampling; `sample`'s weight, BSDF sampling):
/// for each `wo` polar angle (degrees) and `n` random draws, the sums over
/// draws of `f` (at a cosine-weighted `wi`) and of the sampled weight with
/// reflectance `r` and with reflectance 1 on the same random numbers.
/// Outputs per angle and channel `eval_ratio`, `weight_ratio` (both must
/// equal r) and `expected` (r).
pub fn reflectance_applied(
    thetas: &[f32],
    n: u32,
    alpha: f32,
    r: [f32; 3],
    seed: u32,
) -> Result<Outputs> {
    let with = |refl: Vec3A| Material::RoughConductor {
        alpha,
        reflectance: refl,
    };
    let (m, one) = (with(Vec3A::from_array(r)), with(Vec3A::ONE));
    let (mut eval_ratio, mut weight_ratio, mut expected) = (vec![], vec![], vec![]);
    for (row, &th) in thetas.iter().enumerate() {
        let t = th.to_radians();
        let wo = Vec3A::new(t.sin() * 0.4f32.cos(), t.sin() * 0.4f32.sin(), t.cos());
        // f64 sums: f32 sums of 2e4 terms would differ by rounding alone.
        let (mut e, mut e1, mut w, mut w1) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 3], [0.0f64; 3]);
        let acc = |s: &mut [f64; 3], v: Vec3A| (0..3).for_each(|c| s[c] += v[c] as f64);
        for i in 0..n {
            let u = |k| rand_f32(seed ^ 0x5eed, i, row as u32, k);
            let wi = crate::pathtrace::bsdf::cosine_hemisphere([u(0), u(1)]);
            acc(&mut e, m.eval(wo, wi));
            acc(&mut e1, one.eval(wo, wi));
            let (a, b) = (
                m.sample(wo, u(2), [u(3), u(4)]),
                one.sample(wo, u(2), [u(3), u(4)]),
            );
            if let (Some(a), Some(b)) = (a, b) {
                acc(&mut w, a.weight);
                acc(&mut w1, b.weight);
            }
        }
        for c in 0..3 {
            eval_ratio.push(e[c] / e1[c]);
            weight_ratio.push(w[c] / w1[c]);
            expected.push(r[c] as f64);
        }
    }
    let shape = [thetas.len(), 3];
    let mut out = Outputs::default();
    out.tensor("eval_ratio", Tensor::real(&shape, eval_ratio)?);
    out.tensor("weight_ratio", Tensor::real(&shape, weight_ratio)?);
    out.tensor("expected", Tensor::real(&shape, expected)?);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pathtrace::bsdf::cosine_hemisphere;
    use crate::stats::chi2::{chi2_test, Bins, Chi2};

    fn run(sample: impl Fn(u32) -> [f64; 3]) -> Chi2 {
        let bins = Bins {
            theta: 20,
            phi: 40,
            sub: 4,
        };
        let masses = bins.masses(|w| {
            if w[2] > 0.0 {
                w[2] / std::f64::consts::PI
            } else {
                0.0
            }
        });
        let n = 200_000u32;
        let mut obs = vec![0u64; masses.len()];
        for i in 0..n {
            obs[bins.cell(sample(i))] += 1;
        }
        chi2_test(&obs, 0, &masses, n as u64)
    }

    #[test]
    fn cosine_sampler_passes_against_its_pdf() {
        let r = run(|i| {
            let w = cosine_hemisphere([rand_f32(9, i, 0, 0), rand_f32(9, i, 0, 1)]);
            [w.x as f64, w.y as f64, w.z as f64]
        });
        assert!(r.p_value > 0.01, "{r:?}");
    }

    #[test]
    fn uniform_sampler_fails_against_the_cosine_pdf() {
        let r = run(|i| {
            let z = rand_f32(9, i, 0, 0) as f64;
            let ph = 2.0 * std::f64::consts::PI * rand_f32(9, i, 0, 1) as f64;
            let s = (1.0 - z * z).sqrt();
            [s * ph.cos(), s * ph.sin(), z]
        });
        assert!(r.p_value < 1e-9, "{r:?}");
    }
}
