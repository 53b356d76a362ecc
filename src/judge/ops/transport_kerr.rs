//! Operations of the curved-spacetime images and Kerr lists (thin wiring:
//! scene -> `transport::image` / `transport::kerr_trace` / the closed forms
//! of `transport::referee_kerr` -> named tensors).
//!
//! | op | what |
//! | --- | --- |
//! | `transport.render` (Kerr deflection lists, `kerr_image`, `ellis_image`) | see [`run_curved`] |
//! | `transport.kerr_closed_form` | per pixel Bardeen's verdict `shadow_class` (0 escapes, 1 captured, 2 the curve crosses the pixel), `shadow_decided`, `shadow_captured`; scalars `horizon`, `ergosphere_equator`, `photon_pro`, `photon_retro`, `isco`, `isco_retro` |
//! | `transport.image_mirror` | the rendered `image` flipped left-right (`image_lr`) and top-bottom (`image_ud`) |
//! | `transport.research_diff` | renders an image with the scene's integrator and with the research preset `validate`; per-pixel `dir_diff` (angle between final directions, rad), `captured_diff`, `disk_r_diff`, and their maxima as metrics |

use std::time::Instant;

use super::{OpCtx, OpEntry};
use crate::error::{Error, Result};
use crate::real::{Precision, Real};
use crate::scene::transport::{parse, ResearchPreset, ResearchSpec, TaskSpec, TransportScene};
use crate::tensor::{Outputs, Tensor};
use crate::transport::image::{render as render_image, ImageOut, ImageTask, Observer, Pixels};
use crate::transport::integrate::Options;
use crate::transport::kerr_trace::kerr_deflection;
use crate::transport::referee_kerr as rk;
use crate::transport::tasks::{Curved, Task};

pub const OPS: &[OpEntry] = &[
    OpEntry { name: "transport.kerr_closed_form", doc: "Bardeen's shadow per pixel (0/1, 2 = curve crosses the pixel), horizon, ergosphere, photon orbits, ISCO", params: &[], run: closed_form },
    OpEntry { name: "transport.image_mirror", doc: "the rendered image flipped left-right (image_lr) and top-bottom (image_ud)", params: &[], run: mirror },
    OpEntry { name: "transport.research_diff", doc: "per-pixel difference between the scene's integrator and the validate preset", params: &[], run: research_diff },
];

fn t1(v: f64) -> Tensor {
    Tensor::from_shape_vec(&[1], vec![v]).unwrap_or_else(|_| Tensor::scalar(v))
}

fn image_tensors<F: Real>(r: ImageOut<F>, out: &mut Outputs) -> Result<(usize, Vec<i32>, Vec<Vec<f64>>)> {
    let sh = r.shape.clone();
    let n: usize = sh.iter().product();
    let mut sh3 = sh.clone();
    sh3.push(3);
    let q = r.captured.iter().map(|&c| vec![c as f64]).collect();
    let max = |v: &[F]| v.iter().fold(0.0f64, |m, x| m.max(x.f64()));
    out.metric("max_h_drift", max(&r.h_drift));
    if !r.q_drift.is_empty() {
        out.metric("max_e_drift", max(&r.e_drift))
            .metric("max_l_drift", max(&r.l_drift))
            .metric("max_q_drift", max(&r.q_drift));
        out.tensor("e_drift", Tensor::real(&sh, r.e_drift)?);
        out.tensor("l_drift", Tensor::real(&sh, r.l_drift)?);
        out.tensor("q_drift", Tensor::real(&sh, r.q_drift)?);
    }
    out.tensor("escaped", Tensor::from_shape_vec(&sh, r.reason.iter().map(|&c| (c == 0) as u8).collect())?);
    out.tensor("captured", Tensor::from_shape_vec(&sh, r.captured)?);
    out.tensor("final_dir", Tensor::real(&sh3, r.final_dir.into_iter().flatten().collect())?);
    out.tensor("h_drift", Tensor::real(&sh, r.h_drift)?);
    out.tensor("err_est", Tensor::real(&sh, r.err_est)?);
    out.tensor("reason", Tensor::from_shape_vec(&sh, r.reason)?);
    if sh.len() == 2 {
        out.tensor("image", Tensor::real(&sh3, r.image.into_iter().flatten().collect())?);
    }
    if let Some(ri) = r.disk_r_in {
        let inner = r.disk_r.iter().filter(|v| v.f64() > 0.0).fold(f64::INFINITY, |m, v| m.min(v.f64()));
        out.tensor("disk_inner_r", t1(if inner.is_finite() { inner } else { -1.0 }));
        out.tensor("disk_r_in", t1(ri));
        out.tensor("disk_hit", Tensor::from_shape_vec(&sh, r.disk_r.iter().map(|v| (v.f64() > 0.0) as u8).collect())?);
        out.tensor("disk_r", Tensor::real(&sh, r.disk_r)?);
        out.tensor("redshift", Tensor::real(&sh, r.redshift)?);
    }
    if !r.side.is_empty() {
        out.tensor("side", Tensor::from_shape_vec(&sh, r.side)?);
    }
    Ok((n, r.steps, q))
}

/// `transport.render` for [`Curved`] tasks. Deflection lists: `deflection`,
/// `captured`, `escaped`, `h_drift`, `err_est`, `reason`, `e_drift`,
/// `l_drift`, `q_drift`. Images: the per-pixel tensors of
/// `transport::image` (shape (H, W) or (n) for ray lists), `image` (H, W, 3,
/// also as PNG), disk images `disk_r`, `disk_hit`, `redshift`,
/// `disk_inner_r` (smallest disk radius hit, -1 if none) and `disk_r_in`
/// (the ISCO the renderer used); metrics `max_h_drift`, `max_e_drift`,
/// `max_l_drift`, `max_q_drift`. Returns rays, steps and per-ray values.
pub fn run_curved<F: Real>(
    c: &Curved,
    opt: &Options<F>,
    ctx: &OpCtx,
    out: &mut Outputs,
) -> Result<(usize, Vec<i32>, Vec<Vec<f64>>)> {
    match c {
        Curved::KerrDeflection(d) => {
            let r = kerr_deflection(d, opt)?;
            let n = r.deflection.len();
            let q = r.deflection.iter().map(|v| vec![v.f64()]).collect();
            let col = |i: usize| Tensor::real(&[n], r.drift.iter().map(|d| d[i]).collect());
            out.tensor("e_drift", col(0)?).tensor("l_drift", col(1)?).tensor("q_drift", col(2)?);
            out.tensor("deflection", Tensor::real(&[n], r.deflection)?);
            out.tensor("escaped", Tensor::from_shape_vec(&[n], r.captured.iter().map(|c| 1 - c).collect())?);
            out.tensor("captured", Tensor::from_shape_vec(&[n], r.captured)?);
            out.tensor("h_drift", Tensor::real(&[n], r.h_drift)?);
            out.tensor("err_est", Tensor::real(&[n], r.err_est)?);
            out.tensor("reason", Tensor::from_shape_vec(&[n], r.reason)?);
            Ok((n, r.steps, q))
        }
        Curved::Image(t) => image_tensors(render_image(t, opt, &ctx.budget)?, out),
    }
}

fn curved_image(s: &TransportScene) -> Result<ImageTask> {
    match s.build::<f64>()?.0 {
        Task::Curved(Curved::Image(t)) => Ok(t),
        _ => Err(Error::invalid("task", "this operation needs a kerr_image or ellis_image scene")),
    }
}

fn closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let s = parse(ctx.scene()?)?;
    let TaskSpec::KerrImage(spec) = &s.task else {
        return Err(Error::invalid("task", "transport.kerr_closed_form needs a kerr_image scene"));
    };
    let k = spec.build()?;
    let (m, a) = (k.kerr.mass, k.kerr.a.abs());
    let mut out = Outputs::default();
    let (rp, _) = rk::horizons(m, a);
    let (pp, pr) = rk::photon_orbits(m, a);
    let (ip, ir) = rk::isco(m, a);
    out.tensor("horizon", t1(rp))
        .tensor("ergosphere_equator", t1(rk::ergosphere(m, a, std::f64::consts::FRAC_PI_2)))
        .tensor("photon_pro", t1(pp))
        .tensor("photon_retro", t1(pr))
        .tensor("isco", t1(ip))
        .tensor("isco_retro", t1(ir));
    let Observer::Distant { obs, half } = k.observer else {
        return Ok(out);
    };
    // Bardeen's curve is drawn for the spin's sign: a < 0 mirrors alpha.
    let flip = if k.kerr.a < 0.0 { -1.0 } else { 1.0 };
    let (classes, shape) = match &k.pixels {
        Pixels::Grid { width, height } => {
            let c = rk::shadow_classes(m, a, obs.theta_o, *width, *height, half, half);
            let c = if flip < 0.0 {
                (0..width * height).map(|i| c[(i / width) * width + (width - 1 - i % width)]).collect()
            } else {
                c
            };
            (c, vec![*height, *width])
        }
        Pixels::List(l) => {
            let poly = rk::critical_curve(m, a, obs.theta_o, 1 << 18);
            (l.iter().map(|p| rk::inside(&poly, flip * p[0], p[1]) as u8).collect(), vec![l.len()])
        }
    };
    out.tensor("shadow_decided", Tensor::from_shape_vec(&shape, classes.iter().map(|&c| (c != 2) as u8).collect())?);
    out.tensor("shadow_captured", Tensor::from_shape_vec(&shape, classes.iter().map(|&c| (c == 1) as u8).collect())?);
    out.tensor("shadow_class", Tensor::from_shape_vec(&shape, classes)?);
    Ok(out)
}

fn rendered<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<ImageOut<F>> {
    let t = curved_image(s)?;
    let (_, opt) = s.build::<F>()?;
    render_image(&t, &opt, &ctx.budget)
}

fn mirror_in<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<Outputs> {
    let r = rendered::<F>(ctx, s)?;
    let [h, w] = r.shape[..] else {
        return Err(Error::invalid("task", "image_mirror needs a pixel grid"));
    };
    let img: Vec<F> = r.image.iter().flatten().copied().collect();
    let at = |v: usize, u: usize, c: usize| img[(v * w + u) * 3 + c];
    let lr: Vec<F> = (0..h * w * 3).map(|i| at(i / 3 / w, w - 1 - (i / 3) % w, i % 3)).collect();
    let ud: Vec<F> = (0..h * w * 3).map(|i| at(h - 1 - i / 3 / w, (i / 3) % w, i % 3)).collect();
    let mut out = Outputs::default();
    out.tensor("image", Tensor::real(&[h, w, 3], img)?);
    out.tensor("image_lr", Tensor::real(&[h, w, 3], lr)?);
    out.tensor("image_ud", Tensor::real(&[h, w, 3], ud)?);
    Ok(out)
}

fn mirror(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = parse(ctx.scene()?)?;
    match ctx.precision {
        Precision::F32 => mirror_in::<f32>(ctx, &s),
        Precision::F64 => mirror_in::<f64>(ctx, &s),
    }
}

fn research_in<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<Outputs> {
    let plain = TransportScene { research: None, ..s.clone() };
    let valid = TransportScene { research: Some(ResearchSpec { preset: ResearchPreset::Validate }), ..s.clone() };
    let t0 = Instant::now();
    let a = rendered::<F>(ctx, &plain)?;
    let t1s = t0.elapsed().as_secs_f64();
    let b = rendered::<F>(ctx, &valid)?;
    let sh = a.shape.clone();
    let dir: Vec<f64> = a
        .final_dir
        .iter()
        .zip(&b.final_dir)
        .map(|(p, q)| {
            let d: f64 = (0..3).map(|i| p[i].f64() * q[i].f64()).sum();
            let np: f64 = (0..3).map(|i| p[i].f64().powi(2)).sum();
            let nq: f64 = (0..3).map(|i| q[i].f64().powi(2)).sum();
            if np > 0.0 && nq > 0.0 {
                d.clamp(-1.0, 1.0).acos()
            } else {
                0.0
            }
        })
        .collect();
    let cap: Vec<u8> = a.captured.iter().zip(&b.captured).map(|(x, y)| (x != y) as u8).collect();
    let mut out = Outputs::default();
    out.metric("max_dir_diff", dir.iter().fold(0.0, |m: f64, v| m.max(*v)));
    out.metric("captured_diff_count", cap.iter().map(|&c| c as f64).sum());
    out.metric("time_s", t1s);
    if !a.disk_r.is_empty() {
        let d: Vec<f64> = a.disk_r.iter().zip(&b.disk_r).map(|(x, y)| (x.f64() - y.f64()).abs()).collect();
        out.tensor("disk_r_diff", Tensor::from_shape_vec(&sh, d)?);
    }
    out.tensor("dir_diff", Tensor::from_shape_vec(&sh, dir)?);
    out.tensor("captured_diff", Tensor::from_shape_vec(&sh, cap)?);
    Ok(out)
}

fn research_diff(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = parse(ctx.scene()?)?;
    match ctx.precision {
        Precision::F32 => research_in::<f32>(ctx, &s),
        Precision::F64 => research_in::<f64>(ctx, &s),
    }
}
