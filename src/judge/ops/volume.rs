//! Operations of the `volume` renderer (forward), its referees
//! (`volume::referee`: quadrature, closed forms, trilinear probe) and its
//! timing harnesses (`judge::measure::volume`). Outputs name themselves
//! (`volume::outputs`). On the GPU (`backend: gpu`) the forward rows add
//! `stable` and `unstable_frac` (`volume::gpu`); `time_s` is then the GPU
//! time of the chain.

use super::{BackendKind, OpCtx};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::judge::measure::volume as measure;
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;
use crate::scene::volume::FieldSpec;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::Compose;
use crate::volume::field::{FieldDesc, Grid};
use crate::volume::referee::closed_form::{closed_image, optical_depths};
use crate::volume::referee::quadrature::{grid_probe_outputs, probe_points, quadrature};
use crate::volume::{prepare, render, render_rays, Chain, VolumeParams};

ops! {
    "volume.render" CpuGpuF32 op_render ["compose", "grad_from"]
        "SCENES.md outputs of a volume scene (fused chain): rgb, trans, logtrans, depth, opacity, nsamples, hit; with params.grad_from also dsigma, dcolor, dcam";
    "volume.forward" CpuGpuF32 op_forward ["compose"]
        "fused forward render; metrics time_s, samples_per_s; counters rays, samples, early_stop, ...";
    "volume.unfused" CpuGpuF32 op_unfused ["compose", "buffers"]
        "f_ray -> f_samp -> f_int -> f_img; params.buffers: true adds off, t, dt, sigma, alpha, log_t";
    "volume.samples" Cpu op_samples [] "f_samp outputs: off, ray_id, t, dt, sigma, u = (t - a_k) / dt_k, m";
    "volume.reference_quadrature" Any op_reference []
        "independent f64 quadrature of the scene (same lattice and early stop), SCENES.md outputs";
    "volume.closed_form" Any op_closed_form []
        "continuum closed forms of trans, logtrans, opacity, rgb for analytic fields (and grids sampled from them)";
    "volume.grid_probe" Cpu op_grid_probe ["n", "seed"]
        "the scene's density grid at params.n seeded points in [-1.5, 1.5]^3 (in and out of the box): value";
    "volume.grid_probe_reference" Any op_grid_probe_reference ["n", "seed"]
        "the same points through the independent f64 trilinear reference: value, inside";
    "volume.perf" Cpu op_perf ["repeats"]
        "fused vs unfused medians: samples_per_s, unfused_samples_per_s, integrated_samples_per_s, pixels_per_s, fused_speedup";
    "volume.dt_sweep" Cpu op_dt_sweep ["dts", "repeats"]
        "speed against error: seconds and max |trans - closed form| per dt in params.dts, f32 and f64";
}

/// Camera, generator, parameters and the scene's field spec.
fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams, FieldSpec)> {
    let doc = ctx.scene()?;
    let scene = crate::scene::volume::parse(doc)?;
    let (cam, gen, p) = scene.build(doc)?;
    Ok((cam, gen, p, scene.spec.field))
}

/// `params.repeats` (default 3) within `1..=max`.
fn repeats(ctx: &OpCtx, max: usize) -> Result<usize> {
    let r: usize = ctx.param_or("repeats", 3)?;
    if r == 0 || r > max {
        return Err(ctx.bad("repeats", format!("must be in 1..={max}")));
    }
    Ok(r)
}

fn compose_param(ctx: &OpCtx) -> Result<Compose> {
    match ctx.param_or::<String>("compose", "sorted".into())?.as_str() {
        "sorted" => Ok(Compose::Sorted),
        "scatter" => Ok(Compose::Scatter),
        other => Err(ctx.bad("compose", format!("{other:?} is not sorted or scatter"))),
    }
}

fn run_chain<F: Real>(ctx: &OpCtx, chain: Chain, buffers: bool) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let compose = compose_param(ctx)?;
    let r = match ctx.rays {
        // `render --rays FILE`: replay dumped rays through the unfused chain.
        Some(t) => {
            let rays = Rays::<F>::from_tensor(t, "--rays")?;
            let prep = prepare::<F>(&p, &gen.aabb, &ctx.budget)?;
            render_rays(&rays, &gen, &prep, compose, &ctx.budget)?
        }
        None => render::<F>(&cam, &gen, &p, chain, compose, &ctx.budget)?,
    };
    let mut out = Outputs::default();
    r.to_outputs(&mut out)?;
    if ctx.dump && ctx.rays.is_none() {
        out.tensor("rays", f_ray::<F>(&cam, &gen, &ctx.budget)?.to_tensor()?);
    }
    if let (true, Some(s), Some(it)) = (buffers, &r.samples, &r.integrated) {
        s.to_outputs(&mut out)?;
        it.to_outputs(&mut out)?;
    }
    Ok(out)
}

fn run_any(ctx: &OpCtx, chain: Chain) -> Result<Outputs> {
    let buffers = ctx.param_or("buffers", false)?;
    if ctx.backend == BackendKind::Cpu {
        return by_precision!(ctx, run_chain(ctx, chain, buffers));
    }
    if buffers {
        let why = "per-sample buffers are not read back from the GPU chain";
        return Err(Error::NotSupported(format!("{}: {why}", ctx.case_id)));
    }
    let (cam, gen, p, _) = load(ctx)?;
    let gpu = crate::gpu::GpuContext::get()?;
    let g = crate::volume::gpu::render_gpu(
        gpu,
        &cam,
        &gen,
        &p,
        chain,
        compose_param(ctx)?,
        &ctx.budget,
    )?;
    let mut out = Outputs::default();
    g.to_outputs(&mut out)?;
    Ok(out)
}

fn op_forward(ctx: &OpCtx) -> Result<Outputs> {
    run_any(ctx, Chain::Fused)
}

/// `volume.render`: the forward outputs, plus gradients when
/// `params.grad_from` names dL/d rgb (`ops/volume_diff.rs`).
fn op_render(ctx: &OpCtx) -> Result<Outputs> {
    let mut out = op_forward(ctx)?;
    super::volume_diff::render_grads(ctx, &mut out)?;
    Ok(out)
}

fn op_unfused(ctx: &OpCtx) -> Result<Outputs> {
    run_any(ctx, Chain::Unfused)
}

fn samples_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let r = render::<F>(&cam, &gen, &p, Chain::Unfused, Compose::Sorted, &ctx.budget)?;
    let s = r
        .samples
        .ok_or_else(|| Error::invalid(ctx.case_id, "the unfused chain kept no samples"))?;
    let u = s.strata(&f_ray::<F>(&cam, &gen, &ctx.budget)?, p.dt);
    let mut out = Outputs::default();
    s.to_outputs(&mut out)?;
    out.tensor("u", Tensor::real(&[s.len()], u)?);
    out.tensor("m", Tensor::scalar(s.len() as f64));
    out.counter("samples", s.len() as u64);
    Ok(out)
}

fn op_samples(ctx: &OpCtx) -> Result<Outputs> {
    by_precision!(ctx, samples_in(ctx))
}

fn op_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let rays = match ctx.rays {
        Some(t) => Rays::<f64>::from_tensor(t, "--rays")?,
        None => f_ray::<f64>(&cam, &gen, &ctx.budget)?,
    };
    let s = gen.shape();
    if rays.len() != s[0] * s[1] {
        let why = format!(
            "{} rays for a {}x{} region: the reference needs one ray per pixel",
            rays.len(),
            s[1],
            s[0]
        );
        return Err(Error::invalid("--rays", why));
    }
    quadrature(&rays, &p).to_outputs(&s)
}

/// The probe points (seeded, uniform in [-1.5, 1.5]^3) and the scene's grid.
fn probe_setup(ctx: &OpCtx) -> Result<(Vec<[f64; 3]>, crate::volume::field::GridDesc)> {
    let FieldDesc::Grid(g) = load(ctx)?.2.field else {
        return Err(Error::invalid(
            ctx.case_id,
            "grid_probe needs a scene whose field is a grid",
        ));
    };
    let n: u32 = ctx.param_or("n", 4096)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    if n == 0 || n > 1 << 22 {
        return Err(ctx.bad("n", "must be in 1..=4194304"));
    }
    Ok((probe_points(n, seed), g))
}

fn grid_probe_in<F: Real>(pts: &[[f64; 3]], g: &crate::volume::field::GridDesc) -> Result<Tensor> {
    let grid = Grid::<F>::from_desc(g);
    Tensor::real(
        &[pts.len()],
        pts.iter()
            .map(|x| grid.trilinear::<1>(x.map(F::of))[0])
            .collect(),
    )
}

fn op_grid_probe(ctx: &OpCtx) -> Result<Outputs> {
    let (pts, g) = probe_setup(ctx)?;
    let mut out = Outputs::default();
    out.tensor("value", by_precision!(ctx, grid_probe_in(&pts, &g))?);
    Ok(out)
}

fn op_grid_probe_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (pts, g) = probe_setup(ctx)?;
    grid_probe_outputs(&pts, &g)
}

/// Closed-form `(tau, hit)` per pixel of the scene's region, f64 rays.
fn closed_tau(
    ctx: &OpCtx,
    cam: &Camera,
    gen: &RayGen,
    spec: &FieldSpec,
) -> Result<(Vec<f64>, Vec<u8>)> {
    let a = crate::scene::volume::continuum(spec, ctx.case_id)?;
    Ok(optical_depths(&a, &f_ray::<f64>(cam, gen, &ctx.budget)?))
}

fn op_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, spec) = load(ctx)?;
    let c = p.color.uniform().ok_or_else(|| {
        Error::NotSupported(format!(
            "{}: closed form needs a constant colour",
            ctx.case_id
        ))
    })?;
    let (tau, hit) = closed_tau(ctx, &cam, &gen, &spec)?;
    closed_image(&tau, hit, c, p.background, &gen.shape())
}

fn op_perf(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let n = repeats(ctx, 1000)?;
    by_precision!(ctx, measure::forward(&cam, &gen, &p, n, &ctx.budget))
}

fn op_dt_sweep(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, spec) = load(ctx)?;
    let dts: Vec<f64> = ctx.param_req("dts")?;
    let n = repeats(ctx, 100)?;
    if dts.is_empty() {
        return Err(ctx.bad("dts", "need a non-empty list"));
    }
    let (tau, _) = closed_tau(ctx, &cam, &gen, &spec)?;
    measure::dt_sweep((&cam, &gen, &p), &tau, &dts, n, &ctx.budget)
}
