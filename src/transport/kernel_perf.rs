//! The kernels of one photon list in one run: a Schwarzschild deflection
//! list and the same impact parameters in Kerr, each traced with the fused
//! scalar right-hand side (`fused`) and its per-stage referee (`referee`);
//! Schwarzschild also on the lane path ([`super::lane_trace`]): AVX2+FMA
//! lanes (`lanes`, when the CPU has them) and the portable lanes
//! (`portable`). Rounds interleave the kernels (round 1: every kernel, then
//! round 2, ...) and the best CPU time of each counts (the machine may be
//! shared: per-CPU-second rates are the comparable figures, wall rates are
//! reported beside them).
//!
//! Metrics per system `s` in `schw`, `kerr` and kernel `k`:
//! `{s}_{k}_steps_per_cpu_s`, `{s}_{k}_steps_per_s` (wall), `{s}_{k}_cpu_s`;
//! `{s}_speedup` (referee CPU time / fused CPU time, equal steps),
//! `{s}_max_deflection_diff` (rad, referee vs fused), counter `{s}_steps`;
//! for the lane kernels `schw_{k}_speedup` (fused CPU time / lane CPU time),
//! `schw_{k}_max_deflection_diff` (rad, vs fused) and
//! `schw_{k}_class_diff` (rays whose end reason differs from fused).

use super::integrate::Options;
use super::kerr::Kerr;
use super::kerr_trace::{kerr_deflection, kerr_deflection_by, KerrDeflection};
use super::lane_trace::Kernel;
use super::metric::Spacetime;
use super::referee_kernel::{deflection_referee, KerrReferee};
use super::tasks::{deflection_with, Task};
use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::judge::measure::timed;
use crate::tensor::Outputs;

/// One traced list: deflections, end reasons and the photon-steps taken.
type Run = (Vec<f64>, Vec<i32>, u64);

fn total(steps: &[i32]) -> u64 {
    steps.iter().map(|&s| s.max(0) as u64).sum()
}

/// Per kernel: its last result, best CPU s and best wall s over `rounds`
/// interleaved rounds of every kernel.
fn interleaved(rounds: usize, fs: &[(&str, Tracer)]) -> Result<Vec<(Run, f64, f64)>> {
    let mut best: Vec<(Option<Run>, f64, f64)> = fs
        .iter()
        .map(|_| (None, f64::INFINITY, f64::INFINITY))
        .collect();
    for _ in 0..rounds.max(1) {
        for ((_, f), b) in fs.iter().zip(&mut best) {
            let (r, w, c) = timed(f);
            b.0 = Some(r?);
            b.1 = b.1.min(c);
            b.2 = b.2.min(w);
        }
    }
    best.into_iter()
        .map(|(r, c, w)| {
            r.map(|r| (r, c, w))
                .ok_or_else(|| Error::invalid("rounds", "must be >= 1"))
        })
        .collect()
}

fn max_diff(a: &[f64], b: &[f64]) -> f64 {
    a.iter()
        .zip(b)
        .fold(0.0f64, |m, (x, y)| m.max((x - y).abs()))
}

type Tracer<'a> = Box<dyn Fn() -> Result<Run> + 'a>;

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
    let schw = |k: Kernel| -> Tracer {
        Box::new(move || {
            deflection_with(task, opt, budget, &[], k)
                .map(|r| (r.deflection, r.reason, total(&r.steps)))
        })
    };
    let mut schw_kernels = vec![
        ("fused", schw(Kernel::Scalar)),
        ("referee", {
            let t: Tracer = Box::new(|| {
                deflection_referee(task, opt, budget)
                    .map(|r| (r.deflection, r.reason, total(&r.steps)))
            });
            t
        }),
        ("portable", schw(Kernel::Portable)),
    ];
    if Kernel::best() == Kernel::Avx2 {
        schw_kernels.push(("lanes", schw(Kernel::Avx2)));
    }
    let kerr_kernels: Vec<(&str, Tracer)> = vec![
        (
            "fused",
            Box::new(|| {
                kerr_deflection(&kt, opt).map(|r| (r.deflection, r.reason, total(&r.steps)))
            }),
        ),
        (
            "referee",
            Box::new(|| {
                kerr_deflection_by(&kt, opt, KerrReferee)
                    .map(|r| (r.deflection, r.reason, total(&r.steps)))
            }),
        ),
    ];
    for (s, kernels) in [("schw", &schw_kernels), ("kerr", &kerr_kernels)] {
        let res = interleaved(rounds, kernels)?;
        for ((k, _), ((_, _, steps), c, w)) in kernels.iter().zip(&res) {
            out.metric(
                &format!("{s}_{k}_steps_per_cpu_s"),
                *steps as f64 / c.max(0.01),
            );
            out.metric(&format!("{s}_{k}_steps_per_s"), *steps as f64 / w.max(1e-9));
            out.metric(&format!("{s}_{k}_cpu_s"), *c);
        }
        let ((fused, reason, steps), c_fused, _) = &res[0];
        out.counter(&format!("{s}_steps"), *steps);
        out.metric(&format!("{s}_speedup"), res[1].1 / c_fused.max(0.01));
        out.metric(
            &format!("{s}_max_deflection_diff"),
            max_diff(fused, &res[1].0 .0),
        );
        for ((k, _), ((d, r, _), c, _)) in kernels.iter().zip(&res).skip(2) {
            out.metric(&format!("{s}_{k}_speedup"), c_fused / c.max(0.01));
            out.metric(&format!("{s}_{k}_max_deflection_diff"), max_diff(fused, d));
            let class = reason.iter().zip(r).filter(|(x, y)| x != y).count();
            out.metric(&format!("{s}_{k}_class_diff"), class as f64);
        }
    }
    Ok(out)
}
