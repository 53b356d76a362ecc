//! Backend dispatch of `transport.render` (issue 17): each task runs on the
//! CPU fan-out (`crate::transport::tasks`) or, with `backend: gpu`, on
//! `kernels/transport.wgsl` (`crate::transport::gpu`, f32 only), with the
//! same outputs. The GPU pipeline is built before the op's timer starts,
//! so `time_s` / `ns_per_step` cover upload, kernel and readback only.

use super::{BackendKind, OpCtx};
use crate::error::{Error, Result};
use crate::gpu::transport::TracePipeline;
use crate::gpu::GpuContext;
use crate::real::{Precision, Real};
use crate::transport::integrate::Options;
use crate::transport::tasks::{
    Deflection, DeflectionOut, GrinOut, GrinRays, ObserverOut, ObserverScan,
};
use crate::transport::{gpu, tasks};

/// Refuses what the GPU backend cannot run (anything but f32) and warms its
/// pipeline; nothing for the CPU backend.
pub fn prepare(ctx: &OpCtx) -> Result<()> {
    if ctx.backend == BackendKind::Gpu {
        if ctx.precision != Precision::F32 {
            return Err(Error::NotSupported(format!(
                "{}: the GPU computes in f32 only",
                ctx.case_id
            )));
        }
        TracePipeline::new(GpuContext::get()?)?;
    }
    Ok(())
}

pub fn deflection<F: Real>(
    ctx: &OpCtx,
    d: &Deflection<F>,
    opt: &Options<F>,
    dump: &[usize],
) -> Result<DeflectionOut<F>> {
    match ctx.backend {
        BackendKind::Cpu => tasks::deflection(d, opt, &ctx.budget, dump),
        BackendKind::Gpu => gpu::deflection(GpuContext::get()?, d, opt, &ctx.budget, dump),
    }
}

pub fn observer_scan<F: Real>(
    ctx: &OpCtx,
    s: &ObserverScan<F>,
    opt: &Options<F>,
    dump: &[usize],
) -> Result<ObserverOut<F>> {
    match ctx.backend {
        BackendKind::Cpu => tasks::observer_scan(s, opt, &ctx.budget, dump),
        BackendKind::Gpu => gpu::observer_scan(GpuContext::get()?, s, opt, &ctx.budget, dump),
    }
}

pub fn grin_rays<F: Real>(
    ctx: &OpCtx,
    g: &GrinRays<F>,
    opt: &Options<F>,
    dump: &[usize],
) -> Result<GrinOut<F>> {
    match ctx.backend {
        BackendKind::Cpu => tasks::grin_rays(g, opt, &ctx.budget, dump),
        BackendKind::Gpu => gpu::grin_rays(GpuContext::get()?, g, opt, &ctx.budget, dump),
    }
}
