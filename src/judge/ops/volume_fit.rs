//! `volume.fit`: the inverse-rendering proof (issue 18; `volume/fit.rs`).
//!
//! Params: `model` (`dense` | `hash`), `n` (dense grid side, default 32),
//! `views` (8), `held_out` (4), `side` (image side, 32), `iters` (60), `dt`
//! (0.02), `lr_sigma` (2.0), `lr_color` (0.05), `lr_hash` (0.01), `seed`
//! (0), hash sizes `levels` (8), `features` (2), `log2_table` (14),
//! `n_min` (8), `n_max` (64).
//!
//! Outputs: `loss` (per iteration), `loss_drop` (first / last), `psnr_held`
//! (per held-out view), `psnr_held_min`; metrics
//! `psnr_train`, `psnr_held_mean`, `psnr_held_min`, `time_s`. The scene is
//! not used: the target and views are `volume/fit.rs`'s.

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::tensor::{Outputs, Tensor};
use crate::volume::field::hash::HashConfig;
use crate::volume::fit::{fit, FitConfig, Model};

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "volume.fit",
    doc: "fit a dense grid or a hash-grid field to views of a structured target (Adam, f_diff); loss per iteration, PSNR on held-out views",
    params: &[
        "model", "n", "views", "held_out", "side", "iters", "dt", "lr_sigma", "lr_color",
        "lr_hash", "seed", "levels", "features", "log2_table", "n_min", "n_max",
    ],
    support: Support::Cpu,
    run: op_fit,
}];

fn op_fit(ctx: &OpCtx) -> Result<Outputs> {
    let model = match ctx.param_or::<String>("model", "dense".into())?.as_str() {
        "dense" => Model::Dense {
            n: ctx.param_or("n", 32)?,
        },
        "hash" => {
            let h = HashConfig {
                levels: ctx.param_or("levels", 8)?,
                features: ctx.param_or("features", 2)?,
                log2_table: ctx.param_or("log2_table", 14)?,
                n_min: ctx.param_or("n_min", 8)?,
                n_max: ctx.param_or("n_max", 64)?,
            };
            h.validate(&format!("{} params", ctx.case_id))?;
            Model::Hash(h)
        }
        o => {
            return Err(Error::invalid(
                format!("{} params.model", ctx.case_id),
                format!("{o:?} is not dense or hash"),
            ))
        }
    };
    if let Model::Dense { n } = model {
        if !(2..=256).contains(&n) {
            return Err(Error::invalid(
                format!("{} params.n", ctx.case_id),
                format!("{n} is not in 2..=256"),
            ));
        }
    }
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
    };
    if cfg.views == 0 || cfg.held_out == 0 || cfg.side == 0 || cfg.side > 1024 {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "views, held_out must be >= 1 and side in 1..=1024",
        ));
    }
    let r = fit(&cfg, &ctx.budget)?;
    for (i, l) in r.loss.iter().enumerate() {
        eprintln!("{}: iter {i} loss {l:.6e}", ctx.case_id);
    }
    let mean = r.psnr_held.iter().sum::<f64>() / r.psnr_held.len() as f64;
    let min = r.psnr_held.iter().copied().fold(f64::INFINITY, f64::min);
    let mut out = Outputs::default();
    out.tensor("loss", Tensor::real(&[r.loss.len()], r.loss.clone())?);
    out.tensor(
        "psnr_held",
        Tensor::real(&[r.psnr_held.len()], r.psnr_held.clone())?,
    );
    let last = r.loss.last().copied().unwrap_or(f64::NAN);
    out.tensor(
        "loss_drop",
        Tensor::scalar(r.loss.first().map_or(f64::NAN, |f| f / last)),
    );
    out.tensor("psnr_held_min", Tensor::scalar(min));
    out.metric("psnr_train", r.psnr_train);
    out.metric("psnr_held_mean", mean);
    out.metric("psnr_held_min", min);
    out.metric("time_s", r.time_s);
    Ok(out)
}
