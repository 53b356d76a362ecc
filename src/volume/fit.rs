//! Inverse rendering (issue 18): fit a dense grid or a hash-grid field to
//! views of a structured target with Adam and the project's own gradients
//! (`f_diff`, fused chain, canonical reduction).
//!
//! The target ([`target`]) is a dense `(2n)^3` grid (finer than the fitted
//! `n^3` one) holding four coloured Gaussian blobs and a thin grey shell
//! (`0.62 <= r <= 0.68`): edges a blurry fit cannot fake. Views sit on a
//! Fibonacci sphere of radius 3 looking at the origin; the held-out views
//! are the same rule with a half-step offset (never trained on). The loss is
//! `mean_pixels |rgb - target|^2` over every training view per iteration
//! (full batch); PSNR is `10 log10(1 / mse)` on the held-out views.
//!
//! Dense model: density and colour grids, separate Adam learning rates,
//! densities projected onto `>= 0` and colours onto `[0, 1]` after each step.
//! Hash model: every parameter of `HashMlpDesc::flat` in one Adam.

use std::time::Instant;

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::tensor::{Outputs, Tensor};

use super::compose::Compose;
use super::diff::{f_diff, DiffOptions, Reduce, Upstream};
use super::field::hash::{DensityAct, HashConfig, HashMlpDesc};
use super::field::{ColorDesc, FieldDesc, GridDesc, Oob};
use super::sample::{Sampling, TransPath};
use super::{render, Chain, VolumeParams};

/// Adam (Kingma and Ba 2015), f64 state.
#[derive(Clone, Debug)]
pub struct Adam {
    pub lr: f64,
    pub b1: f64,
    pub b2: f64,
    pub eps: f64,
    m: Vec<f64>,
    v: Vec<f64>,
    t: i32,
}

impl Adam {
    pub fn new(n: usize, lr: f64) -> Adam {
        Adam {
            lr,
            b1: 0.9,
            b2: 0.99,
            eps: 1e-15,
            m: vec![0.0; n],
            v: vec![0.0; n],
            t: 0,
        }
    }

    /// One step of `p` against gradient `g`.
    pub fn step(&mut self, p: &mut [f64], g: &[f64]) {
        self.t += 1;
        let (c1, c2) = (1.0 - self.b1.powi(self.t), 1.0 - self.b2.powi(self.t));
        for i in 0..p.len() {
            self.m[i] = self.b1 * self.m[i] + (1.0 - self.b1) * g[i];
            self.v[i] = self.b2 * self.v[i] + (1.0 - self.b2) * g[i] * g[i];
            p[i] -= self.lr * (self.m[i] / c1) / ((self.v[i] / c2).sqrt() + self.eps);
        }
    }
}

/// The model being fitted.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Model {
    Dense { n: usize },
    Hash(HashConfig),
}

/// A fit's sizes and rates.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FitConfig {
    pub model: Model,
    pub views: u32,
    pub held_out: u32,
    pub side: u32,
    pub iters: u32,
    pub dt: f64,
    /// Adam rates: density and colour (dense), all parameters (hash).
    pub lr_sigma: f64,
    pub lr_color: f64,
    pub lr_hash: f64,
    pub seed: u32,
}

/// What a fit measured.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    /// Training loss before each step.
    pub loss: Vec<f64>,
    pub psnr_train: f64,
    /// Per held-out view.
    pub psnr_held: Vec<f64>,
    pub time_s: f64,
}

impl FitConfig {
    /// Refuses sizes out of range (`at` names the parameters): a dense side
    /// outside 2..=256, no views or held-out views, an image side outside
    /// 1..=1024, a hash configuration its own check refuses.
    pub fn validate(&self, at: &str) -> Result<()> {
        match self.model {
            Model::Dense { n } if !(2..=256).contains(&n) => {
                return Err(Error::invalid(
                    format!("{at}.n"),
                    format!("{n} is not in 2..=256"),
                ))
            }
            Model::Hash(h) => h.validate(at)?,
            Model::Dense { .. } => {}
        }
        if self.views == 0 || self.held_out == 0 || self.side == 0 || self.side > 1024 {
            let why = "views, held_out must be >= 1 and side in 1..=1024";
            return Err(Error::invalid(at, why));
        }
        Ok(())
    }
}

impl FitReport {
    /// `loss` (per iteration), `psnr_held` (per held-out view), `loss_drop`
    /// (first / last), `psnr_held_min`; metrics `psnr_train`,
    /// `psnr_held_mean`, `psnr_held_min`, `time_s`.
    pub fn to_outputs(&self) -> Result<Outputs> {
        let mean = self.psnr_held.iter().sum::<f64>() / self.psnr_held.len() as f64;
        let min = self.psnr_held.iter().copied().fold(f64::INFINITY, f64::min);
        let mut out = Outputs::default();
        out.tensor("loss", Tensor::real(&[self.loss.len()], self.loss.clone())?);
        out.tensor(
            "psnr_held",
            Tensor::real(&[self.psnr_held.len()], self.psnr_held.clone())?,
        );
        let last = self.loss.last().copied().unwrap_or(f64::NAN);
        out.tensor(
            "loss_drop",
            Tensor::scalar(self.loss.first().map_or(f64::NAN, |f| f / last)),
        );
        out.tensor("psnr_held_min", Tensor::scalar(min));
        out.metric("psnr_train", self.psnr_train);
        out.metric("psnr_held_mean", mean)
            .metric("psnr_held_min", min);
        out.metric("time_s", self.time_s);
        Ok(out)
    }
}

/// Target density and colour at `x` (module doc).
pub fn target_point(x: [f64; 3]) -> (f64, [f64; 3]) {
    const BLOBS: [([f64; 3], [f64; 3]); 4] = [
        ([0.3, 0.2, 0.1], [0.9, 0.2, 0.1]),
        ([-0.25, 0.25, -0.15], [0.1, 0.8, 0.2]),
        ([0.05, -0.3, 0.25], [0.15, 0.25, 0.95]),
        ([-0.2, -0.15, -0.3], [0.95, 0.85, 0.1]),
    ];
    let mut s = 0.0;
    let mut c = [0.0; 3];
    for (m, col) in BLOBS {
        let r2: f64 = (0..3).map(|a| (x[a] - m[a]).powi(2)).sum();
        let v = 40.0 * (-r2 / (2.0 * 0.1f64.powi(2))).exp();
        s += v;
        for k in 0..3 {
            c[k] += v * col[k];
        }
    }
    let r = (0..3).map(|a| x[a] * x[a]).sum::<f64>().sqrt();
    if (0.62..=0.68).contains(&r) {
        s += 8.0;
        for ck in &mut c {
            *ck += 8.0 * 0.6;
        }
    }
    if s > 0.0 {
        c = c.map(|v| v / s);
    }
    (s, c)
}

/// The target as dense grids of `shape` nodes over [-1, 1]^3.
pub fn target(n: usize) -> (GridDesc, GridDesc) {
    let (b0, b1) = ([-1.0; 3], [1.0; 3]);
    let sig = GridDesc::sample([n; 3], b0, b1, Oob::Zero, |x| target_point(x).0);
    let mut col = GridDesc::filled([n; 3], &[0.0; 3], b0, b1, Oob::Zero);
    let node = |i: usize| -1.0 + 2.0 * i as f64 / (n - 1) as f64;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let c = target_point([node(i), node(j), node(k)]).1;
                let q = ((k * n + j) * n + i) * 3;
                col.data[q..q + 3].copy_from_slice(&c);
            }
        }
    }
    (sig, col)
}

/// View `i` of `count` on a Fibonacci sphere of radius 3 (`offset` 0.5 for
/// held-out views).
pub fn view(i: u32, count: u32, offset: f64, side: u32) -> Result<Camera> {
    let golden = std::f64::consts::PI * (3.0 - 5f64.sqrt());
    let z = 1.0 - 2.0 * (i as f64 + 0.5 + offset * 0.5) / count as f64;
    let r = (1.0 - z * z).max(0.0).sqrt();
    let phi = golden * (i as f64 + offset);
    let p = [3.0 * r * phi.cos(), 3.0 * z, 3.0 * r * phi.sin()];
    let up = if z.abs() > 0.9 {
        [1.0, 0.0, 0.0]
    } else {
        [0.0, 1.0, 0.0]
    };
    Camera::pinhole_look_at(p, [0.0; 3], up, 45.0, side, side)
}

fn params(field: FieldDesc, color: ColorDesc, dt: f64) -> VolumeParams {
    VolumeParams {
        field,
        color,
        dt,
        max_steps: 4096,
        early_stop: 0.0,
        sampling: Sampling::Fixed,
        path: TransPath::Product,
        background: [0.0; 3],
        occupancy: 0,
    }
}

fn rgb_of(p: &VolumeParams, cam: &Camera, gen: &RayGen, b: &MemBudget) -> Result<Vec<[f32; 3]>> {
    Ok(
        render::<f32>(cam, gen, p, Chain::Fused, Compose::Sorted, b)?
            .image
            .rgb,
    )
}

fn mse(a: &[[f32; 3]], b: &[[f32; 3]]) -> f64 {
    let s: f64 = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            (0..3)
                .map(|k| (x[k] as f64 - y[k] as f64).powi(2))
                .sum::<f64>()
        })
        .sum();
    s / (3 * a.len()) as f64
}

fn psnr(m: f64) -> f64 {
    -10.0 * m.max(1e-20).log10()
}

/// Runs a fit (module doc).
pub fn fit(cfg: &FitConfig, budget: &MemBudget) -> Result<FitReport> {
    let t_start = Instant::now();
    let gen = RayGen::new(cfg.side, cfg.side);
    let nt = match cfg.model {
        Model::Dense { n } => 2 * n,
        Model::Hash(_) => 64,
    };
    let (ts, tc) = target(nt);
    let tp = params(FieldDesc::Grid(ts), ColorDesc::Grid(tc), cfg.dt);
    let train: Vec<Camera> = (0..cfg.views)
        .map(|i| view(i, cfg.views, 0.0, cfg.side))
        .collect::<Result<_>>()?;
    let held: Vec<Camera> = (0..cfg.held_out)
        .map(|i| view(i, cfg.held_out, 0.5, cfg.side))
        .collect::<Result<_>>()?;
    let targets: Vec<_> = train
        .iter()
        .map(|c| rgb_of(&tp, c, &gen, budget))
        .collect::<Result<_>>()?;
    let held_t: Vec<_> = held
        .iter()
        .map(|c| rgb_of(&tp, c, &gen, budget))
        .collect::<Result<_>>()?;
    let (b0, b1) = ([-1.0; 3], [1.0; 3]);
    let mut p = match cfg.model {
        Model::Dense { n } => params(
            FieldDesc::Grid(GridDesc::filled([n; 3], &[0.5], b0, b1, Oob::Zero)),
            ColorDesc::Grid(GridDesc::filled([n; 3], &[0.5; 3], b0, b1, Oob::Zero)),
            cfg.dt,
        ),
        Model::Hash(h) => params(
            FieldDesc::HashMlp(Box::new(HashMlpDesc::init(
                h,
                DensityAct::Softplus,
                &[32],
                b0,
                b1,
                cfg.seed,
                1e-2,
                -1.0,
            ))),
            ColorDesc::Mlp,
            cfg.dt,
        ),
    };
    let npix = (cfg.side * cfg.side) as usize;
    let (ns, nc) = match &p.field {
        FieldDesc::Grid(g) => (g.data.len(), 3 * g.data.len()),
        FieldDesc::HashMlp(h) => (h.param_count(), 0),
        FieldDesc::Analytic(_) => (0, 0),
    };
    let (mut adam_s, mut adam_c) = match cfg.model {
        Model::Dense { .. } => (Adam::new(ns, cfg.lr_sigma), Adam::new(nc, cfg.lr_color)),
        Model::Hash(_) => (Adam::new(ns, cfg.lr_hash), Adam::new(0, 0.0)),
    };
    let opt = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let mut loss = Vec::with_capacity(cfg.iters as usize);
    for _ in 0..cfg.iters {
        let (mut gs, mut gc) = (vec![0.0; ns], vec![0.0; nc]);
        let mut l = 0.0;
        for (cam, tgt) in train.iter().zip(&targets) {
            let rgb = rgb_of(&p, cam, &gen, budget)?;
            l += mse(&rgb, tgt) / train.len() as f64;
            let k = 2.0 / (3 * npix * train.len()) as f32;
            let up = Upstream {
                rgb: rgb
                    .iter()
                    .zip(tgt)
                    .map(|(a, b)| [0, 1, 2].map(|c| k * (a[c] - b[c])))
                    .collect(),
                depth: None,
                opacity: None,
            };
            let g = f_diff::<f32>(cam, &gen, &p, &up, &opt, None, budget)?;
            let add = |acc: &mut [f64], v: &Option<Vec<f32>>| {
                if let Some(v) = v {
                    for (a, x) in acc.iter_mut().zip(v) {
                        *a += *x as f64;
                    }
                }
            };
            add(&mut gs, &g.dsigma);
            add(&mut gs, &g.dhash);
            add(&mut gc, &g.dcolor);
        }
        loss.push(l);
        match (&mut p.field, &mut p.color) {
            (FieldDesc::Grid(s), ColorDesc::Grid(c)) => {
                adam_s.step(&mut s.data, &gs);
                adam_c.step(&mut c.data, &gc);
                s.data.iter_mut().for_each(|v| *v = v.max(0.0));
                c.data.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
            }
            (FieldDesc::HashMlp(h), _) => {
                let mut flat = h.flat();
                adam_s.step(&mut flat, &gs);
                h.set_flat(&flat);
            }
            _ => {}
        }
    }
    let mut tr = 0.0;
    for (cam, tgt) in train.iter().zip(&targets) {
        tr += mse(&rgb_of(&p, cam, &gen, budget)?, tgt) / train.len() as f64;
    }
    let psnr_held = held
        .iter()
        .zip(&held_t)
        .map(|(cam, tgt)| Ok(psnr(mse(&rgb_of(&p, cam, &gen, budget)?, tgt))))
        .collect::<Result<_>>()?;
    Ok(FitReport {
        loss,
        psnr_train: psnr(tr),
        psnr_held,
        time_s: t_start.elapsed().as_secs_f64(),
    })
}
