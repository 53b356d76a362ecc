//! The fused kernels against their per-stage referees
//! ([`super::referee_kernel`]) in one run: a Schwarzschild deflection list
//! and the same impact parameters in Kerr, each traced with the fused and
//! the referee right-hand side, `rounds` times each; the best CPU
//! time of each counts (the machine may be shared: per-CPU-second rates are
//! the comparable figures, wall rates are reported beside them).
//!
//! Metrics per system `s` in `schw`, `kerr` and kernel `k` in `fused`,
//! `referee`: `{s}_{k}_steps_per_cpu_s`, `{s}_{k}_steps_per_s` (wall),
//! `{s}_{k}_cpu_s`; `{s}_speedup` (referee CPU time / fused CPU time, equal
//! steps), `{s}_max_deflection_diff` (rad) and counter `{s}_steps`.

use super::integrate::Options;
use super::kerr::Kerr;
use super::kerr_trace::{kerr_deflection, kerr_deflection_by, KerrDeflection};
use super::metric::Spacetime;
use super::referee_kernel::{deflection_referee, KerrReferee};
use super::tasks::{deflection, Task};
use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::judge::measure::timed;
use crate::tensor::Outputs;

/// One traced list: deflections and the photon-steps taken.
type Run = (Vec<f64>, u64);

fn total(steps: &[i32]) -> u64 {
    steps.iter().map(|&s| s.max(0) as u64).sum()
}

/// Best-of-`rounds` (CPU s, wall s) of `f`, and its last result.
fn best(rounds: usize, mut f: impl FnMut() -> Result<Run>) -> Result<(Run, f64, f64)> {
    let (mut cpu, mut wall, mut last) = (f64::INFINITY, f64::INFINITY, None);
    for _ in 0..rounds {
        let (r, w, c) = timed(&mut f);
        last = Some(r?);
        cpu = cpu.min(c);
        wall = wall.min(w);
    }
    Ok((
        last.ok_or_else(|| Error::invalid("rounds", "must be >= 1"))?,
        cpu,
        wall,
    ))
}

/// Runs the comparison for the Schwarzschild deflection list `task` (mass
/// `M`) and Kerr with spin `a` on the same impact parameters and radii.
pub fn compare_kernels(
    task: &Task<f64>,
    opt: &Options<f64>,
    budget: &MemBudget,
    a: f64,
    rounds: usize,
) -> Result<Outputs> {
    let Task::Deflection(task) = task else {
        return Err(Error::invalid(
            "task",
            "transport.perf_kernels needs a deflection scene",
        ));
    };
    let Spacetime::Schwarzschild { mass } = task.spacetime else {
        return Err(Error::invalid(
            "task.spacetime",
            "the kernel comparison needs a Schwarzschild deflection scene",
        ));
    };
    let kt = KerrDeflection {
        kerr: Kerr { mass, a },
        impact: task.impact.clone(),
        r_start: task.r_start,
        r_end: task.r_end,
    };
    let mut out = Outputs::default();
    type Tracer<'a> = Box<dyn Fn() -> Result<Run> + 'a>;
    let systems: [(&str, Tracer, Tracer); 2] = [
        (
            "schw",
            Box::new(|| {
                deflection(task, opt, budget, &[]).map(|r| (r.deflection, total(&r.steps)))
            }),
            Box::new(|| {
                deflection_referee(task, opt, budget).map(|r| (r.deflection, total(&r.steps)))
            }),
        ),
        (
            "kerr",
            Box::new(|| kerr_deflection(&kt, opt).map(|r| (r.deflection, total(&r.steps)))),
            Box::new(|| {
                kerr_deflection_by(&kt, opt, KerrReferee).map(|r| (r.deflection, total(&r.steps)))
            }),
        ),
    ];
    for (s, fused, referee) in &systems {
        let mut cpu = [0.0; 2];
        let mut defl = Vec::new();
        for (i, (k, f)) in [("fused", fused), ("referee", referee)]
            .into_iter()
            .enumerate()
        {
            let ((d, steps), c, w) = best(rounds, f)?;
            cpu[i] = c;
            out.metric(
                &format!("{s}_{k}_steps_per_cpu_s"),
                steps as f64 / c.max(0.01),
            );
            out.metric(&format!("{s}_{k}_steps_per_s"), steps as f64 / w.max(1e-9));
            out.metric(&format!("{s}_{k}_cpu_s"), c);
            out.counter(&format!("{s}_steps"), steps);
            defl.push(d);
        }
        out.metric(&format!("{s}_speedup"), cpu[1] / cpu[0].max(0.01));
        let diff = defl[0]
            .iter()
            .zip(&defl[1])
            .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()));
        out.metric(&format!("{s}_max_deflection_diff"), diff);
    }
    Ok(out)
}
