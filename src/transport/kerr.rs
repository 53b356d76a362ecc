//! Kerr null geodesics in Kerr–Schild Cartesian coordinates (ingoing,
//! horizon-penetrating; no coordinate singularity at the horizon or on the
//! spin axis), state `y = (t, x, y, z, p_t, p_x, p_y, p_z)` (N = 8),
//! geometric units G = c = 1.
//!
//! The metric is `g_{mu nu} = eta_{mu nu} + f l_mu l_nu` with
//! `f = 2 M r^3 / (r^4 + a^2 z^2)`,
//! `l_mu = (1, (r x + a y) / (r^2 + a^2), (r y - a x) / (r^2 + a^2), z / r)`,
//! and `r` the Boyer–Lindquist radius, the root of
//! `(x^2 + y^2) / (r^2 + a^2) + z^2 / r^2 = 1` ([`ks_radius`]). Its inverse is
//! `g^{mu nu} = eta^{mu nu} - f l^mu l^nu`, so with `L = -p_t + l . p`
//! (spatial `l`), `H = (-p_t^2 + |p|^2 - f L^2) / 2`,
//! `dt = -p_t + f L`, `dx_i = p_i - f L l_i`,
//! `dp_i = L^2 d_i f / 2 + f L sum_j p_j d_i l_j` ([`kerr_rhs`], a pure
//! function of `(M, a, y)`: a WGSL twin mirrors its structure line by line).
//!
//! Boyer–Lindquist links (conversions, constants of motion): ingoing
//! Kerr–Schild time and angle are `dt_KS = dt + 2 M r / Delta dr`,
//! `dphi~ = dphi + a / Delta dr`, and `x + i y = (r + i a) e^{i phi~} sin(theta)`,
//! `z = r cos(theta)`. `E = -p_t`, `L_z = x p_y - y p_x` (the rotation
//! Killing field), Carter's `Q = p_theta^2 + cos^2(theta) (L_z^2 / sin^2(theta) - a^2 E^2)`.

use super::hamiltonian::Hamiltonian;
use crate::real::Real;

/// Kerr with mass `M > 0` and spin `a` (`|a| <= M`; the sign is the sense
/// of rotation about +z).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Kerr<F> {
    pub mass: F,
    pub a: F,
}

/// The Boyer–Lindquist radius of the Kerr–Schild point `(x, y, z)`:
/// `r^2 = (w + sqrt(w^2 + 4 a^2 z^2)) / 2`, `w = x^2 + y^2 + z^2 - a^2`
/// (written without cancellation where `w < 0`).
#[inline]
pub fn ks_radius<F: Real>(a: F, x: F, y: F, z: F) -> F {
    let a2z2 = a * a * z * z;
    let w = x * x + y * y + z * z - a * a;
    let s = (w * w + F::of(4.0) * a2z2).sqrt();
    let r2 = if w >= F::zero() {
        F::of(0.5) * (w + s)
    } else {
        F::of(2.0) * a2z2 / (s - w)
    };
    r2.sqrt()
}

/// `H` at state `y` (pure).
#[inline]
pub fn kerr_h<F: Real>(m: F, a: F, y: &[F; 8]) -> F {
    let (x, yy, z) = (y[1], y[2], y[3]);
    let (pt, px, py, pz) = (y[4], y[5], y[6], y[7]);
    let r = ks_radius(a, x, yy, z);
    let (r2, a2) = (r * r, a * a);
    let ra2 = r2 + a2;
    let f = F::of(2.0) * m * r2 * r / (r2 * r2 + a2 * z * z);
    let l = -pt + ((r * x + a * yy) * px + (r * yy - a * x) * py) / ra2 + z / r * pz;
    F::of(0.5) * (-pt * pt + px * px + py * py + pz * pz - f * l * l)
}

/// Hamilton's equations `dy/dlambda` at `y` (pure; see the module doc).
/// CPU twin of `kerr_rhs` in `kernels/transport.wgsl` once that kernel
/// carries Kerr (issue 17).
#[inline]
pub fn kerr_rhs<F: Real>(m: F, a: F, y: &[F; 8]) -> [F; 8] {
    kerr_rhs_h(m, a, y).0
}

/// [`kerr_rhs`] and `H` in one pass: one radius (two square roots) and
/// three divisions (`1/r`, `1/(r^2 + a^2)`, `1/(r^4 + a^2 z^2)`) per call;
/// the per-stage referee ([`super::referee_kernel::KerrReferee`]) divides
/// fifteen times and computes `H` apart.
#[inline]
pub fn kerr_rhs_h<F: Real>(m: F, a: F, y: &[F; 8]) -> ([F; 8], F) {
    let (x, yy, z) = (y[1], y[2], y[3]);
    let (pt, px, py, pz) = (y[4], y[5], y[6], y[7]);
    let two = F::of(2.0);
    let r = ks_radius(a, x, yy, z);
    let (r2, a2) = (r * r, a * a);
    let inv_r = F::one() / r;
    let ra2 = r2 + a2;
    let inv_ra2 = F::one() / ra2;
    let inv_n = F::one() / (r2 * r2 + a2 * z * z);
    let r3n = r2 * r * inv_n;
    let f = two * m * r3n;
    let (lx, ly, lz) = (
        (r * x + a * yy) * inv_ra2,
        (r * yy - a * x) * inv_ra2,
        z * inv_r,
    );
    let lpxy = lx * px + ly * py;
    let big_l = -pt + lpxy + lz * pz;
    // dr/dx_i.
    let (rx, ry, rz) = (x * r3n, yy * r3n, z * r * ra2 * inv_n);
    // d_i f = f (3 r_i / r - (4 r^3 r_i + 2 a^2 z delta_iz) / n).
    let k = F::of(3.0) * inv_r - F::of(4.0) * r3n;
    let fx = f * k * rx;
    let fy = f * k * ry;
    let fz = f * (k * rz - two * a2 * z * inv_n);
    // sum_j p_j d_i l_j = r_i c + (diagonal terms).
    let q = x * px + yy * py;
    let c = (q - two * r * lpxy) * inv_ra2 - pz * z * inv_r * inv_r;
    let gx = rx * c + (r * px - a * py) * inv_ra2;
    let gy = ry * c + (r * py + a * px) * inv_ra2;
    let gz = rz * c + pz * inv_r;
    let half_l2 = F::of(0.5) * big_l * big_l;
    let fl = f * big_l;
    let h = F::of(0.5) * (-pt * pt + px * px + py * py + pz * pz) - f * half_l2;
    (
        [
            -pt + fl,
            px - fl * lx,
            py - fl * ly,
            pz - fl * lz,
            F::zero(),
            half_l2 * fx + fl * gx,
            half_l2 * fy + fl * gy,
            half_l2 * fz + fl * gz,
        ],
        h,
    )
}

impl<F: Real> Kerr<F> {
    /// Outer horizon `r_+ = M + sqrt(M^2 - a^2)`.
    pub fn horizon(&self) -> F {
        self.mass
            + (self.mass * self.mass - self.a * self.a)
                .max(F::zero())
                .sqrt()
    }

    /// The Boyer–Lindquist radius of state `y`.
    #[inline]
    pub fn radius(&self, y: &[F; 8]) -> F {
        ks_radius(self.a, y[1], y[2], y[3])
    }

    /// `(E, L_z, Q)` of state `y` (module doc). On the spin axis
    /// (`x = y = 0`) the `cot(theta)` terms vanish with `L_z`.
    pub fn constants(&self, y: &[F; 8]) -> [F; 3] {
        let (a, x, yy, z) = (self.a, y[1], y[2], y[3]);
        let (px, py, pz) = (y[5], y[6], y[7]);
        let r = ks_radius(a, x, yy, z);
        let e = -y[4];
        let lz = x * py - yy * px;
        let cos_t = z / r;
        let rho = (x * x + yy * yy).sqrt();
        let sin_t = rho / (r * r + a * a).sqrt();
        let q = if rho > F::zero() {
            let p_th = cos_t / sin_t * (x * px + yy * py) - r * sin_t * pz;
            p_th * p_th + cos_t * cos_t * (lz * lz / (sin_t * sin_t) - a * a * e * e)
        } else {
            let p_th = -r * sin_t * pz;
            p_th * p_th - cos_t * cos_t * a * a * e * e
        };
        [e, lz, q]
    }
}

impl<F: Real> Hamiltonian<F, 8> for Kerr<F> {
    const SEPARABLE: bool = false;

    fn h(&self, y: &[F; 8]) -> F {
        kerr_h(self.mass, self.a, y)
    }

    fn dx(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = kerr_rhs(self.mass, self.a, y);
        d[5..].fill(F::zero());
        d
    }

    fn dp(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = kerr_rhs(self.mass, self.a, y);
        d[..5].fill(F::zero());
        d
    }

    fn rhs(&self, y: &[F; 8]) -> [F; 8] {
        kerr_rhs(self.mass, self.a, y)
    }

    fn rhs_h(&self, y: &[F; 8]) -> ([F; 8], F) {
        kerr_rhs_h(self.mass, self.a, y)
    }

    /// The radius `r`: the chart is regular at the horizon, so the step law
    /// need not shrink there.
    fn scale(&self, y: &[F; 8]) -> F {
        self.radius(y)
    }

    /// Scales the spatial momenta by the root `k` nearest 1 of
    /// `H(p_t, k p) = 0` (a quadratic in `k`): keeps `E` and the direction.
    fn project(&self, y: &mut [F; 8]) {
        let (m, a) = (self.mass, self.a);
        let r = self.radius(y);
        let (r2, a2, z) = (r * r, a * a, y[3]);
        let ra2 = r2 + a2;
        let f = F::of(2.0) * m * r2 * r / (r2 * r2 + a2 * z * z);
        let lp = ((r * y[1] + a * y[2]) * y[5] + (r * y[2] - a * y[1]) * y[6]) / ra2 + z / r * y[7];
        let pt = y[4];
        let qa = y[5] * y[5] + y[6] * y[6] + y[7] * y[7] - f * lp * lp;
        let qb = F::of(2.0) * f * pt * lp;
        let qc = -pt * pt * (F::one() + f);
        let disc = qb * qb - F::of(4.0) * qa * qc;
        if qa > F::zero() && disc >= F::zero() {
            let k = (-qb + disc.sqrt()) / (F::of(2.0) * qa);
            if k > F::zero() && k.is_finite() {
                for v in &mut y[5..8] {
                    *v *= k;
                }
            }
        }
    }
}

/// `Delta = r^2 - 2 M r + a^2`.
#[inline]
pub fn delta(m: f64, a: f64, r: f64) -> f64 {
    r * r - 2.0 * m * r + a * a
}

/// A Boyer–Lindquist point `(r, theta, phi)` with covariant momentum
/// `(p_t, p_r, p_theta, p_phi)` as a Kerr–Schild state (`t = 0`, and the
/// Kerr–Schild angle `phi~` taken equal to `phi` there). Needs `Delta != 0`.
pub fn bl_to_ks(m: f64, a: f64, pos: [f64; 3], p: [f64; 4]) -> [f64; 8] {
    let [r, th, ph] = pos;
    let d = delta(m, a, r);
    // Ingoing chart: p~_r = p_r - (2 M r / Delta) p_t - (a / Delta) p_phi.
    let pr = p[1] - 2.0 * m * r / d * p[0] - a / d * p[3];
    let (st, ct) = th.sin_cos();
    let (sp, cp) = ph.sin_cos();
    let x = st * (r * cp - a * sp);
    let y = st * (r * sp + a * cp);
    let z = r * ct;
    // Columns of J = d(x, y, z) / d(r, theta, phi~); p_sph = J^T p_cart.
    let j = [
        [st * cp, ct * (r * cp - a * sp), -y],
        [st * sp, ct * (r * sp + a * cp), x],
        [ct, -r * st, 0.0],
    ];
    let ps = [pr, p[2], p[3]];
    // Solve J^T q = ps (Cramer on the transpose).
    let jt = |i: usize, k: usize| j[k][i];
    let det3 = |m: [[f64; 3]; 3]| {
        m[0][0] * (m[1][1] * m[2][2] - m[1][2] * m[2][1])
            - m[0][1] * (m[1][0] * m[2][2] - m[1][2] * m[2][0])
            + m[0][2] * (m[1][0] * m[2][1] - m[1][1] * m[2][0])
    };
    let mt: [[f64; 3]; 3] = std::array::from_fn(|i| std::array::from_fn(|k| jt(i, k)));
    let det = det3(mt);
    let q: [f64; 3] = std::array::from_fn(|c| {
        let mut mc = mt;
        for (row, v) in mc.iter_mut().zip(ps) {
            row[c] = v;
        }
        det3(mc) / det
    });
    [0.0, x, y, z, p[0], q[0], q[1], q[2]]
}

/// Boyer–Lindquist `p_r` of a null ray with constants `(E, L, Q)` at
/// radius `r`: `Delta p_r = sign sqrt(R)`,
/// `R = (E (r^2 + a^2) - a L)^2 - Delta (Q + (L - a E)^2)`; `None` in a
/// forbidden region (`R < 0`).
pub fn bl_pr(m: f64, a: f64, r: f64, e: f64, l: f64, q: f64, inward: bool) -> Option<f64> {
    let d = delta(m, a, r);
    let big_r = (e * (r * r + a * a) - a * l).powi(2) - d * (q + (l - a * e).powi(2));
    if !(big_r >= 0.0) {
        return None;
    }
    let s = big_r.sqrt() / d;
    Some(if inward { -s } else { s })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::metric::Spacetime;

    fn fd_rhs(k: &Kerr<f64>, y: [f64; 8]) -> [f64; 8] {
        let e = 1e-6;
        let d = |i: usize| {
            let (mut p, mut q) = (y, y);
            p[i] += e;
            q[i] -= e;
            (k.h(&p) - k.h(&q)) / (2.0 * e)
        };
        [d(4), d(5), d(6), d(7), -d(0), -d(1), -d(2), -d(3)]
    }

    #[test]
    fn hamilton_equations_match_differences_of_h() {
        for (a, y) in [
            (0.9, [0.0, 3.0, -2.0, 1.5, -1.0, 0.3, 0.5, -0.2]),
            (-0.5, [0.0, 0.2, 0.1, 4.0, -1.0, -0.1, 0.2, -0.9]),
            // Inside the horizon, and on the spin axis.
            (0.998, [0.0, 0.4, 0.3, 0.9, -1.0, 0.3, 0.5, -1.2]),
            (0.9, [0.0, 0.0, 0.0, 3.0, -1.0, 0.1, 0.2, -0.9]),
        ] {
            let k = Kerr { mass: 1.0, a };
            let (g, f) = (k.rhs(&y), fd_rhs(&k, y));
            for i in 0..8 {
                assert!((g[i] - f[i]).abs() < 1e-7, "a={a} slot {i}: {g:?} vs {f:?}");
            }
        }
    }

    #[test]
    fn radius_solves_the_spheroid_equation_inside_and_out() {
        let a = 0.9f64;
        for (x, y, z) in [
            (3.0, 1.0, 2.0),
            (0.3, 0.2, 1e-3),
            (0.0, 0.0, 2.0),
            (1.5, 0.0, 0.0),
        ] {
            let r = ks_radius(a, x, y, z);
            let lhs = (x * x + y * y) / (r * r + a * a) + z * z / (r * r);
            assert!((lhs - 1.0).abs() < 1e-13, "{x} {y} {z}: {lhs}");
        }
    }

    #[test]
    fn spin_zero_is_schwarzschild() {
        // The same photon in both charts: equal H, and equal dr/dlambda.
        let k = Kerr { mass: 1.0, a: 0.0 };
        let s = Spacetime::Schwarzschild { mass: 1.0f64 };
        let p = s.equatorial_momentum(7.0, 1.0, 4.0, true).unwrap();
        let ks = bl_to_ks(1.0, 0.0, [7.0, std::f64::consts::FRAC_PI_2, 0.3], p);
        assert!(k.h(&ks).abs() < 1e-14, "{}", k.h(&ks));
        let c = k.constants(&ks);
        assert!((c[0] - 1.0).abs() < 1e-15 && (c[1] - 4.0).abs() < 1e-13 && c[2].abs() < 1e-12);
    }

    #[test]
    fn boyer_lindquist_launch_is_null_and_keeps_its_constants() {
        let (m, a) = (1.0, 0.9);
        let (e, l, q) = (1.0, -2.5, 11.0);
        let th = 1.1f64;
        let theta_term = q + a * a * th.cos().powi(2) - l * l / th.tan().powi(2);
        let pth = theta_term.sqrt();
        let pr = bl_pr(m, a, 50.0, e, l, q, true).unwrap();
        let y = bl_to_ks(m, a, [50.0, th, 0.7], [-e, pr, pth, l]);
        let k = Kerr { mass: m, a };
        assert!(k.h(&y).abs() < 1e-12, "{}", k.h(&y));
        assert!((k.radius(&y) - 50.0).abs() < 1e-12);
        let c = k.constants(&y);
        assert!((c[0] - e).abs() < 1e-14);
        assert!((c[1] - l).abs() < 1e-12, "{c:?}");
        assert!((c[2] - q).abs() < 1e-10, "{c:?}");
    }

    #[test]
    fn projection_restores_null_and_keeps_energy() {
        let k = Kerr {
            mass: 1.0,
            a: 0.9f64,
        };
        let mut y = [0.0, 6.0, 1.0, 2.0, -1.0, -0.7, 0.4, 0.1];
        k.project(&mut y);
        assert!(k.h(&y).abs() < 1e-14, "{}", k.h(&y));
        assert_eq!(y[4], -1.0);
    }
}
