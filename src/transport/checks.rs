//! Harnesses that run the integrators against themselves: the observed
//! order of accuracy under step scaling, and the growth of the Hamiltonian
//! drift with the number of steps. The judge's transport ops wire a scene's
//! task to these.

use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};

use super::integrate::Options;
use super::outputs::{f64s, run_task};
use super::tasks::{grin_rays, GrinRays, GrinStop, Task};

/// The task traced with the tier's step scaled by each of three `factors`
/// in one geometric ratio: `order` per ray, `log2(|q1 - q2| / |q2 - q3|) /
/// log2(f1 / f2)` with Euclidean differences over a ray's quantity (0 where
/// the levels agree exactly, so an order gate fails); `levels` (3, n, k);
/// `level_steps`.
pub fn convergence_order<F: Real>(
    task: &Task<F>,
    opt: &Options<F>,
    factors: &[f64],
    budget: &MemBudget,
) -> Result<Outputs> {
    let mut levels: Vec<Vec<Vec<f64>>> = vec![];
    let mut steps = vec![];
    for &k in factors {
        let o = Options {
            tier: opt.tier.scaled_by(F::of(k)),
            ..*opt
        };
        let mut tmp = Outputs::default();
        levels.push(run_task(task, &o, budget, &[], &mut tmp, None)?);
        steps.push(tmp.counters.get("steps").copied().unwrap_or(0) as f64);
    }
    let n = levels[0].len();
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt()
    };
    let order: Vec<f64> = (0..n)
        .map(|i| {
            let d1 = dist(&levels[0][i], &levels[1][i]);
            let d2 = dist(&levels[1][i], &levels[2][i]);
            if d1 > 0.0 && d2 > 0.0 {
                (d1 / d2).log2() / (factors[0] / factors[1]).log2()
            } else {
                0.0
            }
        })
        .collect();
    let mut out = Outputs::default();
    out.tensor("order", f64s(order)?);
    let k = levels[0].first().map_or(0, Vec::len);
    let flat: Vec<f64> = levels.into_iter().flatten().flatten().collect();
    out.tensor(
        "levels",
        Tensor::from_shape_vec(&[factors.len(), n, k], flat)?,
    );
    out.tensor("level_steps", f64s(steps)?);
    Ok(out)
}

/// `max |H|` per ray of a GRIN task after `n[0]` and after `n[1]` steps
/// (`h_drift_short`, `h_drift_long`) and their ratio (`growth`).
pub fn drift_growth<F: Real>(
    task: &Task<F>,
    opt: &Options<F>,
    n: [u64; 2],
    budget: &MemBudget,
) -> Result<Outputs> {
    let Task::Grin(g) = task else {
        return Err(Error::invalid(
            "task",
            "transport.drift_growth needs a `type: grin` task",
        ));
    };
    let run = |k: u64| -> Result<Vec<f64>> {
        let t = GrinRays {
            stop: GrinStop::Steps { n: k },
            ..g.clone()
        };
        let r = grin_rays(&t, opt, budget, &[])?;
        Ok(r.h_drift.iter().map(|v| v.f64()).collect())
    };
    let (a, b) = (run(n[0])?, run(n[1])?);
    let growth = a
        .iter()
        .zip(&b)
        .map(|(x, y)| if *x > 0.0 { y / x } else { f64::MAX })
        .collect();
    let mut out = Outputs::default();
    out.tensor("h_drift_short", f64s(a)?)
        .tensor("h_drift_long", f64s(b)?)
        .tensor("growth", f64s(growth)?);
    Ok(out)
}
