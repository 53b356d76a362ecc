//! Operations of the volume backward pass (`f_diff`, issue 4) and its
//! independent references.
//!
//! | op | what |
//! | --- | --- |
//! | `volume.grad` | `f_diff` of the scene for an upstream `W` (seeded, constant or a file): dsigma / dcolor (grid nodes), dsigma_param / dcolor_const (analytic, constant colour), dcam, probe values, per-sample grads |
//! | `volume.grad_fd` | FD referee, f64: central differences of `L = sum W . rgb (+ w_depth depth + w_opacity opacity)` at the same seeded probes, every pose component, every analytic parameter |
//! | `volume.grad_closed_form` | closed forms: constant and slab densities (`dC/dsigma_i = L_i e^-tau (c - b)`), constant colour, the Gaussian blob's continuum pose gradient |
//! | `volume.grad_perf` | grads/s, backward/forward time ratio, bytes per sample, fused and unfused |
//!
//! The loss is `L = sum_p W_p . rgb_p + w_depth sum_p depth_p + w_opacity
//! sum_p opacity_p`. `W` is `params.w_const` everywhere, else
//! `rand(w_seed, pixel, 0, ch) - 0.5` (SCENES.md RNG), or read from
//! `params.grad_from` ((H, W, 3) float32/float64 .npy).
//!
//! Probes (`params.probes: {sigma: n, color: n, seed: s}`): grid nodes drawn
//! from the middle half of each axis, where the camera's rays cross, with
//! `rand(seed, q, stream, axis)`; colour probes also draw a channel. The
//! referee and `volume.grad` draw the same probes from the same rule.
//!
//! The referee (`volume::referee::finite_diff`) never calls `volume::diff`
//! (a test there says so): it differences the forward render
//! (fused, f64, early stop and skipping off), judged by the forward cases.

use std::path::Path;
use std::time::Instant;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::{f_ray, RayGen};
use crate::real::{Precision, Real};
use crate::rng::rand_f64;
use crate::stats::summary::median;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::Compose;
use crate::volume::diff::{f_diff, DiffOptions, Reduce, Upstream, DEFAULT_CHUNKS};
use crate::volume::field::{ColorDesc, FieldDesc};
use crate::volume::grad_outputs::grad_outputs;
use crate::volume::loss::{LossWeights, ProbeSpec, MAX_PROBES};
use crate::volume::referee::closed_form::grad_closed_form;
use crate::volume::referee::finite_diff::grad_fd;
use crate::volume::{render, Chain, VolumeParams};

const GRAD_PARAMS: &[&str] = &[
    "chain",
    "reduce",
    "chunks",
    "per_sample",
    "probes",
    "w_seed",
    "w_const",
    "w_depth",
    "w_opacity",
    "grad_from",
];

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "volume.grad",
        doc: "f_diff: dsigma, dcolor (grid nodes), dsigma_param, dcolor_const, dcam, dsigma_probe, dcolor_probe; params chain fused|unfused, reduce sorted|chunked (GPU: fixed|float_atomic)",
        params: GRAD_PARAMS,
        support: Support::CpuGpuF32,
        run: op_grad,
    },
    OpEntry {
        name: "volume.grad_fd",
        doc: "FD referee (f64 central differences, early stop and skipping off): dsigma_probe, dcolor_probe, dsigma_param, dcolor_const, dcam",
        params: &[
            "probes",
            "w_seed",
            "w_const",
            "w_depth",
            "w_opacity",
            "grad_from",
            "h_sigma",
            "h_color",
            "h_pose",
        ],
        support: Support::Any,
        run: op_grad_fd,
    },
    OpEntry {
        name: "volume.grad_closed_form",
        doc: "closed-form gradients: dsigma_param (constant, slabs), dcolor_const, dcam (gaussian blob, continuum)",
        params: &["w_seed", "w_const"],
        support: Support::Any,
        run: op_grad_closed_form,
    },
    OpEntry {
        name: "volume.session",
        doc: "GPU steady-state frames (one submit: f_fused + f_img) vs per-stage submits: image tensors of the last frame; session/stages quartiles, session_speedup",
        params: &["frames"],
        support: Support::GpuF32,
        run: super::volume_gpu_diff::session,
    },
    OpEntry {
        name: "volume.grad_perf",
        doc: "backward medians: grads_per_s, bwd_fwd_ratio, unfused_grads_per_s, bytes_per_sample_fused/unfused",
        params: &["repeats", "chunks"],
        support: Support::CpuGpuF32,
        run: op_grad_perf,
    },
];

pub(super) fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams)> {
    let doc = ctx.scene()?;
    crate::scene::volume::parse(doc)?.build(doc)
}

fn at(ctx: &OpCtx, key: &str) -> String {
    format!("{} params.{key}", ctx.case_id)
}

// ---------------------------------------------------------------------------
// The loss.

/// The loss weights of a case (`volume::loss`), one per ray of the region.
pub(super) fn loss_weights(ctx: &OpCtx, gen: &RayGen) -> Result<LossWeights> {
    let roi = gen.region();
    let (h, w) = (roi.height as usize, roi.width as usize);
    let rgb = if let Some(p) = ctx.param::<String>("grad_from")? {
        let direct = Path::new(&p);
        let path = if direct.is_file() {
            direct.to_path_buf()
        } else {
            ctx.resolve(&p)
        };
        let t =
            Tensor::read_npy_checked(&path, &["float32", "float64"], &[Some(h), Some(w), Some(3)])?;
        let v = t.to_f64_vec();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            return Err(Error::invalid(
                path.display().to_string(),
                format!("value at flat index {i} is not finite"),
            ));
        }
        v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect()
    } else if let Some(c) = ctx.param::<f64>("w_const")? {
        if !c.is_finite() {
            return Err(Error::invalid(at(ctx, "w_const"), "must be finite"));
        }
        vec![[c; 3]; h * w]
    } else {
        let seed: u32 = ctx.param_or("w_seed", 1)?;
        (0..h * w)
            .map(|i| {
                let (u, v) = (roi.x + (i % w) as u32, roi.y + (i / w) as u32);
                let px = v * gen.width + u;
                [0, 1, 2].map(|ch| rand_f64(seed, px, 0, ch) - 0.5)
            })
            .collect()
    };
    let depth: f64 = ctx.param_or("w_depth", 0.0)?;
    let opacity: f64 = ctx.param_or("w_opacity", 0.0)?;
    if !(depth.is_finite() && opacity.is_finite()) {
        return Err(Error::invalid(
            at(ctx, "w_depth/w_opacity"),
            "must be finite",
        ));
    }
    Ok(LossWeights {
        rgb,
        depth,
        opacity,
    })
}

/// `f_diff`'s upstream gradient for the loss `w`.
pub(super) fn upstream<F: Real>(w: &LossWeights) -> Upstream<F> {
    let n = w.rgb.len();
    Upstream {
        rgb: w.rgb.iter().map(|c| c.map(F::of)).collect(),
        depth: (w.depth != 0.0).then(|| vec![F::of(w.depth); n]),
        opacity: (w.opacity != 0.0).then(|| vec![F::of(w.opacity); n]),
    }
}

// ---------------------------------------------------------------------------
// Probes.

pub(super) fn probe_spec(ctx: &OpCtx) -> Result<ProbeSpec> {
    let p: ProbeSpec = ctx.param_or("probes", ProbeSpec::default())?;
    if p.sigma > MAX_PROBES || p.color > MAX_PROBES {
        return Err(Error::invalid(
            at(ctx, "probes"),
            format!("at most {MAX_PROBES} probes of each kind"),
        ));
    }
    Ok(p)
}

// ---------------------------------------------------------------------------
// volume.grad

fn options(ctx: &OpCtx) -> Result<DiffOptions> {
    let chain = match ctx.param_or::<String>("chain", "fused".into())?.as_str() {
        "fused" => Chain::Fused,
        "unfused" => Chain::Unfused,
        o => {
            return Err(Error::invalid(
                at(ctx, "chain"),
                format!("{o:?} is not fused or unfused"),
            ))
        }
    };
    let chunks: u32 = ctx.param_or("chunks", DEFAULT_CHUNKS)?;
    let reduce = match ctx.param_or::<String>("reduce", "sorted".into())?.as_str() {
        "sorted" => Reduce::Sorted,
        "chunked" => Reduce::Chunked { chunks },
        o => {
            return Err(Error::invalid(
                at(ctx, "reduce"),
                format!("{o:?} is not sorted or chunked"),
            ))
        }
    };
    Ok(DiffOptions {
        chain,
        reduce,
        per_sample: ctx.param_or("per_sample", false)?,
    })
}

fn grad_in<F: Real>(ctx: &OpCtx, opt: DiffOptions) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let probes = probe_spec(ctx)?;
    let g = f_diff::<F>(&cam, &gen, &p, &upstream(&w), &opt, None, &ctx.budget)?;
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

/// `volume.render` with `params.grad_from` (the `hpjudge render --grad-from`
/// path): the forward outputs plus dsigma / dcolor (grid fields), dcam, and
/// for analytic fields per-sample (`dsigma_samples`, `dcolor_samples`) and
/// per-parameter gradients. Hooked from `volume.render` in `ops/volume.rs`.
pub fn render_grads(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    if ctx.param::<String>("grad_from")?.is_none() {
        return Ok(());
    }
    if ctx.rays.is_some() {
        return Err(Error::NotSupported(
            "render --grad-from with --rays: gradients need camera rays (dcam)".into(),
        ));
    }
    if ctx.backend == BackendKind::Gpu {
        return super::volume_gpu_diff::render_grads(ctx, out);
    }
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let analytic = matches!(p.field, FieldDesc::Analytic(_));
    let opt = DiffOptions {
        chain: if analytic {
            Chain::Unfused
        } else {
            Chain::Fused
        },
        reduce: Reduce::Sorted,
        per_sample: analytic,
    };
    let none = ProbeSpec::default();
    match ctx.precision {
        Precision::F32 => {
            let g = f_diff::<f32>(&cam, &gen, &p, &upstream(&w), &opt, None, &ctx.budget)?;
            grad_outputs(&g, &p, &none, out)
        }
        Precision::F64 => {
            let g = f_diff::<f64>(&cam, &gen, &p, &upstream(&w), &opt, None, &ctx.budget)?;
            grad_outputs(&g, &p, &none, out)
        }
    }
}

// ---------------------------------------------------------------------------
// volume.grad_fd: the finite-difference referee (`volume::referee::finite_diff`).

fn op_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let probes = probe_spec(ctx)?;
    let h_sigma: f64 = ctx.param_or("h_sigma", 1e-4)?;
    let h_color: f64 = ctx.param_or("h_color", 1e-3)?;
    let h_pose: f64 = ctx.param_or("h_pose", 1e-6)?;
    for (k, h) in [
        ("h_sigma", h_sigma),
        ("h_color", h_color),
        ("h_pose", h_pose),
    ] {
        if !(h.is_finite() && h > 0.0 && h < 1.0) {
            return Err(Error::invalid(at(ctx, k), format!("{h} is not in (0, 1)")));
        }
    }
    grad_fd(
        &cam,
        &gen,
        &p,
        &w,
        &probes,
        [h_sigma, h_color, h_pose],
        &ctx.budget,
    )
}

// ---------------------------------------------------------------------------
// volume.grad_closed_form

fn op_grad_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let c = match p.color {
        ColorDesc::Constant(c) => c,
        ColorDesc::Grid(_) | ColorDesc::Mlp => {
            return Err(Error::NotSupported(format!(
                "{}: closed-form gradients need a constant colour",
                ctx.case_id
            )))
        }
    };
    let FieldDesc::Analytic(a) = &p.field else {
        return Err(Error::NotSupported(format!(
            "{}: closed-form gradients need an analytic field",
            ctx.case_id
        )));
    };
    let rays = f_ray::<f64>(&cam, &gen, &ctx.budget)?;
    grad_closed_form(
        a,
        c,
        p.background,
        &rays,
        cam.c2w(),
        &gen,
        &w.rgb,
        ctx.case_id,
    )
}

// ---------------------------------------------------------------------------
// volume.grad_perf

fn perf_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p) = load(ctx)?;
    let repeats: usize = ctx.param_or("repeats", 3)?;
    let chunks: u32 = ctx.param_or("chunks", DEFAULT_CHUNKS)?;
    if repeats == 0 || repeats > 100 {
        return Err(Error::invalid(at(ctx, "repeats"), "must be in 1..=100"));
    }
    let w = upstream::<F>(&loss_weights(ctx, &gen)?);
    let fused = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Chunked { chunks },
        per_sample: false,
    };
    let fused_sorted = DiffOptions {
        reduce: Reduce::Sorted,
        ..fused
    };
    let unfused = DiffOptions {
        chain: Chain::Unfused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let (mut tf, mut tb, mut tbs, mut tu) = (vec![], vec![], vec![], vec![]);
    let (mut samples, mut bf, mut bu) = (0, 0, 0);
    let fwd = crate::volume::diff::forward_buffers::<F>(&gen, &cam, &p, &ctx.budget)?;
    for _ in 0..repeats {
        let t = Instant::now();
        let r = render::<F>(&cam, &gen, &p, Chain::Fused, Compose::Sorted, &ctx.budget)?;
        tf.push(t.elapsed().as_secs_f64());
        samples = r.counters.samples;
        let g = f_diff::<F>(&cam, &gen, &p, &w, &fused, None, &ctx.budget)?;
        tb.push(g.time_s);
        bf = g.bytes_per_sample;
        let g = f_diff::<F>(&cam, &gen, &p, &w, &fused_sorted, None, &ctx.budget)?;
        tbs.push(g.time_s);
        let g = f_diff::<F>(&cam, &gen, &p, &w, &unfused, Some(&fwd), &ctx.budget)?;
        tu.push(g.time_s);
        bu = g.bytes_per_sample;
    }
    let (tf, tb, tbs, tu) = (
        median(&mut tf),
        median(&mut tb),
        median(&mut tbs),
        median(&mut tu),
    );
    let s = samples as f64;
    let mut out = Outputs::default();
    out.metric("forward_time_s", tf);
    out.metric("time_s", tb);
    out.metric("grads_per_s", s / tb);
    out.metric("bwd_fwd_ratio", tb / tf);
    out.metric("sorted_time_s", tbs);
    out.metric("sorted_grads_per_s", s / tbs);
    out.metric("unfused_time_s", tu);
    out.metric("unfused_grads_per_s", s / tu);
    out.metric("bytes_per_sample_fused", bf as f64);
    out.metric("bytes_per_sample_unfused", bu as f64);
    out.metric("threads", rayon::current_num_threads() as f64);
    out.counter("samples", samples);
    Ok(out)
}

fn op_grad_perf(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        return super::volume_gpu_diff::perf(ctx);
    }
    by_precision!(ctx, perf_in(ctx))
}
