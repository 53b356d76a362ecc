//! Operations of the `transport` renderer (curved rays, CPU or `kernels/transport.wgsl`): render
//! (`transport::outputs`), referees, self-checks (`transport::checks`, `image_checks`), the GPU
//! image band (`transport::gpu_parity`) and backend timings (`judge::measure::transport`).

use super::{BackendKind, OpCtx};
use crate::error::{Error, Result};
use crate::gpu::GpuContext;
use crate::real::Real;
use crate::scene::transport::{parse, ResearchPreset, ResearchSpec, TaskSpec, TransportScene};
use crate::scene::transport_refs as refs;
use crate::tensor::Outputs;
use crate::transport::checks::{convergence_order, drift_growth};
use crate::transport::gpu_parity::band_outputs;
use crate::transport::image::{render as render_image, ImageOut, ImageTask};
use crate::transport::image_checks::kerr_closed_form;
use crate::transport::outputs::{run_curved, run_task, shadow_angle_outputs};
use crate::transport::tasks::{Curved, Task};

ops! {
    "transport.render" CpuGpuF32 render []
        "trace a transport scene: deflection/captured/steps/h_drift, or GRIN exit points and periods";
    "transport.deflection_finite" Any deflection_finite []
        "finite-distance deflection by substitution + Gauss-Legendre (Schwarzschild), elliptic F (Ellis)";
    "transport.deflection_darwin" Any deflection_darwin [] "Darwin's exact infinite-distance Schwarzschild deflection";
    "transport.deflection_weak_field" Any weak_field []
        "weak-field series 4M/b + 15 pi M^2/4b^2 + 128 M^3/3b^3 + 3465 pi M^4/64b^4";
    "transport.ellis_infinite" Any ellis_infinite_op [] "Ellis deflection at infinity 2 K(b0/b) - pi by the AGM";
    "transport.shadow_synge" Any shadow_synge [] "Synge's capture angle and expected capture flags for an observer scene";
    "transport.shadow_angle" Cpu shadow_angle_op ["iters"]
        "capture angle by bisection with the integrator (params.iters, default 40)";
    "transport.grin_closed_form" Any grin_closed_form []
        "Luneburg focus R d, fibre period 2 pi cos(theta0)/alpha, sech 2 pi/alpha, fish-eye conjugate -R^2 o/|o|^2";
    "transport.convergence" Cpu convergence ["factors"]
        "observed order under step scaling by params.factors (default [1, 0.5, 0.25])";
    "transport.drift_growth" Cpu drift_growth_op ["steps"]
        "max |H| after params.steps = [n1, n2] steps of a GRIN scene, and the ratio";
    "transport.kerr_closed_form" Any kerr_closed_form_op []
        "Bardeen's shadow per pixel (0/1, 2 = curve crosses the pixel), horizon, ergosphere, photon orbits, ISCO";
    "transport.image_mirror" Cpu mirror [] "the rendered image flipped left-right (image_lr) and top-bottom (image_ud)";
    "transport.image_band" Cpu image_band ["band_px"]
        "the CPU render of an image scene plus `far`: 1 where capture, disk hit and side are constant within params.band_px pixels";
    "transport.research_diff" Cpu research_diff []
        "per-pixel difference between the scene's integrator and the validate preset";
    "transport.perf_backends" GpuF32 perf_backends []
        "the scene's task traced in f32 on the CPU fan-out and on the GPU kernel: photon-steps/s and ns per photon-step of each, and their ratio";
}

fn scene(ctx: &OpCtx) -> Result<TransportScene> {
    parse(ctx.scene()?)
}

fn render_in<F: Real>(
    ctx: &OpCtx,
    s: &TransportScene,
    gpu: Option<&GpuContext>,
) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    let mut out = Outputs::default();
    if let Some(b) = s.research_banner() {
        // warn: the preset overrides the scene's integrator; show it at the default level.
        tracing::warn!("{}", b.line);
        out.counter("research_settings_hash", b.hash);
    }
    run_task(&task, &opt, &ctx.budget, &s.dump_rays, &mut out, gpu)?;
    Ok(out)
}

fn render(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let gpu = match ctx.backend {
        BackendKind::Cpu => None,
        BackendKind::Gpu => {
            let g = GpuContext::get()?;
            let (task, opt) = s.build::<f32>()?;
            crate::transport::gpu::warm(g, &task, &opt, &ctx.budget)?;
            Some(g)
        }
    };
    by_precision!(ctx, render_in(ctx, &s, gpu))
}

fn deflection_finite(ctx: &OpCtx) -> Result<Outputs> {
    refs::deflection_finite(&scene(ctx)?)
}

fn deflection_darwin(ctx: &OpCtx) -> Result<Outputs> {
    refs::deflection_darwin(&scene(ctx)?)
}

fn weak_field(ctx: &OpCtx) -> Result<Outputs> {
    refs::weak_field(&scene(ctx)?)
}

fn ellis_infinite_op(ctx: &OpCtx) -> Result<Outputs> {
    refs::ellis_infinite_deflection(&scene(ctx)?)
}

fn shadow_synge(ctx: &OpCtx) -> Result<Outputs> {
    refs::shadow_synge(&scene(ctx)?)
}

fn grin_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    refs::grin_closed_form(&scene(ctx)?)
}

fn shadow_angle_in<F: Real>(s: &TransportScene, iters: u32) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    shadow_angle_outputs(&task, &opt, iters)
}

fn shadow_angle_op(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let iters: u32 = ctx.param_or("iters", 40)?;
    if iters == 0 || iters > 60 {
        return Err(ctx.bad("iters", "must lie in 1..=60"));
    }
    by_precision!(ctx, shadow_angle_in(&s, iters))
}

fn convergence_in<F: Real>(ctx: &OpCtx, s: &TransportScene, factors: &[f64]) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    convergence_order(&task, &opt, factors, &ctx.budget)
}

fn convergence(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let f: Vec<f64> = ctx.param_or("factors", vec![1.0, 0.5, 0.25])?;
    let ok = f.len() == 3
        && f.iter().all(|f| *f > 0.0 && f.is_finite())
        && f[0] / f[1] == f[1] / f[2]
        && f[0] != f[1];
    if !ok {
        let why = "three positive factors in one geometric ratio, e.g. [1, 0.5, 0.25]";
        return Err(ctx.bad("factors", why));
    }
    by_precision!(ctx, convergence_in(ctx, &s, &f))
}

fn drift_in<F: Real>(ctx: &OpCtx, s: &TransportScene, n: [u64; 2]) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    drift_growth(&task, &opt, n, &ctx.budget)
}

fn drift_growth_op(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let n: [u64; 2] = ctx.param_or("steps", [10_000, 100_000])?;
    if !(n[0] > 0 && n[1] > n[0]) {
        return Err(ctx.bad("steps", "need 0 < steps[0] < steps[1]"));
    }
    by_precision!(ctx, drift_in(ctx, &s, n))
}

fn kerr_closed_form_op(ctx: &OpCtx) -> Result<Outputs> {
    let TaskSpec::KerrImage(spec) = &scene(ctx)?.task else {
        return Err(Error::invalid(
            "task",
            "transport.kerr_closed_form needs a kerr_image scene",
        ));
    };
    kerr_closed_form(&spec.build()?)
}

fn curved_image(s: &TransportScene) -> Result<ImageTask> {
    match s.build::<f64>()?.0 {
        Task::Curved(Curved::Image(t)) => Ok(t),
        _ => Err(Error::invalid(
            "task",
            "this operation needs a kerr_image or ellis_image scene",
        )),
    }
}

fn rendered<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<ImageOut<F>> {
    let t = curved_image(s)?;
    let (_, opt) = s.build::<F>()?;
    render_image(&t, &opt, &ctx.budget)
}

fn mirror_in<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<Outputs> {
    rendered::<F>(ctx, s)?.mirror_outputs()
}

fn mirror(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    by_precision!(ctx, mirror_in(ctx, &s))
}

/// The CPU render in the case's precision (the f64 referee of the GPU
/// image contract, docs/transport_gpu.md) with its parity band.
fn band_in<F: Real>(ctx: &OpCtx, s: &TransportScene, d: usize) -> Result<Outputs> {
    let c = Curved::Image(curved_image(s)?);
    let (_, opt) = s.build::<F>()?;
    let mut out = Outputs::default();
    run_curved(&c, &opt, &ctx.budget, &mut out, None)?;
    band_outputs(&mut out, d)?;
    Ok(out)
}

fn image_band(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let d: usize = ctx.param_or("band_px", 1)?;
    by_precision!(ctx, band_in(ctx, &s, d))
}

/// The scene rendered with its own integrator (timed: `time_s`) and with
/// the research preset `validate`, compared per pixel.
fn research_in<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<Outputs> {
    let plain = TransportScene {
        research: None,
        ..s.clone()
    };
    let valid = TransportScene {
        research: Some(ResearchSpec {
            preset: ResearchPreset::Validate,
        }),
        ..s.clone()
    };
    let t0 = std::time::Instant::now();
    let a = rendered::<F>(ctx, &plain)?;
    let secs = t0.elapsed().as_secs_f64();
    let mut out = a.diff_outputs(&rendered::<F>(ctx, &valid)?)?;
    out.metric("time_s", secs);
    Ok(out)
}

fn research_diff(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    by_precision!(ctx, research_in(ctx, &s))
}

fn perf_backends(ctx: &OpCtx) -> Result<Outputs> {
    let (task, opt) = scene(ctx)?.build::<f32>()?;
    crate::judge::measure::transport::backends(&task, &opt, GpuContext::get()?, &ctx.budget)
}
