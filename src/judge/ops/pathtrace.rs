//! Operations of the `pathtrace` renderer: wiring from case parameters to
//! the renderer, its harnesses (`pathtrace::checks`), its referees
//! (`pathtrace::referee`) and the shared statistics (`crate::stats`).
//!
//! | op | what |
//! | --- | --- |
//! | `pathtrace.render` | `image` (H, W, 3 linear f32), `variance` (of the pixel mean); metrics `time_s`, `paths_per_s` |
//! | `pathtrace.intersect_list` | the renderer's intersection of `params.rays` with `params.shapes`: `t`, `hit`, `normal` |
//! | `pathtrace.intersect_reference` | the same by f64 closed forms written apart (geometric sphere, Cramer quad) |
//! | `pathtrace.self_intersection` | fraction of rays spawned at the scene's hit points that re-hit their own surface at once |
//! | `pathtrace.bsdf_checks` | per material and `wo`: pdf integral, albedo, reciprocity error, chi-square p-values |
//! | `pathtrace.furnace` | render + image mean and its z-score against the environment radiance |
//! | `pathtrace.convergence` | RMSE vs a high-spp render of the same scene over spp and seeds; log-log slope |
//! | `pathtrace.fireflies` | render + fraction of pixels above 10x their 3x3 median luminance |
//! | `pathtrace.features` | render + mean radiance of world-space regions: penumbra, bleeding, caustic |
//! | `pathtrace.rmse_vs_reference` | render + clamped and raw RMSE against a saved independent reference (Mitsuba 3) |
//! | `pathtrace.speed_error` | seconds and RMSE against a reference render over an spp sweep |

use std::collections::BTreeMap;
use std::time::Instant;

use glam::Vec3A;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::judge::plot::{self, Chart, Series};
use crate::pathtrace::checks::{bsdf_checks, region_sum, self_intersection, Region};
use crate::pathtrace::integrator::first_hits;
use crate::pathtrace::listed::{unit, HitList, ShapeParam};
use crate::pathtrace::referee::geometry::intersect_reference;
use crate::pathtrace::{render, Image, Quad, RenderParams, Shape, Sphere};
use crate::scene::pathtrace::PathtraceScene;
use crate::stats::image::{firefly_fraction, image_mean, mean_variance, mse};
use crate::stats::summary::loglog_slope;
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "pathtrace.render",
        doc: "path-traced image (H, W, 3) and variance of the pixel mean; metrics time_s, paths_per_s",
        params: &[],
        support: Support::CpuGpuF32,
        run: render_op,
    },
    OpEntry {
        name: "pathtrace.intersect_list",
        doc: "renderer intersection of params.rays ([ox,oy,oz,dx,dy,dz]) with params.shapes: t, hit, index, normal",
        params: &["rays", "shapes"],
        support: Support::Cpu,
        run: intersect_list,
    },
    OpEntry {
        name: "pathtrace.intersect_reference",
        doc: "f64 closed forms (geometric sphere, Cramer quad) for the rays and shapes of intersect_list",
        params: &["rays", "shapes"],
        support: Support::Any,
        run: intersect_reference_op,
    },
    OpEntry {
        name: "pathtrace.self_intersection",
        doc: "acne_fraction: rays spawned at camera hit points that re-hit their own surface at once",
        params: &["rays"],
        support: Support::Cpu,
        run: self_intersection_op,
    },
    OpEntry {
        name: "pathtrace.bsdf_checks",
        doc: "pdf_integral, albedo, reciprocity_err, weight_err, fresnel_err, chi2_p and chi2_alpha (Sidak) per material and wo",
        params: &["thetas", "samples", "alpha", "roughness"],
        support: Support::Cpu,
        run: bsdf_checks_op,
    },
    OpEntry {
        name: "pathtrace.furnace",
        doc: "render + mean (3,), z-score of the mean against params.expect, max pixel_err",
        params: &["expect"],
        support: Support::CpuGpuF32,
        run: furnace,
    },
    OpEntry {
        name: "pathtrace.convergence",
        doc: "rmse (clamped to [0,1]) vs a ref_spp render over params.spp x params.seeds; log-log slope",
        params: &["spp", "seeds", "ref_spp", "clamp"],
        support: Support::Cpu,
        run: convergence,
    },
    OpEntry {
        name: "pathtrace.fireflies",
        doc: "render + firefly_fraction: pixels whose luminance exceeds 10x their 3x3 median",
        params: &["factor"],
        support: Support::Cpu,
        run: fireflies,
    },
    OpEntry {
        name: "pathtrace.features",
        doc: "render + mean rgb/luminance/(r/g) of named world-space regions of named shapes (params.regions)",
        params: &["regions"],
        support: Support::Cpu,
        run: features,
    },
    OpEntry {
        name: "pathtrace.rmse_vs_reference",
        doc: "render + rmse (clamped [0,1]) and rmse_raw against params.reference (an (H, W, 3) float32 .npy)",
        params: &["reference"],
        support: Support::CpuGpuF32,
        run: rmse_vs_reference,
    },
    OpEntry {
        name: "pathtrace.speed_error",
        doc: "seconds and rmse (clamped [0,1] and raw) vs a ref_spp render (or params.reference .npy) per params.spp; plot_image",
        params: &["spp", "ref_spp", "ref_seed", "reference"],
        support: Support::CpuGpuF32,
        run: speed_error,
    },
];

pub(super) fn load(ctx: &OpCtx) -> Result<PathtraceScene> {
    crate::scene::pathtrace::parse(ctx.scene()?)
}

fn timed_render(s: &PathtraceScene, p: &RenderParams, ctx: &OpCtx) -> Result<(Image, f64)> {
    if ctx.backend == BackendKind::Gpu {
        return super::pathtrace_gpu::timed_render_gpu(s, p, ctx);
    }
    let cam = s.camera.to_real::<f32>(p.width, p.height);
    let t = Instant::now();
    let img = render(&s.scene, &cam, p, &ctx.budget)?;
    Ok((img, t.elapsed().as_secs_f64()))
}

fn image_outputs(img: &Image, secs: f64, p: &RenderParams, out: &mut Outputs) -> Result<()> {
    let shape = [img.height as usize, img.width as usize];
    out.tensor("image", Tensor::real3(&shape, &img.rgb)?);
    out.tensor("variance", Tensor::real3(&shape, &img.variance)?);
    let paths = img.rgb.len() as f64 * p.spp as f64;
    out.metric("time_s", secs)
        .metric("paths_per_s", paths / secs.max(1e-9));
    out.counter("paths", paths as u64)
        .counter("nonfinite_samples", img.nonfinite);
    Ok(())
}

fn render_op(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    Ok(out)
}

/// Renders `s` with `spp` samples and `seed` (other parameters from the scene).
fn render_with(s: &PathtraceScene, spp: u32, seed: u32, ctx: &OpCtx) -> Result<(Image, f64)> {
    let p = RenderParams {
        spp,
        seed,
        ..s.params
    };
    timed_render(s, &p, ctx)
}

fn listed(ctx: &OpCtx) -> Result<(Vec<[f64; 6]>, Vec<ShapeParam>)> {
    let rays: Vec<[f64; 6]> = ctx.param_req("rays")?;
    let shapes: Vec<ShapeParam> = ctx.param_req("shapes")?;
    for (i, r) in rays.iter().enumerate() {
        if r.iter().any(|x| !x.is_finite()) || r[3..].iter().all(|&x| x == 0.0) {
            return Err(Error::invalid(
                format!("{} params.rays[{i}]", ctx.case_id),
                "needs finite numbers and d != 0",
            ));
        }
    }
    Ok((rays, shapes))
}

/// The renderer's intersection as rendering runs it (`packed`, f32). Misses: t = -1, index = -1,
/// normal = 0.
fn intersect_list(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, params) = listed(ctx)?;
    let v = |a: [f64; 3]| Vec3A::new(a[0] as f32, a[1] as f32, a[2] as f32);
    let mut shapes = Vec::with_capacity(params.len());
    for (i, sp) in params.iter().enumerate() {
        shapes.push(match *sp {
            ShapeParam::Sphere { center, radius } => Shape::Sphere(Sphere {
                centre: v(center),
                radius: radius as f32,
            }),
            ShapeParam::Quad { corner, u, v: e } => {
                Shape::Quad(Quad::new(v(corner), v(u), v(e)).ok_or_else(|| {
                    Error::invalid(
                        format!("{} params.shapes[{i}]", ctx.case_id),
                        "degenerate quad",
                    )
                })?)
            }
        });
    }
    let packed = crate::pathtrace::packed::Packed::new(&shapes);
    let mut hits = HitList::default();
    for r in &rays {
        let (o, d) = unit(r);
        let (o, d) = (v(o), v(d).normalize());
        hits.push(packed.intersect(o, d, f32::INFINITY).map(|(th, k)| {
            let (_, n) = shapes[k].surface(o, d, th);
            (th as f64, k, n.to_array().map(|x| x as f64))
        }));
    }
    hits.to_outputs(true)
}

fn intersect_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, shapes) = listed(ctx)?;
    intersect_reference(&rays, &shapes).to_outputs(false)
}

/// Acne fraction of `params.rays` camera rays: see [`self_intersection`].
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

/// BSDF checks at `params.thetas` (degrees): see [`bsdf_checks`].
fn bsdf_checks_op(ctx: &OpCtx) -> Result<Outputs> {
    let thetas: Vec<f64> = ctx.param_or("thetas", vec![0.0, 30.0, 60.0, 85.0])?;
    let n: u32 = ctx.param_or("samples", 500_000)?;
    let alpha: f64 = ctx.param_or("alpha", 0.01)?;
    let rough: f32 = ctx.param_or("roughness", 0.1)?;
    if thetas.iter().any(|t| !(0.0..90.0).contains(t)) || n == 0 {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "thetas must lie in [0, 90) degrees and samples >= 1",
        ));
    }
    bsdf_checks(&thetas, n, alpha, rough, ctx.seed).to_outputs(n)
}

// ---------------------------------------------------------------- images

fn furnace(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let expect: [f64; 3] = ctx.param_req("expect")?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let (mean, se) = image_mean(&img.rgb, &img.variance);
    let z: Vec<f64> = (0..3)
        .map(|c| (mean[c] - expect[c]) / se[c].max(1e-7))
        .collect();
    let err = img
        .rgb
        .iter()
        .flat_map(|p| (0..3).map(move |c| (p[c] as f64 - expect[c]).abs()))
        .fold(0.0, f64::max);
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor("mean", Tensor::real(&[3], mean.to_vec())?);
    out.tensor("z", Tensor::real(&[3], z)?);
    out.tensor("pixel_err", Tensor::scalar(err));
    Ok(out)
}

/// RMSE against a `ref_spp` render (seed `2^31`, independent of the test
/// seeds) at each spp, MSE averaged over `seeds` (correlated samples across
/// spp or seeds would bend the slope away from -0.5). With `clamp: false`
/// the reference's own noise is subtracted from each MSE.
fn convergence(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let seeds: Vec<u32> = ctx.param_or("seeds", vec![1, 2, 3, 4])?;
    let ref_spp: u32 = ctx.param_or("ref_spp", 4096)?;
    let clamp: bool = ctx.param_or("clamp", true)?;
    if spps.len() < 2 || seeds.is_empty() || spps.contains(&0) {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "need >= 2 spp values (all >= 1) and >= 1 seed",
        ));
    }
    let t = Instant::now();
    let (reference, _) = render_with(&s, ref_spp, 1 << 31, ctx)?;
    let noise = if clamp {
        0.0
    } else {
        mean_variance(&reference.variance)
    };
    let mut rmse = Vec::with_capacity(spps.len());
    for &spp in &spps {
        let mut acc = 0.0;
        for &seed in &seeds {
            let (img, _) = render_with(&s, spp, seed, ctx)?;
            acc += (mse(&img.rgb, &reference.rgb, clamp) - noise).max(0.0);
        }
        rmse.push((acc / seeds.len() as f64).sqrt());
    }
    let x: Vec<f64> = spps.iter().map(|&v| v as f64).collect();
    let slope = loglog_slope(&x, &rmse);
    let mut out = Outputs::default();
    out.tensor("spp", Tensor::real(&[x.len()], x)?);
    out.tensor("rmse", Tensor::real(&[rmse.len()], rmse)?);
    out.tensor("slope", Tensor::scalar(slope));
    out.metric("time_s", t.elapsed().as_secs_f64());
    Ok(out)
}

fn fireflies(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let factor: f32 = ctx.param_or("factor", 10.0)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor(
        "firefly_fraction",
        Tensor::scalar(firefly_fraction(&img.rgb, img.width, img.height, factor)),
    );
    Ok(out)
}

/// Per region: `<name>` mean rgb (3,), `<name>_lum` its luminance,
/// `<name>_r_over_g` red over green; counter `<name>_pixels`.
fn features(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let regions: BTreeMap<String, Region> = ctx.param_req("regions")?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let cam = s.camera.to_real::<f32>(s.params.width, s.params.height);
    let hits = first_hits(&s.scene, &cam, s.params.width, s.params.height);
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    for (name, r) in &regions {
        let at = format!("{} params.regions.{name}", ctx.case_id);
        let k = s
            .names
            .iter()
            .position(|n| *n == r.shape)
            .ok_or_else(|| Error::invalid(&at, format!("no shape named {:?}", r.shape)))?;
        let (sum, count) = region_sum(&img.rgb, &hits, k, r);
        if count == 0 {
            return Err(Error::invalid(
                at,
                "the region covers no pixel at this image size",
            ));
        }
        let m = sum.map(|x| x / count as f64);
        out.tensor(name, Tensor::real(&[3], m.to_vec())?);
        out.tensor(
            &format!("{name}_lum"),
            Tensor::scalar(0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2]),
        );
        out.tensor(
            &format!("{name}_r_over_g"),
            Tensor::scalar(m[0] / m[1].max(1e-12)),
        );
        out.counter(&format!("{name}_pixels"), count);
    }
    Ok(out)
}

/// Reads an (H, W, 3) float32 `.npy` reference image of the scene's size.
fn read_reference(ctx: &OpCtx, file: &str, w: usize, h: usize) -> Result<Image> {
    let path = ctx.resolve(file);
    let t = Tensor::read_npy_checked(&path, &["float32"], &[Some(h), Some(w), Some(3)])?;
    let v = t.to_f64_vec();
    if v.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid(
            path.display().to_string(),
            "reference has NaN or Inf",
        ));
    }
    let rgb = v
        .chunks_exact(3)
        .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
        .collect();
    Ok(Image {
        width: w as u32,
        height: h as u32,
        rgb,
        variance: vec![[0.0; 3]; w * h],
        nonfinite: 0,
    })
}

/// The acceptance measure: RMSE of linear radiance clamped to [0, 1]
/// against an independent renderer's converged image (`params.reference`,
/// relative to the manifest), and the unclamped RMSE.
fn rmse_vs_reference(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let file: String = ctx.param_req("reference")?;
    let reference = read_reference(
        ctx,
        &file,
        s.params.width as usize,
        s.params.height as usize,
    )?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    out.tensor(
        "rmse",
        Tensor::scalar(mse(&img.rgb, &reference.rgb, true).sqrt()),
    );
    out.tensor(
        "rmse_raw",
        Tensor::scalar(mse(&img.rgb, &reference.rgb, false).sqrt()),
    );
    Ok(out)
}

/// Speed against error: for each spp, the seconds of one render and its
/// RMSE against a reference, linear radiance clamped to [0, 1] (`rmse`, as
/// the acceptance measures) and raw (`rmse_raw`, the reference's own noise
/// subtracted when it is rendered here). The reference is a `ref_spp` render
/// (seed `ref_seed`) or, with `params.reference`, an (H, W, 3) `.npy` file
/// (relative to the manifest). Metrics `time_s_<spp>`; `plot_image` draws
/// log RMSE against log seconds, with the ideal Monte Carlo rate (slope
/// -1/2 through the first point) as a guide.
fn speed_error(ctx: &OpCtx) -> Result<Outputs> {
    let s = load(ctx)?;
    let spps: Vec<u32> = ctx.param_or("spp", vec![4, 16, 64, 256])?;
    let ref_spp: u32 = ctx.param_or("ref_spp", 4096)?;
    let ref_seed: u32 = ctx.param_or("ref_seed", 1 << 31)?;
    if spps.is_empty() || spps.contains(&0) {
        return Err(Error::invalid(
            format!("{} params.spp", ctx.case_id),
            "need a non-empty list of positive sample counts",
        ));
    }
    let mut out = Outputs::default();
    let (w, h) = (s.params.width as usize, s.params.height as usize);
    let (reference, noise) = match ctx.param::<String>("reference")? {
        Some(file) => (read_reference(ctx, &file, w, h)?, 0.0),
        None => {
            let (r, secs) = render_with(&s, ref_spp, ref_seed, ctx)?;
            out.metric("ref_time_s", secs);
            let noise = mean_variance(&r.variance);
            (r, noise)
        }
    };
    let (mut secs, mut rmse, mut raw) = (vec![], vec![], vec![]);
    for &spp in &spps {
        let (img, t) = render_with(&s, spp, s.params.seed, ctx)?;
        secs.push(t);
        rmse.push(mse(&img.rgb, &reference.rgb, true).sqrt());
        raw.push(
            (mse(&img.rgb, &reference.rgb, false) - noise)
                .max(0.0)
                .sqrt(),
        );
        out.metric(&format!("time_s_{spp}"), t);
    }
    let k = [spps.len()];
    let ideal: Vec<f64> = secs
        .iter()
        .map(|t| rmse[0] * (t / secs[0]).powf(-0.5))
        .collect();
    let chart = Chart::loglog(
        "path tracer: speed against error",
        "seconds",
        "RMSE vs reference",
        vec![
            Series::new("RMSE", secs.clone(), rmse.clone()),
            Series::guide("ideal t^-1/2", secs.clone(), ideal),
        ],
    );
    out.tensor("plot_image", plot::render(&chart)?);
    out.tensor(
        "spp",
        Tensor::real(&k, spps.iter().map(|&v| v as f64).collect())?,
    );
    out.tensor("seconds", Tensor::real(&k, secs)?);
    out.tensor("rmse", Tensor::real(&k, rmse)?);
    out.tensor("rmse_raw", Tensor::real(&k, raw)?);
    Ok(out)
}
