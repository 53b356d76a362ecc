//! Transport speed figures (issue 16), thin wiring:
//! `transport.perf_kernels`: the fused Schwarzschild and Kerr kernels
//! against their per-stage referees in one run
//! (`transport::kernel_perf::compare_kernels`; params `a`, default 0.9,
//! and `rounds`, default 3); `transport.kerr_speed_error`: probe rays
//! across Bardeen's curve per tier (`transport::kerr_speed_error`; params
//! `tiers` (integrator specs), `points` (default 32), `offsets`).

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::scene::transport::parse;
use crate::scene::transport::IntegratorSpec;
use crate::tensor::Outputs;
use crate::transport::image::ImageTask;
use crate::transport::kernel_perf::compare_kernels;
use crate::transport::kerr_speed_error::{sweep, to_outputs};
use crate::transport::tasks::{Curved, Task};

pub const OPS: &[OpEntry] = &[
    OpEntry { name: "transport.perf_kernels", doc: "photon-steps per CPU second of the fused Schwarzschild and Kerr kernels and their per-stage referees, same rays, one run", params: &["a", "rounds"], support: Support::Cpu, run: perf_kernels },
    OpEntry { name: "transport.kerr_speed_error", doc: "per tier: CPU time, boundary error of probe rays across Bardeen's curve, H and Q drift; plot_rgb", params: &["tiers", "points", "offsets"], support: Support::Cpu, run: kerr_speed_error },
];

fn perf_kernels(ctx: &OpCtx) -> Result<Outputs> {
    let (task, opt) = parse(ctx.scene()?)?.build::<f64>()?;
    let Task::Deflection(d) = task else {
        return Err(Error::invalid(
            "task",
            "transport.perf_kernels needs a deflection scene",
        ));
    };
    compare_kernels(
        &d,
        &opt,
        &ctx.budget,
        ctx.param_or("a", 0.9)?,
        ctx.param_or("rounds", 3)?,
    )
}

fn kerr_speed_error(ctx: &OpCtx) -> Result<Outputs> {
    let (task, base) = parse(ctx.scene()?)?.build::<f64>()?;
    let Task::Curved(Curved::Image(ImageTask::Kerr(img))) = task else {
        return Err(Error::invalid(
            "task",
            "transport.kerr_speed_error needs a kerr_image scene",
        ));
    };
    let specs: Vec<IntegratorSpec> = ctx.param_req("tiers")?;
    let tiers = specs
        .iter()
        .map(|s| s.build())
        .collect::<Result<Vec<_>>>()?;
    let offsets: Vec<f64> = ctx.param_or("offsets", (1..=8).map(|k| 10f64.powi(-k)).collect())?;
    let floor = offsets.iter().fold(f64::INFINITY, |m, d| m.min(*d));
    to_outputs(
        &sweep(
            &img,
            &base,
            &tiers,
            ctx.param_or("points", 32)?,
            &offsets,
            &ctx.budget,
        )?,
        floor,
    )
}
