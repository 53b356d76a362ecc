//! The GPU rows of `volume.grad`, `volume.grad_perf`, `volume.render
//! --grad-from` (`volume::diff::gpu::f_diff_gpu`: the CPU rows' tensors;
//! `params.reduce` fixed | float_atomic) and `volume.session` (issue 19).

use super::volume_diff::{load, loss_weights, probe_spec};
use super::OpCtx;
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::judge::measure::volume_gpu as measure;
use crate::real::Precision;
use crate::tensor::Outputs;
use crate::volume::diff::gpu::{f_diff_gpu, GpuDiff};
use crate::volume::loss::ProbeSpec;
use crate::volume::VolumeParams;

fn f32_only(ctx: &OpCtx) -> Result<&'static GpuContext> {
    if ctx.precision != Precision::F32 {
        let why = format!("{}: the GPU computes in f32 only", ctx.case_id);
        return Err(Error::NotSupported(why));
    }
    GpuContext::get()
}

fn run(ctx: &OpCtx, float_atomic: bool) -> Result<(GpuDiff, VolumeParams)> {
    let gpu = f32_only(ctx)?;
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?.upstream::<f32>();
    Ok((
        f_diff_gpu(gpu, &cam, &gen, &p, &w, float_atomic, &ctx.budget)?,
        p,
    ))
}

/// `volume.grad` on the GPU, plus `forward_time_s` and `bwd_fwd_ratio`.
pub fn grad(ctx: &OpCtx) -> Result<Outputs> {
    let probes = probe_spec(ctx)?;
    let float_atomic = match ctx.param_or::<String>("reduce", "fixed".into())?.as_str() {
        "fixed" => false,
        "float_atomic" => true,
        o => {
            return Err(ctx.bad(
                "reduce",
                format!("{o:?} is not fixed or float_atomic (GPU)"),
            ))
        }
    };
    let (g, p) = run(ctx, float_atomic)?;
    let mut out = Outputs::default();
    crate::volume::grad_outputs::grad_outputs(&g.grads, &p, &probes, &mut out)?;
    out.metric("forward_time_s", g.forward_s);
    out.metric("bwd_fwd_ratio", g.grads.time_s / g.forward_s.max(1e-12));
    Ok(out)
}

/// The GPU backward's gradients (fixed-point reduction).
pub fn grads(ctx: &OpCtx) -> Result<crate::volume::diff::Grads<f32>> {
    Ok(run(ctx, false)?.0.grads)
}

/// `volume.render --grad-from` on the GPU: the gradient tensors into `out`.
pub fn render_grads(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    let (g, p) = run(ctx, false)?;
    crate::volume::grad_outputs::grad_outputs(&g.grads, &p, &ProbeSpec::default(), out)
}

/// `volume.grad_perf` on the GPU (`judge::measure::volume_gpu::backward`).
pub fn perf(ctx: &OpCtx) -> Result<Outputs> {
    let repeats: usize = ctx.param_or("repeats", 3)?;
    if repeats == 0 || repeats > 100 {
        return Err(ctx.bad("repeats", "must be in 1..=100"));
    }
    let gpu = f32_only(ctx)?;
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?.upstream::<f32>();
    measure::backward(gpu, (&cam, &gen, &p), &w, repeats, &ctx.budget)
}

/// `volume.session` (GPU only; `judge::measure::volume_gpu::session`).
pub fn session(ctx: &OpCtx) -> Result<Outputs> {
    let frames: usize = ctx.param_or("frames", 10)?;
    if frames == 0 || frames > 1000 {
        return Err(ctx.bad("frames", "must be in 1..=1000"));
    }
    let gpu = f32_only(ctx)?;
    let (cam, gen, p) = load(ctx)?;
    measure::session(gpu, (&cam, &gen, &p), frames, &ctx.budget)
}
