//! Closed forms for Kerr (mass `M`, spin `a`, `0 <= a <= M`), the referees
//! of the Kerr renderer: they share no code with the integrator, the
//! observers or the disk model (which finds its ISCO numerically).
//!
//! - horizons `r_+- = M +- sqrt(M^2 - a^2)`;
//! - the ergosphere `r_E(theta) = M + sqrt(M^2 - a^2 cos^2 theta)`;
//! - equatorial circular photon orbits
//!   `r_ph = 2 M (1 + cos((2/3) acos(-+ a / M)))` (prograde -, retrograde +);
//! - the ISCO (Bardeen, Press & Teukolsky 1972):
//!   `Z1 = 1 + (1 - s^2)^(1/3) ((1 + s)^(1/3) + (1 - s)^(1/3))`, `s = a / M`,
//!   `Z2 = sqrt(3 s^2 + Z1^2)`, `r = M (3 + Z2 -+ sqrt((3 - Z1)(3 + Z1 + 2 Z2)))`;
//! - Bardeen's critical curve: spherical photon orbits at `r` in
//!   `[r_ph prograde, r_ph retrograde]` have
//!   `xi = (r^2 (3M - r) - a^2 (r + M)) / (a (r - M))`,
//!   `eta = r^3 (4 a^2 M - r (r - 3M)^2) / (a^2 (r - M)^2)` and appear to a
//!   distant observer at inclination `theta_o` at
//!   `alpha = -xi / sin(theta_o)`, `beta = +-sqrt(eta + a^2 cos^2 theta_o - xi^2 cot^2 theta_o)`.
//!   `a = 0` is the circle of radius `3 sqrt(3) M`.

/// `(r_+, r_-)`.
pub fn horizons(m: f64, a: f64) -> (f64, f64) {
    let s = (m * m - a * a).sqrt();
    (m + s, m - s)
}

/// The ergosphere's outer boundary at polar angle `theta`.
pub fn ergosphere(m: f64, a: f64, theta: f64) -> f64 {
    m + (m * m - a * a * theta.cos().powi(2)).sqrt()
}

/// `(prograde, retrograde)` equatorial circular photon orbit radii.
pub fn photon_orbits(m: f64, a: f64) -> (f64, f64) {
    let r = |sgn: f64| 2.0 * m * (1.0 + ((2.0 / 3.0) * (sgn * a / m).acos()).cos());
    (r(-1.0), r(1.0))
}

/// `(prograde, retrograde)` innermost stable circular orbit radii.
pub fn isco(m: f64, a: f64) -> (f64, f64) {
    let s = a / m;
    let z1 = 1.0 + (1.0 - s * s).cbrt() * ((1.0 + s).cbrt() + (1.0 - s).cbrt());
    let z2 = (3.0 * s * s + z1 * z1).sqrt();
    let k = ((3.0 - z1) * (3.0 + z1 + 2.0 * z2)).sqrt();
    (m * (3.0 + z2 - k), m * (3.0 + z2 + k))
}

/// `(xi, eta)` of the spherical photon orbit at radius `r` (`a > 0`).
pub fn spherical_orbit(m: f64, a: f64, r: f64) -> (f64, f64) {
    let xi = (r * r * (3.0 * m - r) - a * a * (r + m)) / (a * (r - m));
    let eta = r.powi(3) * (4.0 * a * a * m - r * (r - 3.0 * m).powi(2)) / (a * a * (r - m).powi(2));
    (xi, eta)
}

/// Bardeen's curve as a closed polygon in the `(alpha, beta)` plane:
/// `n` points on the upper branch (`beta >= 0`) from the left end to the
/// right end, then the mirrored lower branch. `a = 0` (or tiny) gives
/// the circle `3 sqrt(3) M`.
pub fn critical_curve(m: f64, a: f64, theta_o: f64, n: usize) -> Vec<[f64; 2]> {
    let n = n.max(8);
    if a.abs() < 1e-9 * m {
        let rc = 27f64.sqrt() * m;
        return (0..2 * n)
            .map(|i| {
                let t = std::f64::consts::PI * i as f64 / n as f64;
                [rc * t.cos(), rc * t.sin()]
            })
            .collect();
    }
    let (st, ct) = theta_o.sin_cos();
    let beta2 = |r: f64| {
        let (xi, eta) = spherical_orbit(m, a, r);
        eta + a * a * ct * ct - xi * xi * ct * ct / (st * st)
    };
    let (r1, r2) = photon_orbits(m, a);
    // The visible arc is where beta^2 >= 0: find its ends by bisection
    // from the orbit radius where beta^2 is largest (a coarse scan).
    let k = 4096;
    let rs: Vec<f64> = (0..=k)
        .map(|i| r1 + (r2 - r1) * i as f64 / k as f64)
        .collect();
    let imax = (0..=k)
        .max_by(|&i, &j| beta2(rs[i]).total_cmp(&beta2(rs[j])))
        .unwrap_or(k / 2);
    let root = |mut lo: f64, mut hi: f64| {
        // beta2(lo) >= 0 > beta2(hi) or the reverse; keep the >= 0 side.
        let pos_lo = beta2(lo) >= 0.0;
        for _ in 0..200 {
            let mid = 0.5 * (lo + hi);
            if (beta2(mid) >= 0.0) == pos_lo {
                lo = mid;
            } else {
                hi = mid;
            }
        }
        if pos_lo {
            lo
        } else {
            hi
        }
    };
    let left = if beta2(r1) >= 0.0 {
        r1
    } else {
        root(rs[imax], r1)
    };
    let right = if beta2(r2) >= 0.0 {
        r2
    } else {
        root(rs[imax], r2)
    };
    // Cosine spacing crowds points at the arc ends, where beta moves fast.
    let pts: Vec<[f64; 2]> = (0..n)
        .map(|i| {
            let u = 0.5 - 0.5 * (std::f64::consts::PI * i as f64 / (n - 1) as f64).cos();
            let r = left + (right - left) * u;
            let (xi, _) = spherical_orbit(m, a, r);
            [-xi / st, beta2(r).max(0.0).sqrt()]
        })
        .collect();
    let mut poly = pts.clone();
    poly.extend(pts.iter().rev().map(|p| [p[0], -p[1]]));
    poly
}

/// Whether `(x, y)` lies inside the closed polygon (even-odd rule).
pub fn inside(poly: &[[f64; 2]], x: f64, y: f64) -> bool {
    let mut c = false;
    let n = poly.len();
    for i in 0..n {
        let (p, q) = (poly[i], poly[(i + 1) % n]);
        if (p[1] > y) != (q[1] > y) && x < p[0] + (y - p[1]) * (q[0] - p[0]) / (q[1] - p[1]) {
            c = !c;
        }
    }
    c
}

/// Per pixel of a `w x h` image over `alpha in [-hw, hw]`,
/// `beta in [-hh, hh]` (row 0 at the top, pixel centres at +0.5): 1 where
/// the whole pixel lies inside Bardeen's curve (captured), 0 where it lies
/// outside, 2 where the curve crosses the pixel (either verdict is right).
/// The curve is sampled finely enough (spacing under a tenth of a pixel)
/// that every pixel it passes through holds a sample.
pub fn shadow_classes(
    m: f64,
    a: f64,
    theta_o: f64,
    w: usize,
    h: usize,
    hw: f64,
    hh: f64,
) -> Vec<u8> {
    let (px, py) = (2.0 * hw / w as f64, 2.0 * hh / h as f64);
    let mut n = 2000;
    let poly = loop {
        let p = critical_curve(m, a, theta_o, n);
        let step = p
            .windows(2)
            .map(|s| ((s[1][0] - s[0][0]).powi(2) + (s[1][1] - s[0][1]).powi(2)).sqrt())
            .fold(0.0, f64::max);
        if step < 0.1 * px.min(py) || n > 1 << 22 {
            break p;
        }
        n *= 2;
    };
    let mut out: Vec<u8> = (0..w * h)
        .map(|i| {
            let (u, v) = (i % w, i / w);
            let x = -hw + px * (u as f64 + 0.5);
            let y = hh - py * (v as f64 + 0.5);
            inside(&poly, x, y) as u8
        })
        .collect();
    // Any pixel holding a curve point, or whose neighbours straddle a
    // segment through it, is a boundary pixel: mark the pixel of every
    // sample and of the midpoints between samples.
    let mut mark = |x: f64, y: f64| {
        let u = ((x + hw) / px).floor();
        let v = ((hh - y) / py).floor();
        if u >= 0.0 && v >= 0.0 && (u as usize) < w && (v as usize) < h {
            out[v as usize * w + u as usize] = 2;
        }
    };
    for s in poly.windows(2) {
        for k in 0..4 {
            let t = k as f64 / 4.0;
            mark(
                s[0][0] + t * (s[1][0] - s[0][0]),
                s[0][1] + t * (s[1][1] - s[0][1]),
            );
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn closed_forms_match_independent_values_for_a_09_and_0998() {
        // Values computed independently (Python, the same closed forms).
        let (rp, rm) = horizons(1.0, 0.9);
        assert!(
            (rp - 1.435_889_894_354_067).abs() < 1e-12
                && (rm - 0.564_110_105_645_933).abs() < 1e-12
        );
        let (pro, retro) = isco(1.0, 0.9);
        assert!((pro - 2.320_883_041_761_887).abs() < 1e-12, "{pro}");
        assert!((retro - 8.717_352_279_606_489).abs() < 1e-12, "{retro}");
        let (pro, _) = isco(1.0, 0.998);
        assert!((pro - 1.236_970_655_175_185).abs() < 1e-12, "{pro}");
        assert!((isco(1.0, 0.0).0 - 6.0).abs() < 1e-12);
        let (pp, pr) = photon_orbits(1.0, 0.9);
        assert!((pp - 1.557_854_627_423_383).abs() < 1e-12, "{pp}");
        assert!((pr - 3.910_267_939_103_037).abs() < 1e-12, "{pr}");
        let (p0, r0) = photon_orbits(1.0, 0.0);
        assert!((p0 - 3.0).abs() < 1e-12 && (r0 - 3.0).abs() < 1e-12);
        assert!((ergosphere(1.0, 0.9, std::f64::consts::FRAC_PI_2) - 2.0).abs() < 1e-15);
        assert!((ergosphere(1.0, 0.9, 0.0) - rp).abs() < 1e-15);
    }

    #[test]
    fn photon_orbits_and_isco_solve_their_defining_equations() {
        // Circular photon orbit: r^{3/2} - 3 M r^{1/2} +- 2 a M^{1/2} = 0.
        for a in [0.3, 0.9, 0.998] {
            let (pp, pr) = photon_orbits(1.0, a);
            assert!((pp.powf(1.5) - 3.0 * pp.sqrt() + 2.0 * a).abs() < 1e-12);
            assert!((pr.powf(1.5) - 3.0 * pr.sqrt() - 2.0 * a).abs() < 1e-12);
            // ISCO: r^2 - 6 M r + 8 a sqrt(M r) - 3 a^2 = 0 (prograde).
            let (ip, ir) = isco(1.0, a);
            assert!((ip * ip - 6.0 * ip + 8.0 * a * ip.sqrt() - 3.0 * a * a).abs() < 1e-9);
            assert!((ir * ir - 6.0 * ir - 8.0 * a * ir.sqrt() - 3.0 * a * a).abs() < 1e-9);
        }
    }

    #[test]
    fn edge_on_curve_spans_the_photon_orbits() {
        // At theta_o = 90 deg the curve's ends are the equatorial photon
        // orbits: alpha = -xi, with b = -+(r_ph + ... ) known values.
        let poly = critical_curve(1.0, 0.9, std::f64::consts::FRAC_PI_2, 4000);
        let xmin = poly.iter().map(|p| p[0]).fold(f64::INFINITY, f64::min);
        let xmax = poly.iter().map(|p| p[0]).fold(f64::NEG_INFINITY, f64::max);
        let (pp, pr) = photon_orbits(1.0, 0.9);
        let b =
            |r: f64, s: f64| -(r.powi(2) * (3.0 - r) - 0.81 * (r + 1.0)) / (0.9 * (r - 1.0)) * s;
        assert!((xmin - b(pp, 1.0)).abs() < 1e-9 && xmin < -2.0, "{xmin}");
        assert!((xmax - b(pr, 1.0)).abs() < 1e-9 && xmax > 6.0, "{xmax}");
        assert!(inside(&poly, 1.0, 0.0) && !inside(&poly, 8.0, 0.0));
    }

    #[test]
    fn classes_mark_only_pixels_the_curve_crosses() {
        let c = shadow_classes(1.0, 0.0, 1.0, 64, 64, 8.0, 8.0);
        let rc = 27f64.sqrt();
        let px = 16.0 / 64.0;
        for (i, &k) in c.iter().enumerate() {
            let (u, v) = (i % 64, i / 64);
            let (x, y) = (-8.0 + px * (u as f64 + 0.5), 8.0 - px * (v as f64 + 0.5));
            let d = (x * x + y * y).sqrt() - rc;
            if d.abs() > 0.71 * px {
                assert_eq!(k, (d < 0.0) as u8, "pixel {u},{v} at distance {d}");
            } else if d.abs() < 0.05 * px {
                assert_eq!(k, 2, "pixel {u},{v} at distance {d}");
            }
        }
    }
}
