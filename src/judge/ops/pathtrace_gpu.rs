//! The path tracer's GPU backend in the judge: [`timed_render_gpu`] is what
//! `pathtrace.render`, `pathtrace.furnace`, `pathtrace.rmse_vs_reference`
//! and `pathtrace.speed_error` run under `backend: gpu`, and one operation
//! that holds the two backends against each other.
//!
//! | op | what |
//! | --- | --- |
//! | `pathtrace.parity` | render on the run's backend and on the CPU (independent seeds); per pixel and channel a two-sample z-test: `p_min`, `sidak_alpha`, `z2_mean`, `max_abs_z`, `zero_var_mismatch` |

use std::time::Instant;

use super::pathtrace::load;
use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::judge::stats::{sidak, z_test};
use crate::pathtrace::gpu::render_gpu;
use crate::pathtrace::{render, Image, RenderParams};
use crate::real::Precision;
use crate::scene::pathtrace::PathtraceScene;
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "pathtrace.parity",
    doc: "run's backend vs CPU (seed params.cpu_seed) per pixel z-test: p_min, sidak_alpha (params.alpha), z2_mean, max_abs_z, zero_var_mismatch",
    params: &["cpu_seed", "alpha"],
    support: Support::CpuGpuF32,
    run: parity,
}];

/// A GPU render of `s` with `p` and the GPU seconds (submit to readback).
pub fn timed_render_gpu(s: &PathtraceScene, p: &RenderParams, ctx: &OpCtx) -> Result<(Image, f64)> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU path tracer computes in f32 only",
            ctx.case_id
        )));
    }
    let gpu = GpuContext::get()?;
    render_gpu(gpu, &s.scene, &s.camera, p, &ctx.budget)
}

fn flat(v: &[[f32; 3]]) -> Vec<f64> {
    v.iter().flat_map(|p| p.map(f64::from)).collect()
}

fn parity(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let cpu_seed: u32 = ctx.param_or("cpu_seed", s.params.seed.wrapping_add(1000))?;
    let alpha: f64 = ctx.param_or("alpha", 0.01)?;
    if cpu_seed == s.params.seed {
        return Err(Error::invalid(
            format!("{} params.cpu_seed", ctx.case_id),
            "must differ from the scene's seed (the z-test needs independent renders)",
        ));
    }
    let t = Instant::now();
    let (img, secs) = match ctx.backend {
        BackendKind::Gpu => timed_render_gpu(&s, &s.params, ctx)?,
        BackendKind::Cpu => {
            let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
            let img = render(&s.scene, &cam, &s.params, &ctx.budget)?;
            (img, t.elapsed().as_secs_f64())
        }
    };
    let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
    let cpu = render(
        &s.scene,
        &cam,
        &RenderParams {
            seed: cpu_seed,
            ..s.params
        },
        &ctx.budget,
    )?;
    let z = z_test(
        &flat(&img.rgb),
        &flat(&img.variance),
        &flat(&cpu.rgb),
        &flat(&cpu.variance),
    );
    let shape = [img.height as usize, img.width as usize];
    let mut out = Outputs::default();
    out.tensor("image", Tensor::real3(&shape, &img.rgb)?);
    out.tensor("cpu_image", Tensor::real3(&shape, &cpu.rgb)?);
    out.tensor("p_min", Tensor::scalar(z.p_min));
    out.tensor("sidak_alpha", Tensor::scalar(sidak(alpha, z.tests)));
    out.tensor("z2_mean", Tensor::scalar(z.z2_mean));
    out.tensor("max_abs_z", Tensor::scalar(z.max_abs_z));
    out.tensor(
        "zero_var_mismatch",
        Tensor::scalar(z.zero_var_mismatch as f64),
    );
    out.metric("time_s", secs);
    out.counter("tests", z.tests as u64)
        .counter("worst_index", z.worst as u64)
        .counter("nonfinite_samples", img.nonfinite + cpu.nonfinite);
    Ok(out)
}
