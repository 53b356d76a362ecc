//! Observers: where a pixel's ray starts and with what momentum.
//!
//! Rays are traced backwards from the observer. For Kerr the backward ray
//! is integrated as a future-directed photon of the time-reversed
//! spacetime, which is Kerr with spin `-a` (`t -> -t` flips the sense of
//! rotation): its ingoing Kerr–Schild chart then covers the horizon the
//! ray falls through, and spatial directions, `Q` and capture are those of
//! the physical photon with `L_z -> -L_z`. [`reversed`] gives that
//! spacetime; every launch here returns a state for it.
//!
//! - [`DistantObserver`] (SCENES.md): pixel `(alpha, beta)` carries
//!   `xi = -alpha sin(theta_o)`, `eta = beta^2 + (alpha^2 - a^2) cos^2(theta_o)`,
//!   `E = 1`, starting at `r_obs` moving inward, `p_theta = -beta` for the
//!   backward ray (a pixel above the centre looks towards the +z pole).
//! - [`LocalObserver`]: a pinhole camera at Boyer–Lindquist `(r, theta, 0)`
//!   looking at the hole (forward `-r^`, up `-theta^` towards +z, right
//!   `phi^`), in the frame of a zero-angular-momentum observer (ZAMO,
//!   exists outside the horizon) or a static observer (outside the
//!   ergosphere); refused where it cannot exist.
//! - Static observers of the spherically symmetric spacetimes (Ellis) use
//!   [`super::metric::Spacetime::static_observer_momentum`] in the ray's
//!   own orbital plane ([`planar_split`]).

use super::kerr::{bl_pr, bl_to_ks, delta, Kerr};
use crate::error::{Error, Result};

/// The spacetime in which backward Kerr rays are integrated (module doc).
pub fn reversed(k: Kerr<f64>) -> Kerr<f64> {
    Kerr {
        mass: k.mass,
        a: -k.a,
    }
}

/// Bardeen's distant observer at `r_obs`, inclination `theta_o` (radians,
/// strictly between 0 and pi).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct DistantObserver {
    pub r_obs: f64,
    pub theta_o: f64,
}

/// Image-plane coordinates of pixel `(u, v)` of a `w x h` image over
/// `[-hw, hw] x [-hh, hh]` (row 0 at the top, centres at +0.5).
pub fn image_plane(u: usize, v: usize, w: usize, h: usize, hw: f64, hh: f64) -> (f64, f64) {
    (
        -hw + 2.0 * hw * (u as f64 + 0.5) / w as f64,
        hh - 2.0 * hh * (v as f64 + 0.5) / h as f64,
    )
}

impl DistantObserver {
    pub fn validate(&self, k: &Kerr<f64>) -> Result<()> {
        let rh = k.horizon();
        if !(self.r_obs.is_finite() && self.r_obs > 2.0 * rh.max(k.mass * 3.0)) {
            return Err(Error::invalid(
                "r_obs",
                format!("{}: a distant observer needs r_obs > 6 M", self.r_obs),
            ));
        }
        if !(self.theta_o > 0.0 && self.theta_o < std::f64::consts::PI) {
            return Err(Error::invalid(
                "inclination_deg",
                "must lie strictly between 0 and 180 (on the axis alpha is undefined)",
            ));
        }
        Ok(())
    }

    /// `(xi, eta)` of the physical photon reaching the image plane at `(alpha, beta)`.
    pub fn constants(&self, a: f64, alpha: f64, beta: f64) -> (f64, f64) {
        let (s, c) = self.theta_o.sin_cos();
        (-alpha * s, beta * beta + (alpha * alpha - a * a) * c * c)
    }

    /// The backward ray of pixel `(alpha, beta)`, a Kerr–Schild state of
    /// [`reversed`]`(k)`.
    pub fn launch(&self, k: &Kerr<f64>, alpha: f64, beta: f64) -> Result<[f64; 8]> {
        let (xi, eta) = self.constants(k.a, alpha, beta);
        let ar = -k.a;
        let pr = bl_pr(k.mass, ar, self.r_obs, 1.0, -xi, eta, true).ok_or_else(|| {
            Error::invalid(
                "image",
                format!("alpha {alpha}, beta {beta}: no real p_r at r_obs (observer too close)"),
            )
        })?;
        Ok(bl_to_ks(
            k.mass,
            ar,
            [self.r_obs, self.theta_o, 0.0],
            [-1.0, pr, -beta, -xi],
        ))
    }
}

/// The frame a local camera is at rest in.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Frame {
    /// Zero angular momentum (`u ~ d_t + omega d_phi`): outside the horizon.
    Zamo,
    /// At rest (`u ~ d_t`): outside the ergosphere.
    Static,
}

/// A pinhole camera at Boyer–Lindquist `(r, theta, phi = 0)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct LocalObserver {
    pub r: f64,
    pub theta: f64,
    pub frame: Frame,
    /// Vertical field of view, degrees.
    pub fov_deg: f64,
}

/// Boyer–Lindquist metric components `(g_tt, g_tphi, g_phiphi, g_rr, g_thth)`.
fn bl_metric(m: f64, a: f64, r: f64, th: f64) -> [f64; 5] {
    let (s, c) = th.sin_cos();
    let sig = r * r + a * a * c * c;
    let d = delta(m, a, r);
    let big_a = (r * r + a * a).powi(2) - a * a * d * s * s;
    [
        -(1.0 - 2.0 * m * r / sig),
        -2.0 * m * a * r * s * s / sig,
        big_a * s * s / sig,
        sig / d,
        sig,
    ]
}

impl LocalObserver {
    /// Refuses a camera that cannot exist at its place (named reason).
    pub fn validate(&self, k: &Kerr<f64>) -> Result<()> {
        if !(self.theta > 0.0 && self.theta < std::f64::consts::PI) {
            return Err(Error::invalid(
                "observer.theta_deg",
                "must lie strictly between 0 and 180 (the camera's up is theta^)",
            ));
        }
        if !(self.fov_deg > 0.0 && self.fov_deg < 180.0) {
            return Err(Error::invalid("observer.fov_deg", "must lie in (0, 180)"));
        }
        let rh = k.horizon();
        if !(self.r > rh) {
            return Err(Error::invalid(
                "observer.r",
                format!(
                    "{}: no observer can stay at rest at or inside the horizon r_+ = {rh}",
                    self.r
                ),
            ));
        }
        let g = bl_metric(k.mass, k.a, self.r, self.theta);
        if self.frame == Frame::Static && g[0] >= 0.0 {
            return Err(Error::invalid(
                "observer.frame",
                format!(
                    "static observer at r = {}, theta = {} deg lies inside the ergosphere (g_tt >= 0); use zamo",
                    self.r,
                    self.theta.to_degrees()
                ),
            ));
        }
        Ok(())
    }

    /// The backward ray through pixel `(u, v)` of a `w x h` image: a
    /// Kerr–Schild state of [`reversed`]`(k)` with unit local energy.
    pub fn launch(&self, k: &Kerr<f64>, u: usize, v: usize, w: usize, h: usize) -> [f64; 8] {
        let f = (h as f64 / 2.0) / (self.fov_deg.to_radians() / 2.0).tan();
        let x = (u as f64 + 0.5 - w as f64 / 2.0) / f;
        let y = -(v as f64 + 0.5 - h as f64 / 2.0) / f;
        let n = (x * x + y * y + 1.0).sqrt();
        // Local direction: forward -r^, right phi^, up -theta^.
        let (dr, dth, dph) = (-1.0 / n, -y / n, x / n);
        let ar = -k.a;
        let (m, r, th) = (k.mass, self.r, self.theta);
        let [gtt, gtp, gpp, grr, gthth] = bl_metric(m, ar, r, th);
        // Observer 4-velocity u = N (d_t + w d_phi).
        let w_ang = match self.frame {
            Frame::Zamo => -gtp / gpp,
            Frame::Static => 0.0,
        };
        let norm = -(gtt + 2.0 * w_ang * gtp + w_ang * w_ang * gpp);
        let nn = 1.0 / norm.sqrt();
        let ut = [nn, 0.0, 0.0, nn * w_ang];
        // e_phi: d_phi minus its projection on u, normalised.
        let dphi_u = nn * (gtp + w_ang * gpp); // g(d_phi, u)
        let mut ep = [ut[0] * dphi_u, 0.0, 0.0, 1.0 + ut[3] * dphi_u];
        let ep_n = (gtt * ep[0] * ep[0] + 2.0 * gtp * ep[0] * ep[3] + gpp * ep[3] * ep[3]).sqrt();
        for c in &mut ep {
            *c /= ep_n;
        }
        let er = 1.0 / grr.sqrt();
        let eth = 1.0 / gthth.sqrt();
        let pu = [ut[0] + dph * ep[0], dr * er, dth * eth, ut[3] + dph * ep[3]];
        // Lower the index.
        let p = [
            gtt * pu[0] + gtp * pu[3],
            grr * pu[1],
            gthth * pu[2],
            gtp * pu[0] + gpp * pu[3],
        ];
        bl_to_ks(m, ar, [r, th, 0.0], p)
    }
}

/// The plane of a ray leaving a point on the +x axis in direction `d`
/// (unit, Cartesian): the angle `psi` from the inward radial direction
/// `-x`, and the in-plane unit vector `t` perpendicular to x towards
/// which the ray turns (`(0, 1, 0)` for a purely radial ray).
pub fn planar_split(d: [f64; 3]) -> (f64, [f64; 3]) {
    let psi = (-d[0]).clamp(-1.0, 1.0).acos();
    let n = (d[1] * d[1] + d[2] * d[2]).sqrt();
    let t = if n > 0.0 {
        [0.0, d[1] / n, d[2] / n]
    } else {
        [0.0, 1.0, 0.0]
    };
    (psi, t)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::hamiltonian::Hamiltonian;
    use crate::transport::referee_kerr::ergosphere;

    #[test]
    fn distant_launch_is_null_with_the_pixels_constants() {
        let k = Kerr { mass: 1.0, a: 0.9 };
        let o = DistantObserver {
            r_obs: 1000.0,
            theta_o: 17f64.to_radians(),
        };
        let y = o.launch(&k, 3.0, -2.0).unwrap();
        let kr = reversed(k);
        assert!(kr.h(&y).abs() < 1e-12);
        let c = kr.constants(&y);
        let (xi, eta) = o.constants(0.9, 3.0, -2.0);
        assert!((c[0] - 1.0).abs() < 1e-15);
        assert!((c[1] + xi).abs() < 1e-9, "{c:?} xi {xi}");
        assert!((c[2] - eta).abs() < 1e-7, "{c:?} eta {eta}");
    }

    #[test]
    fn local_cameras_launch_null_rays_and_refuse_impossible_places() {
        let k = Kerr { mass: 1.0, a: 0.9 };
        let kr = reversed(k);
        for frame in [Frame::Zamo, Frame::Static] {
            let o = LocalObserver {
                r: 8.0,
                theta: 1.2,
                frame,
                fov_deg: 60.0,
            };
            o.validate(&k).unwrap();
            for (u, v) in [(0, 0), (31, 17), (63, 63)] {
                let y = o.launch(&k, u, v, 64, 64);
                assert!(kr.h(&y).abs() < 1e-12, "{frame:?} {u} {v}: {}", kr.h(&y));
            }
        }
        // Inside the ergosphere (equator, r < 2) static is refused, ZAMO is not.
        let inside = ergosphere(1.0, 0.9, std::f64::consts::FRAC_PI_2) - 0.1;
        let st = LocalObserver {
            r: inside,
            theta: std::f64::consts::FRAC_PI_2,
            frame: Frame::Static,
            fov_deg: 60.0,
        };
        let e = st.validate(&k).unwrap_err().to_string();
        assert!(e.contains("ergosphere"), "{e}");
        assert!(LocalObserver {
            frame: Frame::Zamo,
            ..st
        }
        .validate(&k)
        .is_ok());
        let e = LocalObserver {
            r: 1.4,
            frame: Frame::Zamo,
            ..st
        }
        .validate(&k)
        .unwrap_err()
        .to_string();
        assert!(e.contains("horizon"), "{e}");
    }

    #[test]
    fn zamo_camera_far_away_sees_the_distant_observers_constants() {
        // A ZAMO at r = 1e4 looking at pixel offset x: alpha ~ r x.
        let k = Kerr { mass: 1.0, a: 0.9 };
        let o = LocalObserver {
            r: 1e4,
            theta: 1.0,
            frame: Frame::Zamo,
            fov_deg: 0.1,
        };
        let y = o.launch(&k, 40, 10, 64, 64);
        let c = reversed(k).constants(&y);
        let f = 32.0 / (0.05f64.to_radians()).tan();
        let (x, yy) = ((40.5 - 32.0) / f, -(10.5 - 32.0) / f);
        let (alpha, beta) = (1e4 * x, 1e4 * yy);
        let d = DistantObserver {
            r_obs: 1e4,
            theta_o: 1.0,
        };
        let (xi, eta) = d.constants(0.9, alpha, beta);
        assert!((c[1] + xi).abs() < 1e-3 * xi.abs().max(1.0), "{c:?} {xi}");
        assert!(
            (c[2] - eta).abs() < 1e-3 * eta.abs().max(1.0),
            "{c:?} {eta}"
        );
    }
}
