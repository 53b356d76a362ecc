//! Operations of the `pathtrace` renderer: wiring from case parameters to
//! the renderer (CPU, or GPU under `backend: gpu`), its harnesses
//! (`pathtrace::checks`), referees (`pathtrace::referee`), image measures
//! (`pathtrace::outputs`) and sweeps (`judge::measure::pathtrace`).

use std::collections::BTreeMap;
use std::time::Instant;

use super::{BackendKind, OpCtx};
use crate::error::{Error, Result};
use crate::judge::measure::pathtrace as measure;

use crate::pathtrace::checks::{
    bsdf_checks, intersect_listed, reflectance_applied, self_intersection, Region,
};
use crate::pathtrace::integrator::first_hits;
use crate::pathtrace::listed::ShapeParam;
use crate::pathtrace::referee::geometry::intersect_reference;
use crate::pathtrace::{render, Image, RenderParams};
use crate::scene::pathtrace::PathtraceScene;
use crate::stats::image::{firefly_fraction, mean_variance, mse};
use crate::tensor::{Outputs, Tensor};

ops! {
    "pathtrace.render" F32 render_op []
        "path-traced image (H, W, 3) and variance of the pixel mean; metrics time_s, paths_per_s";
    "pathtrace.intersect_list" CpuF32 intersect_list ["rays", "shapes"]
        "renderer intersection of params.rays ([ox,oy,oz,dx,dy,dz]) with params.shapes: t, hit, index, normal";
    "pathtrace.intersect_reference" Any intersect_reference_op ["rays", "shapes"]
        "f64 closed forms (geometric sphere, Cramer quad) for the rays and shapes of intersect_list";
    "pathtrace.self_intersection" CpuF32 self_intersection_op ["rays"]
        "acne_fraction: rays spawned at camera hit points that re-hit their own surface at once";
    "pathtrace.bsdf_checks" CpuF32 bsdf_checks_op ["thetas", "samples", "alpha", "roughness"]
        "pdf_integral, albedo, reciprocity_err, weight_err, fresnel_err, chi2_p and chi2_alpha (Sidak) per material and wo";
    "pathtrace.furnace" F32 furnace ["expect"]
        "render + mean (3,), z-score of the mean against params.expect, max pixel_err";
    "pathtrace.convergence" CpuF32 convergence ["spp", "seeds", "ref_spp", "clamp"]
        "rmse (clamped to [0,1]) vs a ref_spp render over params.spp x params.seeds; log-log slope";
    "pathtrace.fireflies" CpuF32 fireflies ["factor"]
        "render + firefly_fraction: pixels whose luminance exceeds 10x their 3x3 median";
    "pathtrace.features" CpuF32 features ["regions"]
        "render + mean rgb/luminance/(r/g) of named world-space regions of named shapes (params.regions)";
    "pathtrace.rmse_vs_reference" F32 rmse_vs_reference ["reference"]
        "render + rmse (clamped [0,1]) and rmse_raw against params.reference (an (H, W, 3) float32 .npy)";
    "pathtrace.speed_error" F32 speed_error ["spp", "ref_spp", "ref_seed", "reference", "backends"]
        "seconds and rmse (clamped [0,1] and raw) vs a ref_spp render (or params.reference .npy) per params.spp, on each of params.backends (names prefixed cpu_/gpu_); plot_image";
    "pathtrace.tracers" CpuF32 tracers ["repeats"]
        "scalar, packet and wavefront CPU paths interleaved: <tracer>_cpu_s, <tracer>_paths_per_cpu_s, wavefront_over_scalar/packet, same_image";
    "pathtrace.parity" F32 parity ["cpu_seed", "alpha"]
        "run's backend vs CPU (seed params.cpu_seed) per pixel z-test: p_min, sidak_alpha (params.alpha), z2_mean, max_abs_z, zero_var_mismatch";
    "pathtrace.reflectance_applied" CpuF32 reflectance_op ["thetas", "samples", "alpha", "reflectance"]
        "rough conductor: eval_ratio and weight_ratio (reflectance r over 1, same directions) and expected = r, per wo angle and channel";
}

fn load(ctx: &OpCtx) -> Result<PathtraceScene> {
    crate::scene::pathtrace::parse(ctx.scene()?)
}

/// A render of `s` with `p` on the case's backend, and its seconds (GPU:
/// submit to readback).
fn timed_render(s: &PathtraceScene, p: &RenderParams, ctx: &OpCtx) -> Result<(Image, f64)> {
    timed_render_on(s, p, ctx, ctx.backend)
}

/// [`timed_render`] on `backend`.
fn timed_render_on(
    s: &PathtraceScene,
    p: &RenderParams,
    ctx: &OpCtx,
    backend: BackendKind,
) -> Result<(Image, f64)> {
    if backend == BackendKind::Gpu {
        let gpu = crate::gpu::GpuContext::get()?;
        return crate::pathtrace::gpu::render_gpu(gpu, &s.scene, &s.camera, p, &ctx.budget);
    }
    let cam = s.camera.to_real::<f32>(p.width, p.height);
    let t = Instant::now();
    let img = render(&s.scene, &cam, p, &ctx.budget)?;
    Ok((img, t.elapsed().as_secs_f64()))
}

/// Renders `s` with `spp` samples and `seed` (other parameters from the
/// scene) on `backend`.
fn render_with(
    s: &PathtraceScene,
    (spp, seed): (u32, u32),
    ctx: &OpCtx,
    backend: BackendKind,
) -> Result<(Image, f64)> {
    let p = RenderParams {
        spp,
        seed,
        ..s.params
    };
    timed_render_on(s, &p, ctx, backend)
}

/// The scene, its render and the render's outputs.
fn rendered(ctx: &OpCtx) -> Result<(PathtraceScene, Image, Outputs)> {
    let s = load(ctx)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    img.to_outputs(secs, s.params.spp, &mut out)?;
    Ok((s, img, out))
}

fn render_op(ctx: &OpCtx) -> Result<Outputs> {
    Ok(rendered(ctx)?.2)
}

fn listed(ctx: &OpCtx) -> Result<(Vec<[f64; 6]>, Vec<ShapeParam>)> {
    Ok((ctx.listed_rays("rays")?, ctx.param_req("shapes")?))
}

fn intersect_list(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, shapes) = listed(ctx)?;
    intersect_listed(&rays, &shapes, &ctx.at("shapes"))?.to_outputs(true)
}

fn intersect_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, shapes) = listed(ctx)?;
    intersect_reference(&rays, &shapes).to_outputs(false)
}

fn self_intersection_op(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let n: u32 = ctx.param_or("rays", 100_000)?;
    let (w, h) = (s.params.width, s.params.height);
    let cam = s.camera.to_real::<f32>(w, h);
    let (tested, acne) = self_intersection(&s.scene, &cam, (w, h), n, ctx.seed);
    let mut out = Outputs::default();
    out.tensor(
        "acne_fraction",
        Tensor::scalar(acne as f64 / tested.max(1) as f64),
    );
    out.counter("rays_tested", tested).counter("acne", acne);
    Ok(out)
}

/// `params.thetas` (degrees, each in [0, 90)) and `samples` (>= 1).
fn thetas_samples<T: serde::de::DeserializeOwned + Into<f64> + Copy>(
    ctx: &OpCtx,
    thetas: Vec<T>,
    samples: u32,
) -> Result<(Vec<T>, u32)> {
    let thetas: Vec<T> = ctx.param_or("thetas", thetas)?;
    let n: u32 = ctx.param_or("samples", samples)?;
    if thetas.iter().any(|&t| !(0.0..90.0).contains(&t.into())) || n == 0 {
        let why = "thetas must lie in [0, 90) degrees and samples >= 1";
        return Err(Error::invalid(format!("{} params", ctx.case_id), why));
    }
    Ok((thetas, n))
}

fn bsdf_checks_op(ctx: &OpCtx) -> Result<Outputs> {
    let (thetas, n) = thetas_samples::<f64>(ctx, vec![0.0, 30.0, 60.0, 85.0], 500_000)?;
    let alpha: f64 = ctx.param_or("alpha", 0.01)?;
    let rough: f32 = ctx.param_or("roughness", 0.1)?;
    bsdf_checks(&thetas, n, alpha, rough, ctx.seed).to_outputs(n)
}

fn reflectance_op(ctx: &OpCtx) -> Result<Outputs> {
    let (thetas, n) = thetas_samples::<f32>(ctx, vec![0.0, 30.0, 60.0, 85.0], 10_000)?;
    let alpha: f32 = ctx.param_or("alpha", 0.1)?;
    if alpha.is_nan() || alpha <= 0.0 {
        return Err(ctx.bad("alpha", "must be > 0"));
    }
    reflectance_applied(
        &thetas,
        n,
        alpha,
        ctx.param_or("reflectance", [0.8, 0.8, 0.9])?,
        ctx.seed,
    )
}

fn furnace(ctx: &OpCtx) -> Result<Outputs> {
    let expect: [f64; 3] = ctx.param_req("expect")?;
    let (_, img, mut out) = rendered(ctx)?;
    img.furnace_outputs(expect, &mut out)?;
    Ok(out)
}

fn convergence(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let seeds: Vec<u32> = ctx.param_or("seeds", vec![1, 2, 3, 4])?;
    if spps.len() < 2 || seeds.is_empty() || spps.contains(&0) {
        let why = "need >= 2 spp values (all >= 1) and >= 1 seed";
        return Err(Error::invalid(format!("{} params", ctx.case_id), why));
    }
    let (ref_spp, clamp) = (ctx.param_or("ref_spp", 4096)?, ctx.param_or("clamp", true)?);
    let render = |spp, seed| render_with(&s, (spp, seed), ctx, ctx.backend);
    measure::convergence(&spps, &seeds, (ref_spp, clamp), render)
}

fn fireflies(ctx: &OpCtx) -> Result<Outputs> {
    let factor: f32 = ctx.param_or("factor", 10.0)?;
    let (_, img, mut out) = rendered(ctx)?;
    let f = firefly_fraction(&img.rgb, img.width, img.height, factor);
    out.tensor("firefly_fraction", Tensor::scalar(f));
    Ok(out)
}

fn features(ctx: &OpCtx) -> Result<Outputs> {
    let regions: BTreeMap<String, Region> = ctx.param_req("regions")?;
    let (s, img, mut out) = rendered(ctx)?;
    let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
    let hits = first_hits(&s.scene, &cam, s.params.width, s.params.height);
    let at = ctx.at("regions");
    img.region_outputs(&hits, &s.names, &regions, &at, &mut out)?;
    Ok(out)
}

/// `params.reference`: an (H, W, 3) float32 `.npy` of the scene's size,
/// relative to the manifest.
fn read_reference(ctx: &OpCtx, s: &PathtraceScene, file: &str) -> Result<Image> {
    Image::read_npy(
        &ctx.resolve(file),
        s.params.width as usize,
        s.params.height as usize,
    )
}

/// RMSE of linear radiance clamped to [0, 1] against an independent
/// renderer's converged image (`params.reference`), and the unclamped RMSE.
fn rmse_vs_reference(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let reference = read_reference(ctx, &s, &ctx.param_req::<String>("reference")?)?;
    let (_, img, mut out) = rendered(ctx)?;
    for (name, clamp) in [("rmse", true), ("rmse_raw", false)] {
        let e = mse(&img.rgb, &reference.rgb, clamp).sqrt();
        out.tensor(name, Tensor::scalar(e));
    }
    Ok(out)
}

/// Speed against error over `params.spp` (`measure::pathtrace::speed_error`)
/// against a `ref_spp` render (seed `ref_seed`) or `params.reference`.
fn speed_error(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let (ref_spp, ref_seed) = (
        ctx.param_or("ref_spp", 4096)?,
        ctx.param_or("ref_seed", 1 << 31)?,
    );
    if spps.is_empty() || spps.contains(&0) {
        return Err(ctx.bad("spp", "need a non-empty list of positive sample counts"));
    }
    let mut out = Outputs::default();
    let (reference, noise) = match ctx.param::<String>("reference")? {
        Some(file) => (read_reference(ctx, &s, &file)?, 0.0),
        None => {
            let (r, secs) = render_with(&s, (ref_spp, ref_seed), ctx, ctx.backend)?;
            out.metric("ref_time_s", secs);
            let noise = mean_variance(&r.variance);
            (r, noise)
        }
    };
    let backends: Vec<BackendKind> = ctx.param_or("backends", vec![ctx.backend])?;
    let s = &s;
    let renders: Vec<_> = backends
        .iter()
        .map(|&b| move |spp, seed| render_with(s, (spp, seed), ctx, b))
        .collect();
    let named: Vec<(&str, measure::Render)> = backends
        .iter()
        .zip(&renders)
        .map(|(b, r)| (b.name(), r as measure::Render))
        .collect();
    measure::speed_error(&spps, s.params.seed, (&reference, noise), &named, &mut out)?;
    Ok(out)
}

/// The three CPU tracers on the case's scene (`measure::pathtrace::tracers`).
fn tracers(ctx: &OpCtx) -> Result<Outputs> {
    measure::tracers(&load(ctx)?, ctx.param_or("repeats", 3)?, &ctx.budget)
}

/// The run's backend against the CPU with another seed: per pixel and
/// channel a two-sample z-test (`Image::parity_outputs`).
fn parity(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let cpu_seed: u32 = ctx.param_or("cpu_seed", s.params.seed.wrapping_add(1000))?;
    let alpha: f64 = ctx.param_or("alpha", 0.01)?;
    if cpu_seed == s.params.seed {
        let why = "must differ from the scene's seed (the z-test needs independent renders)";
        return Err(ctx.bad("cpu_seed", why));
    }
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
    let p = RenderParams {
        seed: cpu_seed,
        ..s.params
    };
    let cpu = render(&s.scene, &cam, &p, &ctx.budget)?;
    let mut out = Outputs::default();
    img.parity_outputs(&cpu, alpha, &mut out)?;
    out.metric("time_s", secs);
    Ok(out)
}
