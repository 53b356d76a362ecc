//! Operations of the hash-grid + MLP field (issue 18) and its references.
//!
//! | op | what |
//! | --- | --- |
//! | `volume.hash_encode` / `_reference` | encoding, sigma and rgb at seeded points (uniform in the box grown 10%, and lattice nodes of every level): ours (`field/hash.rs`) vs the f64 referee (`volume/referee/hash.rs`); the referee also counts hash collisions among the probed corners |
//! | `volume.hash_mlp_grad` / `_fd` | `dL/dparams` (every parameter) and `dL/dx` of `L = sum_points g . (sigma, rgb)` (`g = rand(seed, point, 1, ch) - 0.5`): ours vs central differences of the referee (f64) |
//! | `volume.hash_grad` / `_fd` | render-loss gradient (`volume.grad`'s loss) at seeded parameter probes: `f_diff`'s `dhash` vs central differences of the f64 fused render |
//! | `volume.hash_refusals` | loads each scene of `params.scenes` and outputs `refused` = 1 where loading fails with a message containing `expect`; `accepted` = 1 for each scene of `params.good` that loads |
//!
//! Points: every 4th is a lattice node unless `params.nodes: false` (the
//! gradient cases: the encoding has a kink there).
//!
//! Probes (`params.probes: {table: n, mlp: n, seed: s}`): table entries of
//! corners in the middle half of level `q mod L` (where rays cross) with
//! feature `q mod F`, drawn by `rand(seed, q, 2, axis)`; network parameters
//! uniform over the weights and biases by `rand(seed, q, 3, 0)`.

use super::volume_diff::{loss_weights, upstream};
use super::{OpCtx, OpEntry, Support};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::real::{Precision, Real};
use crate::rng::rand_f64;
use crate::scene::SceneDoc;
use crate::tensor::{Outputs, Tensor};
use crate::volume::diff::{f_diff, DiffOptions, Reduce};
use crate::volume::field::hash::{HashMlp, HashMlpDesc, MAX_WIDTH};
use crate::volume::field::FieldDesc;
use crate::volume::referee::finite_diff::{central, fd_loss};
use crate::volume::referee::hash as referee;
use crate::volume::{Chain, VolumeParams};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "volume.hash_encode",
        doc: "hash-grid field at seeded points: enc (n, L F), sigma, rgb (ours)",
        params: &["points", "seed", "nodes"],
        support: Support::Cpu,
        run: op_encode,
    },
    OpEntry {
        name: "volume.hash_encode_reference",
        doc: "the same from the f64 referee (volume/referee/hash.rs), plus collisions among probed corners",
        params: &["points", "seed", "nodes"],
        support: Support::Cpu,
        run: op_encode_reference,
    },
    OpEntry {
        name: "volume.hash_mlp_grad",
        doc: "dparams (every parameter) and dx of sum_points g . (sigma, rgb), ours",
        params: &["points", "seed", "nodes"],
        support: Support::Cpu,
        run: op_mlp_grad,
    },
    OpEntry {
        name: "volume.hash_mlp_grad_fd",
        doc: "the same by central differences of the f64 referee",
        params: &["points", "seed", "nodes"],
        support: Support::Cpu,
        run: op_mlp_grad_fd,
    },
    OpEntry {
        name: "volume.hash_grad",
        doc: "f_diff dhash at seeded parameter probes (dhash_probe), all dhash, dcam; params chain, reduce",
        params: &["probes", "w_seed", "chain", "reduce"],
        support: Support::Cpu,
        run: op_grad,
    },
    OpEntry {
        name: "volume.hash_grad_fd",
        doc: "central differences of the f64 fused render loss at the same probes",
        params: &["probes", "w_seed", "chain", "reduce", "h"],
        support: Support::Cpu,
        run: op_grad_fd,
    },
    OpEntry {
        name: "volume.hash_refusals",
        doc: "refused[i] = 1 where loading params.scenes[i].scene fails with a message containing .expect; accepted[i] = 1 where params.good[i] loads",
        params: &["scenes", "good"],
        support: Support::Cpu,
        run: op_refusals,
    },
];

fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams, HashMlpDesc)> {
    let doc = ctx.scene()?;
    let (cam, gen, p) = crate::scene::volume::parse(doc)?.build(doc)?;
    let d = match &p.field {
        FieldDesc::HashMlp(h) => (**h).clone(),
        _ => {
            return Err(Error::invalid(
                ctx.case_id,
                "this operation needs a `field: {type: hash_mlp}` scene",
            ))
        }
    };
    Ok((cam, gen, p, d))
}

/// The probe points of a case (module doc).
fn points(ctx: &OpCtx, d: &HashMlpDesc) -> Result<Vec<[f64; 3]>> {
    let n: u32 = ctx.param_or("points", 256)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    let nodes: bool = ctx.param_or("nodes", true)?;
    if n == 0 || n > 1 << 16 {
        return Err(Error::invalid(
            format!("{} params.points", ctx.case_id),
            format!("{n} is not in 1..=65536"),
        ));
    }
    Ok((0..n)
        .map(|q| {
            let ext = [0usize, 1, 2].map(|a| d.bmax[a] - d.bmin[a]);
            if nodes && q % 4 == 3 {
                // A lattice node of level q mod L (weight 1 on one corner).
                let nl = referee::resolution(d, q as usize % d.cfg.levels);
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
        .collect())
}

fn encode_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (_, _, _, d) = load(ctx)?;
    let pts = points(ctx, &d)?;
    let m = HashMlp::<F>::from_desc(&d);
    let w = d.cfg.width();
    let (mut enc, mut sig, mut rgb) = (vec![], vec![], vec![]);
    for x in &pts {
        let x = x.map(F::of);
        let mut h = [F::zero(); MAX_WIDTH];
        m.encode(&m.corners(x), &mut h);
        enc.extend_from_slice(&h[..w]);
        let (s, c) = m.query(x);
        sig.push(s);
        rgb.push(c);
    }
    let mut out = Outputs::default();
    out.tensor("enc", Tensor::real(&[pts.len(), w], enc)?);
    out.tensor("sigma", Tensor::real(&[pts.len()], sig)?);
    out.tensor("rgb", Tensor::real3(&[pts.len()], &rgb)?);
    Ok(out)
}

fn op_encode(ctx: &OpCtx) -> Result<Outputs> {
    match ctx.precision {
        Precision::F32 => encode_in::<f32>(ctx),
        Precision::F64 => encode_in::<f64>(ctx),
    }
}

fn op_encode_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (_, _, _, d) = load(ctx)?;
    let pts = points(ctx, &d)?;
    let w = d.cfg.width();
    let (mut enc, mut sig, mut rgb) = (vec![], vec![], vec![]);
    // Distinct corners per (level, entry) on hashed levels.
    let mut seen =
        std::collections::BTreeMap::<(usize, u64), std::collections::BTreeSet<[u64; 3]>>::new();
    for x in &pts {
        enc.extend(referee::encode(&d, *x));
        let (s, c) = referee::query(&d, *x);
        sig.push(s);
        rgb.push(c);
        for l in 0..d.cfg.levels {
            let n = referee::resolution(&d, l);
            if (n + 1).pow(3) <= 1 << d.cfg.log2_table {
                continue;
            }
            let b = [0, 1, 2].map(|a| {
                let p = ((x[a] - d.bmin[a]) / (d.bmax[a] - d.bmin[a])).clamp(0.0, 1.0);
                ((p * n as f64).floor() as u64).min(n - 1)
            });
            for c in 0..8u64 {
                let v = [b[0] + (c & 1), b[1] + (c >> 1 & 1), b[2] + (c >> 2 & 1)];
                let e = referee::entry(&d, l, v[0], v[1], v[2]);
                seen.entry((l, e)).or_default().insert(v);
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

/// Upstream `g` of point `q`.
fn point_g(seed: u32, q: u32) -> [f64; 4] {
    [0, 1, 2, 3].map(|c| rand_f64(seed, q, 1, c) - 0.5)
}

fn mlp_grad_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (_, _, _, d) = load(ctx)?;
    let pts = points(ctx, &d)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    let m = HashMlp::<F>::from_desc(&d);
    let mut dp = vec![F::zero(); m.param_count()];
    let mut dx = Vec::with_capacity(pts.len());
    for (q, x) in pts.iter().enumerate() {
        let g = point_g(seed, q as u32).map(F::of);
        dx.push(m.backward(x.map(F::of), g, Some(&mut dp)));
    }
    let mut out = Outputs::default();
    out.tensor("dparams", Tensor::real(&[dp.len()], dp)?);
    out.tensor("dx", Tensor::real3(&[pts.len()], &dx)?);
    Ok(out)
}

fn op_mlp_grad(ctx: &OpCtx) -> Result<Outputs> {
    match ctx.precision {
        Precision::F32 => mlp_grad_in::<f32>(ctx),
        Precision::F64 => mlp_grad_in::<f64>(ctx),
    }
}

/// `sum_points g . (sigma, rgb)` by the referee, per point.
fn ref_loss(d: &HashMlpDesc, pts: &[[f64; 3]], seed: u32) -> Vec<f64> {
    pts.iter()
        .enumerate()
        .map(|(q, x)| {
            let g = point_g(seed, q as u32);
            let (s, c) = referee::query(d, *x);
            g[0] * s + g[1] * c[0] + g[2] * c[1] + g[3] * c[2]
        })
        .collect()
}

fn op_mlp_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (_, _, _, d) = load(ctx)?;
    let pts = points(ctx, &d)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    let h = 1e-6;
    let p0 = d.flat();
    let dp: Vec<f64> = crate::parallel::par_collect("hash_mlp_fd", p0.len(), |i| {
        let mut e = d.clone();
        let mut p = p0.clone();
        p[i] += h;
        e.set_flat(&p);
        let lp = ref_loss(&e, &pts, seed);
        p[i] -= 2.0 * h;
        e.set_flat(&p);
        let lm = ref_loss(&e, &pts, seed);
        central(&lp, &lm, h)
    });
    let mut dx = Vec::with_capacity(pts.len());
    for (q, x) in pts.iter().enumerate() {
        let g = point_g(seed, q as u32);
        let f = |y: [f64; 3]| {
            let (s, c) = referee::query(&d, y);
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

#[derive(Clone, Copy, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Probes {
    table: u32,
    mlp: u32,
    #[serde(default)]
    seed: u32,
}

/// Flat parameter indices of the probes (module doc).
fn probe_indices(ctx: &OpCtx, d: &HashMlpDesc) -> Result<Vec<usize>> {
    let p: Probes = ctx.param_or(
        "probes",
        Probes {
            table: 12,
            mlp: 12,
            seed: 0,
        },
    )?;
    let (nl, nf, t) = (d.cfg.levels, d.cfg.features, d.cfg.table_size());
    let mut v = Vec::new();
    for q in 0..p.table {
        let l = q as usize % nl;
        let n = referee::resolution(d, l) as f64;
        let c = [0, 1, 2].map(|a| (n * (0.25 + 0.5 * rand_f64(p.seed, q, 2, a))).round() as u64);
        let e = referee::entry(d, l, c[0], c[1], c[2]) as usize;
        v.push((l * t + e) * nf + q as usize % nf);
    }
    let (t0, np) = (d.table.len(), d.param_count());
    for q in 0..p.mlp {
        v.push(t0 + ((rand_f64(p.seed, q, 3, 0) * (np - t0) as f64) as usize).min(np - t0 - 1));
    }
    Ok(v)
}

fn diff_options(ctx: &OpCtx) -> Result<DiffOptions> {
    let chain = match ctx.param_or::<String>("chain", "fused".into())?.as_str() {
        "fused" => Chain::Fused,
        "unfused" => Chain::Unfused,
        o => {
            return Err(Error::invalid(
                format!("{} params.chain", ctx.case_id),
                format!("{o:?} is not fused or unfused"),
            ))
        }
    };
    let reduce = match ctx.param_or::<String>("reduce", "sorted".into())?.as_str() {
        "sorted" => Reduce::Sorted,
        "chunked" => Reduce::Chunked { chunks: 8 },
        o => {
            return Err(Error::invalid(
                format!("{} params.reduce", ctx.case_id),
                format!("{o:?} is not sorted or chunked"),
            ))
        }
    };
    Ok(DiffOptions {
        chain,
        reduce,
        per_sample: false,
    })
}

fn grad_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, d) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let idx = probe_indices(ctx, &d)?;
    let g = f_diff::<F>(
        &cam,
        &gen,
        &p,
        &upstream(&w),
        &diff_options(ctx)?,
        None,
        &ctx.budget,
    )?;
    let dh = g
        .dhash
        .ok_or_else(|| Error::invalid(ctx.case_id, "f_diff returned no dhash"))?;
    let mut out = Outputs::default();
    out.tensor(
        "dhash_probe",
        Tensor::real(&[idx.len()], idx.iter().map(|&i| dh[i]).collect())?,
    );
    out.tensor("dhash", Tensor::real(&[dh.len()], dh)?);
    out.tensor("dcam", Tensor::real(&[6], g.dcam.to_vec())?);
    out.metric("time_s", g.time_s);
    Ok(out)
}

fn op_grad(ctx: &OpCtx) -> Result<Outputs> {
    match ctx.precision {
        Precision::F32 => grad_in::<f32>(ctx),
        Precision::F64 => grad_in::<f64>(ctx),
    }
}

fn op_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, mut p, d) = load(ctx)?;
    p.early_stop = 0.0;
    p.occupancy = 0;
    let w = loss_weights(ctx, &gen)?;
    let idx = probe_indices(ctx, &d)?;
    let p0 = d.flat();
    let h: f64 = ctx.param_or("h", 1e-5)?;
    let mut v = Vec::with_capacity(idx.len());
    for &i in &idx {
        let with = |delta: f64| -> Result<Vec<f64>> {
            let mut e = d.clone();
            let mut q = p0.clone();
            q[i] += delta;
            e.set_flat(&q);
            let pp = VolumeParams {
                field: FieldDesc::HashMlp(Box::new(e)),
                ..p.clone()
            };
            fd_loss(&cam, &gen, &pp, &w, &ctx.budget)
        };
        v.push(central(&with(h)?, &with(-h)?, h));
    }
    let mut out = Outputs::default();
    out.tensor("dhash_probe", Tensor::real(&[v.len()], v)?);
    Ok(out)
}

#[derive(Clone, Debug, serde::Deserialize)]
#[serde(deny_unknown_fields)]
struct Refusal {
    scene: String,
    expect: String,
}

fn op_refusals(ctx: &OpCtx) -> Result<Outputs> {
    let list: Vec<Refusal> = ctx.param_req("scenes")?;
    let mut refused = Vec::with_capacity(list.len());
    for r in &list {
        let path = ctx.resolve(&r.scene);
        let res =
            SceneDoc::load(&path, &[]).and_then(|doc| crate::scene::volume::load(&doc).map(|_| ()));
        let ok = match res {
            Ok(()) => {
                eprintln!("{}: {} was accepted", ctx.case_id, path.display());
                false
            }
            Err(e) => {
                let m = e.to_string();
                eprintln!("{}: {} refused: {m}", ctx.case_id, path.display());
                m.contains(&r.expect)
            }
        };
        refused.push(ok as u8 as f64);
    }
    let good: Vec<String> = ctx.param_or("good", vec![])?;
    let mut accepted = Vec::with_capacity(good.len());
    for g in &good {
        let path = ctx.resolve(g);
        let res =
            SceneDoc::load(&path, &[]).and_then(|doc| crate::scene::volume::load(&doc).map(|_| ()));
        if let Err(e) = &res {
            eprintln!("{}: {} refused: {e}", ctx.case_id, path.display());
        }
        accepted.push(res.is_ok() as u8 as f64);
    }
    let mut out = Outputs::default();
    out.tensor("refused", Tensor::real(&[refused.len()], refused)?);
    out.tensor("accepted", Tensor::real(&[accepted.len()], accepted)?);
    Ok(out)
}
