//! The GPU backend of the volume forward operations (`volume.render`,
//! `volume.forward`, `volume.unfused` with `backend: gpu`): the same outputs
//! as the CPU rows, plus
//!
//! - `stable` (uint8, H x W): 1 where every decision of the pixel's ray
//!   (early stop, lattice end, occupancy cell face, slab break or shell
//!   radius) was clear of its threshold by more than rounding, 0 where f32
//!   and the f64 referee may legitimately take different branches (one
//!   sample more or less). Parity cases compare `nsamples` exactly and
//!   `logtrans` tightly only where `stable` is 1.
//! - `unstable_frac` (scalar): the share of rays with `stable = 0`, bounded
//!   by the parity cases so the mask cannot hide a real bug.
//!
//! Metrics: `time_s` is the GPU time of the chain (submit to readback,
//! without pipeline builds and uploads), `samples_per_s` = samples / time_s.

use super::super::OpCtx;
use super::{load, render_outputs};
use crate::error::{Error, Result};
use crate::real::Precision;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::Compose;
use crate::volume::gpu::render_gpu;
use crate::volume::Chain;

/// Runs `chain` on the GPU for the case's scene.
pub fn run_chain_gpu(ctx: &OpCtx, chain: Chain, compose: Compose) -> Result<Outputs> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU computes in f32 only",
            ctx.case_id
        )));
    }
    if ctx.param_or("buffers", false)? {
        return Err(Error::NotSupported(format!(
            "{}: per-sample buffers are not read back from the GPU chain",
            ctx.case_id
        )));
    }
    let gpu = crate::gpu::GpuContext::get()?;
    let (cam, gen, p, _) = load(ctx)?;
    let g = render_gpu(gpu, &cam, &gen, &p, chain, compose, &ctx.budget)?;
    let mut out = Outputs::default();
    render_outputs(&g.render, &mut out)?;
    let shape = [g.render.image.height, g.render.image.width];
    let unstable = g.stable.iter().filter(|&&s| s == 0).count();
    out.tensor(
        "unstable_frac",
        Tensor::scalar(unstable as f64 / g.stable.len().max(1) as f64),
    );
    out.tensor("stable", Tensor::from_shape_vec(&shape, g.stable)?);
    out.counter("unstable", unstable as u64);
    Ok(out)
}
