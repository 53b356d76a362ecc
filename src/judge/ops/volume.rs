//! Operations of the `volume` renderer and its independent references.
//!
//! | op | what |
//! | --- | --- |
//! | `volume.render` | SCENES.md outputs of a volume scene (fused chain): rgb, trans, logtrans, depth, opacity, nsamples, hit |
//! | `volume.forward` | the same, fused; metrics time_s, samples_per_s; counters |
//! | `volume.unfused` | the same through f_ray -> f_samp -> f_int -> f_img; `params.buffers` adds per-sample tensors |
//! | `volume.samples` | f_samp outputs: off, ray_id, t, dt, sigma, u (stratified offsets), m |
//! | `volume.reference_quadrature` | the discrete midpoint/stratified quadrature, f64, written here independently |
//! | `volume.closed_form` | continuum transmittance of the analytic field (constant, slabs, gaussian via erf, shell chord, linear) |
//! | `volume.grid_probe` / `_reference` | a density grid at seeded points in and out of the box, ours vs an independent trilinear (OOB zero / clamp) |
//! | `volume.perf` | fused vs unfused: samples/s, integrated_samples/s, pixels/s, fused_speedup |
//! | `volume.dt_sweep` | seconds and max error vs the closed form for each dt in `params.dts`, f32 and f64 |
//!
//! The references never call `crate::volume`'s stages: they share only the
//! scene parser, the camera and `f_ray` (judged by the `rays` cases).

use std::time::Instant;

use statrs::function::erf::erf;

mod gpu;

use super::{BackendKind, OpCtx, OpEntry};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::{Precision, Real};
use crate::rng::rand_f64;
use crate::scene::volume::FieldSpec;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::{Compose, Image};
use crate::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc, Oob};
use crate::volume::sample::{Sampling, TransPath};
use crate::volume::{prepare, render, render_prepared, render_rays, Chain, Render, VolumeParams};

const RENDER_PARAMS: &[&str] = &["compose"];

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "volume.render",
        doc: "SCENES.md outputs of a volume scene (fused chain): rgb, trans, logtrans, depth, opacity, nsamples, hit; with params.grad_from also dsigma, dcolor, dcam",
        params: &["compose", "grad_from"],
        run: op_render,
    },
    OpEntry {
        name: "volume.forward",
        doc: "fused forward render; metrics time_s, samples_per_s; counters rays, samples, early_stop, ...",
        params: RENDER_PARAMS,
        run: op_forward,
    },
    OpEntry {
        name: "volume.unfused",
        doc: "f_ray -> f_samp -> f_int -> f_img; params.buffers: true adds off, t, dt, sigma, alpha, log_t",
        params: &["compose", "buffers"],
        run: op_unfused,
    },
    OpEntry {
        name: "volume.samples",
        doc: "f_samp outputs: off, ray_id, t, dt, sigma, u = (t - a_k) / dt_k, m",
        params: &[],
        run: op_samples,
    },
    OpEntry {
        name: "volume.reference_quadrature",
        doc: "independent f64 quadrature of the scene (same lattice and early stop), SCENES.md outputs",
        params: &[],
        run: op_reference,
    },
    OpEntry {
        name: "volume.closed_form",
        doc: "continuum closed forms of trans, logtrans, opacity, rgb for analytic fields (and grids sampled from them)",
        params: &[],
        run: op_closed_form,
    },
    OpEntry {
        name: "volume.grid_probe",
        doc: "the scene's density grid at params.n seeded points in [-1.5, 1.5]^3 (in and out of the box): value",
        params: &["n", "seed"],
        run: op_grid_probe,
    },
    OpEntry {
        name: "volume.grid_probe_reference",
        doc: "the same points through the independent f64 trilinear reference: value, inside",
        params: &["n", "seed"],
        run: op_grid_probe_reference,
    },
    OpEntry {
        name: "volume.perf",
        doc: "fused vs unfused medians: samples_per_s, unfused_samples_per_s, integrated_samples_per_s, pixels_per_s, fused_speedup",
        params: &["repeats"],
        run: op_perf,
    },
    OpEntry {
        name: "volume.dt_sweep",
        doc: "speed against error: seconds and max |trans - closed form| per dt in params.dts, f32 and f64",
        params: &["dts", "repeats"],
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

fn image_outputs<F: Real>(img: &Image<F>, out: &mut Outputs) -> Result<()> {
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
    match ctx.precision {
        Precision::F32 => run_chain::<f32>(ctx, Chain::Fused, false),
        Precision::F64 => run_chain::<f64>(ctx, Chain::Fused, false),
    }
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
    match ctx.precision {
        Precision::F32 => run_chain::<f32>(ctx, Chain::Unfused, buffers),
        Precision::F64 => run_chain::<f64>(ctx, Chain::Unfused, buffers),
    }
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
    ctx.cpu_only()?;
    match ctx.precision {
        Precision::F32 => samples_in::<f32>(ctx),
        Precision::F64 => samples_in::<f64>(ctx),
    }
}

// ---------------------------------------------------------------------------
// Independent f64 quadrature reference: a plain loop per pixel.

/// Density at `x`, from the parameters, written apart from `volume::field`.
fn ref_sigma(f: &FieldDesc, x: [f64; 3]) -> f64 {
    match f {
        FieldDesc::Analytic(Analytic::Constant { s }) => *s,
        FieldDesc::Analytic(Analytic::Slabs {
            axis,
            breaks,
            sigma,
        }) => {
            let v = x[*axis];
            let last = sigma.len() - 1;
            match breaks.iter().rposition(|&b| b <= v) {
                Some(i) if i < last => sigma[i],
                Some(i) if v <= breaks[last + 1] => sigma[i.min(last)],
                _ => 0.0,
            }
        }
        FieldDesc::Analytic(Analytic::Gaussian {
            amplitude,
            mean,
            std,
        }) => {
            let d2: f64 = x.iter().zip(mean).map(|(a, b)| (a - b) * (a - b)).sum();
            amplitude * (-d2 / (2.0 * std * std)).exp()
        }
        FieldDesc::Analytic(Analytic::Shell { centre, r0, r1, s }) => {
            let r = x
                .iter()
                .zip(centre)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            if r >= *r0 && r <= *r1 {
                *s
            } else {
                0.0
            }
        }
        FieldDesc::HashMlp(h) => crate::volume::referee_hash::query(h, x).0,
        FieldDesc::Analytic(Analytic::Linear { a, g }) => {
            a + g[0] * x[0] + g[1] * x[1] + g[2] * x[2]
        }
        FieldDesc::Grid(g) => ref_grid(g, x, 0),
    }
}

/// Trilinear value of channel `c` (align_corners = True semantics).
fn ref_grid(g: &GridDesc, x: [f64; 3], c: usize) -> f64 {
    let [nz, ny, nx] = g.shape;
    let n = [nx, ny, nz];
    let mut lo = [0i64; 3];
    let mut w = [0.0; 3];
    for a in 0..3 {
        let mut u = (x[a] - g.bmin[a]) / (g.bmax[a] - g.bmin[a]) * (n[a] - 1) as f64;
        if g.oob == Oob::Clamp {
            u = u.clamp(0.0, (n[a] - 1) as f64);
        }
        let f = u.floor().min(if g.oob == Oob::Clamp {
            (n[a] - 2) as f64
        } else {
            f64::INFINITY
        });
        lo[a] = f as i64;
        w[a] = u - f;
    }
    let mut v = 0.0;
    for corner in 0..8 {
        let idx = [0, 1, 2].map(|a| lo[a] + (corner >> a & 1) as i64);
        if (0..3).any(|a| idx[a] < 0 || idx[a] >= n[a] as i64) {
            continue;
        }
        let wt: f64 = (0..3)
            .map(|a| {
                if corner >> a & 1 == 1 {
                    w[a]
                } else {
                    1.0 - w[a]
                }
            })
            .product();
        let flat = ((idx[2] as usize * ny + idx[1] as usize) * nx + idx[0] as usize) * g.ch + c;
        v += wt * g.data[flat];
    }
    v
}

fn ref_color(p: &VolumeParams, x: [f64; 3]) -> [f64; 3] {
    match (&p.color, &p.field) {
        (ColorDesc::Constant(v), _) => *v,
        (ColorDesc::Grid(g), _) => [0, 1, 2].map(|k| ref_grid(g, x, k)),
        (ColorDesc::Mlp, FieldDesc::HashMlp(h)) => crate::volume::referee_hash::query(h, x).1,
        // Refused by `check_pairing` when the scene is built.
        (ColorDesc::Mlp, _) => [f64::NAN; 3],
    }
}

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
    let (mut rgb, mut trans, mut logt, mut depth, mut opac, mut ns, mut hit) = (
        vec![[0.0; 3]; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0i32; n],
        vec![0u8; n],
    );
    for i in 0..n {
        let (o, d, t0, t1) = (rays.o[i], rays.d[i], rays.t0[i], rays.t1[i]);
        let (mut tr, mut lt, mut c, mut dep, mut taken) =
            (1.0f64, 0.0f64, [0.0f64; 3], 0.0f64, 0i32);
        if t1 > t0 {
            hit[i] = 1;
            let mut k: u32 = 0;
            while k < p.max_steps {
                let a = t0 + k as f64 * p.dt;
                if a >= t1 {
                    break;
                }
                if tr < p.early_stop {
                    break;
                }
                let b = (t0 + (k + 1) as f64 * p.dt).min(t1);
                let t = match p.sampling {
                    Sampling::Fixed => 0.5 * (a + b),
                    Sampling::Stratified { seed } => {
                        a + rand_f64(seed, rays.pixel[i], 0, k) * (b - a)
                    }
                };
                let x = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                let tau = ref_sigma(&p.field, x) * (b - a);
                let alpha = -(-tau).exp_m1();
                let col = ref_color(&p, x);
                for ch in 0..3 {
                    c[ch] += tr * alpha * col[ch];
                }
                dep += tr * alpha * t;
                lt -= tau;
                tr = match p.path {
                    TransPath::Product => tr * (1.0 - alpha),
                    TransPath::Log => lt.exp(),
                };
                taken += 1;
                k += 1;
            }
        }
        rgb[i] = [0, 1, 2].map(|ch| c[ch] + tr * p.background[ch]);
        (trans[i], logt[i], depth[i], opac[i], ns[i]) = (tr, lt, dep, 1.0 - tr, taken);
    }
    let s = [roi.height as usize, roi.width as usize];
    let mut out = Outputs::default();
    out.tensor("rgb", Tensor::real3(&s, &rgb)?);
    out.tensor("trans", Tensor::real(&s, trans)?);
    out.tensor("logtrans", Tensor::real(&s, logt)?);
    out.tensor("depth", Tensor::real(&s, depth)?);
    out.tensor("opacity", Tensor::real(&s, opac)?);
    out.tensor("nsamples", Tensor::from_shape_vec(&s, ns)?);
    out.tensor("hit", Tensor::from_shape_vec(&s, hit)?);
    Ok(out)
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
    ctx.cpu_only()?;
    let (pts, g) = probe_setup(ctx)?;
    let mut out = Outputs::default();
    let t = match ctx.precision {
        Precision::F32 => grid_probe_in::<f32>(&pts, &g)?,
        Precision::F64 => grid_probe_in::<f64>(&pts, &g)?,
    };
    out.tensor("value", t);
    Ok(out)
}

fn op_grid_probe_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (pts, g) = probe_setup(ctx)?;
    let v: Vec<f64> = pts.iter().map(|&x| ref_grid(&g, x, 0)).collect();
    let inside: Vec<u8> = pts
        .iter()
        .map(|x| (0..3).all(|a| x[a] >= g.bmin[a] && x[a] <= g.bmax[a]) as u8)
        .collect();
    let mut out = Outputs::default();
    out.tensor("value", Tensor::real(&[pts.len()], v)?);
    out.tensor("inside", Tensor::from_shape_vec(&[pts.len()], inside)?);
    Ok(out)
}

// ---------------------------------------------------------------------------
// Continuum closed forms.

/// Length of `[t0, t1]` inside the ball of radius `r` about `c` (|d| = 1).
fn ball_chord(o: [f64; 3], d: [f64; 3], c: [f64; 3], r: f64, t0: f64, t1: f64) -> f64 {
    let oc = [o[0] - c[0], o[1] - c[1], o[2] - c[2]];
    let b = oc[0] * d[0] + oc[1] * d[1] + oc[2] * d[2];
    let q = oc[0] * oc[0] + oc[1] * oc[1] + oc[2] * oc[2] - r * r;
    let disc = b * b - q;
    if disc <= 0.0 {
        return 0.0;
    }
    let h = disc.sqrt();
    ((-b + h).min(t1) - (-b - h).max(t0)).max(0.0)
}

/// Optical depth `int_{t0}^{t1} sigma(o + t d) dt` of an analytic field.
fn optical_depth(a: &Analytic, o: [f64; 3], d: [f64; 3], t0: f64, t1: f64) -> f64 {
    match a {
        Analytic::Constant { s } => s * (t1 - t0),
        Analytic::Slabs {
            axis,
            breaks,
            sigma,
        } => {
            let (ox, dx) = (o[*axis], d[*axis]);
            let mut tau = 0.0;
            for i in 0..sigma.len() {
                let (lo, hi) = if dx == 0.0 {
                    let inside = breaks[i] <= ox && ox < breaks[i + 1]
                        || (i + 1 == sigma.len() && ox == breaks[i + 1]);
                    if inside {
                        (t0, t1)
                    } else {
                        (0.0, 0.0)
                    }
                } else {
                    let (ta, tb) = ((breaks[i] - ox) / dx, (breaks[i + 1] - ox) / dx);
                    (ta.min(tb).max(t0), ta.max(tb).min(t1))
                };
                tau += sigma[i] * (hi - lo).max(0.0);
            }
            tau
        }
        Analytic::Gaussian {
            amplitude,
            mean,
            std,
        } => {
            let om = [o[0] - mean[0], o[1] - mean[1], o[2] - mean[2]];
            let tc = -(om[0] * d[0] + om[1] * d[1] + om[2] * d[2]);
            let p = [om[0] + tc * d[0], om[1] + tc * d[1], om[2] + tc * d[2]];
            let b2 = p[0] * p[0] + p[1] * p[1] + p[2] * p[2];
            let k = std * std::f64::consts::SQRT_2;
            amplitude
                * (-b2 / (2.0 * std * std)).exp()
                * std
                * (std::f64::consts::PI / 2.0).sqrt()
                * (erf((t1 - tc) / k) - erf((t0 - tc) / k))
        }
        Analytic::Shell { centre, r0, r1, s } => {
            s * (ball_chord(o, d, *centre, *r1, t0, t1) - ball_chord(o, d, *centre, *r0, t0, t1))
        }
        Analytic::Linear { a, g } => {
            let go = g[0] * o[0] + g[1] * o[1] + g[2] * o[2];
            let gd = g[0] * d[0] + g[1] * d[1] + g[2] * d[2];
            (a + go) * (t1 - t0) + gd * (t1 * t1 - t0 * t0) / 2.0
        }
    }
}

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
    let mut tau = Vec::with_capacity(rays.len());
    let mut hit = Vec::with_capacity(rays.len());
    for i in 0..rays.len() {
        let h = rays.t1[i] > rays.t0[i];
        tau.push(if h {
            optical_depth(&a, rays.o[i], rays.d[i], rays.t0[i], rays.t1[i])
        } else {
            0.0
        });
        hit.push(h as u8);
    }
    Ok((tau, hit))
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
    let trans: Vec<f64> = tau.iter().map(|t| (-t).exp()).collect();
    let rgb: Vec<[f64; 3]> = tau
        .iter()
        .map(|t| {
            let (tr, op) = ((-t).exp(), -(-t).exp_m1());
            [0, 1, 2].map(|k| c[k] * op + tr * p.background[k])
        })
        .collect();
    let mut out = Outputs::default();
    out.tensor(
        "logtrans",
        Tensor::real(&s, tau.iter().map(|t| -t).collect())?,
    );
    out.tensor(
        "opacity",
        Tensor::real(&s, tau.iter().map(|t| -(-t).exp_m1()).collect())?,
    );
    out.tensor("trans", Tensor::real(&s, trans)?);
    out.tensor("rgb", Tensor::real3(&s, &rgb)?);
    out.tensor("hit", Tensor::from_shape_vec(&s, hit)?);
    Ok(out)
}

// ---------------------------------------------------------------------------
// Performance.

/// CPU seconds (user + system) this process has used, from /proc/self/stat
/// (10 ms ticks); `None` where that file is missing. On a shared machine the
/// wall clock counts time other jobs held the cores; CPU time does not.
fn process_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks: f64 = f.get(11)?.parse::<f64>().ok()? + f.get(12)?.parse::<f64>().ok()?;
    Some(ticks / 100.0)
}

fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

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
    ctx.cpu_only()?;
    match ctx.precision {
        Precision::F32 => perf_in::<f32>(ctx),
        Precision::F64 => perf_in::<f64>(ctx),
    }
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
    ctx.cpu_only()?;
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
    out.tensor("plot_rgb", sweep_plot(&cols)?);
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

/// Speed against error as a 320 x 240 raster (no text, so no fonts): x =
/// log10 seconds, y = log10 max error, both spanning the data's decades
/// (grey lines at each decade); f32 points red, f64 blue, joined in dt
/// order. The judge writes it as `plot_rgb.png`.
fn sweep_plot(cols: &[Vec<f64>; 4]) -> Result<Tensor> {
    const W: usize = 320;
    const H: usize = 240;
    const PAD: f64 = 16.0;
    let mut img = vec![[1.0f64; 3]; W * H];
    let lg = |v: f64| v.max(1e-300).log10();
    let (xs, ys): (Vec<f64>, Vec<f64>) = (
        cols[0].iter().chain(&cols[2]).map(|&v| lg(v)).collect(),
        cols[1].iter().chain(&cols[3]).map(|&v| lg(v)).collect(),
    );
    let span = |v: &[f64]| {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min).floor();
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil();
        (lo, if hi > lo { hi } else { lo + 1.0 })
    };
    let ((x0, x1), (y0, y1)) = (span(&xs), span(&ys));
    let px = |x: f64| PAD + (x - x0) / (x1 - x0) * (W as f64 - 2.0 * PAD);
    let py = |y: f64| H as f64 - PAD - (y - y0) / (y1 - y0) * (H as f64 - 2.0 * PAD);
    let mut put = |x: f64, y: f64, c: [f64; 3]| {
        let (i, j) = (x.round() as i64, y.round() as i64);
        if i >= 0 && j >= 0 && (i as usize) < W && (j as usize) < H {
            img[j as usize * W + i as usize] = c;
        }
    };
    let grey = [0.6; 3];
    for d in (x0 as i64)..=(x1 as i64) {
        for j in 0..H {
            put(px(d as f64), j as f64, grey);
        }
    }
    for d in (y0 as i64)..=(y1 as i64) {
        for i in 0..W {
            put(i as f64, py(d as f64), grey);
        }
    }
    for (t, e, c) in [
        (&cols[0], &cols[1], [0.8, 0.05, 0.05]),
        (&cols[2], &cols[3], [0.05, 0.1, 0.8]),
    ] {
        let pts: Vec<(f64, f64)> = t
            .iter()
            .zip(e.iter())
            .map(|(&a, &b)| (px(lg(a)), py(lg(b))))
            .collect();
        for w in pts.windows(2) {
            for k in 0..=200 {
                let f = k as f64 / 200.0;
                put(
                    w[0].0 + f * (w[1].0 - w[0].0),
                    w[0].1 + f * (w[1].1 - w[0].1),
                    c,
                );
            }
        }
        for &(x, y) in &pts {
            for dy in -3..=3 {
                for dx in -3..=3 {
                    put(x + dx as f64, y + dy as f64, c);
                }
            }
        }
    }
    Tensor::real3(&[H, W], &img)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn gaussian_closed_form_matches_a_fine_midpoint_sum() {
        let a = Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.1, 0.0, 0.0],
            std: 0.3,
        };
        let (o, d) = ([0.05, 0.2, 3.0], [0.0, 0.0, -1.0]);
        let n = 200_000;
        let h = 2.0 / n as f64;
        let sum: f64 = (0..n)
            .map(|k| {
                ref_sigma(
                    &FieldDesc::Analytic(a.clone()),
                    [0.05, 0.2, 1.0 - (k as f64 + 0.5) * h],
                ) * h
            })
            .sum();
        assert!((optical_depth(&a, o, d, 2.0, 4.0) - sum).abs() < 1e-8);
    }

    #[test]
    fn shell_chord_of_a_central_ray_is_twice_the_thickness() {
        let a = Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        };
        let tau = optical_depth(&a, [0.0, 0.0, 3.0], [0.0, 0.0, -1.0], 2.0, 4.0);
        assert!((tau - 30.0 * 0.2).abs() < 1e-12);
    }

    #[test]
    fn slab_reference_uses_half_open_membership() {
        let f = FieldDesc::Analytic(Analytic::Slabs {
            axis: 0,
            breaks: vec![-1.0, -0.2, 0.3, 1.0],
            sigma: vec![0.5, 8.0, 1.0],
        });
        assert_eq!(ref_sigma(&f, [-0.2, 0.0, 0.0]), 8.0);
        assert_eq!(ref_sigma(&f, [1.0, 0.0, 0.0]), 1.0);
        assert_eq!(ref_sigma(&f, [-1.0, 0.0, 0.0]), 0.5);
        assert_eq!(ref_sigma(&f, [1.5, 0.0, 0.0]), 0.0);
    }
}
