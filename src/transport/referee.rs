//! Referees of the transport renderer: closed forms and quadratures in f64
//! that share no code with the integrators (`integrate`, `metric`, `grin`,
//! `tasks`); a test below holds this file to that.
//!
//! Schwarzschild: orbit roots, the finite-distance sweep by substitution +
//! Gauss–Legendre, Darwin's exact deflection (Carlson R_F), the weak-field
//! series, Synge's capture angle. Ellis: elliptic integrals. GRIN: focus
//! points and periods of the Luneburg lens, fibres and fish-eye.

use std::f64::consts::PI;

use crate::stats::quadrature::integrate;

/// The spacetimes with a closed-form sweep (descriptions only).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spacetime {
    Minkowski,
    Schwarzschild { mass: f64 },
    Ellis { b0: f64 },
}

/// Real roots of `2 M u^3 - u^2 + 1/b^2` in increasing order, when three
/// (b above 3 sqrt(3) M), by the trigonometric formula and Newton polish.
pub fn orbit_roots(m: f64, b: f64) -> Option<[f64; 3]> {
    // u^3 + a u^2 + c = 0, a = -1/(2M), c = 1/(2 M b^2); u = v - a/3.
    let a = -1.0 / (2.0 * m);
    let c = 1.0 / (2.0 * m * b * b);
    let p = -a * a / 3.0;
    let q = 2.0 * a * a * a / 27.0 + c;
    if 4.0 * p * p * p + 27.0 * q * q >= 0.0 {
        return None;
    }
    let k = 2.0 * (-p / 3.0).sqrt();
    let th = ((3.0 * q / (2.0 * p)) * (-3.0 / p).sqrt())
        .clamp(-1.0, 1.0)
        .acos()
        / 3.0;
    let mut r: [f64; 3] =
        std::array::from_fn(|j| k * (th - 2.0 * PI * j as f64 / 3.0).cos() - a / 3.0);
    let f = |u: f64| 2.0 * m * u * u * u - u * u + 1.0 / (b * b);
    let df = |u: f64| 6.0 * m * u * u - 2.0 * u;
    for u in &mut r {
        for _ in 0..3 {
            let d = df(*u);
            if d != 0.0 {
                *u -= f(*u) / d;
            }
        }
    }
    r.sort_by(f64::total_cmp);
    Some(r)
}

/// `int_{u0}^{u_t} du / sqrt(1/b^2 - u^2 (1 - 2 M u))` (half the sweep from
/// radius 1/u0 to the turning point), with `u = u_t - s^2` removing the
/// turning-point singularity and `s = sqrt(u3 - u_t) sinh(w)` the
/// near-double-root peak: the integrand becomes
/// `2 / sqrt(2 M (u_t - u1 - s^2))`, smooth on [0, w0].
// `!(ut > u0)` also refuses a NaN turning point.
#[allow(clippy::neg_cmp_op_on_partial_ord)]
pub fn schwarzschild_half_sweep(m: f64, b: f64, u0: f64) -> Option<f64> {
    let [u1, ut, u3] = orbit_roots(m, b)?;
    if !(ut > u0) {
        return None;
    }
    let d = u3 - ut;
    let w0 = ((ut - u0).sqrt() / d.sqrt()).asinh();
    Some(integrate(
        |w| {
            let s = d.sqrt() * w.sinh();
            2.0 / (2.0 * m * (ut - u1 - s * s)).sqrt()
        },
        0.0,
        w0,
        40,
    ))
}

/// Carlson's symmetric elliptic integral R_F(x, y, z) (duplication).
pub fn carlson_rf(mut x: f64, mut y: f64, mut z: f64) -> f64 {
    for _ in 0..200 {
        let a = (x + y + z) / 3.0;
        let dev = ((a - x).abs()).max((a - y).abs()).max((a - z).abs());
        if dev < 1e-4 * a {
            let (dx, dy) = ((a - x) / a, (a - y) / a);
            let dz = -dx - dy;
            let e2 = dx * dy - dz * dz;
            let e3 = dx * dy * dz;
            return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0)
                / a.sqrt();
        }
        let (sx, sy, sz) = (x.sqrt(), y.sqrt(), z.sqrt());
        let l = sx * sy + sy * sz + sz * sx;
        x = 0.25 * (x + l);
        y = 0.25 * (y + l);
        z = 0.25 * (z + l);
    }
    f64::NAN
}

/// Incomplete elliptic integral of the first kind F(phi, k), |phi| <= pi/2.
pub fn ellip_f(phi: f64, k: f64) -> f64 {
    let (s, c) = phi.sin_cos();
    s * carlson_rf(c * c, 1.0 - k * k * s * s, 1.0)
}

/// Complete K(k) by the arithmetic-geometric mean.
pub fn ellip_k_agm(k: f64) -> f64 {
    let (mut a, mut g) = (1.0f64, (1.0 - k * k).sqrt());
    for _ in 0..60 {
        let (an, gn) = (0.5 * (a + g), (a * g).sqrt());
        a = an;
        g = gn;
        if (a - g).abs() <= 1e-16 * a {
            break;
        }
    }
    PI / (2.0 * a)
}

/// Sweep `delta_phi` between radii `rs` and `re` (Ellis: `l`) for impact
/// parameter `b`; `(sweep, captured, side)`.
pub fn finite_sweep(st: &Spacetime, b: f64, rs: f64, re: f64) -> (f64, bool, i32) {
    match *st {
        Spacetime::Minkowski => (PI - (b / rs).asin() - (b / re).asin(), false, 1),
        Spacetime::Schwarzschild { mass } => match (
            schwarzschild_half_sweep(mass, b, 1.0 / rs),
            schwarzschild_half_sweep(mass, b, 1.0 / re),
        ) {
            (Some(a), Some(c)) => (a + c, false, 1),
            _ => (0.0, true, 1),
        },
        Spacetime::Ellis { b0 } => {
            let (us, ue) = (
                1.0 / (b0 * b0 + rs * rs).sqrt(),
                1.0 / (b0 * b0 + re * re).sqrt(),
            );
            if b > b0 {
                // dphi = d psi / sqrt(1 - k^2 sin^2 psi), b u = sin psi, k = b0 / b.
                let k = b0 / b;
                let kk = ellip_f(PI / 2.0, k);
                (
                    2.0 * kk - ellip_f((b * us).asin(), k) - ellip_f((b * ue).asin(), k),
                    false,
                    1,
                )
            } else {
                // dphi = (b/b0) d chi / sqrt(1 - (b/b0)^2 sin^2 chi), b0 u = sin chi.
                let k = b / b0;
                let kk = ellip_f(PI / 2.0, k);
                (
                    (b / b0)
                        * (2.0 * kk - ellip_f((b0 * us).asin(), k) - ellip_f((b0 * ue).asin(), k)),
                    false,
                    -1,
                )
            }
        }
    }
}

/// Darwin (1959): with periapsis P (largest root of P^3 - b^2 P + 2 M b^2),
/// `Q^2 = (P - 2M)(P + 6M)`, `k^2 = (Q - P + 6M) / 2Q`,
/// `sin^2 zeta = (Q - P + 2M) / (Q - P + 6M)`:
/// `alpha = -pi + 4 sqrt(P/Q) (K(k) - F(zeta, k))`.
pub fn darwin(m: f64, b: f64) -> Option<f64> {
    if b <= 27f64.sqrt() * m {
        return None;
    }
    let p = 2.0 * b / 3f64.sqrt() * ((-(27f64.sqrt()) * m / b).acos() / 3.0).cos();
    let q = ((p - 2.0 * m) * (p + 6.0 * m)).sqrt();
    let k = ((q - p + 6.0 * m) / (2.0 * q)).sqrt();
    let zeta = ((q - p + 2.0 * m) / (q - p + 6.0 * m)).sqrt().asin();
    Some(-PI + 4.0 * (p / q).sqrt() * (ellip_f(PI / 2.0, k) - ellip_f(zeta, k)))
}

/// Synge (1966): `sin psi = 3 sqrt(3) M sqrt(1 - 2M/r) / r`, with psi past
/// 90 degrees inside the photon sphere (r < 3M).
pub fn synge_deg(m: f64, r: f64) -> f64 {
    let s = (27f64.sqrt() * m * (1.0 - 2.0 * m / r).sqrt() / r).min(1.0);
    let psi = s.asin().to_degrees();
    if r < 3.0 * m {
        180.0 - psi
    } else {
        psi
    }
}

/// The weak-field deflection series to 4th order in `x = M / b`:
/// `4x + 15 pi x^2 / 4 + 128 x^3 / 3 + 3465 pi x^4 / 64`.
pub fn weak_field_series(x: f64) -> f64 {
    4.0 * x + 15.0 * PI / 4.0 * x * x + 128.0 / 3.0 * x.powi(3) + 3465.0 * PI / 64.0 * x.powi(4)
}

/// The series' first omitted (5th-order) term, `3584 x^5 / 5`.
pub fn weak_field_truncation(x: f64) -> f64 {
    3584.0 / 5.0 * x.powi(5)
}

/// Ellis deflection at infinity, `2 K(b0 / b) - pi` (b > b0).
pub fn ellis_infinite(b0: f64, b: f64) -> f64 {
    2.0 * ellip_k_agm(b0 / b) - PI
}

/// Unit direction of a listed ray `[ox, oy, oz, dx, dy, dz]`.
pub fn unit(r: &[f64; 6]) -> [f64; 3] {
    let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
    [r[3] / n, r[4] / n, r[5] / n]
}

/// Luneburg lens of radius `radius`: a parallel beam along `d` focuses at
/// `R d` on the far side; `(focus, hits the lens)` for listed ray `r`.
pub fn luneburg_focus(radius: f64, r: &[f64; 6]) -> ([f64; 3], bool) {
    let d = unit(r);
    let od = r[0] * d[0] + r[1] * d[1] + r[2] * d[2];
    let perp2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2] - od * od;
    (d.map(|c| radius * c), perp2 < radius * radius)
}

/// Parabolic fibre: axial distance of one period, `2 pi cos(theta0) / alpha`
/// (`cos(theta0)` the ray direction's x component).
pub fn fibre_period(alpha: f64, r: &[f64; 6]) -> f64 {
    2.0 * PI * unit(r)[0] / alpha
}

/// Sech fibre: every ray's period is `2 pi / alpha`.
pub fn sech_period(alpha: f64) -> f64 {
    2.0 * PI / alpha
}

/// Maxwell fish-eye of radius `R`: the point conjugate to the origin `o`
/// of listed ray `r`, `-R^2 o / |o|^2`.
pub fn fisheye_conjugate(radius: f64, r: &[f64; 6]) -> [f64; 3] {
    let o2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
    [0, 1, 2].map(|k| -radius * radius * r[k] / o2)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elliptic_integrals_agree_with_each_other_and_known_values() {
        for k in [0.0, 0.3, 0.9, 0.999] {
            assert!(
                (ellip_f(PI / 2.0, k) - ellip_k_agm(k)).abs() < 1e-14,
                "k={k}"
            );
        }
        // K(1/sqrt 2) = Gamma(1/4)^2 / (4 sqrt(pi)) = 1.854074677301372.
        assert!((ellip_k_agm(0.5f64.sqrt()) - 1.854_074_677_301_372).abs() < 1e-14);
        assert!((ellip_f(0.7, 0.0) - 0.7).abs() < 1e-15);
    }

    #[test]
    fn quadrature_sweep_matches_darwin_far_out() {
        for b in [5.3, 6.0, 10.0, 100.0] {
            let q = 2.0 * schwarzschild_half_sweep(1.0, b, 0.0).unwrap() - PI;
            let d = darwin(1.0, b).unwrap();
            assert!((q - d).abs() < 1e-10, "b={b}: {q} vs {d}");
        }
        // Near-critical: the sinh substitution keeps the quadrature accurate.
        let b = 27f64.sqrt() + 1e-6;
        let (q, d) = (
            2.0 * schwarzschild_half_sweep(1.0, b, 0.0).unwrap() - PI,
            darwin(1.0, b).unwrap(),
        );
        assert!((q - d).abs() < 1e-8, "{q} vs {d}");
        assert!(schwarzschild_half_sweep(1.0, 5.0, 1e-3).is_none());
    }

    #[test]
    fn darwin_matches_the_weak_field_series_for_large_b() {
        let b = 1000.0;
        let x: f64 = 1.0 / b;
        let series = 4.0 * x
            + 15.0 * PI / 4.0 * x * x
            + 128.0 / 3.0 * x.powi(3)
            + 3465.0 * PI / 64.0 * x.powi(4);
        // The difference is the 5th-order term 3584/5 (M/b)^5 = 7.2e-13.
        let d = darwin(1.0, b).unwrap() - series;
        assert!((d / (3584.0 / 5.0 * x.powi(5)) - 1.0).abs() < 0.05, "{d:e}");
    }

    #[test]
    fn ellis_finite_sweep_tends_to_2k_minus_pi() {
        let st = Spacetime::Ellis { b0: 1.0 };
        let (s, _, side) = finite_sweep(&st, 2.0, 1e12, 1e12);
        assert!((s - PI - (2.0 * ellip_k_agm(0.5) - PI)).abs() < 1e-11);
        assert_eq!(side, 1);
        assert_eq!(finite_sweep(&st, 0.5, 100.0, 100.0).2, -1);
    }

    #[test]
    fn synge_angle_is_45_at_6m_and_90_at_3m() {
        assert!((synge_deg(1.0, 6.0) - 45.0).abs() < 1e-12);
        assert!((synge_deg(1.0, 3.0) - 90.0).abs() < 1e-6);
        assert!(synge_deg(1.0, 2.5) > 90.0);
    }

    #[test]
    fn this_referee_never_uses_the_integrators() {
        let allowed = ["crate::stats"];
        assert_eq!(
            crate::independence::foreign_paths(include_str!("referee.rs"), &allowed),
            Vec::<String>::new()
        );
    }
}
