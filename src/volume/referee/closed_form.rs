//! Closed forms of the forward and backward passes in f64: optical depths
//! of the analytic fields along a ray (constant, slabs, Gaussian via erf,
//! shell via ball chords, linear) and the gradients of constant/slab
//! densities, constant colour and the Gaussian blob's camera pose. Written
//! apart from `volume::field`, `volume::integrate` and `volume::diff`.

use statrs::function::erf::erf;

use crate::error::{Error, Result};
use crate::rays::{RayGen, Rays};
use crate::tensor::{Outputs, Tensor};
use crate::volume::field::Analytic;

/// Length of `[t0, t1]` inside the ball of radius `r` about `c` (|d| = 1).
pub fn ball_chord(o: [f64; 3], d: [f64; 3], c: [f64; 3], r: f64, t0: f64, t1: f64) -> f64 {
    let oc = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
    let b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
    let q = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - r * r;
    let disc = b * b - q;
    if disc <= 0.0 {
        return 0.0;
    }
    let h = disc.sqrt();
    ((-b + h).min(t1) - (-b - h).max(t0)).max(0.0)
}

/// Optical depth `int_{t0}^{t1} sigma(o + t d) dt` of an analytic field.
pub fn optical_depth(a: &Analytic, o: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> f64 {
    match a {
        Analytic::Constant { s } => s * (t1 - t0),
        Analytic::Slabs {
            axis,
            breaks,
            sigma,
        } => {
            let (ox, dx) = (o[*axis], d[*axis]);
            let mut tau = 0.0;
            for i in 0..sigma.len() {
                let (lo, hi) = if dx == 0.0 {
                    let inside = breaks[i] <= ox && ox < breaks[i + 1]
                        || (i + 1 == sigma.len() && ox == breaks[i + 1]);
                    if inside {
                        (t0, t1)
                    } else {
                        (0.0, 0.0)
                    }
                } else {
                    let (ta, tb) = ((breaks[i] - ox) / dx, (breaks[i + 1] - ox) / dx);
                    (ta.min(tb).max(t0), ta.max(tb).min(t1))
                };
                tau += sigma[i] * (hi - lo).max(0.0);
            }
            tau
        }
        Analytic::Gaussian {
            amplitude,
            mean,
            std,
        } => {
            let om = [o[0] - mean[0], o[1] - mean[1], o[2] - mean[2]];
            let tc = -(om[0] * d[0] + om[1] * d[1] + om[2] * d[2]);
            let p = [om[0] + tc * d[0], om[1] + tc * d[1], om[2] + tc * d[2]];
            let b2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
            let k = std * std::f64::consts::SQRT_2;
            amplitude
                * (-b2 / (2.0 * std * std)).exp()
                * std
                * (std::f64::consts::PI / 2.0).sqrt()
                * (erf((t1 - tc) / k) - erf((t0 - tc) / k))
        }
        Analytic::Shell { centre, r0, r1, s } => {
            s * (ball_chord(o, d, *centre, *r1, t0, t1) - ball_chord(o, d, *centre, *r0, t0, t1))
        }
        Analytic::Linear { a, g } => {
            let go = g[0] * o[0] + g[1] * o[1] + g[2] * o[2];
            let gd = g[0] * d[0] + g[1] * d[1] + g[2] * d[2];
            (a + go) * (t1 - t0) + gd * (t1 * t1 - t0 * t0) / 2.0
        }
    }
}

/// Closed-form `(tau, hit)` of `a` along each of `rays`.
pub fn optical_depths(a: &Analytic, rays: &Rays<f64>) -> (Vec<f64>, Vec<u8>) {
    let mut tau = Vec::with_capacity(rays.len());
    let mut hit = Vec::with_capacity(rays.len());
    for i in 0..rays.len() {
        let h = rays.t1[i] > rays.t0[i];
        tau.push(if h {
            optical_depth(a, rays.o[i], rays.d[i], rays.t0[i], rays.t1[i])
        } else {
            0.0
        });
        hit.push(h as u8);
    }
    (tau, hit)
}

/// The image of constant colour `c` over `background` for optical depths
/// `tau`: tensors `logtrans`, `opacity`, `trans`, `rgb`, `hit` of shape `s`.
pub fn closed_image(
    tau: &[f64],
    hit: Vec<u8>,
    c: [f64; 3],
    background: [f64; 3],
    s: &[usize],
) -> Result<Outputs> {
    let trans: Vec<f64> = tau.iter().map(|t| (-t).exp()).collect();
    let rgb: Vec<[f64; 3]> = tau
        .iter()
        .map(|t| {
            let (tr, op) = ((-t).exp(), -(-t).exp_m1());
            [0, 1, 2].map(|k| c[k] * op + tr * background[k])
        })
        .collect();
    let mut out = Outputs::default();
    out.tensor(
        "logtrans",
        Tensor::real(s, tau.iter().map(|t| -t).collect())?,
    );
    out.tensor(
        "opacity",
        Tensor::real(s, tau.iter().map(|t| -(-t).exp_m1()).collect())?,
    );
    out.tensor("trans", Tensor::real(s, trans)?);
    out.tensor("rgb", Tensor::real3(s, &rgb)?);
    out.tensor("hit", Tensor::from_shape_vec(s, hit)?);
    Ok(out)
}

/// Length of `[t0, t1]` inside slab `[lo, hi)` along `axis` (|d| = 1).
pub fn slab_len(o: f64, d: f64, lo: f64, hi: f64, t0: f64, t1: f64) -> f64 {
    if d == 0.0 {
        return if lo <= o && o < hi { t1 - t0 } else { 0.0 };
    }
    let (a, b) = ((lo - o) / d, (hi - o) / d);
    (a.max(b).min(t1) - a.min(b).max(t0)).max(0.0)
}

/// Entry and exit planes of a ray and the box: `(axis, t)` of each, or
/// `None` where `near` / `far` holds instead.
pub type Planes = (Option<(usize, f64)>, Option<(usize, f64)>);

/// The active entry / exit planes of the box, written from the slab method
/// in f64: `(axis, t)` or `None` where `near` / `far` holds.
pub fn box_planes(o: [f64; 3], d: [f64; 3], gen: &RayGen) -> Planes {
    let mut enter = (gen.near, None);
    let mut exit = (gen.far, None);
    for a in 0..3 {
        if d[a] == 0.0 {
            continue;
        }
        let ta = (gen.aabb.min[a] - o[a]) / d[a];
        let tb = (gen.aabb.max[a] - o[a]) / d[a];
        if ta.min(tb) > enter.0 {
            enter = (ta.min(tb), Some(a));
        }
        if ta.max(tb) < exit.0 {
            exit = (ta.max(tb), Some(a));
        }
    }
    (enter.1.map(|a| (a, enter.0)), exit.1.map(|a| (a, exit.0)))
}

/// `(tau, dtau/do, dtau/dd)` of the Gaussian along `o + t d`, `t in [t0, t1]`.
#[allow(clippy::too_many_arguments)]
pub fn gaussian_tau_grad(
    amp: f64,
    mean: [f64; 3],
    s: f64,
    o: [f64; 3],
    d: [f64; 3],
    t0: f64,
    t1: f64,
    planes: Planes,
) -> (f64, [f64; 3], [f64; 3]) {
    let p = [o[0] - mean[0], o[1] - mean[1], o[2] - mean[2]];
    let tc = -(p[0] * d[0] + p[1] * d[1] + p[2] * d[2]);
    let q = [p[0] + tc * d[0], p[1] + tc * d[1], p[2] + tc * d[2]];
    let b2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2];
    let s2 = s * s;
    let ae = amp * (-b2 / (2.0 * s2)).exp();
    let (u0, u1) = (t0 - tc, t1 - tc);
    let (g0, g1) = ((-u0 * u0 / (2.0 * s2)).exp(), (-u1 * u1 / (2.0 * s2)).exp());
    let k = s * std::f64::consts::SQRT_2;
    let i0 = ae * s * (std::f64::consts::PI / 2.0).sqrt() * (erf(u1 / k) - erf(u0 / k));
    let i1 = ae * s2 * (g0 - g1);
    let i2 = s2 * i0 + ae * s2 * (u0 * g0 - u1 * g1);
    let mut go = [0.0; 3];
    let mut gd = [0.0; 3];
    for a in 0..3 {
        go[a] = -(q[a] * i0 + d[a] * i1) / s2;
        gd[a] = -(q[a] * (i1 + tc * i0) + d[a] * (i2 + tc * i1)) / s2;
    }
    // Endpoints: tau gains sigma(x1) dt1 and loses sigma(x0) dt0.
    for (pl, sign) in [(planes.0, -1.0), (planes.1, 1.0)] {
        if let Some((a, t)) = pl {
            let x = [0, 1, 2].map(|c| o[c] + t * d[c] - mean[c]);
            let sig = amp * (-(x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) / (2.0 * s2)).exp();
            go[a] += sign * sig * (-1.0 / d[a]);
            gd[a] += sign * sig * (-t / d[a]);
        }
    }
    (i0, go, gd)
}

/// Closed-form gradients of `L = sum W . rgb` for analytic field `a` with
/// constant colour `c` over background `bg`, along `rays` (one per pixel,
/// weights `w_rgb`) of camera pose `c2w` clipped by `gen`'s box: tensors
/// `dsigma_param` (constant, slabs), `dcolor_const`, and `dcam` (Gaussian
/// blob: the continuum pose gradient, box planes included). `at` names the
/// case in errors.
// Rays are structs of arrays: one index reads o, d, t0, t1 and the weights.
#[allow(clippy::too_many_arguments, clippy::needless_range_loop)]
pub fn grad_closed_form(
    a: &Analytic,
    c: [f64; 3],
    bg: [f64; 3],
    rays: &Rays<f64>,
    c2w: &[[f64; 4]; 3],
    gen: &RayGen,
    w_rgb: &[[f64; 3]],
    at: &str,
) -> Result<Outputs> {
    let nparam = match a {
        Analytic::Constant { .. } => 1,
        Analytic::Slabs { sigma, .. } => sigma.len(),
        _ => 0,
    };
    let mut dparam = vec![0.0; nparam];
    let mut dcol = [0.0; 3];
    let (mut drho, mut dw) = ([0.0; 3], [0.0; 3]);
    let m = c2w;
    let rt = |v: [f64; 3]| [0, 1, 2].map(|j| m[0][j] * v[0] + m[1][j] * v[1] + m[2][j] * v[2]);
    for i in 0..rays.len() {
        let (o, d, t0, t1) = (rays.o[i], rays.d[i], rays.t0[i], rays.t1[i]);
        if t1 <= t0 {
            continue;
        }
        let wc: f64 = (0..3).map(|ch| w_rgb[i][ch] * (c[ch] - bg[ch])).sum();
        let (tau, lens) = match a {
            Analytic::Constant { s } => (s * (t1 - t0), vec![t1 - t0]),
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => {
                let n = sigma.len();
                let lens: Vec<f64> = (0..n)
                    .map(|k| {
                        // The last slab is closed: extend it by nothing but
                        // include its end (a measure-zero difference).
                        slab_len(o[*axis], d[*axis], breaks[k], breaks[k + 1], t0, t1)
                    })
                    .collect();
                let tau = lens.iter().zip(sigma).map(|(l, s)| l * s).sum();
                (tau, lens)
            }
            Analytic::Gaussian {
                amplitude,
                mean,
                std,
            } => {
                let (tau, go, gd) =
                    gaussian_tau_grad(*amplitude, *mean, *std, o, d, t0, t1, box_planes(o, d, gen));
                let k = wc * (-tau).exp();
                let go = go.map(|v| k * v);
                let gd = gd.map(|v| k * v);
                let r = rt(go);
                let oc = [0, 1, 2].map(|a| o[a] - m[a][3]);
                let x1 = [
                    oc[1] * go[2] - oc[2] * go[1],
                    oc[2] * go[0] - oc[0] * go[2],
                    oc[0] * go[1] - oc[1] * go[0],
                ];
                let x2 = [
                    d[1] * gd[2] - d[2] * gd[1],
                    d[2] * gd[0] - d[0] * gd[2],
                    d[0] * gd[1] - d[1] * gd[0],
                ];
                let wv = rt([x1[0] + x2[0], x1[1] + x2[1], x1[2] + x2[2]]);
                for a in 0..3 {
                    drho[a] += r[a];
                    dw[a] += wv[a];
                }
                (tau, vec![])
            }
            _ => {
                return Err(Error::NotSupported(format!(
                    "{at}: closed-form gradients exist for constant, slabs and gaussian"
                )))
            }
        };
        let e = (-tau).exp();
        for (dp, l) in dparam.iter_mut().zip(&lens) {
            *dp += wc * l * e;
        }
        for ch in 0..3 {
            dcol[ch] += w_rgb[i][ch] * -(-tau).exp_m1();
        }
    }
    let mut out = Outputs::default();
    if nparam > 0 {
        out.tensor("dsigma_param", Tensor::real(&[nparam], dparam)?);
    }
    out.tensor("dcolor_const", Tensor::real(&[3], dcol.to_vec())?);
    if matches!(a, Analytic::Gaussian { .. }) {
        let v = vec![drho[0], drho[1], drho[2], dw[0], dw[1], dw[2]];
        out.tensor("dcam", Tensor::real(&[6], v)?);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::field::FieldDesc;
    use crate::volume::referee::quadrature::ref_sigma;

    #[test]
    fn gaussian_closed_form_matches_a_fine_midpoint_sum() {
        let a = Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.1, 0.0, 0.0],
            std: 0.3,
        };
        let (o, d) = ([0.05, 0.2, 3.0], [0.0, 0.0, -1.0]);
        let n = 200_000;
        let h = 2.0 / n as f64;
        let sum: f64 = (0..n)
            .map(|k| {
                ref_sigma(
                    &FieldDesc::Analytic(a.clone()),
                    [0.05, 0.2, 1.0 - (k as f64 + 0.5) * h],
                ) * h
            })
            .sum();
        assert!((optical_depth(&a, o, d, 2.0, 4.0) - sum).abs() < 1e-8);
    }

    #[test]
    fn shell_chord_of_a_central_ray_is_twice_the_thickness() {
        let a = Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        };
        let tau = optical_depth(&a, [0.0, 0.0, 3.0], [0.0, 0.0, -1.0], 2.0, 4.0);
        assert!((tau - 30.0 * 0.2).abs() < 1e-12);
    }

    #[test]
    fn gaussian_tau_gradient_matches_differences_of_its_own_tau() {
        let (amp, mean, s) = (20.0, [0.1, -0.05, 0.0], 0.3);
        let o = [0.2, 0.15, 3.0];
        let d0 = [-0.05, -0.03, -1.0];
        let n: f64 = d0[0] * d0[0] + d0[1] * d0[1] + d0[2] * d0[2];
        let d = d0.map(|v: f64| v / n.sqrt());
        let gen = RayGen::new(1, 1);
        let tau_of = |o: [f64; 3], d: [f64; 3]| {
            let (p0, p1) = box_planes(o, d, &gen);
            let (t0, t1) = (p0.unwrap().1, p1.unwrap().1);
            gaussian_tau_grad(amp, mean, s, o, d, t0, t1, (p0, p1))
        };
        let (_, go, gd) = tau_of(o, d);
        let h = 1e-6;
        for a in 0..3 {
            let (mut op, mut om) = (o, o);
            op[a] += h;
            om[a] -= h;
            let fd = (tau_of(op, d).0 - tau_of(om, d).0) / (2.0 * h);
            assert!((fd - go[a]).abs() < 1e-6, "o{a}: {fd} {}", go[a]);
            // Only directions that keep |d| = 1 matter: v = e_a - d_a d.
            let v = [0, 1, 2].map(|c| (c == a) as i32 as f64 - d[a] * d[c]);
            let unit = |x: [f64; 3]| {
                let l = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
                x.map(|c| c / l)
            };
            let dp = unit([0, 1, 2].map(|c| d[c] + h * v[c]));
            let dm = unit([0, 1, 2].map(|c| d[c] - h * v[c]));
            let fd = (tau_of(o, dp).0 - tau_of(o, dm).0) / (2.0 * h);
            let an: f64 = (0..3).map(|c| gd[c] * v[c]).sum();
            assert!((fd - an).abs() < 1e-5, "d{a}: {fd} {an}");
        }
    }
}
