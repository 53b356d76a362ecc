//! Transport speed figures (issue 16): the fused kernels against their
//! per-stage referees (`transport::kernel_perf`) and Kerr shadow speed
//! against error per tier (`transport::kerr_speed_error`).

use super::OpCtx;
use crate::error::Result;
use crate::scene::transport::{parse, IntegratorSpec};
use crate::tensor::Outputs;
use crate::transport::{kernel_perf, kerr_speed_error};

ops! {
    "transport.perf_kernels" Cpu perf_kernels ["a", "rounds"]
        "photon-steps per CPU second of the fused Schwarzschild and Kerr kernels and their per-stage referees, same rays, one run (a: 0.9, rounds: 3)";
    "transport.kerr_speed_error" Cpu kerr_speed_error ["tiers", "points", "offsets"]
        "per tier: CPU time, boundary error of probe rays across Bardeen's curve, H and Q drift; plot_rgb (points: 32, offsets: 1e-1..1e-8)";
}

fn perf_kernels(ctx: &OpCtx) -> Result<Outputs> {
    let (task, opt) = parse(ctx.scene()?)?.build::<f64>()?;
    let (a, rounds) = (ctx.param_or("a", 0.9)?, ctx.param_or("rounds", 3)?);
    kernel_perf::compare_kernels(&task, &opt, &ctx.budget, a, rounds)
}

fn kerr_speed_error(ctx: &OpCtx) -> Result<Outputs> {
    let (task, base) = parse(ctx.scene()?)?.build::<f64>()?;
    let specs: Vec<IntegratorSpec> = ctx.param_req("tiers")?;
    let tiers = specs
        .iter()
        .map(|s| s.build())
        .collect::<Result<Vec<_>>>()?;
    let offsets: Vec<f64> = ctx.param_or("offsets", (1..=8).map(|k| 10f64.powi(-k)).collect())?;
    let n = ctx.param_or("points", 32)?;
    kerr_speed_error::run(&task, &base, &tiers, n, &offsets, &ctx.budget)
}
