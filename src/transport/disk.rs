//! The thin equatorial disk of `kerr_disk.yaml` and the celestial
//! checkerboards: what a pixel shows once its ray has ended.
//!
//! Disk model (the project's choice, SCENES.md leaves it open):
//! - matter on prograde circular geodesic orbits from the ISCO to `r_out`;
//!   the ISCO is found here numerically, as the minimum of the circular
//!   orbits' specific energy ([`isco_numeric`]), independently of the
//!   closed form in [`super::referee_kerr::isco`] that judges it;
//! - redshift factor `g = 1 / (u^t (1 - Omega xi))` for a photon of
//!   `E = 1`, `L_z = xi` reaching the observer, with
//!   `Omega = M^(1/2) / (r^(3/2) + a M^(1/2))` and
//!   `u^t = (r^(3/2) + a M^(1/2)) / (r^(3/4) sqrt(r^(3/2) - 3 M r^(1/2) + 2 a M^(1/2)))`;
//! - emissivity `j(r) = (r_isco / r)^2`, observed intensity `g^4 j`
//!   (bolometric), shown as `x / (1 + x)` with `x = 4 g^4 j`;
//! - colour: a blackbody-like ramp on the observed temperature
//!   `T = g (r / r_isco)^(-3/4)` ([`ramp`]): deep red at `T <= 0.3`,
//!   orange at 0.6, warm white at 1, pale blue at `T >= 1.6`.
//!
//! Celestial spheres: a checkerboard of `cell` degrees in latitude
//! (from +z) and longitude, cells centred on the equator and on longitude
//! 0 so that the pattern is mirror-symmetric in y and z ([`checker`]).

/// `(E, u^t, Omega)` of the prograde circular equatorial orbit at `r`
/// (`None` where no timelike circular orbit exists).
fn circular(m: f64, a: f64, r: f64) -> Option<(f64, f64, f64)> {
    let sm = m.sqrt();
    let den2 = r.powf(1.5) - 3.0 * m * r.sqrt() + 2.0 * a * sm;
    if !(den2 > 0.0) {
        return None;
    }
    let den = r.powf(0.75) * den2.sqrt();
    let e = (r.powf(1.5) - 2.0 * m * r.sqrt() + a * sm) / den;
    let ut = (r.powf(1.5) + a * sm) / den;
    let om = sm / (r.powf(1.5) + a * sm);
    Some((e, ut, om))
}

/// The prograde ISCO as the minimum of `E(r)` over circular orbits: a scan
/// of 4000 radii in `(r_+, 12 M]`, then golden-section search around the
/// smallest sample to 1e-13 M.
pub fn isco_numeric(m: f64, a: f64) -> f64 {
    let rh = m + (m * m - a * a).max(0.0).sqrt();
    let (lo, hi) = (rh, 12.0 * m);
    let n = 4000;
    let e = |r: f64| circular(m, a, r).map_or(f64::INFINITY, |c| c.0);
    let rs: Vec<f64> = (1..=n)
        .map(|i| lo + (hi - lo) * i as f64 / n as f64)
        .collect();
    let k = (0..n)
        .min_by(|&i, &j| e(rs[i]).total_cmp(&e(rs[j])))
        .unwrap_or(0);
    let (mut x0, mut x1) = (rs[k.saturating_sub(1)], rs[(k + 1).min(n - 1)]);
    let gr = (5f64.sqrt() - 1.0) / 2.0;
    while x1 - x0 > 1e-13 * m {
        let (c, d) = (x1 - gr * (x1 - x0), x0 + gr * (x1 - x0));
        if e(c) < e(d) {
            x1 = d;
        } else {
            x0 = c;
        }
    }
    0.5 * (x0 + x1)
}

/// Redshift factor of disk matter at `r` seen by a photon with `L_z = xi`
/// (`E = 1`); 0 where no circular orbit exists.
pub fn redshift(m: f64, a: f64, r: f64, xi: f64) -> f64 {
    circular(m, a, r).map_or(0.0, |(_, ut, om)| 1.0 / (ut * (1.0 - om * xi)))
}

/// Piecewise-linear colour ramp on the observed temperature `t`.
pub fn ramp(t: f64) -> [f64; 3] {
    const STOPS: [(f64, [f64; 3]); 4] = [
        (0.3, [0.55, 0.05, 0.02]),
        (0.6, [1.0, 0.45, 0.1]),
        (1.0, [1.0, 0.9, 0.75]),
        (1.6, [0.7, 0.8, 1.0]),
    ];
    if t <= STOPS[0].0 {
        return STOPS[0].1;
    }
    for w in STOPS.windows(2) {
        let ((t0, c0), (t1, c1)) = (w[0], w[1]);
        if t <= t1 {
            let s = (t - t0) / (t1 - t0);
            return std::array::from_fn(|i| c0[i] + s * (c1[i] - c0[i]));
        }
    }
    STOPS[3].1
}

/// Linear RGB of disk matter at `r` with redshift factor `g`.
pub fn disk_colour(r: f64, r_isco: f64, g: f64) -> [f64; 3] {
    let j = (r_isco / r).powi(2);
    let x = 4.0 * g.powi(4) * j;
    let b = x / (1.0 + x);
    ramp(g * (r / r_isco).powf(-0.75)).map(|c| c * b)
}

/// Parity (0 or 1) of the checkerboard cell holding unit direction `d`.
pub fn checker(d: [f64; 3], cell_deg: f64) -> u8 {
    let lat = d[2].clamp(-1.0, 1.0).asin().to_degrees();
    let lon = d[1].atan2(d[0]).to_degrees();
    let i = (lat / cell_deg + 0.5).floor() as i64;
    let j = (lon / cell_deg + 0.5).floor() as i64;
    ((i + j).rem_euclid(2)) as u8
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::referee_kerr::isco;

    #[test]
    fn numeric_isco_matches_the_closed_form() {
        for a in [0.0, 0.5, 0.9, 0.998] {
            let (want, _) = isco(1.0, a);
            let got = isco_numeric(1.0, a);
            assert!((got - want).abs() < 1e-6, "a = {a}: {got} vs {want}");
        }
    }

    #[test]
    fn redshift_is_schwarzschilds_for_a_face_on_photon() {
        // a = 0, xi = 0: g = sqrt(1 - 3M/r).
        for r in [6.0, 10.0, 20.0] {
            assert!((redshift(1.0, 0.0, r, 0.0) - (1.0 - 3.0 / r).sqrt()).abs() < 1e-14);
        }
        // Photons with L_z along the matter's motion (xi > 0: the approaching
        // side, at negative alpha) are blueshifted.
        assert!(redshift(1.0, 0.9, 6.0, 5.0) > 1.0);
        assert!(redshift(1.0, 0.9, 6.0, 5.0) > redshift(1.0, 0.9, 6.0, -5.0));
    }

    #[test]
    fn checkerboard_is_mirror_symmetric_in_y_and_z() {
        for d in [[0.3f64, 0.5, 0.81], [-0.7, 0.1, -0.7], [0.99, 0.01, 0.1]] {
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
            let d = [d[0] / n, d[1] / n, d[2] / n];
            let c = checker(d, 10.0);
            assert_eq!(c, checker([d[0], -d[1], d[2]], 10.0));
            assert_eq!(c, checker([d[0], d[1], -d[2]], 10.0));
        }
    }
}
