//! The transport tasks traced on the CPU fan-out and on the GPU kernel in
//! one run (the perf scenarios `transport_backends_*`).

use std::time::Instant;

use crate::budget::MemBudget;
use crate::error::Result;
use crate::gpu::GpuContext;
use crate::tensor::Outputs;
use crate::transport::integrate::Options;
use crate::transport::tasks::Task;
use crate::transport::{gpu, tasks};

/// Traces `task` on the CPU (`gpu` None) or the GPU; the seconds and the
/// photon-steps taken.
fn traced(
    task: &Task<f32>,
    opt: &Options<f32>,
    g: Option<&GpuContext>,
    b: &MemBudget,
) -> Result<(f64, u64)> {
    let t = Instant::now();
    let steps = match (task, g) {
        (Task::Curved(_), _) => return Err(gpu::curved_not_supported()),
        (Task::Deflection(d), None) => tasks::deflection(d, opt, b, &[])?.steps,
        (Task::Deflection(d), Some(c)) => gpu::deflection(c, d, opt, b, &[])?.steps,
        (Task::Observer(s), None) => tasks::observer_scan(s, opt, b, &[])?.steps,
        (Task::Observer(s), Some(c)) => gpu::observer_scan(c, s, opt, b, &[])?.steps,
        (Task::Grin(r), None) => tasks::grin_rays(r, opt, b, &[])?.steps,
        (Task::Grin(r), Some(c)) => gpu::grin_rays(c, r, opt, b, &[])?.steps,
    };
    let steps = steps.iter().map(|&s| s.max(0) as u64).sum();
    Ok((t.elapsed().as_secs_f64(), steps))
}

/// Photon-steps/s, ns per photon-step and seconds of each backend (the GPU
/// pipeline built first), and `gpu_over_cpu_speed`.
pub fn backends(
    task: &Task<f32>,
    opt: &Options<f32>,
    g: &GpuContext,
    b: &MemBudget,
) -> Result<Outputs> {
    gpu::warm(g, task, opt, b)?;
    let mut out = Outputs::default();
    let mut ns = [0.0; 2];
    for (k, (c, name)) in [(None, "cpu"), (Some(g), "gpu")].into_iter().enumerate() {
        let (secs, steps) = traced(task, opt, c, b)?;
        ns[k] = secs * 1e9 / steps.max(1) as f64;
        out.metric(&format!("{name}_ns_per_step"), ns[k]);
        out.metric(
            &format!("{name}_steps_per_s"),
            steps as f64 / secs.max(1e-12),
        );
        out.metric(&format!("{name}_time_s"), secs);
        out.counter(&format!("{name}_steps"), steps);
    }
    out.metric("gpu_over_cpu_speed", ns[0] / ns[1].max(1e-30));
    Ok(out)
}
