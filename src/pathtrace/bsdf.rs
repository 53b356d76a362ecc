//! Materials (seed 004 "Material System"; SCENES.md "Cornell box"): a closed
//! enum with one `match` per method, every formula in local shading space
//! where `z` is the surface's unit geometric normal (outward for spheres,
//! `normalize(u x v)` for quads). Directions `wo` (towards the viewer) and
//! `wi` (towards the light) are unit vectors pointing away from the surface.
//!
//! Reflective materials are two-sided: they mirror `wo` and `wi` into the
//! hemisphere of `wo` (`s = sign(wo.z)`) and reflect only when `wi` lies on
//! that side too.
//!
//! | material | f(wo, wi) | sampling | pdf(wo, wi) |
//! | --- | --- | --- | --- |
//! | Lambertian | `albedo / pi` | cosine hemisphere | `|wi.z| / pi` |
//! | rough conductor | `F D(h) G1(wo) G1(wi) / (4 |wo.z| |wi.z|)`, F = reflectance | GGX visible normals (Heitz 2018) | `G1(wo) D(h) / (4 |wo.z|)` |
//! | smooth dielectric | delta: reflect with Fresnel F, refract with 1 - F | choose by F | delta |
//! | emitter | 0 (black both sides) | none | 0 |
//!
//! GGX (Trowbridge-Reitz) with `h = normalize(wo + wi)`:
//! `D(h) = a^2 / (pi (h.z^2 (a^2 - 1) + 1)^2)`, Smith
//! `G1(w) = 2 |w.z| / (|w.z| + sqrt(a^2 + (1 - a^2) w.z^2))`, separable
//! `G = G1(wi) G1(wo)`. The visible-normal sampler may return `wi` below the
//! surface (a sample worth 0); the pdf above is its density over the whole
//! sphere and integrates to 1 there.
//!
//! Dielectric: exact unpolarised Fresnel for `eta = n_t / n_i`:
//! `rs = (c - eta ct) / (c + eta ct)`, `rp = (eta c - ct) / (eta c + ct)`,
//! `F = (rs^2 + rp^2) / 2`, `F = 1` (total internal reflection) when
//! `sin^2 t = (1 - c^2) / eta^2 >= 1`. Refraction carries radiance scaling
//! `1 / eta^2` (transport of radiance, Veach 1997 §5.2).
//!
//! WGSL twin (GPU issue to come): the same kind codes and formulas.

use std::f32::consts::{FRAC_1_PI, PI};

use glam::Vec3A;

/// A surface material.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Material {
    Lambertian {
        albedo: Vec3A,
    },
    /// GGX rough conductor with constant Fresnel reflectance.
    RoughConductor {
        alpha: f32,
        reflectance: Vec3A,
    },
    /// Smooth dielectric: `ior` inside (the side opposite the normal), 1 outside.
    Dielectric {
        ior: f32,
    },
    /// A one-sided area emitter: radiance towards `+z`, black otherwise, no
    /// reflection on either side.
    Emitter {
        radiance: Vec3A,
    },
}

/// One sampled direction.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BsdfSample {
    /// Sampled `wi` (local).
    pub wi: Vec3A,
    /// `f |wi.z| / pdf` (for a delta lobe: the lobe's weight).
    pub weight: Vec3A,
    /// Solid-angle density of `wi` (unused for delta lobes).
    pub pdf: f32,
    /// Whether `wi` came from a delta (specular) lobe.
    pub delta: bool,
    /// `eta^2` of a refraction (1 otherwise): the radiance scaling to undo
    /// when deciding Russian roulette (Mitsuba's `eta` tracking).
    pub eta2: f32,
}

impl Material {
    /// Whether every lobe is a delta (no light sampling there).
    #[inline]
    pub fn is_delta(&self) -> bool {
        matches!(self, Material::Dielectric { .. })
    }

    /// Whether the material scatters light at all.
    #[inline]
    pub fn scatters(&self) -> bool {
        !matches!(self, Material::Emitter { .. })
    }

    /// `f(wo, wi)` (no cosine). Zero for delta lobes and emitters.
    #[inline]
    pub fn eval(&self, wo: Vec3A, wi: Vec3A) -> Vec3A {
        if wo.z * wi.z <= 0.0 {
            return Vec3A::ZERO;
        }
        match *self {
            Material::Lambertian { albedo } => albedo * FRAC_1_PI,
            Material::RoughConductor { alpha, reflectance } => {
                let (o, i) = (wo.z.abs(), wi.z.abs());
                let h = upper(wo + wi).normalize();
                reflectance
                    * (ggx_d(h.z, alpha) * smith_g1(o, alpha) * smith_g1(i, alpha) / (4.0 * o * i))
            }
            Material::Dielectric { .. } | Material::Emitter { .. } => Vec3A::ZERO,
        }
    }

    /// Solid-angle density with which [`Material::sample`] returns `wi`.
    #[inline]
    pub fn pdf(&self, wo: Vec3A, wi: Vec3A) -> f32 {
        match *self {
            Material::Lambertian { .. } => {
                if wo.z * wi.z <= 0.0 {
                    0.0
                } else {
                    wi.z.abs() * FRAC_1_PI
                }
            }
            Material::RoughConductor { alpha, .. } => {
                let s = sign(wo.z);
                let (o, i) = (wo * s, wi * s);
                let hs = o + i;
                if o.z <= 0.0 || hs.length_squared() == 0.0 {
                    return 0.0;
                }
                let h = hs.normalize();
                if h.z <= 0.0 || o.dot(h) <= 0.0 {
                    return 0.0;
                }
                smith_g1(o.z, alpha) * ggx_d(h.z, alpha) / (4.0 * o.z)
            }
            Material::Dielectric { .. } | Material::Emitter { .. } => 0.0,
        }
    }

    /// Samples `wi` from `u_lobe` (lobe choice) and `u` (direction); `None`
    /// when the material does not scatter or the sample is worth 0.
    #[inline]
    pub fn sample(&self, wo: Vec3A, u_lobe: f32, u: [f32; 2]) -> Option<BsdfSample> {
        match *self {
            Material::Lambertian { albedo } => {
                let l = cosine_hemisphere(u);
                let wi = Vec3A::new(l.x, l.y, l.z * sign(wo.z));
                Some(BsdfSample {
                    wi,
                    weight: albedo,
                    pdf: l.z * FRAC_1_PI,
                    delta: false,
                    eta2: 1.0,
                })
            }
            Material::RoughConductor { alpha, reflectance } => {
                let s = sign(wo.z);
                let o = wo * s;
                if o.z <= 0.0 {
                    return None;
                }
                let h = sample_ggx_vndf(o, alpha, u);
                let i = 2.0 * o.dot(h) * h - o;
                if i.z <= 0.0 {
                    return None;
                }
                let pdf = smith_g1(o.z, alpha) * ggx_d(h.z, alpha) / (4.0 * o.z);
                let weight = reflectance * smith_g1(i.z, alpha);
                Some(BsdfSample {
                    wi: i * s,
                    weight,
                    pdf,
                    delta: false,
                    eta2: 1.0,
                })
            }
            Material::Dielectric { ior } => {
                let c = wo.z.abs();
                let eta = if wo.z > 0.0 { ior } else { 1.0 / ior };
                let (f, ct) = fresnel_dielectric(c, eta);
                if u_lobe < f {
                    let wi = Vec3A::new(-wo.x, -wo.y, wo.z);
                    Some(BsdfSample {
                        wi,
                        weight: Vec3A::ONE,
                        pdf: 0.0,
                        delta: true,
                        eta2: 1.0,
                    })
                } else {
                    let wi = Vec3A::new(-wo.x / eta, -wo.y / eta, -sign(wo.z) * ct);
                    let inv = 1.0 / (eta * eta);
                    Some(BsdfSample {
                        wi,
                        weight: Vec3A::splat(inv),
                        pdf: 0.0,
                        delta: true,
                        eta2: eta * eta,
                    })
                }
            }
            Material::Emitter { .. } => None,
        }
    }

    /// Radiance leaving the surface towards `wo` (local): the emitter's
    /// radiance on its front (`wo.z > 0`), 0 everywhere else.
    #[inline]
    pub fn emitted(&self, wo: Vec3A) -> Vec3A {
        match *self {
            Material::Emitter { radiance } if wo.z > 0.0 => radiance,
            _ => Vec3A::ZERO,
        }
    }
}

#[inline]
fn sign(x: f32) -> f32 {
    if x < 0.0 {
        -1.0
    } else {
        1.0
    }
}

/// `v` mirrored into the upper hemisphere (z >= 0).
#[inline]
fn upper(v: Vec3A) -> Vec3A {
    Vec3A::new(v.x, v.y, v.z.abs())
}

/// GGX normal distribution `D(h) = a^2 / (pi (cos^2 (a^2 - 1) + 1)^2)` for
/// `cos = h.z > 0` (0 otherwise).
#[inline]
pub fn ggx_d(cos_h: f32, alpha: f32) -> f32 {
    if cos_h <= 0.0 {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let k = cos_h * cos_h * (a2 - 1.0) + 1.0;
    a2 / (PI * k * k)
}

/// Smith masking for GGX, `G1 = 2 c / (c + sqrt(a^2 + (1 - a^2) c^2))`, `c = |w.z|`.
#[inline]
pub fn smith_g1(cos: f32, alpha: f32) -> f32 {
    let c = cos.abs();
    let a2 = alpha * alpha;
    2.0 * c / (c + (a2 + (1.0 - a2) * c * c).sqrt())
}

/// Exact dielectric Fresnel reflectance for incidence cosine `c` in [0, 1]
/// and relative index `eta = n_t / n_i`: `(F, cos_t)`; `(1, 0)` under total
/// internal reflection.
#[inline]
pub fn fresnel_dielectric(c: f32, eta: f32) -> (f32, f32) {
    let sin2_t = (1.0 - c * c) / (eta * eta);
    if sin2_t >= 1.0 {
        return (1.0, 0.0);
    }
    let ct = (1.0 - sin2_t).sqrt();
    let rs = (c - eta * ct) / (c + eta * ct);
    let rp = (eta * c - ct) / (eta * c + ct);
    (0.5 * (rs * rs + rp * rp), ct)
}

/// `(sin, cos)` of `2 pi u` for `u` in [0, 1], branch-free (the same
/// operations per lane in the eight-lane path, `wave8`): `x = 4 u`, quadrant
/// `q = floor(x + 1/2)`, `t = (x - q) pi/2` in [-pi/4, pi/4], Taylor
/// polynomials of sin (degree 9) and cos (degree 8) in `t` (truncation
/// below 3e-8), rotated by `q` quarter turns. Plain multiplies and adds
/// (no `mul_add`), so every target rounds alike. Within 3e-7 of libm.
#[inline(always)]
pub fn sin_cos_2pi(u: f32) -> (f32, f32) {
    let x = 4.0 * u;
    let q = (x + 0.5).floor();
    let t = (x - q) * std::f32::consts::FRAC_PI_2;
    let t2 = t * t;
    let s = t + t
        * t2
        * (-1.0 / 6.0 + t2 * (1.0 / 120.0 + t2 * (-1.0 / 5040.0 + t2 * (1.0 / 362_880.0))));
    let c = 1.0 + t2 * (-0.5 + t2 * (1.0 / 24.0 + t2 * (-1.0 / 720.0 + t2 * (1.0 / 40_320.0))));
    let qi = q as i32;
    let (a, b) = if qi & 1 != 0 { (c, s) } else { (s, c) };
    let a = if qi & 2 != 0 { -a } else { a };
    let b = if (qi + 1) & 2 != 0 { -b } else { b };
    (a, b)
}

/// Cosine-weighted direction on the upper hemisphere: `r = sqrt(u0)`,
/// `phi = 2 pi u1`, `z = sqrt(1 - u0)` (> 0 for u0 in [0, 1)).
#[inline]
pub fn cosine_hemisphere(u: [f32; 2]) -> Vec3A {
    let r = u[0].sqrt();
    let (s, c) = sin_cos_2pi(u[1]);
    Vec3A::new(r * c, r * s, (1.0 - u[0]).max(0.0).sqrt())
}

/// A GGX visible normal for `wo` (upper hemisphere), Heitz 2018 ("Sampling
/// the GGX Distribution of Visible Normals", JCGT 7(4)), listing 1.
#[inline]
pub fn sample_ggx_vndf(wo: Vec3A, alpha: f32, u: [f32; 2]) -> Vec3A {
    let vh = Vec3A::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = if lensq > 0.0 {
        Vec3A::new(-vh.y, vh.x, 0.0) / lensq.sqrt()
    } else {
        Vec3A::X
    };
    let t2 = vh.cross(t1);
    let r = u[0].sqrt();
    let (sp, cp) = sin_cos_2pi(u[1]);
    let p1 = r * cp;
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * (1.0 - p1 * p1).max(0.0).sqrt() + s * r * sp;
    let nh = p1 * t1 + p2 * t2 + (1.0 - p1 * p1 - p2 * p2).max(0.0).sqrt() * vh;
    Vec3A::new(alpha * nh.x, alpha * nh.y, nh.z.max(0.0)).normalize()
}

/// An orthonormal frame with `n` as its z axis (Duff et al. 2017, branchless).
#[derive(Clone, Copy, Debug)]
pub struct Frame {
    pub t: Vec3A,
    pub b: Vec3A,
    pub n: Vec3A,
}

impl Frame {
    #[inline]
    pub fn new(n: Vec3A) -> Frame {
        let s = 1.0f32.copysign(n.z);
        let a = -1.0 / (s + n.z);
        let b = n.x * n.y * a;
        Frame {
            t: Vec3A::new(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
            b: Vec3A::new(b, s + n.y * n.y * a, -n.y),
            n,
        }
    }
    #[inline]
    pub fn to_local(&self, v: Vec3A) -> Vec3A {
        Vec3A::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
    #[inline]
    pub fn to_world(&self, v: Vec3A) -> Vec3A {
        v.x * self.t + v.y * self.b + v.z * self.n
    }
}

#[cfg(test)]
mod tests {
    use std::f32::consts::TAU;

    use super::*;
    use crate::rng::rand_f32;

    fn dir(theta: f32, phi: f32) -> Vec3A {
        Vec3A::new(
            theta.sin() * phi.cos(),
            theta.sin() * phi.sin(),
            theta.cos(),
        )
    }

    fn metal() -> Material {
        Material::RoughConductor {
            alpha: 0.1,
            reflectance: Vec3A::new(0.8, 0.8, 0.9),
        }
    }

    /// Midpoint quadrature of `g` over the sphere in (theta, phi).
    fn sphere_integral(n: usize, g: impl Fn(Vec3A) -> f64) -> f64 {
        let (dt, dp) = (
            std::f64::consts::PI / n as f64,
            2.0 * std::f64::consts::PI / (2 * n) as f64,
        );
        let mut sum = 0.0;
        for i in 0..n {
            let th = (i as f64 + 0.5) * dt;
            for j in 0..2 * n {
                let ph = (j as f64 + 0.5) * dp;
                sum += g(dir(th as f32, ph as f32)) * th.sin() * dt * dp;
            }
        }
        sum
    }

    #[test]
    fn polynomial_sin_cos_is_within_3e7_of_libm() {
        let mut worst = 0.0f32;
        for i in 0..=200_000u32 {
            let u = i as f32 / 200_000.0;
            let (s, c) = sin_cos_2pi(u);
            let (rs, rc) = (2.0 * std::f64::consts::PI * u as f64).sin_cos();
            worst = worst.max((s as f64 - rs).abs().max((c as f64 - rc).abs()) as f32);
        }
        assert!(worst < 3e-7, "{worst}");
    }

    #[test]
    fn frame_is_orthonormal_and_round_trips() {
        for i in 0..1000 {
            let n = dir(rand_f32(3, i, 0, 0) * PI, rand_f32(3, i, 0, 1) * 2.0 * PI);
            let f = Frame::new(n);
            assert!(
                f.t.dot(f.b).abs() < 1e-6 && f.t.dot(n).abs() < 1e-6 && f.b.dot(n).abs() < 1e-6
            );
            assert!((f.t.cross(f.b) - n).length() < 1e-5);
            let v = Vec3A::new(0.3, -0.5, 0.8);
            assert!((f.to_world(f.to_local(v)) - v).length() < 1e-6);
        }
    }

    #[test]
    fn pdfs_integrate_to_one_over_the_sphere() {
        for m in [Material::Lambertian { albedo: Vec3A::ONE }, metal()] {
            for th in [0.1f32, 0.8, 1.4] {
                let wo = dir(th, 0.3);
                let i = sphere_integral(800, |wi| m.pdf(wo, wi) as f64);
                assert!((i - 1.0).abs() < 2e-3, "{m:?} theta {th}: {i}");
            }
        }
    }

    #[test]
    fn directional_albedo_is_at_most_one() {
        let white = Material::RoughConductor {
            alpha: 0.1,
            reflectance: Vec3A::ONE,
        };
        for th in [0.0f32, 0.7, 1.3, 1.55] {
            let wo = dir(th, 0.0);
            let a = sphere_integral(800, |wi| (white.eval(wo, wi).x * wi.z.abs()) as f64);
            assert!(a <= 1.0 + 1e-3 && a > 0.8, "theta {th}: {a}");
        }
    }

    #[test]
    fn reflection_is_reciprocal() {
        for i in 0..1000 {
            let a = dir(rand_f32(4, i, 0, 0) * 1.5, rand_f32(4, i, 0, 1) * TAU);
            let b = dir(rand_f32(4, i, 0, 2) * 1.5, rand_f32(4, i, 0, 3) * TAU);
            for m in [
                Material::Lambertian {
                    albedo: Vec3A::splat(0.73),
                },
                metal(),
            ] {
                let (x, y) = (m.eval(a, b), m.eval(b, a));
                assert!(
                    (x - y).abs().max_element() <= 1e-5 * x.max_element().max(1.0),
                    "{x} {y}"
                );
            }
        }
    }

    #[test]
    fn sample_weight_equals_f_cos_over_pdf() {
        for m in [
            Material::Lambertian {
                albedo: Vec3A::splat(0.73),
            },
            metal(),
        ] {
            for i in 0..2000 {
                let wo = dir(rand_f32(5, i, 0, 0) * 1.5, 0.7);
                let Some(s) = m.sample(wo, 0.5, [rand_f32(5, i, 0, 1), rand_f32(5, i, 0, 2)])
                else {
                    continue;
                };
                assert!(
                    (s.pdf - m.pdf(wo, s.wi)).abs() <= 1e-3 * s.pdf,
                    "{} {}",
                    s.pdf,
                    m.pdf(wo, s.wi)
                );
                let w = m.eval(wo, s.wi) * s.wi.z.abs() / s.pdf;
                assert!(
                    (w - s.weight).abs().max_element() <= 1e-3 * w.max_element(),
                    "{w} {}",
                    s.weight
                );
            }
        }
    }

    #[test]
    fn fresnel_matches_known_values() {
        let (f, ct) = fresnel_dielectric(1.0, 1.5);
        assert!((f - 0.04).abs() < 1e-6 && (ct - 1.0).abs() < 1e-6);
        // Brewster angle: rp = 0, so F = rs^2 / 2.
        let tb = 1.5f32.atan();
        let (f, ct) = fresnel_dielectric(tb.cos(), 1.5);
        let rs = (tb.cos() - 1.5 * ct) / (tb.cos() + 1.5 * ct);
        assert!((f - 0.5 * rs * rs).abs() < 1e-6);
        // Inside glass past the critical angle asin(1/1.5): total internal reflection.
        let crit = (1.0f32 / 1.5).asin();
        assert_eq!(
            fresnel_dielectric((crit + 0.01).cos(), 1.0 / 1.5),
            (1.0, 0.0)
        );
        assert!(fresnel_dielectric((crit - 0.01).cos(), 1.0 / 1.5).0 < 1.0);
    }

    #[test]
    fn refraction_obeys_snell_and_reverses() {
        let glass = Material::Dielectric { ior: 1.5 };
        let wo = dir(0.6, 1.0);
        let s = glass.sample(wo, 0.999, [0.0, 0.0]).unwrap();
        assert!(s.wi.z < 0.0 && s.delta);
        let sin_i = (1.0 - wo.z * wo.z).sqrt();
        let sin_t = (1.0 - s.wi.z * s.wi.z).sqrt();
        assert!((sin_i - 1.5 * sin_t).abs() < 1e-6);
        assert!((s.wi.length() - 1.0).abs() < 1e-6);
        assert!((s.weight.x - 1.0 / 2.25).abs() < 1e-6);
        // Going back out along the reversed ray returns to wo.
        let back = glass.sample(s.wi, 0.999, [0.0, 0.0]).unwrap();
        assert!((back.wi - wo).length() < 1e-5);
    }

    #[test]
    fn emitter_is_one_sided_and_black() {
        let l = Material::Emitter {
            radiance: Vec3A::splat(15.0),
        };
        assert_eq!(l.emitted(Vec3A::Z), Vec3A::splat(15.0));
        assert_eq!(l.emitted(-Vec3A::Z), Vec3A::ZERO);
        assert!(l.sample(Vec3A::Z, 0.5, [0.5, 0.5]).is_none());
        assert_eq!(l.eval(Vec3A::Z, Vec3A::Z), Vec3A::ZERO);
    }
}
