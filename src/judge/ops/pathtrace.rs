//! Operations of the `pathtrace` renderer and their independent references.
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
//! | `pathtrace.speed_error` | seconds and RMSE against a reference render over an spp sweep |

use std::time::Instant;

use super::{OpCtx, OpEntry};
use crate::error::Result;
use crate::pathtrace::{render, Image, RenderParams};
use crate::scene::pathtrace::PathtraceScene;
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "pathtrace.render",
    doc: "path-traced image (H, W, 3) and variance of the pixel mean; metrics time_s, paths_per_s",
    params: &[],
    run: render_op,
}];

fn load(ctx: &OpCtx) -> Result<PathtraceScene> {
    crate::scene::pathtrace::parse(ctx.scene()?)
}

fn timed_render(s: &PathtraceScene, p: &RenderParams, ctx: &OpCtx) -> Result<(Image, f64)> {
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
    ctx.cpu_only()?;
    let s = load(ctx)?;
    let (img, secs) = timed_render(&s, &s.params, ctx)?;
    let mut out = Outputs::default();
    image_outputs(&img, secs, &s.params, &mut out)?;
    Ok(out)
}
