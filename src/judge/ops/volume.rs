//! Operations of the `volume` renderer and its independent references.
//!
//! | op | what |
//! | --- | --- |
//! | `volume.render` | SCENES.md outputs of a volume scene (fused chain): rgb, trans, logtrans, depth, opacity, nsamples, hit |
//! | `volume.forward` | the same, fused; metrics time_s, samples_per_s; counters |
//! | `volume.unfused` | the same through f_ray -> f_samp -> f_int -> f_img; `params.buffers` adds per-sample tensors |
//! | `volume.samples` | f_samp outputs: off, ray_id, t, dt, sigma, u (stratified offsets), m |
//! | `volume.reference_quadrature` | the discrete midpoint/stratified quadrature, f64 (`volume::referee::quadrature`) |
//! | `volume.closed_form` | continuum transmittance of the analytic field (constant, slabs, gaussian via erf, shell chord, linear; `volume::referee::closed_form`) |
//! | `volume.grid_probe` / `_reference` | a density grid at seeded points in and out of the box, ours vs an independent trilinear (OOB zero / clamp) |
//! | `volume.perf` | fused vs unfused: samples/s, integrated_samples/s, pixels/s, fused_speedup |
//! | `volume.dt_sweep` | seconds and max error vs the closed form for each dt in `params.dts`, f32 and f64 |
//!
//! The references (`volume::referee`) never call `crate::volume`'s stages
//! (a test there says so); they share only the parameter types, the camera
//! and `f_ray` (judged by the `rays` cases). This file only wires them.

use std::time::Instant;

mod gpu;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::judge::measure::process_cpu_s;
use crate::judge::plot::{self, Chart, Series};
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;
use crate::rng::rand_f64;
use crate::scene::volume::FieldSpec;
use crate::stats::summary::median;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::{Compose, Image};
use crate::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc};
use crate::volume::referee::closed_form::{closed_image, optical_depths};
use crate::volume::referee::quadrature::{grid_probe, quadrature};
use crate::volume::{prepare, render, render_prepared, render_rays, Chain, Render, VolumeParams};

const RENDER_PARAMS: &[&str] = &["compose"];

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "volume.render",
        doc: "SCENES.md outputs of a volume scene (fused chain): rgb, trans, logtrans, depth, opacity, nsamples, hit; with params.grad_from also dsigma, dcolor, dcam",
        params: &["compose", "grad_from"],
        support: Support::CpuGpuF32,
        run: op_render,
    },
    OpEntry {
        name: "volume.forward",
        doc: "fused forward render; metrics time_s, samples_per_s; counters rays, samples, early_stop, ...",
        params: RENDER_PARAMS,
        support: Support::CpuGpuF32,
        run: op_forward,
    },
    OpEntry {
        name: "volume.unfused",
        doc: "f_ray -> f_samp -> f_int -> f_img; params.buffers: true adds off, t, dt, sigma, alpha, log_t",
        params: &["compose", "buffers"],
        support: Support::CpuGpuF32,
        run: op_unfused,
    },
    OpEntry {
        name: "volume.samples",
        doc: "f_samp outputs: off, ray_id, t, dt, sigma, u = (t - a_k) / dt_k, m",
        params: &[],
        support: Support::Cpu,
        run: op_samples,
    },
    OpEntry {
        name: "volume.reference_quadrature",
        doc: "independent f64 quadrature of the scene (same lattice and early stop), SCENES.md outputs",
        params: &[],
        support: Support::Any,
        run: op_reference,
    },
    OpEntry {
        name: "volume.closed_form",
        doc: "continuum closed forms of trans, logtrans, opacity, rgb for analytic fields (and grids sampled from them)",
        params: &[],
        support: Support::Any,
        run: op_closed_form,
    },
    OpEntry {
        name: "volume.grid_probe",
        doc: "the scene's density grid at params.n seeded points in [-1.5, 1.5]^3 (in and out of the box): value",
        params: &["n", "seed"],
        support: Support::Cpu,
        run: op_grid_probe,
    },
    OpEntry {
        name: "volume.grid_probe_reference",
        doc: "the same points through the independent f64 trilinear reference: value, inside",
        params: &["n", "seed"],
        support: Support::Any,
        run: op_grid_probe_reference,
    },
    OpEntry {
        name: "volume.perf",
        doc: "fused vs unfused medians: samples_per_s, unfused_samples_per_s, integrated_samples_per_s, pixels_per_s, fused_speedup",
        params: &["repeats"],
        support: Support::Cpu,
        run: op_perf,
    },
    OpEntry {
        name: "volume.dt_sweep",
        doc: "speed against error: seconds and max |trans - closed form| per dt in params.dts, f32 and f64",
        params: &["dts", "repeats"],
        support: Support::Cpu,
        run: op_dt_sweep,
    },
];

/// Camera, generator, parameters and the scene's field spec.
fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams, FieldSpec)> {
    let doc = ctx.scene()?;
    let scene = crate::scene::volume::parse(doc)?;
    let (cam, gen, p) = scene.build(doc)?;
    Ok((cam, gen, p, scene.spec.field))
}

fn compose_param(ctx: &OpCtx) -> Result<Compose> {
    match ctx.param_or::<String>("compose", "sorted".into())?.as_str() {
        "sorted" => Ok(Compose::Sorted),
        "scatter" => Ok(Compose::Scatter),
        other => Err(Error::invalid(
            format!("{} params.compose", ctx.case_id),
            format!("{other:?} is not sorted or scatter"),
        )),
    }
}

pub(super) fn image_outputs<F: Real>(img: &Image<F>, out: &mut Outputs) -> Result<()> {
    let s = [img.height, img.width];
    out.tensor("rgb", Tensor::real3(&s, &img.rgb)?);
    out.tensor("trans", Tensor::real(&s, img.trans.clone())?);
    out.tensor("logtrans", Tensor::real(&s, img.logtrans.clone())?);
    out.tensor("depth", Tensor::real(&s, img.depth.clone())?);
    out.tensor("opacity", Tensor::real(&s, img.opacity.clone())?);
    out.tensor(
        "nsamples",
        Tensor::from_shape_vec(&s, img.nsamples.clone())?,
    );
    out.tensor("hit", Tensor::from_shape_vec(&s, img.hit.clone())?);
    Ok(())
}

fn render_outputs<F: Real>(r: &Render<F>, out: &mut Outputs) -> Result<()> {
    image_outputs(&r.image, out)?;
    for (k, v) in r.counters.pairs() {
        out.counter(k, v);
    }
    out.tensor("samples_total", Tensor::scalar(r.counters.samples as f64));
    let chain_s = r.timings.fused + r.timings.ray + r.timings.samp + r.timings.int + r.timings.img;
    out.metric("time_s", chain_s);
    out.metric(
        "samples_per_s",
        r.counters.samples as f64 / chain_s.max(1e-12),
    );
    Ok(())
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
    render_outputs(&r, &mut out)?;
    if ctx.dump && ctx.rays.is_none() {
        out.tensor("rays", f_ray::<F>(&cam, &gen, &ctx.budget)?.to_tensor()?);
    }
    if let (true, Some(s), Some(it)) = (buffers, &r.samples, &r.integrated) {
        let m = [s.len()];
        out.tensor(
            "off",
            Tensor::from_shape_vec(&[s.off.len()], s.off.iter().map(|&o| o as i32).collect())?,
        );
        out.tensor(
            "ray_id",
            Tensor::from_shape_vec(&m, s.ray_id.iter().map(|&o| o as i32).collect())?,
        );
        out.tensor("t", Tensor::real(&m, s.t.clone())?);
        out.tensor("dt", Tensor::real(&m, s.dt.clone())?);
        out.tensor("sigma", Tensor::real(&m, s.sigma.clone())?);
        out.tensor("alpha", Tensor::real(&m, it.alpha.clone())?);
        out.tensor("log_t", Tensor::real(&m, it.log_t.clone())?);
    }
    Ok(out)
}

fn op_forward(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        return gpu::run_chain_gpu(ctx, Chain::Fused, compose_param(ctx)?);
    }
    by_precision!(ctx, run_chain(ctx, Chain::Fused, false))
}

/// `volume.render`: the forward outputs, plus gradients when
/// `params.grad_from` names dL/d rgb (issue 4, `ops/volume_diff.rs`).
fn op_render(ctx: &OpCtx) -> Result<Outputs> {
    let mut out = op_forward(ctx)?;
    super::volume_diff::render_grads(ctx, &mut out)?;
    Ok(out)
}

fn op_unfused(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        return gpu::run_chain_gpu(ctx, Chain::Unfused, compose_param(ctx)?);
    }
    let buffers = ctx.param_or("buffers", false)?;
    by_precision!(ctx, run_chain(ctx, Chain::Unfused, buffers))
}

fn samples_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let r = render::<F>(&cam, &gen, &p, Chain::Unfused, Compose::Sorted, &ctx.budget)?;
    let s = r
        .samples
        .ok_or_else(|| Error::invalid(ctx.case_id, "the unfused chain kept no samples"))?;
    let rays = f_ray::<F>(&cam, &gen, &ctx.budget)?;
    // u_k = (t_k - a_k) / dt_k with k the sample's place in its ray
    // (meaningful without occupancy skipping), in f64.
    let mut u = Vec::with_capacity(s.len());
    for r in 0..s.off.len() - 1 {
        for (k, j) in (s.off[r] as usize..s.off[r + 1] as usize).enumerate() {
            let a = rays.t0[r].f64() + k as f64 * p.dt;
            u.push(((s.t[j].f64() - a) / s.dt[j].f64()).clamp(0.0, 1.0));
        }
    }
    let m = [s.len()];
    let mut out = Outputs::default();
    out.tensor(
        "off",
        Tensor::from_shape_vec(&[s.off.len()], s.off.iter().map(|&o| o as i32).collect())?,
    );
    out.tensor(
        "ray_id",
        Tensor::from_shape_vec(&m, s.ray_id.iter().map(|&o| o as i32).collect())?,
    );
    out.tensor("t", Tensor::real(&m, s.t.clone())?);
    out.tensor("dt", Tensor::real(&m, s.dt.clone())?);
    out.tensor("sigma", Tensor::real(&m, s.sigma.clone())?);
    out.tensor("u", Tensor::real(&m, u)?);
    out.tensor("m", Tensor::scalar(s.len() as f64));
    out.counter("samples", s.len() as u64);
    Ok(out)
}

fn op_samples(ctx: &OpCtx) -> Result<Outputs> {
    by_precision!(ctx, samples_in(ctx))
}

// ---------------------------------------------------------------------------
// Independent references: `volume::referee`.

fn op_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let rays = match ctx.rays {
        Some(t) => Rays::<f64>::from_tensor(t, "--rays")?,
        None => f_ray::<f64>(&cam, &gen, &ctx.budget)?,
    };
    let roi = gen.region();
    let n = rays.len();
    if n != roi.width as usize * roi.height as usize {
        return Err(Error::invalid(
            "--rays",
            format!(
                "{n} rays for a {}x{} region: the reference needs one ray per pixel",
                roi.width, roi.height
            ),
        ));
    }
    let s = [roi.height as usize, roi.width as usize];
    quadrature(&rays, &p).to_outputs(&s)
}

/// The probe points (f64) and the scene's grid.
fn probe_setup(ctx: &OpCtx) -> Result<(Vec<[f64; 3]>, GridDesc)> {
    let (_, _, p, _) = load(ctx)?;
    let FieldDesc::Grid(g) = p.field else {
        return Err(Error::invalid(
            ctx.case_id,
            "grid_probe needs a scene whose field is a grid",
        ));
    };
    let n: u32 = ctx.param_or("n", 4096)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    if n == 0 || n > 1 << 22 {
        return Err(Error::invalid(
            format!("{} params.n", ctx.case_id),
            "must be in 1..=4194304",
        ));
    }
    let pts = (0..n)
        .map(|i| [0, 1, 2].map(|d| rand_f64(seed, i, 0, d) * 3.0 - 1.5))
        .collect();
    Ok((pts, g))
}

fn grid_probe_in<F: Real>(pts: &[[f64; 3]], g: &GridDesc) -> Result<Tensor> {
    let grid = crate::volume::field::Grid::<F>::from_desc(g);
    let v: Vec<F> = pts
        .iter()
        .map(|x| grid.trilinear::<1>(x.map(F::of))[0])
        .collect();
    Tensor::real(&[pts.len()], v)
}

fn op_grid_probe(ctx: &OpCtx) -> Result<Outputs> {
    let (pts, g) = probe_setup(ctx)?;
    let mut out = Outputs::default();
    let t = by_precision!(ctx, grid_probe_in(&pts, &g))?;
    out.tensor("value", t);
    Ok(out)
}

fn op_grid_probe_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (pts, g) = probe_setup(ctx)?;
    let (v, inside) = grid_probe(&pts, &g);
    let mut out = Outputs::default();
    out.tensor("value", Tensor::real(&[pts.len()], v)?);
    out.tensor("inside", Tensor::from_shape_vec(&[pts.len()], inside)?);
    Ok(out)
}

// ---------------------------------------------------------------------------
// Continuum closed forms.

fn continuum_field(spec: &FieldSpec, at: &str) -> Result<Analytic> {
    let f = match spec {
        FieldSpec::Grid { from: Some(f), .. } => f.as_ref(),
        FieldSpec::Grid { .. } => {
            return Err(Error::NotSupported(format!(
                "{at}: no closed form for a grid read from a file"
            )))
        }
        other => other,
    };
    crate::scene::volume::analytic(f, at)
}

/// Closed-form `(tau, hit)` per pixel of the scene's region, f64 rays.
fn closed_tau(
    ctx: &OpCtx,
    cam: &Camera,
    gen: &RayGen,
    spec: &FieldSpec,
) -> Result<(Vec<f64>, Vec<u8>)> {
    let a = continuum_field(spec, ctx.case_id)?;
    let rays = f_ray::<f64>(cam, gen, &ctx.budget)?;
    Ok(optical_depths(&a, &rays))
}

fn op_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, spec) = load(ctx)?;
    let c = match p.color {
        ColorDesc::Constant(c) => c,
        ColorDesc::Grid(ref g) if g.data.chunks(3).all(|v| v == &g.data[..3]) => {
            [g.data[0], g.data[1], g.data[2]]
        }
        ColorDesc::Grid(_) | ColorDesc::Mlp => {
            return Err(Error::NotSupported(format!(
                "{}: closed form needs a constant colour",
                ctx.case_id
            )))
        }
    };
    let (tau, hit) = closed_tau(ctx, &cam, &gen, &spec)?;
    let roi = gen.region();
    let s = [roi.height as usize, roi.width as usize];
    closed_image(&tau, hit, c, p.background, &s)
}

// ---------------------------------------------------------------------------
// Performance.

fn perf_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, _) = load(ctx)?;
    let repeats: usize = ctx.param_or("repeats", 3)?;
    if repeats == 0 || repeats > 1000 {
        return Err(Error::invalid(
            format!("{} params.repeats", ctx.case_id),
            "must be in 1..=1000",
        ));
    }
    let (mut fused, mut unfused, mut int, mut img) = (vec![], vec![], vec![], vec![]);
    let (mut cpu_fused, mut cpu_unfused) = (0.0, 0.0);
    let mut samples = 0;
    let mut last = None;
    // The plan (grid conversion, colour packing) is built once, as a
    // training loop would; each repeat renders one frame with each chain.
    let prep = prepare::<F>(&p, &gen.aabb, &ctx.budget)?;
    for _ in 0..repeats {
        let c0 = process_cpu_s();
        let f = render_prepared(
            &cam,
            &gen,
            &prep,
            Chain::Fused,
            Compose::Sorted,
            &ctx.budget,
        )?;
        let c1 = process_cpu_s();
        let u = render_prepared(
            &cam,
            &gen,
            &prep,
            Chain::Unfused,
            Compose::Sorted,
            &ctx.budget,
        )?;
        let c2 = process_cpu_s();
        if let (Some(c0), Some(c1), Some(c2)) = (c0, c1, c2) {
            cpu_fused += c1 - c0;
            cpu_unfused += c2 - c1;
        }
        if f.image != u.image {
            return Err(Error::invalid(
                ctx.case_id,
                "fused and unfused images differ: speed of different results",
            ));
        }
        fused.push(f.timings.fused + f.timings.img);
        unfused.push(u.timings.ray + u.timings.samp + u.timings.int + u.timings.img);
        int.push(u.timings.int);
        img.push(u.timings.img);
        samples = f.counters.samples;
        last = Some(f);
    }
    let (tf, tu, ti, tg) = (
        median(&mut fused),
        median(&mut unfused),
        median(&mut int),
        median(&mut img),
    );
    let pixels = gen.region().width as f64 * gen.region().height as f64;
    let mut out = Outputs::default();
    if let Some(f) = last {
        render_outputs(&f, &mut out)?;
    }
    out.metric("time_s", tf);
    out.metric("samples_per_s", samples as f64 / tf);
    out.metric("unfused_time_s", tu);
    out.metric("unfused_samples_per_s", samples as f64 / tu);
    out.metric("integrated_samples_per_s", samples as f64 / ti.max(1e-12));
    out.metric("pixels_per_s", pixels / tg.max(1e-12));
    out.metric("fused_speedup", tu / tf);
    out.metric("threads", rayon::current_num_threads() as f64);
    // Frames per CPU second (ray generation to image): the speed of the code
    // on a core it has to itself, whatever else the machine runs.
    if cpu_fused > 0.0 && cpu_unfused > 0.0 {
        out.metric(
            "samples_per_cpu_s",
            (samples * repeats as u64) as f64 / cpu_fused,
        );
        out.metric(
            "unfused_samples_per_cpu_s",
            (samples * repeats as u64) as f64 / cpu_unfused,
        );
    }
    Ok(out)
}

fn op_perf(ctx: &OpCtx) -> Result<Outputs> {
    by_precision!(ctx, perf_in(ctx))
}

fn sweep_point<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    tau: &[f64],
    ctx: &OpCtx,
    repeats: usize,
) -> Result<(f64, f64)> {
    let mut times = vec![];
    let mut err = 0.0f64;
    for _ in 0..repeats {
        let t = Instant::now();
        let r = render::<F>(cam, gen, p, Chain::Fused, Compose::Sorted, &ctx.budget)?;
        times.push(t.elapsed().as_secs_f64());
        err = r
            .image
            .trans
            .iter()
            .zip(tau)
            .map(|(a, t)| (a.f64() - (-t).exp()).abs())
            .fold(0.0, f64::max);
    }
    Ok((median(&mut times), err))
}

fn op_dt_sweep(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, spec) = load(ctx)?;
    let dts: Vec<f64> = ctx.param_req("dts")?;
    let repeats: usize = ctx.param_or("repeats", 3)?;
    if dts.is_empty() || repeats == 0 || repeats > 100 {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "need a non-empty `dts` and repeats in 1..=100",
        ));
    }
    let (tau, _) = closed_tau(ctx, &cam, &gen, &spec)?;
    let mut cols: [Vec<f64>; 4] = Default::default();
    for &dt in &dts {
        let q = VolumeParams {
            dt,
            early_stop: 0.0,
            max_steps: crate::volume::sample::MAX_STEPS_LIMIT,
            ..p.clone()
        };
        let (t32, e32) = sweep_point::<f32>(&cam, &gen, &q, &tau, ctx, repeats)?;
        let (t64, e64) = sweep_point::<f64>(&cam, &gen, &q, &tau, ctx, repeats)?;
        for (c, v) in cols.iter_mut().zip([t32, e32, t64, e64]) {
            c.push(v);
        }
    }
    let n = [dts.len()];
    let mut out = Outputs::default();
    let chart = Chart::loglog(
        "volume forward: speed against error over dt",
        "seconds per frame",
        "max error vs closed form",
        vec![
            Series::new("f32", cols[0].clone(), cols[1].clone()),
            Series::new("f64", cols[2].clone(), cols[3].clone()),
        ],
    );
    out.tensor("plot_rgb", plot::render(&chart)?);
    out.tensor("dt", Tensor::real(&n, dts.clone())?);
    for (name, c) in ["time_f32", "err_f32", "time_f64", "err_f64"]
        .iter()
        .zip(cols.iter())
    {
        out.tensor(name, Tensor::real(&n, c.clone())?);
        for (dt, v) in dts.iter().zip(c) {
            out.metric(&format!("{name}_dt{dt}"), *v);
        }
    }
    Ok(out)
}
