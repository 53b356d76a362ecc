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
use crate::judge::plot::{self, Chart, Series};
use crate::rays::RayGen;
use crate::tensor::{Outputs, Tensor};

use super::compose::Compose;
use super::diff::{f_diff_prepared, DiffOptions, Kernel::Lanes, Reduce, Upstream};
use super::field::hash::{DensityAct, HashConfig, HashMlpDesc};
use super::field::{ColorDesc, FieldDesc, Grid, GridDesc, Oob};
use super::sample::{Sampling, TransPath};
use super::{prepare, render, render_prepared, Chain, VolumeParams};

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
    pub fn len(&self) -> usize {
        self.m.len()
    }

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
    /// Dense model: coarse-to-fine stages (1 = off). Stage `s` of `S` fits
    /// a grid of side `max(2, n >> (S-1-s))`, an equal share of the
    /// iterations each; each stage starts from the previous one's grids
    /// upsampled trilinearly ([`upsample`]), with fresh Adam state.
    pub stages: u32,
    /// Dense model: weights of the smoothness prior on density and colour,
    /// `w * mean over neighbouring node pairs of (a - b)^2` added to the loss
    /// ([`smoothness`]; 0 = off).
    pub tv_sigma: f64,
    pub tv_color: f64,
    /// Every learning rate decays exponentially to `lr_final` times its
    /// start over the iterations (1 = constant).
    pub lr_final: f64,
}

/// What a fit measured.
#[derive(Clone, Debug, PartialEq)]
pub struct FitReport {
    /// Training loss before each step.
    pub loss: Vec<f64>,
    pub psnr_train: f64,
    /// Per held-out view.
    pub psnr_held: Vec<f64>,
    /// Dense model: the held-out PSNR of the target itself sampled at the
    /// fitted grid's nodes (what the model's resolution allows without
    /// fitting; NaN for the hash model, and then not a metric).
    pub psnr_held_nodes: f64,
    pub time_s: f64,
}

impl FitConfig {
    /// Refuses sizes out of range (`at` names the parameters): a dense side
    /// outside 2..=256, no views or held-out views, an image side outside
    /// 1..=1024, a hash configuration its own check refuses, stages outside
    /// 1..=8, a negative or non-finite prior weight, `lr_final <= 0`.
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
        if !(1..=8).contains(&self.stages) {
            let why = format!("{} is not in 1..=8", self.stages);
            return Err(Error::invalid(format!("{at}.stages"), why));
        }
        for (k, v) in [("tv_sigma", self.tv_sigma), ("tv_color", self.tv_color)] {
            if !(v.is_finite() && v >= 0.0) {
                return Err(Error::invalid(
                    format!("{at}.{k}"),
                    format!("{v} is not a finite value >= 0"),
                ));
            }
        }
        if !(self.lr_final.is_finite() && self.lr_final > 0.0) {
            let why = format!("{} is not a finite value > 0", self.lr_final);
            return Err(Error::invalid(format!("{at}.lr_final"), why));
        }
        Ok(())
    }
}

impl FitReport {
    /// `loss` (per iteration), `loss_rgb` (the loss curve, log y, titled
    /// `title`), `psnr_held` (per held-out view), `loss_drop` (first /
    /// last), `psnr_held_min`, `psnr_held_mean`; metrics `psnr_train`,
    /// `psnr_held_nodes` (dense), `psnr_held_mean`, `psnr_held_min`, `time_s`.
    pub fn to_outputs(&self, title: &str) -> Result<Outputs> {
        let n = self.loss.len();
        let mean = self.psnr_held.iter().sum::<f64>() / self.psnr_held.len() as f64;
        let min = self.psnr_held.iter().copied().fold(f64::INFINITY, f64::min);
        let chart = Chart {
            title: format!("{title}: training loss"),
            x_label: "iteration".into(),
            y_label: "mean squared error over training views".into(),
            log_x: false,
            log_y: true,
            series: vec![Series::new(
                "loss",
                (0..n).map(|i| i as f64).collect(),
                self.loss.clone(),
            )],
        };
        let mut out = Outputs::default();
        out.tensor("loss", Tensor::real(&[n], self.loss.clone())?);
        out.tensor("loss_rgb", plot::render(&chart)?);
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
        out.tensor("psnr_held_mean", Tensor::scalar(mean));
        out.metric("psnr_train", self.psnr_train);
        if self.psnr_held_nodes.is_finite() {
            out.metric("psnr_held_nodes", self.psnr_held_nodes);
        }
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

/// The smoothness prior: `w * mean over pairs of neighbouring nodes (along
/// each axis, per channel) of (a - b)^2`; adds its gradient to `grad` and
/// returns its value.
pub fn smoothness(g: &GridDesc, w: f64, grad: &mut [f64]) -> f64 {
    if w == 0.0 {
        return 0.0;
    }
    let [nz, ny, nx] = g.shape;
    let ch = g.ch;
    let stride = [ch, ch * nx, ch * nx * ny];
    let n = [nx, ny, nz];
    let pairs: usize = (0..3)
        .map(|a| ch * (n[a] - 1) * n.iter().product::<usize>() / n[a])
        .sum();
    let k = w / pairs as f64;
    let mut sum = 0.0;
    for z in 0..nz {
        for y in 0..ny {
            for x in 0..nx {
                let at = [x, y, z];
                let q = z * stride[2] + y * stride[1] + x * stride[0];
                for a in 0..3 {
                    if at[a] + 1 == n[a] {
                        continue;
                    }
                    for c in 0..ch {
                        let d = g.data[q + c] - g.data[q + stride[a] + c];
                        sum += d * d;
                        grad[q + c] += 2.0 * k * d;
                        grad[q + stride[a] + c] -= 2.0 * k * d;
                    }
                }
            }
        }
    }
    k * sum
}

/// `g` resampled on a grid of side `n` over the same box (trilinear at the
/// new nodes; 1 or 3 channels).
pub fn upsample(g: &GridDesc, n: usize) -> GridDesc {
    let src = Grid::<f64>::from_desc(g);
    let mut out = GridDesc::filled([n; 3], &vec![0.0; g.ch], g.bmin, g.bmax, g.oob);
    let node = |a: usize, i: usize| g.bmin[a] + i as f64 * (g.bmax[a] - g.bmin[a]) / (n - 1) as f64;
    for k in 0..n {
        for j in 0..n {
            for i in 0..n {
                let x = [node(0, i), node(1, j), node(2, k)];
                let q = ((k * n + j) * n + i) * g.ch;
                if g.ch == 1 {
                    out.data[q] = src.trilinear::<1>(x)[0];
                } else {
                    out.data[q..q + 3].copy_from_slice(&src.trilinear::<3>(x));
                }
            }
        }
    }
    out
}

/// The fitted model's parameters and their Adam states.
struct State {
    p: VolumeParams,
    adam_s: Adam,
    adam_c: Adam,
}

impl State {
    /// Stage `s` of the fit: the dense grids at that stage's side (from
    /// `prev`'s, upsampled, or the initial constants), or the hash field.
    fn new(cfg: &FitConfig, s: u32, prev: Option<VolumeParams>) -> State {
        let (b0, b1) = ([-1.0; 3], [1.0; 3]);
        let p = match (cfg.model, prev) {
            (Model::Dense { n }, prev) => {
                let side = (n >> (cfg.stages.max(1) - 1 - s)).max(2);
                let (sg, cg) = match prev {
                    Some(VolumeParams {
                        field: FieldDesc::Grid(sg),
                        color: ColorDesc::Grid(cg),
                        ..
                    }) => (upsample(&sg, side), upsample(&cg, side)),
                    _ => (
                        GridDesc::filled([side; 3], &[0.5], b0, b1, Oob::Zero),
                        GridDesc::filled([side; 3], &[0.5; 3], b0, b1, Oob::Zero),
                    ),
                };
                params(FieldDesc::Grid(sg), ColorDesc::Grid(cg), cfg.dt)
            }
            (Model::Hash(h), _) => params(
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
        let (adam_s, adam_c) = match &p.field {
            FieldDesc::Grid(g) => (
                Adam::new(g.data.len(), cfg.lr_sigma),
                Adam::new(3 * g.data.len(), cfg.lr_color),
            ),
            FieldDesc::HashMlp(h) => (Adam::new(h.param_count(), cfg.lr_hash), Adam::new(0, 0.0)),
            FieldDesc::Analytic(_) => (Adam::new(0, 0.0), Adam::new(0, 0.0)),
        };
        State { p, adam_s, adam_c }
    }

    /// One Adam step at rate factor `decay`: image gradients `gs`
    /// (density or hash parameters) and `gc` (colour), plus the smoothness
    /// prior's on dense grids; returns the prior's value.
    fn step(&mut self, cfg: &FitConfig, decay: f64, mut gs: Vec<f64>, mut gc: Vec<f64>) -> f64 {
        match (&mut self.p.field, &mut self.p.color) {
            (FieldDesc::Grid(s), ColorDesc::Grid(c)) => {
                let prior =
                    smoothness(s, cfg.tv_sigma, &mut gs) + smoothness(c, cfg.tv_color, &mut gc);
                self.adam_s.lr = cfg.lr_sigma * decay;
                self.adam_c.lr = cfg.lr_color * decay;
                self.adam_s.step(&mut s.data, &gs);
                self.adam_c.step(&mut c.data, &gc);
                s.data.iter_mut().for_each(|v| *v = v.max(0.0));
                c.data.iter_mut().for_each(|v| *v = v.clamp(0.0, 1.0));
                prior
            }
            (FieldDesc::HashMlp(h), _) => {
                let mut flat = h.flat();
                self.adam_s.lr = cfg.lr_hash * decay;
                self.adam_s.step(&mut flat, &gs);
                h.set_flat(&flat);
                0.0
            }
            _ => 0.0,
        }
    }
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
    let held_psnr = |p: &VolumeParams| -> Result<Vec<f64>> {
        held.iter()
            .zip(&held_t)
            .map(|(cam, tgt)| Ok(psnr(mse(&rgb_of(p, cam, &gen, budget)?, tgt))))
            .collect()
    };
    let psnr_held_nodes = match cfg.model {
        Model::Dense { n } => {
            let (s, c) = target(n);
            let v = held_psnr(&params(FieldDesc::Grid(s), ColorDesc::Grid(c), cfg.dt))?;
            v.iter().sum::<f64>() / v.len() as f64
        }
        Model::Hash(_) => f64::NAN,
    };
    let npix = (cfg.side * cfg.side) as usize;
    let opt = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let stages = match cfg.model {
        Model::Dense { .. } => cfg.stages.max(1),
        Model::Hash(_) => 1,
    };
    let mut loss = Vec::with_capacity(cfg.iters as usize);
    let mut st = State::new(cfg, 0, None);
    for s in 0..stages {
        if s > 0 {
            st = State::new(cfg, s, Some(st.p));
        }
        let iters = cfg.iters * (s + 1) / stages - cfg.iters * s / stages;
        for _ in 0..iters {
            let (mut gs, mut gc) = (vec![0.0; st.adam_s.len()], vec![0.0; st.adam_c.len()]);
            let mut l = 0.0;
            // One f32 medium per iteration, shared by every view's forward
            // and backward.
            let prep = prepare::<f32>(&st.p, &gen.aabb, budget)?;
            for (cam, tgt) in train.iter().zip(&targets) {
                let rgb = render_prepared(cam, &gen, &prep, Chain::Fused, Compose::Sorted, budget)?
                    .image
                    .rgb;
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
                let g = f_diff_prepared(cam, &gen, &st.p, &prep, &up, &opt, None, budget, Lanes)?;
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
            let decay = cfg
                .lr_final
                .powf(loss.len() as f64 / cfg.iters.max(1) as f64);
            tracing::info!(
                iter = loss.len(),
                loss = l,
                elapsed_s = t_start.elapsed().as_secs_f64(),
                "fit"
            );
            loss.push(l);
            st.step(cfg, decay, gs, gc);
        }
    }
    let mut tr = 0.0;
    for (cam, tgt) in train.iter().zip(&targets) {
        tr += mse(&rgb_of(&st.p, cam, &gen, budget)?, tgt) / train.len() as f64;
    }
    Ok(FitReport {
        loss,
        psnr_train: psnr(tr),
        psnr_held: held_psnr(&st.p)?,
        psnr_held_nodes,
        time_s: t_start.elapsed().as_secs_f64(),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn grid(n: usize, ch: usize) -> GridDesc {
        let mut g = GridDesc::filled([n; 3], &vec![0.0; ch], [-1.0; 3], [1.0; 3], Oob::Zero);
        for (i, v) in g.data.iter_mut().enumerate() {
            *v = ((i * 7919) % 97) as f64 / 97.0;
        }
        g
    }

    #[test]
    fn smoothness_gradient_matches_central_differences() {
        let g = grid(4, 3);
        let mut an = vec![0.0; g.data.len()];
        smoothness(&g, 0.7, &mut an);
        for q in [0, 5, 31, 100, 191] {
            let mut d = [0.0; 2];
            for (s, h) in [(0, 1e-6), (1, -1e-6)] {
                let mut g2 = g.clone();
                g2.data[q] += h;
                d[s] = smoothness(&g2, 0.7, &mut vec![0.0; g.data.len()]);
            }
            let fd = (d[0] - d[1]) / 2e-6;
            assert!((fd - an[q]).abs() < 1e-7, "node {q}: fd {fd} vs {}", an[q]);
        }
    }

    #[test]
    fn smoothness_of_a_constant_grid_is_zero_and_of_a_step_is_its_share_of_pairs() {
        let c = GridDesc::filled([3; 3], &[2.0], [-1.0; 3], [1.0; 3], Oob::Zero);
        assert_eq!(smoothness(&c, 1.0, &mut [0.0; 27]), 0.0);
        // One node raised by 1: it has 3 neighbours (a corner), 54 pairs.
        let mut s = c.clone();
        s.data[0] = 3.0;
        assert!((smoothness(&s, 1.0, &mut [0.0; 27]) - 3.0 / 54.0).abs() < 1e-15);
    }

    #[test]
    fn upsample_keeps_a_linear_field_and_the_shared_nodes() {
        let lin = |x: [f64; 3]| 1.0 + 0.5 * x[0] - 0.25 * x[1] + 2.0 * x[2];
        let g = GridDesc::sample([5; 3], [-1.0; 3], [1.0; 3], Oob::Zero, lin);
        let u = upsample(&g, 9);
        let want = GridDesc::sample([9; 3], [-1.0; 3], [1.0; 3], Oob::Zero, lin);
        for (a, b) in u.data.iter().zip(&want.data) {
            assert!((a - b).abs() < 1e-12, "{a} vs {b}");
        }
        let c = upsample(&grid(5, 3), 9);
        assert_eq!(c.data[..3], grid(5, 3).data[..3]);
    }
}
