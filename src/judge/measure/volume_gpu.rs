//! GPU volume timings (issue 19): the backward's fixed-point and
//! float-atomic reductions against the forward they walk, and steady-state
//! session frames against per-stage submits.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::GpuContext;
use crate::rays::RayGen;
use crate::stats::summary::{median, quartiles};
use crate::tensor::Outputs;
use crate::volume::diff::gpu::f_diff_gpu;
use crate::volume::diff::Upstream;
use crate::volume::session::latency;
use crate::volume::VolumeParams;

/// Medians over `repeats` of the forward, the fixed-point backward and the
/// float-atomic backward: grads_per_s, bwd_fwd_ratio,
/// float_atomic_grads_per_s, fixed_over_float_atomic.
pub fn backward(
    gpu: &GpuContext,
    (cam, gen, p): (&Camera, &RayGen, &VolumeParams),
    w: &Upstream<f32>,
    repeats: usize,
    budget: &MemBudget,
) -> Result<Outputs> {
    let (mut tf, mut tb, mut ta, mut samples) = (vec![], vec![], vec![], 0);
    for _ in 0..repeats {
        let g = f_diff_gpu(gpu, cam, gen, p, w, false, budget)?;
        samples = g.grads.samples;
        tf.push(g.forward_s);
        tb.push(g.grads.time_s);
        ta.push(f_diff_gpu(gpu, cam, gen, p, w, true, budget)?.grads.time_s);
    }
    let (tf, tb, ta) = (median(&mut tf), median(&mut tb), median(&mut ta));
    let s = samples as f64;
    let mut out = Outputs::default();
    for (k, v) in [
        ("forward_time_s", tf),
        ("time_s", tb),
        ("grads_per_s", s / tb),
        ("bwd_fwd_ratio", tb / tf),
        ("float_atomic_time_s", ta),
        ("float_atomic_grads_per_s", s / ta),
        ("fixed_over_float_atomic", tb / ta),
    ] {
        out.metric(k, v);
    }
    out.counter("samples", samples);
    Ok(out)
}

/// `frames` session frames against as many per-stage renders: the last
/// frame's image tensors, per-frame quartiles of both (`session_q1_s`,
/// `session_median_s`, `session_q3_s`, `stages_*`), `session_speedup`.
pub fn session(
    gpu: &GpuContext,
    (cam, gen, p): (&Camera, &RayGen, &VolumeParams),
    frames: usize,
    budget: &MemBudget,
) -> Result<Outputs> {
    let l = latency(gpu, cam, gen, p, frames, budget)?;
    let mut out = Outputs::default();
    l.image.to_outputs(&mut out)?;
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
