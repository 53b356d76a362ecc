//! The GPU backend of `volume.grad`, `volume.grad_perf` and `volume.render`
//! with `grad_from` (issue 19): `volume::diff::gpu::f_diff_gpu`, the same
//! tensors as the CPU rows. `params.reduce`: `fixed` (default: the
//! deterministic fixed-point reduction) or `float_atomic` (the f32
//! compare-exchange fast path). Metrics add `forward_time_s` (the unfused
//! forward the backward walks) and `bwd_fwd_ratio`. Also `volume.session`
//! (GPU only): steady-state frames against per-stage submits.

use super::volume::image_outputs;
use super::volume_diff::{load, loss_weights, probe_spec, upstream};
use super::OpCtx;
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::real::Precision;
use crate::stats::summary::{median, quartiles};
use crate::tensor::Outputs;
use crate::volume::diff::gpu::{f_diff_gpu, GpuDiff};
use crate::volume::grad_outputs::grad_outputs;
use crate::volume::loss::ProbeSpec;
use crate::volume::session::latency;

fn run(ctx: &OpCtx, float_atomic: bool) -> Result<(GpuDiff, crate::volume::VolumeParams)> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU backward computes in f32 only",
            ctx.case_id
        )));
    }
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let gpu = GpuContext::get()?;
    let g = f_diff_gpu(
        gpu,
        &cam,
        &gen,
        &p,
        &upstream(&w),
        float_atomic,
        &ctx.budget,
    )?;
    Ok((g, p))
}

fn float_atomic(ctx: &OpCtx) -> Result<bool> {
    match ctx.param_or::<String>("reduce", "fixed".into())?.as_str() {
        "fixed" => Ok(false),
        "float_atomic" => Ok(true),
        o => Err(Error::invalid(
            format!("{} params.reduce", ctx.case_id),
            format!("{o:?} is not fixed or float_atomic (the GPU reductions)"),
        )),
    }
}

/// `volume.grad` on the GPU.
pub fn grad(ctx: &OpCtx) -> Result<Outputs> {
    let probes = probe_spec(ctx)?;
    let (g, p) = run(ctx, float_atomic(ctx)?)?;
    let mut out = Outputs::default();
    grad_outputs(&g.grads, &p, &probes, &mut out)?;
    out.metric("forward_time_s", g.forward_s);
    out.metric("bwd_fwd_ratio", g.grads.time_s / g.forward_s.max(1e-12));
    Ok(out)
}

/// `volume.render --grad-from` on the GPU: the gradient tensors into `out`.
pub fn render_grads(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    let (g, p) = run(ctx, false)?;
    grad_outputs(&g.grads, &p, &ProbeSpec::default(), out)
}

/// `volume.grad_perf` on the GPU: medians over `repeats` of the fixed-point
/// and float-atomic backward and of the forward they walk.
pub fn perf(ctx: &OpCtx) -> Result<Outputs> {
    let repeats: usize = ctx.param_or("repeats", 3)?;
    if repeats == 0 || repeats > 100 {
        return Err(Error::invalid(
            format!("{} params.repeats", ctx.case_id),
            "must be in 1..=100",
        ));
    }
    let (mut tf, mut tb, mut ta, mut samples) = (vec![], vec![], vec![], 0);
    for _ in 0..repeats {
        let (g, _) = run(ctx, false)?;
        samples = g.grads.samples;
        tf.push(g.forward_s);
        tb.push(g.grads.time_s);
        ta.push(run(ctx, true)?.0.grads.time_s);
    }
    let (tf, tb, ta) = (median(&mut tf), median(&mut tb), median(&mut ta));
    let s = samples as f64;
    let mut out = Outputs::default();
    out.metric("forward_time_s", tf);
    out.metric("time_s", tb);
    out.metric("grads_per_s", s / tb);
    out.metric("bwd_fwd_ratio", tb / tf);
    out.metric("float_atomic_time_s", ta);
    out.metric("float_atomic_grads_per_s", s / ta);
    out.metric("fixed_over_float_atomic", tb / ta);
    out.counter("samples", samples);
    Ok(out)
}

/// `volume.session` (GPU): `params.frames` steady-state frames (one submit
/// each) interleaved with as many per-stage renders; the last frame's image
/// tensors, and per-frame seconds as quartiles (`session_q1_s`,
/// `session_median_s`, `session_q3_s`, `stages_*`) and `session_speedup`
/// (per-stage median over session median).
pub fn session(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU computes in f32 only",
            ctx.case_id
        )));
    }
    let frames: usize = ctx.param_or("frames", 10)?;
    if frames == 0 || frames > 1000 {
        return Err(Error::invalid(
            format!("{} params.frames", ctx.case_id),
            "must be in 1..=1000",
        ));
    }
    let (cam, gen, p) = load(ctx)?;
    let l = latency(GpuContext::get()?, &cam, &gen, &p, frames, &ctx.budget)?;
    let mut out = Outputs::default();
    image_outputs(&l.image, &mut out)?;
    let (sm, sq1, sq3) = quartiles(&l.session_s);
    let (pm, pq1, pq3) = quartiles(&l.stages_s);
    for (k, v) in [
        ("session_q1_s", sq1),
        ("session_median_s", sm),
        ("session_q3_s", sq3),
        ("stages_q1_s", pq1),
        ("stages_median_s", pm),
        ("stages_q3_s", pq3),
        ("session_speedup", pm / sm.max(1e-12)),
    ] {
        out.metric(k, v);
    }
    Ok(out)
}
