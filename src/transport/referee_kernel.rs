//! The per-stage right-hand sides the fused kernels replaced, kept as their
//! referees (issue 16): every stage recomputes the metric in full with libm
//! trig and plain divisions, and `H` is a separate evaluation. Wrapping a
//! system in [`SpacetimeReferee`] or [`KerrReferee`] traces it with these
//! formulas through the same loop, so a run with each measures the
//! kernels' speed-up and their agreement (`transport.perf_kernels`, the
//! tests below). Nothing here calls `metric::Spacetime`'s or
//! `kerr::kerr_rhs_h`'s arithmetic; scale and projection (step law and
//! constraint, not the kernel) are the wrapped system's.

use super::hamiltonian::Hamiltonian;
use super::integrate::Options;
use super::kerr::{ks_radius, Kerr};
use super::metric::Spacetime;
use super::tasks::{deflection_out, deflection_setup, Deflection, DeflectionOut};
use crate::budget::MemBudget;
use crate::error::Result;
use crate::parallel::par_collect;
use crate::real::Real;

/// [`Spacetime`] with the per-stage formulas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SpacetimeReferee<F>(pub Spacetime<F>);

/// `A, dA/dr, B, dB/dr, R2, dR2/dr` at `r`.
fn radial<F: Real>(st: &Spacetime<F>, r: F) -> [F; 6] {
    let (one, zero, two) = (F::one(), F::zero(), F::of(2.0));
    match *st {
        Spacetime::Minkowski => [one, zero, one, zero, r * r, two * r],
        Spacetime::Schwarzschild { mass } => {
            let f = one - two * mass / r;
            let df = two * mass / (r * r);
            [one / f, -df / (f * f), f, df, r * r, two * r]
        }
        Spacetime::Ellis { b0 } => [one, zero, one, zero, b0 * b0 + r * r, two * r],
    }
}

impl<F: Real> Hamiltonian<F, 8> for SpacetimeReferee<F> {
    const SEPARABLE: bool = false;

    fn h(&self, y: &[F; 8]) -> F {
        let [a, _, b, _, r2, _] = radial(&self.0, y[1]);
        let s = y[2].sin();
        let ang = (y[6] * y[6] + y[7] * y[7] / (s * s)) / r2;
        (-a * y[4] * y[4] + b * y[5] * y[5] + ang) * F::of(0.5)
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
        let [a, da, b, db, r2, dr2] = radial(&self.0, y[1]);
        let (s, co) = y[2].sin_cos();
        let half = F::of(0.5);
        let z = F::zero();
        let s2 = s * s;
        let ang = y[6] * y[6] + y[7] * y[7] / s2;
        let dpr = -half * (-da * y[4] * y[4] + db * y[5] * y[5]) + half * dr2 * ang / (r2 * r2);
        let dpth = y[7] * y[7] * co / (r2 * s2 * s);
        [
            -a * y[4],
            b * y[5],
            y[6] / r2,
            y[7] / (r2 * s2),
            z,
            dpr,
            dpth,
            z,
        ]
    }

    fn scale(&self, y: &[F; 8]) -> F {
        self.0.scale(y)
    }

    fn project(&self, y: &mut [F; 8]) {
        self.0.project(y)
    }
}

/// [`Kerr`] with the per-stage formulas.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KerrReferee<F>(pub Kerr<F>);

impl<F: Real> Hamiltonian<F, 8> for KerrReferee<F> {
    const SEPARABLE: bool = false;

    fn h(&self, y: &[F; 8]) -> F {
        let (m, a) = (self.0.mass, self.0.a);
        let (x, yy, z) = (y[1], y[2], y[3]);
        let (pt, px, py, pz) = (y[4], y[5], y[6], y[7]);
        let r = ks_radius(a, x, yy, z);
        let (r2, a2) = (r * r, a * a);
        let ra2 = r2 + a2;
        let f = F::of(2.0) * m * r2 * r / (r2 * r2 + a2 * z * z);
        let l = -pt + ((r * x + a * yy) * px + (r * yy - a * x) * py) / ra2 + z / r * pz;
        F::of(0.5) * (-pt * pt + px * px + py * py + pz * pz - f * l * l)
    }

    fn dx(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = self.rhs(y);
        d[5..].fill(F::zero());
        d
    }

    fn dp(&self, y: &[F; 8]) -> [F; 8] {
        let mut d = self.rhs(y);
        d[..5].fill(F::zero());
        d
    }

    fn rhs(&self, y: &[F; 8]) -> [F; 8] {
        let (m, a) = (self.0.mass, self.0.a);
        let (x, yy, z) = (y[1], y[2], y[3]);
        let (pt, px, py, pz) = (y[4], y[5], y[6], y[7]);
        let two = F::of(2.0);
        let r = ks_radius(a, x, yy, z);
        let (r2, a2) = (r * r, a * a);
        let ra2 = r2 + a2;
        let n = r2 * r2 + a2 * z * z;
        let f = two * m * r2 * r / n;
        let (lx, ly, lz) = ((r * x + a * yy) / ra2, (r * yy - a * x) / ra2, z / r);
        let lpxy = lx * px + ly * py;
        let big_l = -pt + lpxy + lz * pz;
        let r3n = r2 * r / n;
        let (rx, ry, rz) = (x * r3n, yy * r3n, z * r * ra2 / n);
        let k4 = F::of(4.0) * r2 * r / n;
        let fx = f * (F::of(3.0) / r - k4) * rx;
        let fy = f * (F::of(3.0) / r - k4) * ry;
        let fz = f * ((F::of(3.0) / r - k4) * rz - two * a2 * z / n);
        let q = x * px + yy * py;
        let c = (q - two * r * lpxy) / ra2 - pz * z / r2;
        let gx = rx * c + (r * px - a * py) / ra2;
        let gy = ry * c + (r * py + a * px) / ra2;
        let gz = rz * c + pz / r;
        let half_l2 = F::of(0.5) * big_l * big_l;
        let fl = f * big_l;
        [
            -pt + fl,
            px - fl * lx,
            py - fl * ly,
            pz - fl * lz,
            F::zero(),
            half_l2 * fx + fl * gx,
            half_l2 * fy + fl * gy,
            half_l2 * fz + fl * gz,
        ]
    }

    fn scale(&self, y: &[F; 8]) -> F {
        self.0.scale(y)
    }

    fn project(&self, y: &mut [F; 8]) {
        self.0.project(y)
    }
}

/// A deflection list traced with [`SpacetimeReferee`] (same start states,
/// events and loop as `tasks::deflection`).
pub fn deflection_referee<F: Real>(
    task: &Deflection<F>,
    opt: &Options<F>,
    budget: &MemBudget,
) -> Result<DeflectionOut<F>> {
    let (ev, starts) = deflection_setup(task, opt, budget, &[])?;
    let sys = SpacetimeReferee(task.spacetime);
    let traces = par_collect("transport.deflection_referee", starts.len(), |i| {
        let t = super::integrate::trace(&sys, starts[i], opt, &ev, |_, _| {});
        (t, Vec::new())
    });
    Ok(deflection_out(task, traces, &[]))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::integrate::{StepLaw, Tier};
    use crate::transport::kerr_trace::{kerr_deflection, kerr_deflection_by, KerrDeflection};

    fn rel(a: f64, b: f64) -> f64 {
        (a - b).abs() / b.abs().max(1e-3)
    }

    #[test]
    fn fused_kernels_agree_with_the_per_stage_formulas() {
        let y = [0.3, 7.5, 1.1, 0.4, -1.0, -0.6, 0.8, 3.0];
        for st in [
            Spacetime::Minkowski,
            Spacetime::Schwarzschild { mass: 1.0 },
            Spacetime::Ellis { b0: 1.0 },
        ] {
            let (k, h) = st.rhs_h(&y);
            let r = SpacetimeReferee(st);
            let kr = r.rhs(&y);
            assert!(
                (0..8).all(|i| rel(k[i], kr[i]) < 1e-14),
                "{st:?}: {k:?} vs {kr:?}"
            );
            assert!((h - r.h(&y)).abs() < 1e-14);
        }
        let k = Kerr { mass: 1.0, a: 0.9 };
        for y in [
            [0.0, 6.0, -2.0, 1.5, -1.0, -0.7, 0.3, 0.2],
            [0.0, 0.1, 0.05, 1.6, -1.0, 0.1, -0.2, -0.9],
        ] {
            let (d, h) = k.rhs_h(&y);
            let r = KerrReferee(k);
            let dr = r.rhs(&y);
            assert!((0..8).all(|i| rel(d[i], dr[i]) < 1e-13), "{d:?} vs {dr:?}");
            assert!((h - r.h(&y)).abs() < 1e-13);
        }
    }

    fn rk4() -> Options<f64> {
        Options {
            tier: Tier::Rk4(StepLaw::Scaled {
                eta: 0.01,
                h_min: 1e-6,
                h_max: 1e6,
            }),
            project: false,
            max_steps: 1_000_000,
        }
    }

    /// The SCENES.md list: deflections agree to 1e-11 rad (measured max
    /// 1e-12 order) and the step counts are equal.
    #[test]
    fn fused_kernels_trace_the_referees_deflections() {
        let impact = vec![5.3, 6.0, 8.0, 10.0, 20.0, 50.0, 100.0, 300.0];
        let task = Deflection {
            spacetime: Spacetime::Schwarzschild { mass: 1.0 },
            impact: impact.clone(),
            r_start: 1000.0,
            r_end: 1000.0,
            horizon_eps: 1e-6,
        };
        let b = MemBudget::fixed(1 << 30);
        let new = crate::transport::tasks::deflection(&task, &rk4(), &b, &[]).unwrap();
        let old = deflection_referee(&task, &rk4(), &b).unwrap();
        assert_eq!(new.steps, old.steps);
        for (a, b) in new.deflection.iter().zip(&old.deflection) {
            assert!((a - b).abs() < 1e-11, "{a} vs {b}");
        }
        let kt = KerrDeflection {
            kerr: Kerr { mass: 1.0, a: 0.9 },
            impact,
            r_start: 1000.0,
            r_end: 1000.0,
        };
        let new = kerr_deflection(&kt, &rk4()).unwrap();
        let old = kerr_deflection_by(&kt, &rk4(), KerrReferee).unwrap();
        assert_eq!(new.steps, old.steps);
        assert_eq!(new.captured, old.captured);
        for (a, b) in new.deflection.iter().zip(&old.deflection) {
            assert!((a - b).abs() < 1e-11, "{a} vs {b}");
        }
    }
}
