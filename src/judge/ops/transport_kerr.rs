//! Operations of the curved-spacetime images and Kerr lists (thin wiring:
//! scene -> `transport::image` / `transport::kerr_trace` / the closed forms
//! of `transport::referee_kerr` -> named tensors).
//!
//! | op | what |
//! | --- | --- |
//! | `transport.render` (Kerr deflection lists, `kerr_image`, `ellis_image`) | see `transport::outputs::run_curved` |
//! | `transport.kerr_closed_form` | per pixel Bardeen's verdict `shadow_class` (0 escapes, 1 captured, 2 the curve crosses the pixel), `shadow_decided`, `shadow_captured`; scalars `horizon`, `ergosphere_equator`, `photon_pro`, `photon_retro`, `isco`, `isco_retro` |
//! | `transport.image_mirror` | the rendered `image` flipped left-right (`image_lr`) and top-bottom (`image_ud`) |
//! | `transport.research_diff` | renders an image with the scene's integrator and with the research preset `validate`; per-pixel `dir_diff` (angle between final directions, rad), `captured_diff`, `disk_r_diff`, and their maxima as metrics |

use std::time::Instant;

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::real::Real;
use crate::scene::transport::{parse, ResearchPreset, ResearchSpec, TaskSpec, TransportScene};
use crate::tensor::{Outputs, Tensor};
use crate::transport::image::{render as render_image, ImageOut, ImageTask, Observer, Pixels};
use crate::transport::outputs::t1;
use crate::transport::referee_kerr as rk;
use crate::transport::tasks::{Curved, Task};

pub const OPS: &[OpEntry] = &[
    OpEntry { name: "transport.kerr_closed_form", doc: "Bardeen's shadow per pixel (0/1, 2 = curve crosses the pixel), horizon, ergosphere, photon orbits, ISCO", params: &[], support: Support::Any, run: closed_form },
    OpEntry { name: "transport.image_mirror", doc: "the rendered image flipped left-right (image_lr) and top-bottom (image_ud)", params: &[], support: Support::Cpu, run: mirror },
    OpEntry { name: "transport.research_diff", doc: "per-pixel difference between the scene's integrator and the validate preset", params: &[], support: Support::Cpu, run: research_diff },
];

fn curved_image(s: &TransportScene) -> Result<ImageTask> {
    match s.build::<f64>()?.0 {
        Task::Curved(Curved::Image(t)) => Ok(t),
        _ => Err(Error::invalid(
            "task",
            "this operation needs a kerr_image or ellis_image scene",
        )),
    }
}

fn closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let s = parse(ctx.scene()?)?;
    let TaskSpec::KerrImage(spec) = &s.task else {
        return Err(Error::invalid(
            "task",
            "transport.kerr_closed_form needs a kerr_image scene",
        ));
    };
    let k = spec.build()?;
    let (m, a) = (k.kerr.mass, k.kerr.a.abs());
    let mut out = Outputs::default();
    let (rp, _) = rk::horizons(m, a);
    let (pp, pr) = rk::photon_orbits(m, a);
    let (ip, ir) = rk::isco(m, a);
    out.tensor("horizon", t1(rp))
        .tensor(
            "ergosphere_equator",
            t1(rk::ergosphere(m, a, std::f64::consts::FRAC_PI_2)),
        )
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
                (0..width * height)
                    .map(|i| c[(i / width) * width + (width - 1 - i % width)])
                    .collect()
            } else {
                c
            };
            (c, vec![*height, *width])
        }
        Pixels::List(l) => {
            let poly = rk::critical_curve(m, a, obs.theta_o, 1 << 18);
            (
                l.iter()
                    .map(|p| rk::inside(&poly, flip * p[0], p[1]) as u8)
                    .collect(),
                vec![l.len()],
            )
        }
    };
    out.tensor(
        "shadow_decided",
        Tensor::from_shape_vec(&shape, classes.iter().map(|&c| (c != 2) as u8).collect())?,
    );
    out.tensor(
        "shadow_captured",
        Tensor::from_shape_vec(&shape, classes.iter().map(|&c| (c == 1) as u8).collect())?,
    );
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
    let lr: Vec<F> = (0..h * w * 3)
        .map(|i| at(i / 3 / w, w - 1 - (i / 3) % w, i % 3))
        .collect();
    let ud: Vec<F> = (0..h * w * 3)
        .map(|i| at(h - 1 - i / 3 / w, (i / 3) % w, i % 3))
        .collect();
    let mut out = Outputs::default();
    out.tensor("image", Tensor::real(&[h, w, 3], img)?);
    out.tensor("image_lr", Tensor::real(&[h, w, 3], lr)?);
    out.tensor("image_ud", Tensor::real(&[h, w, 3], ud)?);
    Ok(out)
}

fn mirror(ctx: &OpCtx) -> Result<Outputs> {
    let s = parse(ctx.scene()?)?;
    by_precision!(ctx, mirror_in(ctx, &s))
}

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
    let cap: Vec<u8> = a
        .captured
        .iter()
        .zip(&b.captured)
        .map(|(x, y)| (x != y) as u8)
        .collect();
    let mut out = Outputs::default();
    out.metric("max_dir_diff", dir.iter().fold(0.0, |m: f64, v| m.max(*v)));
    out.metric("captured_diff_count", cap.iter().map(|&c| c as f64).sum());
    out.metric("time_s", t1s);
    if !a.disk_r.is_empty() {
        let d: Vec<f64> = a
            .disk_r
            .iter()
            .zip(&b.disk_r)
            .map(|(x, y)| (x.f64() - y.f64()).abs())
            .collect();
        out.tensor("disk_r_diff", Tensor::from_shape_vec(&sh, d)?);
    }
    out.tensor("dir_diff", Tensor::from_shape_vec(&sh, dir)?);
    out.tensor("captured_diff", Tensor::from_shape_vec(&sh, cap)?);
    Ok(out)
}

fn research_diff(ctx: &OpCtx) -> Result<Outputs> {
    let s = parse(ctx.scene()?)?;
    by_precision!(ctx, research_in(ctx, &s))
}
