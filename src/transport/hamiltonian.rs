//! The one interface every transport law implements: a Hamiltonian on a
//! phase space of `N` reals, `y = (x, p)` with `x = y[..N/2]` the position
//! and `p = y[N/2..]` the covariant momentum, integrated in an affine
//! parameter `lambda` by Hamilton's equations
//! `dx/dlambda = dH/dp`, `dp/dlambda = -dH/dx`.
//!
//! Two closed families implement it: [`crate::transport::grin::Medium`]
//! (`N = 6`, GRIN optics) and [`crate::transport::metric::Spacetime`]
//! (`N = 8`, null geodesics). Kerr joins `Spacetime` as a variant. Rays live on
//! the constraint surface `H = 0`; `|H|` along a ray measures drift.

use crate::real::Real;

/// A Hamiltonian system the integrators can step. Everything here is pure
/// and allocation-free (arrays on the stack).
pub trait Hamiltonian<F: Real, const N: usize>: Sync {
    /// `H = T(p) + V(x)` with `dH/dp` a function of `p` alone and `dH/dx`
    /// a function of `x` alone: the kick-drift (Störmer–Verlet, Yoshida)
    /// tiers need this and are refused otherwise.
    const SEPARABLE: bool;

    /// `H(y)`.
    fn h(&self, y: &[F; N]) -> F;

    /// `dH/dp` in the position slots, zero in the momentum slots.
    fn dx(&self, y: &[F; N]) -> [F; N];

    /// `-dH/dx` in the momentum slots, zero in the position slots.
    fn dp(&self, y: &[F; N]) -> [F; N];

    /// `dy/dlambda` (both halves at once; implementors may share work).
    fn rhs(&self, y: &[F; N]) -> [F; N] {
        let mut a = self.dx(y);
        let b = self.dp(y);
        for i in 0..N {
            a[i] += b[i];
        }
        a
    }

    /// `(dy/dlambda, H)` at `y` in one pass. The RK4 loop takes a step's
    /// first stage and the drift `|H|` of its start from one call at the
    /// end of the step before; implementors share the metric terms between
    /// the two (the default computes them apart).
    fn rhs_h(&self, y: &[F; N]) -> ([F; N], F) {
        (self.rhs(y), self.h(y))
    }

    /// The local length scale that step laws multiply (`h = eta * scale`):
    /// 1 for GRIN media, `r` (Minkowski), `r - 2M` (Schwarzschild, the
    /// distance from the horizon), `sqrt(b0^2 + l^2)` (Ellis).
    fn scale(&self, y: &[F; N]) -> F;

    /// Moves `y` back onto `H = 0` (optional constraint projection). Each
    /// implementor documents which conserved quantities it keeps.
    fn project(&self, y: &mut [F; N]);
}

/// `a + s * b`, element-wise.
#[inline]
pub fn axpy<F: Real, const N: usize>(a: &[F; N], s: F, b: &[F; N]) -> [F; N] {
    let mut o = *a;
    for i in 0..N {
        o[i] += s * b[i];
    }
    o
}

/// `true` when every element is finite.
#[inline]
pub fn all_finite<F: Real, const N: usize>(y: &[F; N]) -> bool {
    y.iter().all(|v| v.is_finite())
}
