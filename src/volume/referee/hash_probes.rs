//! Where the hash-field cases probe, and the referee's side of them: seeded
//! points (uniform in the box grown 10%, and every 4th a lattice node of
//! level `q mod L` unless `nodes` is false: the encoding has a kink there),
//! upstream weights `g = rand(seed, point, 1, ch) - 0.5`, parameter probes
//! (table entries of corners in the middle half of level `q mod L` with
//! feature `q mod F` by `rand(seed, q, 2, axis)`; network parameters
//! uniform over the weights and biases by `rand(seed, q, 3, 0)`), the
//! referee's encoding with its hash collisions, and central differences of
//! the referee and of the f64 forward render. Uses `hash.rs` and
//! `finite_diff.rs` beside it and the field's description, never
//! `field::hash`'s code.

use std::collections::{BTreeMap, BTreeSet};

use super::finite_diff::{central, fd_loss};
use super::hash::{encode, entry, query, resolution};
use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::RayGen;
use crate::rng::rand_f64;
use crate::tensor::{Outputs, Tensor};
use crate::volume::field::hash::HashMlpDesc;
use crate::volume::field::FieldDesc;
use crate::volume::loss::LossWeights;
use crate::volume::VolumeParams;

/// `n` probe points of `d`'s box (module doc).
pub fn points(d: &HashMlpDesc, n: u32, seed: u32, nodes: bool) -> Vec<[f64; 3]> {
    let ext = [0usize, 1, 2].map(|a| d.bmax[a] - d.bmin[a]);
    (0..n)
        .map(|q| {
            if nodes && q % 4 == 3 {
                // A lattice node of level q mod L (weight 1 on one corner).
                let nl = resolution(d, q as usize % d.cfg.levels);
                [0usize, 1, 2].map(|a| {
                    let i = (rand_f64(seed, q, 0, a as u32) * (nl + 1) as f64)
                        .floor()
                        .min(nl as f64);
                    d.bmin[a] + ext[a] * i / nl as f64
                })
            } else {
                [0usize, 1, 2]
                    .map(|a| d.bmin[a] + ext[a] * (rand_f64(seed, q, 0, a as u32) * 1.2 - 0.1))
            }
        })
        .collect()
}

/// Upstream `g` of point `q`.
pub fn point_g(seed: u32, q: u32) -> [f64; 4] {
    [0, 1, 2, 3].map(|c| rand_f64(seed, q, 1, c) - 0.5)
}

/// `params.probes` of the hash gradient cases: `table` table probes and
/// `mlp` network probes (default 12 each), drawn with `seed`.
#[derive(Clone, Copy, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeCounts {
    pub table: u32,
    pub mlp: u32,
    #[serde(default)]
    pub seed: u32,
}

impl Default for ProbeCounts {
    fn default() -> Self {
        ProbeCounts {
            table: 12,
            mlp: 12,
            seed: 0,
        }
    }
}

/// Flat parameter indices of `table` table probes and `mlp` network probes.
pub fn probe_indices(d: &HashMlpDesc, table: u32, mlp: u32, seed: u32) -> Vec<usize> {
    let (nl, nf, t) = (d.cfg.levels, d.cfg.features, d.cfg.table_size());
    let mut v = Vec::new();
    for q in 0..table {
        let l = q as usize % nl;
        let n = resolution(d, l) as f64;
        let c = [0, 1, 2].map(|a| (n * (0.25 + 0.5 * rand_f64(seed, q, 2, a))).round() as u64);
        let e = entry(d, l, c[0], c[1], c[2]) as usize;
        v.push((l * t + e) * nf + q as usize % nf);
    }
    let (t0, np) = (d.table.len(), d.param_count());
    for q in 0..mlp {
        v.push(t0 + ((rand_f64(seed, q, 3, 0) * (np - t0) as f64) as usize).min(np - t0 - 1));
    }
    v
}

/// The referee's enc (n, L F), sigma, rgb at `pts`, and `collisions`: the
/// distinct corners sharing an entry of a hashed level, among the probed
/// corners.
pub fn encode_outputs(d: &HashMlpDesc, pts: &[[f64; 3]]) -> Result<Outputs> {
    let w = d.cfg.width();
    let (mut enc, mut sig, mut rgb) = (vec![], vec![], vec![]);
    let mut seen = BTreeMap::<(usize, u64), BTreeSet<[u64; 3]>>::new();
    for x in pts {
        enc.extend(encode(d, *x));
        let (s, c) = query(d, *x);
        sig.push(s);
        rgb.push(c);
        for l in 0..d.cfg.levels {
            let n = resolution(d, l);
            if (n + 1).pow(3) <= 1 << d.cfg.log2_table {
                continue;
            }
            let b = [0, 1, 2].map(|a| {
                let p = ((x[a] - d.bmin[a]) / (d.bmax[a] - d.bmin[a])).clamp(0.0, 1.0);
                ((p * n as f64).floor() as u64).min(n - 1)
            });
            for c in 0..8u64 {
                let v = [b[0] + (c & 1), b[1] + (c >> 1 & 1), b[2] + (c >> 2 & 1)];
                seen.entry((l, entry(d, l, v[0], v[1], v[2])))
                    .or_default()
                    .insert(v);
            }
        }
    }
    let collisions: usize = seen.values().map(|s| s.len() - 1).sum();
    let mut out = Outputs::default();
    out.tensor("enc", Tensor::real(&[pts.len(), w], enc)?);
    out.tensor("sigma", Tensor::real(&[pts.len()], sig)?);
    out.tensor("rgb", Tensor::real3(&[pts.len()], &rgb)?);
    out.tensor("collisions", Tensor::scalar(collisions as f64));
    out.counter("collisions", collisions as u64);
    Ok(out)
}

/// `g . (sigma, rgb)` per point by the referee.
fn point_losses(d: &HashMlpDesc, pts: &[[f64; 3]], seed: u32) -> Vec<f64> {
    pts.iter()
        .enumerate()
        .map(|(q, x)| {
            let g = point_g(seed, q as u32);
            let (s, c) = query(d, *x);
            g[0] * s + g[1] * c[0] + g[2] * c[1] + g[3] * c[2]
        })
        .collect()
}

/// dparams (every parameter) and dx of `sum_points g . (sigma, rgb)` by
/// central differences of the referee (h = 1e-6).
pub fn mlp_grad_fd(d: &HashMlpDesc, pts: &[[f64; 3]], seed: u32) -> Result<Outputs> {
    let h = 1e-6;
    let p0 = d.flat();
    let dp: Vec<f64> = crate::parallel::par_collect("hash_mlp_fd", p0.len(), |i| {
        let mut e = d.clone();
        let mut p = p0.clone();
        p[i] += h;
        e.set_flat(&p);
        let lp = point_losses(&e, pts, seed);
        p[i] -= 2.0 * h;
        e.set_flat(&p);
        let lm = point_losses(&e, pts, seed);
        central(&lp, &lm, h)
    });
    let mut dx = Vec::with_capacity(pts.len());
    for (q, x) in pts.iter().enumerate() {
        let g = point_g(seed, q as u32);
        let f = |y: [f64; 3]| {
            let (s, c) = query(d, y);
            g[0] * s + g[1] * c[0] + g[2] * c[1] + g[3] * c[2]
        };
        dx.push([0, 1, 2].map(|a| {
            let (mut xp, mut xm) = (*x, *x);
            xp[a] += h;
            xm[a] -= h;
            (f(xp) - f(xm)) / (2.0 * h)
        }));
    }
    let mut out = Outputs::default();
    out.tensor("dparams", Tensor::real(&[dp.len()], dp)?);
    out.tensor("dx", Tensor::real3(&[pts.len()], &dx)?);
    Ok(out)
}

/// Central differences (step `h`) of the f64 fused render loss `w` at the
/// flat parameters `idx` of the hash field `d` in scene `p`.
pub fn render_grad_fd(
    (cam, gen, p): (&Camera, &RayGen, &VolumeParams),
    d: &HashMlpDesc,
    w: &LossWeights,
    idx: &[usize],
    h: f64,
    budget: &MemBudget,
) -> Result<Vec<f64>> {
    let p0 = d.flat();
    let mut v = Vec::with_capacity(idx.len());
    for &i in idx {
        let with = |delta: f64| -> Result<Vec<f64>> {
            let mut e = d.clone();
            let mut q = p0.clone();
            q[i] += delta;
            e.set_flat(&q);
            let field = FieldDesc::HashMlp(Box::new(e));
            fd_loss(cam, gen, &VolumeParams { field, ..p.clone() }, w, budget)
        };
        v.push(central(&with(h)?, &with(-h)?, h));
    }
    Ok(v)
}
