//! `transport.image_band` (issue 17, docs/transport_gpu.md): an image
//! scene rendered on the CPU in the case's precision (the f64 referee of
//! the GPU image contract), with the tensors of `transport.render`, plus
//! `far` (1 where `captured`, `disk_hit` and `side` are constant within
//! `params.band_px` pixels: `transport::gpu_parity`) and the metric
//! `near_frac` (the fraction of pixels that are not far).

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::real::Real;
use crate::scene::transport::parse;
use crate::tensor::{Outputs, Tensor};
use crate::transport::gpu_parity::far_from_edges;
use crate::transport::outputs::run_curved;
use crate::transport::tasks::{Curved, Task};

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "transport.image_band",
    doc: "the CPU render of an image scene plus `far`: 1 where capture, disk hit and side are constant within params.band_px pixels",
    params: &["band_px"],
    support: Support::Cpu,
    run: image_band,
}];

fn band_in<F: Real>(ctx: &OpCtx, d: usize) -> Result<Outputs> {
    let (task, opt) = parse(ctx.scene()?)?.build::<F>()?;
    let Task::Curved(c @ Curved::Image(_)) = &task else {
        return Err(Error::invalid(
            "task",
            "transport.image_band needs an image scene",
        ));
    };
    let mut out = Outputs::default();
    run_curved(c, &opt, &ctx.budget, &mut out, None)?;
    let shape = out.tensors.get("captured").map(|t| t.shape().to_vec());
    let [h, w] = shape.unwrap_or_default()[..] else {
        return Err(Error::invalid(
            "task",
            "transport.image_band needs a pixel grid",
        ));
    };
    let classes: Vec<Vec<f64>> = ["captured", "disk_hit", "side"]
        .iter()
        .filter_map(|n| out.tensors.get(*n).map(|t| t.to_f64_vec()))
        .collect();
    let far = far_from_edges(h, w, &classes, d);
    let near = far.iter().filter(|&&f| f == 0).count();
    out.metric("near_frac", near as f64 / (h * w) as f64);
    out.tensor("far", Tensor::from_shape_vec(&[h, w], far)?);
    Ok(out)
}

fn image_band(ctx: &OpCtx) -> Result<Outputs> {
    let d: usize = ctx.param_or("band_px", 1)?;
    by_precision!(ctx, band_in(ctx, d))
}
