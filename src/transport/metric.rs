//! Spacetimes: null geodesics as the flow of `H = g^{mu nu} p_mu p_nu / 2`
//! on `y = (t, r, theta, phi, p_t, p_r, p_theta, p_phi)` (N = 8), covariant
//! momenta, geometric units G = c = 1. The three static, spherically
//! symmetric members share one form
//! `H = (-A(r) p_t^2 + B(r) p_r^2 + (p_theta^2 + p_phi^2 / sin^2 theta) / R2(r)) / 2`:
//!
//! | spacetime | A | B | R2 | radial coordinate |
//! | --- | --- | --- | --- | --- |
//! | `Minkowski` | 1 | 1 | r^2 | r > 0 |
//! | `Schwarzschild` (mass M) | 1 / (1 - 2M/r) | 1 - 2M/r | r^2 | r > 2M |
//! | `Ellis` (throat b0) | 1 | 1 | b0^2 + l^2 | l in R; sign(l) is the side |
//!
//! `t` and `phi` are cyclic (`p_t = -E`, `p_phi = L` conserved). Kerr
//! (Boyer–Lindquist, the same state layout) joins as a variant with its own
//! arm in each method.

use super::hamiltonian::Hamiltonian;
use crate::real::Real;

/// A spacetime (closed set; see the module table).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Spacetime<F> {
    Minkowski,
    Schwarzschild { mass: F },
    Ellis { b0: F },
}

/// `A, dA/dr, B, dB/dr, R2, 1/R2, dR2/dr` at radial coordinate `r`.
struct Radial<F> {
    a: F,
    da: F,
    b: F,
    db: F,
    r2: F,
    inv_r2: F,
    dr2: F,
}

impl<F: Real> Spacetime<F> {
    /// The radial terms with two divisions at most (`1/r` and `1/f` for
    /// Schwarzschild, `1/R2` otherwise): every stage of a step calls this.
    #[inline]
    fn radial(&self, r: F) -> Radial<F> {
        let (one, zero, two) = (F::one(), F::zero(), F::of(2.0));
        match *self {
            Spacetime::Minkowski | Spacetime::Ellis { .. } => {
                let r2 = match *self {
                    Spacetime::Ellis { b0 } => b0 * b0 + r * r,
                    _ => r * r,
                };
                Radial {
                    a: one,
                    da: zero,
                    b: one,
                    db: zero,
                    r2,
                    inv_r2: one / r2,
                    dr2: two * r,
                }
            }
            Spacetime::Schwarzschild { mass } => {
                let inv_r = one / r;
                let f = one - two * mass * inv_r;
                let df = two * mass * inv_r * inv_r;
                let inv_f = one / f;
                Radial {
                    a: inv_f,
                    da: -df * inv_f * inv_f,
                    b: f,
                    db: df,
                    r2: r * r,
                    inv_r2: inv_r * inv_r,
                    dr2: two * r,
                }
            }
        }
    }

    /// The horizon radius (`2M` for Schwarzschild), if any.
    pub fn horizon(&self) -> Option<F> {
        match *self {
            Spacetime::Schwarzschild { mass } => Some(F::of(2.0) * mass),
            Spacetime::Minkowski | Spacetime::Ellis { .. } => None,
        }
    }

    /// Covariant momentum of a photon at radius `r` in the equatorial plane
    /// with energy `E = -p_t`, angular momentum `L = p_phi`, moving inward
    /// (`inward = true`) or outward, from `H = 0`; `None` where `r` lies in
    /// the forbidden region (no real `p_r`).
    pub fn equatorial_momentum(&self, r: F, e: F, l: F, inward: bool) -> Option<[F; 4]> {
        let c = self.radial(r);
        let pr2 = (c.a * e * e - l * l / c.r2) / c.b;
        if !(pr2 >= F::zero()) {
            return None;
        }
        let pr = if inward { -pr2.sqrt() } else { pr2.sqrt() };
        Some([-e, pr, F::zero(), l])
    }
}

impl<F: Real> Spacetime<F> {
    /// Covariant momentum of a photon of unit local energy leaving a
    /// static observer at radius `r` in the equatorial plane at angle `psi`
    /// from the inward radial direction (towards +phi): in the observer's
    /// orthonormal frame `p = (1, -cos psi, 0, sin psi)`, so
    /// `p_t = -1/sqrt(A)`, `p_r = -cos(psi)/sqrt(B)`, `p_phi = sqrt(R2) sin psi`.
    pub fn static_observer_momentum(&self, r: F, psi: F) -> [F; 4] {
        let c = self.radial(r);
        let (s, co) = psi.sin_cos();
        [
            -F::one() / c.a.sqrt(),
            -co / c.b.sqrt(),
            F::zero(),
            c.r2.sqrt() * s,
        ]
    }
}

/// The angular terms at `theta`: `1/sin`, `cos`, `ang = p_theta^2 + p_phi^2 / sin^2`.
struct Angular<F> {
    inv_s: F,
    co: F,
    ang: F,
}

#[inline]
fn angular<F: Real>(y: &[F; 8]) -> Angular<F> {
    let (s, co) = y[2].sin_cos();
    let inv_s = F::one() / s;
    Angular {
        inv_s,
        co,
        ang: y[6] * y[6] + y[7] * y[7] * inv_s * inv_s,
    }
}

impl<F: Real> Hamiltonian<F, 8> for Spacetime<F> {
    const SEPARABLE: bool = false;

    fn h(&self, y: &[F; 8]) -> F {
        self.rhs_h(y).1
    }

    fn dx(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = self.rhs(y);
        d[4..].fill(F::zero());
        d
    }

    fn dp(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = self.rhs(y);
        d[..4].fill(F::zero());
        d
    }

    fn rhs(&self, y: &[F; 8]) -> [F; 8] {
        self.rhs_h(y).0
    }

    /// One `sin_cos` and three divisions (`1/r`, `1/f`, `1/sin`) for the
    /// whole right-hand side and `H` (the per-stage referee,
    /// [`super::referee_kernel::SpacetimeReferee`], divides nine times per
    /// stage and evaluates `H` apart, with its own `sin`).
    #[inline]
    fn rhs_h(&self, y: &[F; 8]) -> ([F; 8], F) {
        let c = self.radial(y[1]);
        let g = angular(y);
        let half = F::of(0.5);
        let z = F::zero();
        let (pt2, pr2) = (y[4] * y[4], y[5] * y[5]);
        let inv_s2 = g.inv_s * g.inv_s;
        let dpr = -half * (-c.da * pt2 + c.db * pr2) + half * c.dr2 * g.ang * c.inv_r2 * c.inv_r2;
        let dpth = y[7] * y[7] * g.co * inv_s2 * g.inv_s * c.inv_r2;
        let h = (-c.a * pt2 + c.b * pr2 + g.ang * c.inv_r2) * half;
        (
            [
                -c.a * y[4],
                c.b * y[5],
                y[6] * c.inv_r2,
                y[7] * c.inv_r2 * inv_s2,
                z,
                dpr,
                dpth,
                z,
            ],
            h,
        )
    }

    fn scale(&self, y: &[F; 8]) -> F {
        match *self {
            Spacetime::Minkowski => y[1].abs(),
            Spacetime::Schwarzschild { mass } => y[1] - F::of(2.0) * mass,
            Spacetime::Ellis { b0 } => (b0 * b0 + y[1] * y[1]).sqrt(),
        }
    }

    /// Scales the spatial momenta `(p_r, p_theta, p_phi)` by one factor so
    /// that `H = 0`: keeps `E` and the direction of motion, changes `L`
    /// by the same relative amount as the drift.
    fn project(&self, y: &mut [F; 8]) {
        let c = self.radial(y[1]);
        let spatial = c.b * y[5] * y[5] + angular(y).ang * c.inv_r2;
        let time = c.a * y[4] * y[4];
        if spatial > F::zero() && time > F::zero() {
            let k = (time / spatial).sqrt();
            for v in &mut y[5..8] {
                *v *= k;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_rhs(st: &Spacetime<f64>, y: [f64; 8]) -> [f64; 8] {
        let e = 1e-6;
        let d = |i: usize| {
            let (mut a, mut b) = (y, y);
            a[i] += e;
            b[i] -= e;
            (st.h(&a) - st.h(&b)) / (2.0 * e)
        };
        [d(4), d(5), d(6), d(7), -d(0), -d(1), -d(2), -d(3)]
    }

    #[test]
    fn hamilton_equations_match_differences_of_h() {
        let y = [0.3, 7.5, 1.1, 0.4, -1.0, -0.6, 0.8, 3.0];
        for st in [
            Spacetime::Minkowski,
            Spacetime::Schwarzschild { mass: 1.0 },
            Spacetime::Ellis { b0: 1.0 },
        ] {
            let a = st.rhs(&y);
            let f = fd_rhs(&st, y);
            let split = super::super::hamiltonian::axpy(&st.dx(&y), 1.0, &st.dp(&y));
            for i in 0..8 {
                assert!(
                    (a[i] - f[i]).abs() < 1e-8,
                    "{st:?} slot {i}: {a:?} vs {f:?}"
                );
                assert!((a[i] - split[i]).abs() < 1e-15);
            }
        }
        // Ellis at negative l (the other side).
        let st = Spacetime::Ellis { b0: 1.0 };
        let y = [0.0, -3.0, 1.0, 0.0, -1.0, 0.5, 0.2, 1.5];
        let (a, f) = (st.rhs(&y), fd_rhs(&st, y));
        assert!((0..8).all(|i| (a[i] - f[i]).abs() < 1e-8));
    }

    #[test]
    fn equatorial_launch_is_null_and_forbidden_region_is_refused() {
        let st = Spacetime::Schwarzschild { mass: 1.0f64 };
        let p = st.equatorial_momentum(1000.0, 1.0, 10.0, true).unwrap();
        let y = [
            0.0,
            1000.0,
            std::f64::consts::FRAC_PI_2,
            0.0,
            p[0],
            p[1],
            p[2],
            p[3],
        ];
        assert!(st.h(&y).abs() < 1e-15);
        assert!(p[1] < 0.0);
        // b = 10 has its turning point near r = 8.7: r = 5 is forbidden.
        assert!(st.equatorial_momentum(5.0, 1.0, 10.0, true).is_none());
        assert_eq!(st.horizon(), Some(2.0));
    }

    #[test]
    fn static_observer_photons_are_null() {
        for st in [
            Spacetime::Minkowski,
            Spacetime::Schwarzschild { mass: 1.0f64 },
            Spacetime::Ellis { b0: 1.0 },
        ] {
            for psi in [0.0, 0.7, 1.9, 3.0] {
                let p = st.static_observer_momentum(6.0, psi);
                let y = [
                    0.0,
                    6.0,
                    std::f64::consts::FRAC_PI_2,
                    0.0,
                    p[0],
                    p[1],
                    p[2],
                    p[3],
                ];
                assert!(st.h(&y).abs() < 1e-15, "{st:?} psi={psi}");
            }
        }
    }

    #[test]
    fn projection_restores_null_and_keeps_energy() {
        let st = Spacetime::Schwarzschild { mass: 1.0f64 };
        let mut y = [0.0, 10.0, 1.2, 0.0, -1.0, -0.5, 0.3, 4.0];
        st.project(&mut y);
        assert!(st.h(&y).abs() < 1e-15);
        assert_eq!(y[4], -1.0);
    }
}
