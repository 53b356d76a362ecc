//! Operations of the `pathtrace` renderer and their independent references.
//!
//! | op | what |
//! | --- | --- |
//! | `pathtrace.render` | `image` (H, W, 3 linear f32), `variance` (of the pixel mean); metrics `time_s`, `paths_per_s` |
//! | `pathtrace.intersect_list` | the renderer's intersection of `params.rays` with `params.shapes`: `t`, `hit`, `normal` |
//! | `pathtrace.intersect_reference` | the same by f64 closed forms written apart (geometric sphere, Cramer quad) |
//! | `pathtrace.self_intersection` | fraction of rays spawned at the scene's hit points that re-hit their own surface at once |
//! | `pathtrace.bsdf_checks` | per material and `wo`: pdf integral, albedo, reciprocity error, chi-square p-values |
//! | `pathtrace.furnace` | render + image mean and its z-score against the environment radiance |
//! | `pathtrace.convergence` | RMSE vs a high-spp render of the same scene over spp and seeds; log-log slope |
//! | `pathtrace.fireflies` | render + fraction of pixels above 10x their 3x3 median luminance |
//! | `pathtrace.features` | render + mean radiance of world-space regions: penumbra, bleeding, caustic |
//! | `pathtrace.rmse_vs_reference` | render + clamped and raw RMSE against a saved independent reference (Mitsuba 3) |
//! | `pathtrace.speed_error` | seconds and RMSE against a reference render over an spp sweep |

use std::time::Instant;

use std::collections::BTreeMap;

use glam::Vec3A;
use serde::Deserialize;
use statrs::distribution::{ContinuousCDF, Normal};

use super::{BackendKind, OpCtx, OpEntry};
use crate::error::{Error, Result};
use crate::pathtrace::chi2::{chi2_test, sidak, Bins};
use crate::pathtrace::integrator::first_hits;
use crate::pathtrace::shapes::{intersect, spawn_origin};
use crate::pathtrace::{render, Image, Material, Quad, RenderParams, Shape, Sphere};
use crate::rng::rand_f32;
use crate::scene::pathtrace::PathtraceScene;
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "pathtrace.render",
        doc: "path-traced image (H, W, 3) and variance of the pixel mean; metrics time_s, paths_per_s",
        params: &[],
        run: render_op,
    },
    OpEntry {
        name: "pathtrace.intersect_list",
        doc: "renderer intersection of params.rays ([ox,oy,oz,dx,dy,dz]) with params.shapes: t, hit, index, normal",
        params: &["rays", "shapes"],
        run: intersect_list,
    },
    OpEntry {
        name: "pathtrace.intersect_reference",
        doc: "f64 closed forms (geometric sphere, Cramer quad) for the rays and shapes of intersect_list",
        params: &["rays", "shapes"],
        run: intersect_reference,
    },
    OpEntry {
        name: "pathtrace.self_intersection",
        doc: "acne_fraction: rays spawned at camera hit points that re-hit their own surface at once",
        params: &["rays"],
        run: self_intersection,
    },
    OpEntry {
        name: "pathtrace.bsdf_checks",
        doc: "pdf_integral, albedo, reciprocity_err, weight_err, fresnel_err, chi2_p and chi2_alpha (Sidak) per material and wo",
        params: &["thetas", "samples", "alpha", "roughness"],
        run: bsdf_checks,
    },
    OpEntry {
        name: "pathtrace.furnace",
        doc: "render + mean (3,), z-score of the mean against params.expect, max pixel_err",
        params: &["expect"],
        run: furnace,
    },
    OpEntry {
        name: "pathtrace.convergence",
        doc: "rmse (clamped to [0,1]) vs a ref_spp render over params.spp x params.seeds; log-log slope",
        params: &["spp", "seeds", "ref_spp", "clamp"],
        run: convergence,
    },
    OpEntry {
        name: "pathtrace.fireflies",
        doc: "render + firefly_fraction: pixels whose luminance exceeds 10x their 3x3 median",
        params: &["factor"],
        run: fireflies,
    },
    OpEntry {
        name: "pathtrace.features",
        doc: "render + mean rgb/luminance/(r/g) of named world-space regions of named shapes (params.regions)",
        params: &["regions"],
        run: features,
    },
    OpEntry {
        name: "pathtrace.rmse_vs_reference",
        doc: "render + rmse (clamped [0,1]) and rmse_raw against params.reference (an (H, W, 3) float32 .npy)",
        params: &["reference"],
        run: rmse_vs_reference,
    },
    OpEntry {
        name: "pathtrace.speed_error",
        doc: "seconds and rmse (clamped [0,1] and raw) vs a ref_spp render (or params.reference .npy) per params.spp; plot_image",
        params: &["spp", "ref_spp", "ref_seed", "reference"],
        run: speed_error,
    },
];

pub(super) fn load(ctx: &OpCtx) -> Result<PathtraceScene> {
    crate::scene::pathtrace::parse(ctx.scene()?)
}

fn timed_render(s: &PathtraceScene, p: &RenderParams, ctx: &OpCtx) -> Result<(Image, f64)> {
    if ctx.backend == BackendKind::Gpu {
        return super::pathtrace_gpu::timed_render_gpu(s, p, ctx);
    }
    let cam = s.camera.to_real::<f32>(p.width, p.height);
    let t = Instant::now();
    let img = render(&s.scene, &cam, p, &ctx.budget)?;
    Ok((img, t.elapsed().as_secs_f64()))
}

fn image_outputs(img: &Image, secs: f64, p: &RenderParams, out: &mut Outputs) -> Result<()> {
    let shape = [img.height as usize, img.width as usize];
    out.tensor("image", Tensor::real3(&shape, &img.rgb)?);
    out.tensor("variance", Tensor::real3(&shape, &img.variance)?);
    let paths = img.rgb.len() as f64 * p.spp as f64;
    out.metric("time_s", secs)
        .metric("paths_per_s", paths / secs.max(1e-9));
    out.counter("paths", paths as u64)
        .counter("nonfinite_samples", img.nonfinite);
    Ok(())
}

fn render_op(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    Ok(out)
}

/// Renders `s` with `spp` samples and `seed` (other parameters from the scene).
fn render_with(s: &PathtraceScene, spp: u32, seed: u32, ctx: &OpCtx) -> Result<(Image, f64)> {
    let p = RenderParams {
        spp,
        seed,
        ..s.params
    };
    timed_render(s, &p, ctx)
}

// ---------------------------------------------------------------- geometry

#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
enum ShapeParam {
    Sphere {
        center: [f64; 3],
        radius: f64,
    },
    Quad {
        corner: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
    },
}

fn listed(ctx: &OpCtx) -> Result<(Vec<[f64; 6]>, Vec<ShapeParam>)> {
    let rays: Vec<[f64; 6]> = ctx.param_req("rays")?;
    let shapes: Vec<ShapeParam> = ctx.param_req("shapes")?;
    for (i, r) in rays.iter().enumerate() {
        if r.iter().any(|x| !x.is_finite()) || r[3..].iter().all(|&x| x == 0.0) {
            return Err(Error::invalid(
                format!("{} params.rays[{i}]", ctx.case_id),
                "needs finite numbers and d != 0",
            ));
        }
    }
    Ok((rays, shapes))
}

fn unit(r: &[f64; 6]) -> ([f64; 3], [f64; 3]) {
    let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
    ([r[0], r[1], r[2]], [r[3] / n, r[4] / n, r[5] / n])
}

fn hit_outputs(
    t: Vec<f64>,
    index: Vec<i32>,
    normal: Vec<[f64; 3]>,
    f32_out: bool,
) -> Result<Outputs> {
    let n = [t.len()];
    let hit: Vec<u8> = index.iter().map(|&i| (i >= 0) as u8).collect();
    let mut out = Outputs::default();
    if f32_out {
        out.tensor(
            "t",
            Tensor::real(&n, t.iter().map(|&x| x as f32).collect())?,
        );
        out.tensor(
            "normal",
            Tensor::real3(
                &n,
                &normal
                    .iter()
                    .map(|v| v.map(|x| x as f32))
                    .collect::<Vec<_>>(),
            )?,
        );
    } else {
        out.tensor("t", Tensor::real(&n, t)?);
        out.tensor("normal", Tensor::real3(&n, &normal)?);
    }
    out.tensor("hit", Tensor::from_shape_vec(&n, hit)?);
    out.tensor("index", Tensor::from_shape_vec(&n, index)?);
    Ok(out)
}

/// The renderer's intersection as rendering runs it (`packed`, f32). Misses: t = -1, index = -1,
/// normal = 0.
fn intersect_list(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let (rays, params) = listed(ctx)?;
    let v = |a: [f64; 3]| Vec3A::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let mut shapes = Vec::with_capacity(params.len());
    for (i, sp) in params.iter().enumerate() {
        shapes.push(match *sp {
            ShapeParam::Sphere { center, radius } => Shape::Sphere(Sphere {
                centre: v(center),
                radius: radius as f32,
            }),
            ShapeParam::Quad { corner, u, v: e } => {
                Shape::Quad(Quad::new(v(corner), v(u), v(e)).ok_or_else(|| {
                    Error::invalid(
                        format!("{} params.shapes[{i}]", ctx.case_id),
                        "degenerate quad",
                    )
                })?)
            }
        });
    }
    let packed = crate::pathtrace::packed::Packed::new(&shapes);
    let (mut t, mut index, mut normal) = (vec![], vec![], vec![]);
    for r in &rays {
        let (o, d) = unit(r);
        let (o, d) = (v(o), v(d).normalize());
        match packed.intersect(o, d, f32::INFINITY) {
            Some((th, k)) => {
                let (_, n) = shapes[k].surface(o, d, th);
                t.push(th as f64);
                index.push(k as i32);
                normal.push(n.to_array().map(|x| x as f64));
            }
            None => {
                t.push(-1.0);
                index.push(-1);
                normal.push([0.0; 3]);
            }
        }
    }
    hit_outputs(t, index, normal, true)
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Geometric sphere test in f64: closest approach `tca = (c - o).d`,
/// squared miss distance `m2 = |c - o|^2 - tca^2`, half chord
/// `thc = sqrt(r^2 - m2)`; roots `tca -+ thc`. Quad: solve
/// `o + t d = corner + a u + b v` by Cramer's rule on the 3x3 system.
/// Written apart from `pathtrace::shapes` so that each checks the other.
fn reference_hit(sp: &ShapeParam, o: [f64; 3], d: [f64; 3]) -> Option<(f64, [f64; 3])> {
    match *sp {
        ShapeParam::Sphere { center, radius } => {
            let l = sub(center, o);
            let tca = dot(l, d);
            let m2 = dot(l, l) - tca * tca;
            if m2 > radius * radius {
                return None;
            }
            let thc = (radius * radius - m2).max(0.0).sqrt();
            let t = [tca - thc, tca + thc].into_iter().find(|&t| t > 0.0)?;
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            Some((t, sub(p, center).map(|x| x / radius)))
        }
        ShapeParam::Quad { corner, u, v } => {
            // [u v -d] [a b t]^T = o - corner.
            let rhs = sub(o, corner);
            let md = d.map(|x| -x);
            let det = dot(u, cross(v, md));
            if det == 0.0 {
                return None;
            }
            let a = dot(rhs, cross(v, md)) / det;
            let b = dot(u, cross(rhs, md)) / det;
            let t = dot(u, cross(v, rhs)) / det;
            if !(t > 0.0 && (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)) {
                return None;
            }
            let n = cross(u, v);
            let nl = dot(n, n).sqrt();
            Some((t, n.map(|x| x / nl)))
        }
    }
}

fn intersect_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, shapes) = listed(ctx)?;
    let (mut t, mut index, mut normal) = (vec![], vec![], vec![]);
    for r in &rays {
        let (o, d) = unit(r);
        let best = shapes
            .iter()
            .enumerate()
            .filter_map(|(k, sp)| reference_hit(sp, o, d).map(|(t, n)| (t, k, n)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        match best {
            Some((th, k, n)) => {
                t.push(th);
                index.push(k as i32);
                normal.push(n);
            }
            None => {
                t.push(-1.0);
                index.push(-1);
                normal.push([0.0; 3]);
            }
        }
    }
    hit_outputs(t, index, normal, false)
}

/// For `params.rays` random camera rays of the scene (pixel and direction
/// from `rand(seed, i, 0, dim)`): at the first hit, spawn one ray on the
/// viewer's side (reflection) and one through the surface (refraction) and
/// count "acne": a reflected ray that hits the same shape (planes and convex
/// spheres cannot), or a transmitted ray into a sphere that meets it again
/// on the entry side instead of the far side.
fn self_intersection(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = load(ctx)?;
    let n: u32 = ctx.param_or("rays", 100_000)?;
    let (w, h) = (s.params.width, s.params.height);
    let cam = s.camera.to_real::<f32>(w, h);
    let shapes = s.scene.shapes();
    let (mut tested, mut acne) = (0u64, 0u64);
    for i in 0..n {
        let r = |k| rand_f32(ctx.seed, i, 0, k);
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
    let mut out = Outputs::default();
    out.tensor(
        "acne_fraction",
        Tensor::scalar(acne as f64 / tested.max(1) as f64),
    );
    out.counter("rays_tested", tested).counter("acne", acne);
    Ok(out)
}

// ---------------------------------------------------------------- BSDFs

fn dir(theta: f64, phi: f64) -> Vec3A {
    Vec3A::new(
        (theta.sin() * phi.cos()) as f32,
        (theta.sin() * phi.sin()) as f32,
        theta.cos() as f32,
    )
}

/// Midpoint quadrature over the sphere, `n` x `2n` cells in (theta, phi).
fn sphere_quad(n: usize, g: impl Fn(Vec3A) -> f64) -> f64 {
    let pi = std::f64::consts::PI;
    let (dt, dp) = (pi / n as f64, pi / n as f64);
    let mut sum = 0.0;
    for i in 0..n {
        let th = (i as f64 + 0.5) * dt;
        for j in 0..2 * n {
            sum += g(dir(th, (j as f64 + 0.5) * dp)) * th.sin() * dt * dp;
        }
    }
    sum
}

/// Fresnel reflectance of a smooth dielectric by the angle forms
/// `rs = -sin(i - t) / sin(i + t)`, `rp = tan(i - t) / tan(i + t)` (f64;
/// normal incidence `((n1 - n2) / (n1 + n2))^2`; 1 past the critical angle).
fn fresnel_angles(theta_i: f64, n1: f64, n2: f64) -> f64 {
    let st = n1 / n2 * theta_i.sin();
    if st >= 1.0 {
        return 1.0;
    }
    if theta_i == 0.0 {
        return ((n1 - n2) / (n1 + n2)).powi(2);
    }
    let tt = st.asin();
    let rs = -(theta_i - tt).sin() / (theta_i + tt).sin();
    let rp = (theta_i - tt).tan() / (theta_i + tt).tan();
    0.5 * (rs * rs + rp * rp)
}

/// Checks every sampled lobe at each `wo` polar angle in `params.thetas`
/// (degrees): Lambertian (albedo 1) and rough conductor (reflectance 1,
/// alpha `params.roughness`, default 0.1) rows, then one dielectric row per
/// angle (from outside, then from inside the glass).
fn bsdf_checks(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let thetas: Vec<f64> = ctx.param_or("thetas", vec![0.0, 30.0, 60.0, 85.0])?;
    let n: u32 = ctx.param_or("samples", 500_000)?;
    let alpha: f64 = ctx.param_or("alpha", 0.01)?;
    let rough: f32 = ctx.param_or("roughness", 0.1)?;
    if thetas.iter().any(|t| !(0.0..90.0).contains(t)) || n == 0 {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "thetas must lie in [0, 90) degrees and samples >= 1",
        ));
    }
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
        for &th in &thetas {
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
                let r = |k| rand_f32(ctx.seed ^ seed_row, i, 0, k);
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
        for &th in &thetas {
            seed_row += 1;
            let mut wo = dir(th.to_radians(), 0.4);
            wo.z *= side;
            let f_ref = fresnel_angles(th.to_radians(), n1, n2);
            let mut refl = 0u64;
            for i in 0..n {
                if let Some(s) =
                    glass.sample(wo, rand_f32(ctx.seed ^ seed_row, i, 0, 0), [0.5, 0.5])
                {
                    if s.wi.z * wo.z > 0.0 {
                        refl += 1;
                    }
                }
            }
            let f_code = crate::pathtrace::bsdf::fresnel_dielectric(
                wo.z.abs(),
                if side > 0.0 { 1.5 } else { 1.0 / 1.5 },
            )
            .0;
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
    let a = sidak(alpha, k);
    let rows = [pdf_int.len()];
    let mut out = Outputs::default();
    out.tensor("pdf_integral", Tensor::real(&rows, pdf_int)?);
    out.tensor("albedo", Tensor::real(&rows, albedo)?);
    out.tensor("reciprocity_err", Tensor::real(&rows, recip)?);
    out.tensor("weight_err", Tensor::real(&rows, werr)?);
    out.tensor("fresnel_err", Tensor::scalar(fres_err));
    out.tensor("chi2_p", Tensor::real(&[k], chi_p)?);
    out.tensor("chi2_alpha", Tensor::real(&[k], vec![a; k])?);
    out.counter("tests", k as u64)
        .counter("samples_per_test", n as u64);
    Ok(out)
}

// ---------------------------------------------------------------- images

/// Image mean over pixels (per channel) and its standard error from the
/// per-pixel variance of the mean: `se = sqrt(sum var_i) / N`.
fn image_mean(img: &Image) -> ([f64; 3], [f64; 3]) {
    let n = img.rgb.len() as f64;
    let (mut m, mut v) = ([0.0; 3], [0.0; 3]);
    for (p, q) in img.rgb.iter().zip(&img.variance) {
        for c in 0..3 {
            m[c] += p[c] as f64;
            v[c] += q[c] as f64;
        }
    }
    (m.map(|x| x / n), v.map(|x| x.sqrt() / n))
}

fn furnace(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let expect: [f64; 3] = ctx.param_req("expect")?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let (mean, se) = image_mean(&img);
    let z: Vec<f64> = (0..3)
        .map(|c| (mean[c] - expect[c]) / se[c].max(1e-7))
        .collect();
    let err = img
        .rgb
        .iter()
        .flat_map(|p| (0..3).map(move |c| (p[c] as f64 - expect[c]).abs()))
        .fold(0.0, f64::max);
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor("mean", Tensor::real(&[3], mean.to_vec())?);
    out.tensor("z", Tensor::real(&[3], z)?);
    out.tensor("pixel_err", Tensor::scalar(err));
    Ok(out)
}

/// Mean squared error between two images over pixels and channels, values
/// clamped to [0, 1] first when `clamp`.
fn mse(a: &Image, b: &Image, clamp: bool) -> f64 {
    let f = |x: f32| {
        if clamp {
            x.clamp(0.0, 1.0) as f64
        } else {
            x as f64
        }
    };
    let s: f64 = a
        .rgb
        .iter()
        .zip(&b.rgb)
        .flat_map(|(p, q)| (0..3).map(move |c| (f(p[c]) - f(q[c])).powi(2)))
        .sum();
    s / (3 * a.rgb.len()) as f64
}

/// Mean variance of the reference's pixel means: what its own noise adds
/// to an MSE measured against it (subtracted; exact for unclamped values).
fn ref_noise(r: &Image) -> f64 {
    r.variance
        .iter()
        .flat_map(|v| v.iter().map(|&x| x as f64))
        .sum::<f64>()
        / (3 * r.variance.len()) as f64
}

/// Least-squares slope of `ln y` against `ln x`.
fn loglog_slope(x: &[f64], y: &[f64]) -> f64 {
    let lx: Vec<f64> = x.iter().map(|v| v.ln()).collect();
    let ly: Vec<f64> = y.iter().map(|v| v.max(1e-300).ln()).collect();
    let n = lx.len() as f64;
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = lx.iter().map(|a| (a - mx) * (a - mx)).sum();
    if sxx > 0.0 {
        sxy / sxx
    } else {
        0.0
    }
}

/// RMSE against a `ref_spp` render (seed `2^31`, independent of the test
/// seeds) at each spp, MSE averaged over `seeds` (correlated samples across
/// spp or seeds would bend the slope away from -0.5). With `clamp: false`
/// the reference's own noise is subtracted from each MSE.
fn convergence(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let seeds: Vec<u32> = ctx.param_or("seeds", vec![1, 2, 3, 4])?;
    let ref_spp: u32 = ctx.param_or("ref_spp", 4096)?;
    let clamp: bool = ctx.param_or("clamp", true)?;
    if spps.len() < 2 || seeds.is_empty() || spps.contains(&0) {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "need >= 2 spp values (all >= 1) and >= 1 seed",
        ));
    }
    let t = Instant::now();
    let (reference, _) = render_with(&s, ref_spp, 1 << 31, ctx)?;
    let noise = if clamp { 0.0 } else { ref_noise(&reference) };
    let mut rmse = Vec::with_capacity(spps.len());
    for &spp in &spps {
        let mut acc = 0.0;
        for &seed in &seeds {
            let (img, _) = render_with(&s, spp, seed, ctx)?;
            acc += (mse(&img, &reference, clamp) - noise).max(0.0);
        }
        rmse.push((acc / seeds.len() as f64).sqrt());
    }
    let x: Vec<f64> = spps.iter().map(|&v| v as f64).collect();
    let slope = loglog_slope(&x, &rmse);
    let mut out = Outputs::default();
    out.tensor("spp", Tensor::real(&[x.len()], x)?);
    out.tensor("rmse", Tensor::real(&[rmse.len()], rmse)?);
    out.tensor("slope", Tensor::scalar(slope));
    out.metric("time_s", t.elapsed().as_secs_f64());
    Ok(out)
}

fn luminance(p: &[f32; 3]) -> f32 {
    0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
}

/// Fraction of pixels whose luminance exceeds `factor` (10) times the
/// median of their 3x3 neighbourhood (itself included; clipped at borders).
fn firefly_fraction(img: &Image, factor: f32) -> f64 {
    let (w, h) = (img.width as i64, img.height as i64);
    let lum: Vec<f32> = img.rgb.iter().map(luminance).collect();
    let mut count = 0u64;
    let mut nb = Vec::with_capacity(9);
    for y in 0..h {
        for x in 0..w {
            nb.clear();
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (u, v) = (x + dx, y + dy);
                    if u >= 0 && v >= 0 && u < w && v < h {
                        nb.push(lum[(v * w + u) as usize]);
                    }
                }
            }
            nb.sort_by(f32::total_cmp);
            let med = nb[nb.len() / 2];
            if lum[(y * w + x) as usize] > factor * med {
                count += 1;
            }
        }
    }
    count as f64 / (w * h) as f64
}

fn fireflies(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = load(ctx)?;
    let factor: f32 = ctx.param_or("factor", 10.0)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor(
        "firefly_fraction",
        Tensor::scalar(firefly_fraction(&img, factor)),
    );
    Ok(out)
}

/// A region: the pixels whose centre ray first hits shape `shape` at a
/// point within `[r_min, r_max]` of `center` (world space).
#[derive(Clone, Debug, Deserialize)]
#[serde(deny_unknown_fields)]
struct Region {
    shape: String,
    center: [f32; 3],
    #[serde(default)]
    r_min: f32,
    r_max: f32,
}

/// Per region: `<name>` mean rgb (3,), `<name>_lum` its luminance,
/// `<name>_r_over_g` red over green; counter `<name>_pixels`.
fn features(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = load(ctx)?;
    let regions: BTreeMap<String, Region> = ctx.param_req("regions")?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
    let hits = first_hits(&s.scene, &cam, s.params.width, s.params.height);
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    for (name, r) in &regions {
        let at = format!("{} params.regions.{name}", ctx.case_id);
        let k = s
            .names
            .iter()
            .position(|n| *n == r.shape)
            .ok_or_else(|| Error::invalid(&at, format!("no shape named {:?}", r.shape)))?;
        let c = Vec3A::from_array(r.center);
        let (mut sum, mut count) = ([0.0f64; 3], 0u64);
        for (i, &(idx, p)) in hits.iter().enumerate() {
            let dist = (Vec3A::from_array(p) - c).length();
            if idx == k as i32 && dist >= r.r_min && dist <= r.r_max {
                for ch in 0..3 {
                    sum[ch] += img.rgb[i][ch] as f64;
                }
                count += 1;
            }
        }
        if count == 0 {
            return Err(Error::invalid(
                at,
                "the region covers no pixel at this image size",
            ));
        }
        let m = sum.map(|x| x / count as f64);
        out.tensor(name, Tensor::real(&[3], m.to_vec())?);
        out.tensor(
            &format!("{name}_lum"),
            Tensor::scalar(0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]),
        );
        out.tensor(
            &format!("{name}_r_over_g"),
            Tensor::scalar(m[0] / m[1].max(1e-12)),
        );
        out.counter(&format!("{name}_pixels"), count);
    }
    Ok(out)
}

/// Reads an (H, W, 3) float32 `.npy` reference image of the scene's size.
fn read_reference(ctx: &OpCtx, file: &str, w: usize, h: usize) -> Result<Image> {
    let path = ctx.resolve(file);
    let t = Tensor::read_npy_checked(&path, &["float32"], &[Some(h), Some(w), Some(3)])?;
    let v = t.to_f64_vec();
    if v.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid(
            path.display().to_string(),
            "reference has NaN or Inf",
        ));
    }
    let rgb = v
        .chunks_exact(3)
        .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
        .collect();
    Ok(Image {
        width: w as u32,
        height: h as u32,
        rgb,
        variance: vec![[0.0; 3]; w * h],
        nonfinite: 0,
    })
}

/// The acceptance measure: RMSE of linear radiance clamped to [0, 1]
/// against an independent renderer's converged image (`params.reference`,
/// relative to the manifest), and the unclamped RMSE.
fn rmse_vs_reference(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let file: String = ctx.param_req("reference")?;
    let reference = read_reference(
        ctx,
        &file,
        s.params.width as usize,
        s.params.height as usize,
    )?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor("rmse", Tensor::scalar(mse(&img, &reference, true).sqrt()));
    out.tensor(
        "rmse_raw",
        Tensor::scalar(mse(&img, &reference, false).sqrt()),
    );
    Ok(out)
}

/// Speed against error: for each spp, the seconds of one render and its
/// RMSE against a reference, linear radiance clamped to [0, 1] (`rmse`, as
/// the acceptance measures) and raw (`rmse_raw`, the reference's own noise
/// subtracted when it is rendered here). The reference is a `ref_spp` render
/// (seed `ref_seed`) or, with `params.reference`, an (H, W, 3) `.npy` file
/// (relative to the manifest). Metrics `time_s_<spp>`; `plot_image` draws
/// log RMSE against log seconds (see [`plot_loglog`]).
fn speed_error(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let ref_spp: u32 = ctx.param_or("ref_spp", 4096)?;
    let ref_seed: u32 = ctx.param_or("ref_seed", 1 << 31)?;
    let mut out = Outputs::default();
    let (w, h) = (s.params.width as usize, s.params.height as usize);
    let (reference, noise) = match ctx.param::<String>("reference")? {
        Some(file) => (read_reference(ctx, &file, w, h)?, 0.0),
        None => {
            let (r, secs) = render_with(&s, ref_spp, ref_seed, ctx)?;
            out.metric("ref_time_s", secs);
            let noise = ref_noise(&r);
            (r, noise)
        }
    };
    let (mut secs, mut rmse, mut raw) = (vec![], vec![], vec![]);
    for &spp in &spps {
        let (img, t) = render_with(&s, spp, s.params.seed, ctx)?;
        secs.push(t);
        rmse.push(mse(&img, &reference, true).sqrt());
        raw.push((mse(&img, &reference, false) - noise).max(0.0).sqrt());
        out.metric(&format!("time_s_{spp}"), t);
    }
    let k = [spps.len()];
    out.tensor(
        "plot_image",
        Tensor::real3(&[PLOT_H, PLOT_W], &plot_loglog(&secs, &rmse))?,
    );
    out.tensor(
        "spp",
        Tensor::real(&k, spps.iter().map(|&v| v as f64).collect())?,
    );
    out.tensor("seconds", Tensor::real(&k, secs)?);
    out.tensor("rmse", Tensor::real(&k, rmse)?);
    out.tensor("rmse_raw", Tensor::real(&k, raw)?);
    Ok(out)
}

const PLOT_W: usize = 480;
const PLOT_H: usize = 360;

/// A log-log line plot (linear RGB, white background) of `ys` against `xs`:
/// axes span whole decades around the data, light grey lines mark each
/// decade, the data are a blue polyline with square markers, and a dashed
/// grey line of slope -1/2 through the first point shows the ideal Monte
/// Carlo rate. Axis labels live in the report that shows the plot.
fn plot_loglog(xs: &[f64], ys: &[f64]) -> Vec<[f32; 3]> {
    let mut img = vec![[1.0f32; 3]; PLOT_W * PLOT_H];
    let lx: Vec<f64> = xs.iter().map(|v| v.max(1e-12).log10()).collect();
    let ly: Vec<f64> = ys.iter().map(|v| v.max(1e-12).log10()).collect();
    let span = |v: &[f64]| {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min).floor();
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil();
        if lo.is_finite() && hi > lo {
            (lo, hi)
        } else {
            (-1.0, 1.0)
        }
    };
    let ((x0, x1), (y0, y1)) = (span(&lx), span(&ly));
    let m = 20.0;
    let px = |x: f64| m + (x - x0) / (x1 - x0) * (PLOT_W as f64 - 2.0 * m);
    let py = |y: f64| PLOT_H as f64 - m - (y - y0) / (y1 - y0) * (PLOT_H as f64 - 2.0 * m);
    let put = |img: &mut Vec<[f32; 3]>, x: f64, y: f64, c: [f32; 3]| {
        let (u, v) = (x.round(), y.round());
        if u >= 0.0 && v >= 0.0 && (u as usize) < PLOT_W && (v as usize) < PLOT_H {
            img[v as usize * PLOT_W + u as usize] = c;
        }
    };
    let grey = [0.8f32; 3];
    for d in (x0 as i32)..=(x1 as i32) {
        for v in 0..PLOT_H {
            put(&mut img, px(d as f64), v as f64, grey);
        }
    }
    for d in (y0 as i32)..=(y1 as i32) {
        for u in 0..PLOT_W {
            put(&mut img, u as f64, py(d as f64), grey);
        }
    }
    let line =
        |img: &mut Vec<[f32; 3]>, a: (f64, f64), b: (f64, f64), c: [f32; 3], dashed: bool| {
            let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) as usize).max(1);
            for i in 0..=n {
                if dashed && (i / 6) % 2 == 1 {
                    continue;
                }
                let t = i as f64 / n as f64;
                put(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
            }
        };
    if let (Some(&fx), Some(&fy)) = (lx.first(), ly.first()) {
        let y_at = |x: f64| fy - 0.5 * (x - fx);
        line(
            &mut img,
            (px(x0), py(y_at(x0))),
            (px(x1), py(y_at(x1))),
            [0.45; 3],
            true,
        );
    }
    let blue = [0.05f32, 0.15, 0.8];
    for i in 1..lx.len() {
        line(
            &mut img,
            (px(lx[i - 1]), py(ly[i - 1])),
            (px(lx[i]), py(ly[i])),
            blue,
            false,
        );
    }
    for (&x, &y) in lx.iter().zip(&ly) {
        for du in -3..=3 {
            for dv in -3..=3 {
                put(&mut img, px(x) + du as f64, py(y) + dv as f64, blue);
            }
        }
    }
    img
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fresnel_angle_form_matches_normal_incidence_and_tir() {
        assert!((fresnel_angles(0.0, 1.0, 1.5) - 0.04).abs() < 1e-15);
        assert!((fresnel_angles(1e-4, 1.0, 1.5) - 0.04).abs() < 1e-8);
        assert_eq!(fresnel_angles(1.0, 1.5, 1.0), 1.0);
    }

    #[test]
    fn reference_hits_agree_on_a_centre_hit_and_a_quad() {
        let s = ShapeParam::Sphere {
            center: [0.0; 3],
            radius: 1.0,
        };
        assert_eq!(
            reference_hit(&s, [0.0, 0.0, 5.0], [0.0, 0.0, -1.0])
                .unwrap()
                .0,
            4.0
        );
        let q = ShapeParam::Quad {
            corner: [-1.0, -1.0, 0.0],
            u: [2.0, 0.0, 0.0],
            v: [0.0, 2.0, 0.0],
        };
        let (t, n) = reference_hit(&q, [0.5, 0.5, 2.0], [0.0, 0.0, -1.0]).unwrap();
        assert_eq!((t, n), (2.0, [0.0, 0.0, 1.0]));
    }

    #[test]
    fn fireflies_are_pixels_far_above_their_neighbourhood_median() {
        let mut img = Image {
            width: 4,
            height: 4,
            rgb: vec![[0.1; 3]; 16],
            variance: vec![[0.0; 3]; 16],
            nonfinite: 0,
        };
        assert_eq!(firefly_fraction(&img, 10.0), 0.0);
        img.rgb[5] = [5.0; 3];
        assert_eq!(firefly_fraction(&img, 10.0), 1.0 / 16.0);
    }

    #[test]
    fn loglog_slope_of_inverse_sqrt_is_minus_half() {
        let x = [4.0, 16.0, 64.0, 256.0];
        let y: Vec<f64> = x.iter().map(|v: &f64| 3.0 / v.sqrt()).collect();
        assert!((loglog_slope(&x, &y) + 0.5).abs() < 1e-12);
    }
}
