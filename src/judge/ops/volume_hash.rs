//! Operations of the hash-grid + MLP field and its referee: ours
//! (`field/hash_outputs.rs`) against `volume/referee/hash_probes.rs`, which
//! also says where the cases probe (`params.points`, `seed`, `nodes`;
//! `params.probes: {table: n, mlp: n, seed: s}`).

use super::volume_diff::{loss_weights, options};
use super::{BackendKind, OpCtx};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::real::Real;
use crate::scene::SceneDoc;
use crate::tensor::{Outputs, Tensor};
use crate::volume::diff::{f_diff, Grads};
use crate::volume::field::hash::{HashMlp, HashMlpDesc};
use crate::volume::field::FieldDesc;
use crate::volume::grad_outputs::hash_outputs;
use crate::volume::hash_kinks::{smooth_outputs, KINK_MARGIN};
use crate::volume::referee::hash_probes as referee;
use crate::volume::VolumeParams;

ops! {
    "volume.hash_encode" Cpu op_encode ["points", "seed", "nodes"]
        "hash-grid field at seeded points: enc (n, L F), sigma, rgb (ours)";
    "volume.hash_encode_reference" Cpu op_encode_reference ["points", "seed", "nodes"]
        "the same from the f64 referee (volume/referee/hash.rs), plus collisions among probed corners";
    "volume.hash_mlp_grad" Cpu op_mlp_grad ["points", "seed", "nodes"]
        "dparams (every parameter) and dx of sum_points g . (sigma, rgb), ours";
    "volume.hash_mlp_grad_fd" Cpu op_mlp_grad_fd ["points", "seed", "nodes"]
        "the same by central differences of the f64 referee";
    "volume.hash_grad" CpuGpuF32 op_grad ["probes", "w_seed", "chain", "reduce", "kink_margin"]
        "f_diff dhash at seeded parameter probes (dhash_probe), all dhash, dcam; params chain, reduce; on the CPU also dhash_smooth (0 on table values a sample within params.kink_margin of a ReLU kink touches, on the kinked unit's fan-in and bias, and on every layer before it) and counters kink_samples, kink_params";
    "volume.hash_grad_fd" Cpu op_grad_fd ["probes", "w_seed", "chain", "reduce", "h"]
        "central differences of the f64 fused render loss at the same probes";
    "volume.hash_refusals" Cpu op_refusals ["scenes", "good"]
        "refused[i] = 1 where loading params.scenes[i].scene fails with a message containing .expect; accepted[i] = 1 where params.good[i] loads";
}

fn load(ctx: &OpCtx) -> Result<(Camera, RayGen, VolumeParams, HashMlpDesc)> {
    let doc = ctx.scene()?;
    let (cam, gen, p) = crate::scene::volume::parse(doc)?.build(doc)?;
    let FieldDesc::HashMlp(h) = &p.field else {
        return Err(Error::invalid(
            ctx.case_id,
            "this operation needs a `field: {type: hash_mlp}` scene",
        ));
    };
    let d = (**h).clone();
    Ok((cam, gen, p, d))
}

/// The field's description, the probe points and `params.seed`.
fn points(ctx: &OpCtx) -> Result<(HashMlpDesc, Vec<[f64; 3]>, u32)> {
    let d = load(ctx)?.3;
    let n: u32 = ctx.param_or("points", 256)?;
    let seed: u32 = ctx.param_or("seed", 1)?;
    if n == 0 || n > 1 << 16 {
        return Err(ctx.bad("points", format!("{n} is not in 1..=65536")));
    }
    let pts = referee::points(&d, n, seed, ctx.param_or("nodes", true)?);
    Ok((d, pts, seed))
}

fn encode_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (d, pts, _) = points(ctx)?;
    HashMlp::<F>::from_desc(&d).probe_outputs(&pts, d.cfg.width())
}

fn op_encode(ctx: &OpCtx) -> Result<Outputs> {
    by_precision!(ctx, encode_in(ctx))
}

fn op_encode_reference(ctx: &OpCtx) -> Result<Outputs> {
    let (d, pts, _) = points(ctx)?;
    referee::encode_outputs(&d, &pts)
}

fn mlp_grad_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (d, pts, seed) = points(ctx)?;
    HashMlp::<F>::from_desc(&d).grad_outputs(&pts, |q| referee::point_g(seed, q))
}

fn op_mlp_grad(ctx: &OpCtx) -> Result<Outputs> {
    by_precision!(ctx, mlp_grad_in(ctx))
}

fn op_mlp_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (d, pts, seed) = points(ctx)?;
    referee::mlp_grad_fd(&d, &pts, seed)
}

fn probe_indices(ctx: &OpCtx, d: &HashMlpDesc) -> Result<Vec<usize>> {
    let p: referee::ProbeCounts = ctx.param_or("probes", referee::ProbeCounts::default())?;
    Ok(referee::probe_indices(d, p.table, p.mlp, p.seed))
}

fn grad_in<F: Real>(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, p, d) = load(ctx)?;
    let w = loss_weights(ctx, &gen)?;
    let idx = probe_indices(ctx, &d)?;
    let g = f_diff::<F>(
        &cam,
        &gen,
        &p,
        &w.upstream(),
        &options(ctx)?,
        None,
        &ctx.budget,
    )?;
    let mut out = grad_tensors(g, &idx)?;
    let margin = ctx.param_or("kink_margin", KINK_MARGIN)?;
    smooth_outputs((&cam, &gen, &p), &d, margin, &ctx.budget, &mut out)?;
    Ok(out)
}

/// dhash_probe, dhash, dcam and time_s of a backward pass.
fn grad_tensors<F: Real>(g: Grads<F>, idx: &[usize]) -> Result<Outputs> {
    let mut out = Outputs::default();
    hash_outputs(g, idx, &mut out)?;
    Ok(out)
}

fn op_grad(ctx: &OpCtx) -> Result<Outputs> {
    if ctx.backend == BackendKind::Gpu {
        let g = super::volume_gpu_diff::grads(ctx)?;
        return grad_tensors(g, &probe_indices(ctx, &load(ctx)?.3)?);
    }
    by_precision!(ctx, grad_in(ctx))
}

fn op_grad_fd(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen, mut p, d) = load(ctx)?;
    p.early_stop = 0.0;
    p.occupancy = 0;
    let w = loss_weights(ctx, &gen)?;
    let idx = probe_indices(ctx, &d)?;
    let h: f64 = ctx.param_or("h", 1e-5)?;
    let v = referee::render_grad_fd((&cam, &gen, &p), &d, &w, &idx, h, &ctx.budget)?;
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

/// Loads the volume scene at `file` (relative to the manifest), logging the verdict.
fn loads(ctx: &OpCtx, file: &str) -> Result<()> {
    let path = ctx.resolve(file);
    let res =
        SceneDoc::load(&path, &[]).and_then(|doc| crate::scene::volume::load(&doc).map(|_| ()));
    match &res {
        Ok(()) => eprintln!("{}: {} was accepted", ctx.case_id, path.display()),
        Err(e) => eprintln!("{}: {} refused: {e}", ctx.case_id, path.display()),
    }
    res
}

fn op_refusals(ctx: &OpCtx) -> Result<Outputs> {
    let list: Vec<Refusal> = ctx.param_req("scenes")?;
    let refused: Vec<f64> = list
        .iter()
        .map(|r| {
            loads(ctx, &r.scene).map_or_else(|e| e.to_string().contains(&r.expect), |_| false) as u8
                as f64
        })
        .collect();
    let good: Vec<String> = ctx.param_or("good", vec![])?;
    let accepted: Vec<f64> = good
        .iter()
        .map(|g| loads(ctx, g).is_ok() as u8 as f64)
        .collect();
    let mut out = Outputs::default();
    out.tensor("refused", Tensor::real(&[refused.len()], refused)?);
    out.tensor("accepted", Tensor::real(&[accepted.len()], accepted)?);
    Ok(out)
}
