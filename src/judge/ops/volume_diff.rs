//! Operations of the volume backward pass (`f_diff`) and its referees:
//! finite differences (`volume::referee::finite_diff`, f64, early stop and
//! skipping off) and closed forms (`volume::referee::closed_form`).
//!
//! The loss is `L = sum_p W_p . rgb_p + w_depth sum_p depth_p + w_opacity
//! sum_p opacity_p` (`volume::loss`). `W` is `params.w_const` everywhere,
//! else `rand(w_seed, pixel, 0, ch) - 0.5`, or read from `params.grad_from`
//! ((H, W, 3) float32/float64 .npy). Probes (`params.probes: {sigma: n,
//! color: n, seed: s}`) are grid nodes drawn by `volume::loss::probe_nodes`,
//! the same rule on both sides.

use std::path::Path;

use super::volume_gpu_diff::session as op_session;
use super::{BackendKind, OpCtx};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::judge::measure::volume as measure;
use crate::rays::{f_ray, RayGen};
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};
use crate::volume::diff::{f_diff, DiffOptions, Reduce, DEFAULT_CHUNKS};
use crate::volume::field::{ColorDesc, FieldDesc};
use crate::volume::grad_outputs::grad_outputs;
use crate::volume::loss::{LossWeights, ProbeSpec, MAX_PROBES};
use crate::volume::referee::closed_form::grad_closed_form;
use crate::volume::referee::finite_diff::grad_fd;
use crate::volume::{Chain, VolumeParams};

ops! {
    "volume.grad" CpuGpuF32 op_grad ["chain", "reduce", "chunks", "per_sample", "probes", "w_seed", "w_const", "w_depth",
        "w_opacity", "grad_from"]
        "f_diff: dsigma, dcolor (grid nodes), dsigma_param, dcolor_const, dcam, dsigma_probe, dcolor_probe; params chain fused|unfused, reduce sorted|chunked (GPU: fixed|float_atomic)";
    "volume.grad_fd" Any op_grad_fd ["probes", "w_seed", "w_const", "w_depth", "w_opacity", "grad_from", "h_sigma",
        "h_color", "h_pose"]
        "FD referee (f64 central differences, early stop and skipping off): dsigma_probe, dcolor_probe, dsigma_param, dcolor_const, dcam";
    "volume.grad_closed_form" Any op_grad_closed_form ["w_seed", "w_const"]
        "closed-form gradients: dsigma_param (constant, slabs), dcolor_const, dcam (gaussian blob, continuum)";
    "volume.grad_perf" CpuGpuF32 op_grad_perf ["repeats", "chunks"]
        "backward medians: grads_per_s, bwd_fwd_ratio, unfused_grads_per_s, bytes_per_sample_fused/unfused (GPU: float_atomic_grads_per_s, fixed_over_float_atomic)";
    "volume.session" GpuF32 op_session ["frames"]
        "GPU steady-state frames (one submit: f_fused + f_img) vs per-stage submits: the last frame's image; session/stages quartiles, session_speedup";
}

pub(super) fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams)> {
    let doc = ctx.scene()?;
    crate::scene::volume::parse(doc)?.build(doc)
}

/// The loss weights of a case (module doc), one per ray of the region.
pub(super) fn loss_weights(ctx: &OpCtx, gen: &RayGen) -> Result<LossWeights> {
    let [h, w] = gen.shape();
    let rgb = if let Some(p) = ctx.param::<String>("grad_from")? {
        let path = if Path::new(&p).is_file() {
            p.into()
        } else {
            ctx.resolve(&p)
        };
        LossWeights::read_rgb(&path, h, w)?
    } else if let Some(c) = ctx.param::<f64>("w_const")? {
        if !c.is_finite() {
            return Err(ctx.bad("w_const", "must be finite"));
        }
        vec![[c; 3]; h * w]
    } else {
        LossWeights::seeded(gen, ctx.param_or("w_seed", 1)?)
    };
    let depth: f64 = ctx.param_or("w_depth", 0.0)?;
    let opacity: f64 = ctx.param_or("w_opacity", 0.0)?;
    if !(depth.is_finite() && opacity.is_finite()) {
        return Err(ctx.bad("w_depth/w_opacity", "must be finite"));
    }
    Ok(LossWeights {
        rgb,
        depth,
        opacity,
    })
}

/// `params.chain` (fused | unfused), `reduce` (sorted | chunked, `chunks`)
/// and `per_sample`.
pub(super) fn options(ctx: &OpCtx) -> Result<DiffOptions> {
    let chain = match ctx.param_or::<String>("chain", "fused".into())?.as_str() {
        "fused" => Chain::Fused,
        "unfused" => Chain::Unfused,
        o => return Err(ctx.bad("chain", format!("{o:?} is not fused or unfused"))),
    };
    let chunks: u32 = ctx.param_or("chunks", DEFAULT_CHUNKS)?;
    let reduce = match ctx.param_or::<String>("reduce", "sorted".into())?.as_str() {
        "sorted" => Reduce::Sorted,
        "chunked" => Reduce::Chunked { chunks },
        o => return Err(ctx.bad("reduce", format!("{o:?} is not sorted or chunked"))),
    };
    let per_sample = ctx.param_or("per_sample", false)?;
    Ok(DiffOptions {
        chain,
        reduce,
        per_sample,
    })
}

pub(super) fn probe_spec(ctx: &OpCtx) -> Result<ProbeSpec> {
    let p: ProbeSpec = ctx.param_or("probes", ProbeSpec::default())?;
    if p.sigma > MAX_PROBES || p.color > MAX_PROBES {
        return Err(ctx.bad(
            "probes",
            format!("at most {MAX_PROBES} probes of each kind"),
        ));
    }
    Ok(p)
}

fn grad_in<F: Real>(ctx: &OpCtx, opt: DiffOptions) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let probes = probe_spec(ctx)?;
    let g = f_diff::<F>(&cam, &gen, &p, &w.upstream(), &opt, None, &ctx.budget)?;
    let mut out = Outputs::default();
    grad_outputs(&g, &p, &probes, &mut out)?;
    let rays = gen.region().width as f64 * gen.region().height as f64;
    out.tensor("samples_per_ray", Tensor::scalar(g.samples as f64 / rays));
    Ok(out)
}

fn op_grad(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        return super::volume_gpu_diff::grad(ctx);
    }
    let opt = options(ctx)?;
    by_precision!(ctx, grad_in(ctx, opt))
}

/// `volume.render` with `params.grad_from` (`hpjudge render --grad-from`):
/// adds dsigma / dcolor (grid fields), dcam, and for analytic fields
/// per-sample (`dsigma_samples`, `dcolor_samples`) and per-parameter
/// gradients to the forward outputs.
pub fn render_grads(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    if ctx.param::<String>("grad_from")?.is_none() {
        return Ok(());
    }
    if ctx.rays.is_some() {
        let why = "render --grad-from with --rays: gradients need camera rays (dcam)";
        return Err(Error::NotSupported(why.into()));
    }
    if ctx.backend == BackendKind::Gpu {
        return super::volume_gpu_diff::render_grads(ctx, out);
    }
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let analytic = matches!(p.field, FieldDesc::Analytic(_));
    let chain = if analytic {
        Chain::Unfused
    } else {
        Chain::Fused
    };
    let opt = DiffOptions {
        chain,
        reduce: Reduce::Sorted,
        per_sample: analytic,
    };
    by_precision!(ctx, grads_into(ctx, (&cam, &gen, &p), &w, &opt, out))
}

fn grads_into<F: Real>(
    ctx: &OpCtx,
    (cam, gen, p): (&Camera, &RayGen, &VolumeParams),
    w: &LossWeights,
    opt: &DiffOptions,
    out: &mut Outputs,
) -> Result<()> {
    let g = f_diff::<F>(cam, gen, p, &w.upstream(), opt, None, &ctx.budget)?;
    grad_outputs(&g, p, &ProbeSpec::default(), out)
}

fn op_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let probes = probe_spec(ctx)?;
    let mut h = [0.0f64; 3];
    for (i, (k, d)) in [("h_sigma", 1e-4), ("h_color", 1e-3), ("h_pose", 1e-6)]
        .into_iter()
        .enumerate()
    {
        h[i] = ctx.param_or(k, d)?;
        if !(h[i].is_finite() && h[i] > 0.0 && h[i] < 1.0) {
            return Err(Error::invalid(
                ctx.at(k),
                format!("{} is not in (0, 1)", h[i]),
            ));
        }
    }
    grad_fd(&cam, &gen, &p, &w, &probes, h, &ctx.budget)
}

fn op_grad_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let (ColorDesc::Constant(c), FieldDesc::Analytic(a)) = (&p.color, &p.field) else {
        let why = "closed-form gradients need an analytic field and a constant colour";
        return Err(Error::NotSupported(format!("{}: {why}", ctx.case_id)));
    };
    let rays = f_ray::<f64>(&cam, &gen, &ctx.budget)?;
    grad_closed_form(
        a,
        *c,
        p.background,
        &rays,
        cam.c2w(),
        &gen,
        &w.rgb,
        ctx.case_id,
    )
}

fn perf_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let repeats: usize = ctx.param_or("repeats", 3)?;
    let chunks: u32 = ctx.param_or("chunks", DEFAULT_CHUNKS)?;
    if repeats == 0 || repeats > 100 {
        return Err(ctx.bad("repeats", "must be in 1..=100"));
    }
    let w = loss_weights(ctx, &gen)?.upstream::<F>();
    measure::backward::<F>(&cam, &gen, &p, &w, chunks, repeats, &ctx.budget)
}

fn op_grad_perf(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        return super::volume_gpu_diff::perf(ctx);
    }
    by_precision!(ctx, perf_in(ctx))
}
