//! `volume.fit`: the inverse-rendering proof. `volume/fit.rs` says what
//! each parameter means (`FitConfig`) and what is output
//! (`FitReport::to_outputs`); the defaults are below. The scene is not
//! used: the target and views are `volume/fit.rs`'s.

use super::OpCtx;
use crate::error::Result;
use crate::tensor::Outputs;
use crate::volume::field::hash::HashConfig;
use crate::volume::fit::{fit, FitConfig, Model};

ops! {
    "volume.fit" Cpu op_fit ["model", "n", "views", "held_out", "side", "iters", "dt", "lr_sigma", "lr_color",
        "lr_hash", "seed", "levels", "features", "log2_table", "n_min", "n_max", "stages", "tv_sigma", "tv_color",
        "lr_final"]
        "fit a dense grid or a hash-grid field to views of a structured target (Adam, f_diff); loss per iteration, PSNR on held-out views";
}

fn op_fit(ctx: &OpCtx) -> Result<Outputs> {
    let model = match ctx.param_or::<String>("model", "dense".into())?.as_str() {
        "dense" => Model::Dense {
            n: ctx.param_or("n", 32)?,
        },
        "hash" => Model::Hash(HashConfig {
            levels: ctx.param_or("levels", 8)?,
            features: ctx.param_or("features", 2)?,
            log2_table: ctx.param_or("log2_table", 14)?,
            n_min: ctx.param_or("n_min", 8)?,
            n_max: ctx.param_or("n_max", 64)?,
        }),
        o => return Err(ctx.bad("model", format!("{o:?} is not dense or hash"))),
    };
    let cfg = FitConfig {
        model,
        views: ctx.param_or("views", 8)?,
        held_out: ctx.param_or("held_out", 4)?,
        side: ctx.param_or("side", 32)?,
        iters: ctx.param_or("iters", 60)?,
        dt: ctx.param_or("dt", 0.02)?,
        lr_sigma: ctx.param_or("lr_sigma", 2.0)?,
        lr_color: ctx.param_or("lr_color", 0.05)?,
        lr_hash: ctx.param_or("lr_hash", 0.01)?,
        seed: ctx.param_or("seed", 0)?,
        stages: ctx.param_or("stages", 1)?,
        tv_sigma: ctx.param_or("tv_sigma", 0.0)?,
        tv_color: ctx.param_or("tv_color", 0.0)?,
        lr_final: ctx.param_or("lr_final", 1.0)?,
    };
    cfg.validate(&format!("{} params", ctx.case_id))?;
    let r = fit(&cfg, &ctx.budget)?;
    for (i, l) in r.loss.iter().enumerate() {
        eprintln!("{}: iter {i} loss {l:.6e}", ctx.case_id);
    }
    r.to_outputs(ctx.case_id)
}
