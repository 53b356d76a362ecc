//! Backend dispatch of `transport.render` (issue 17): each task runs on the
//! CPU fan-out (`crate::transport::tasks`) or, with `backend: gpu`, on
//! `kernels/transport.wgsl` (`crate::transport::gpu`, f32 only), with the
//! same outputs. The GPU pipeline is built before the op's timer starts,
//! so `time_s` / `ns_per_step` cover upload, kernel and readback only.
//!
//! `transport.perf_backends` runs one scene's task on both backends in f32
//! (the perf scenario `transport_backends_*`): metrics `cpu_ns_per_step`,
//! `gpu_ns_per_step`, `*_steps_per_s`, `*_time_s`, `gpu_over_cpu_speed`.

use std::time::Instant;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::real::Precision;
use crate::scene::transport::{parse, TransportScene};
use crate::tensor::Outputs;
use crate::transport::integrate::Options;
use crate::transport::tasks::{Curved, Task};
use crate::transport::{gpu, image, tasks};

/// Refuses what the GPU backend cannot run (anything but f32) and builds
/// the scene's pipeline; nothing for the CPU backend.
pub fn prepare(ctx: &OpCtx, s: &TransportScene) -> Result<()> {
    if ctx.backend == BackendKind::Gpu {
        if ctx.precision != Precision::F32 {
            return Err(Error::NotSupported(format!(
                "{}: the GPU computes in f32 only",
                ctx.case_id
            )));
        }
        let (task, opt) = s.build::<f32>()?;
        gpu::warm(GpuContext::get()?, &task, &opt, &ctx.budget)?;
    }
    Ok(())
}

/// The GPU context when `ctx` runs on the GPU backend, else `None`.
pub fn gpu(ctx: &OpCtx) -> Result<Option<&'static GpuContext>> {
    match ctx.backend {
        BackendKind::Cpu => Ok(None),
        BackendKind::Gpu => GpuContext::get().map(Some),
    }
}

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "transport.perf_backends",
    doc: "the scene's task traced in f32 on the CPU fan-out and on the GPU kernel: photon-steps/s and ns per photon-step of each, and their ratio",
    params: &[],
    support: Support::GpuF32,
    run: perf_backends,
}];

/// Traces `task` on `backend`; the seconds and the photon-steps taken.
fn timed(
    ctx: &OpCtx,
    backend: BackendKind,
    task: &Task<f32>,
    opt: &Options<f32>,
) -> Result<(f64, u64)> {
    let g = gpu(&OpCtx { backend, ..*ctx })?;
    let b = &ctx.budget;
    let t = Instant::now();
    let steps = match (task, g) {
        (Task::Curved(Curved::Image(t)), None) => image::render(t, opt, b)?.steps,
        (Task::Curved(Curved::Image(t)), Some(c)) => gpu::render_image(c, t, opt, b)?.steps,
        (Task::Curved(_), _) => return Err(gpu::curved_not_supported()),
        (Task::Deflection(d), None) => tasks::deflection(d, opt, b, &[])?.steps,
        (Task::Deflection(d), Some(c)) => gpu::deflection(c, d, opt, b, &[])?.steps,
        (Task::Observer(s), None) => tasks::observer_scan(s, opt, b, &[])?.steps,
        (Task::Observer(s), Some(c)) => gpu::observer_scan(c, s, opt, b, &[])?.steps,
        (Task::Grin(r), None) => tasks::grin_rays(r, opt, b, &[])?.steps,
        (Task::Grin(r), Some(c)) => gpu::grin_rays(c, r, opt, b, &[])?.steps,
    };
    Ok((
        t.elapsed().as_secs_f64(),
        steps.iter().map(|&s| s.max(0) as u64).sum(),
    ))
}

fn perf_backends(ctx: &OpCtx) -> Result<Outputs> {
    let s = parse(ctx.scene()?)?;
    let (task, opt) = s.build::<f32>()?;
    gpu::warm(GpuContext::get()?, &task, &opt, &ctx.budget)?;
    let mut out = Outputs::default();
    let mut ns = [0.0; 2];
    for (k, (b, name)) in [(BackendKind::Cpu, "cpu"), (BackendKind::Gpu, "gpu")]
        .into_iter()
        .enumerate()
    {
        let (secs, steps) = timed(ctx, b, &task, &opt)?;
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
