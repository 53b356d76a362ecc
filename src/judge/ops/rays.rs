//! Operations of the ray stage (`f_ray`), its referee (`rays::referee`) and
//! two tables (the RNG, `expm1`); `const` gives hand-made expectations.
//! The template for a new op file: a table, then one short function per row.

use serde::Deserialize;

use super::{BackendKind, OpCtx};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu;
use crate::pathtrace::sampler::Sampler;
use crate::rays::referee::{clip_list_reference, clip_reference};
use crate::rays::{clip_list_in, clip_list_outputs, f_ray, Aabb, RayGen, Rays};
use crate::real::{Precision, Real};
use crate::rng::table_keys;
use crate::tensor::{ListedTensor, Outputs, Tensor};

ops! {
    "rays.generate" CpuGpuF32 generate [] "f_ray on a rays scene: o, d, t0, t1, hit, pixel; metric mrays_per_s";
    "rays.render" CpuGpuF32 generate [] "hpjudge render of a rays scene (same as rays.generate)";
    "rays.clip_reference" Any clip_reference_op [] "independent f64 rays and box entry/exit by face intersection";
    "rays.pinhole_reference" Any pinhole_reference_op [] "pinhole directions d from the scene's numbers alone";
    "rays.clip_list" Cpu clip_list_op ["rays", "aabb", "near", "far"]
        "clip the rays in params.rays ([ox,oy,oz,dx,dy,dz] each) to params.aabb";
    "rays.clip_list_reference" Any clip_list_reference_op ["rays", "aabb", "near", "far"]
        "independent f64 face-intersection clip of params.rays";
    "rays.jitter_offsets" Cpu jitter_offsets [] "jittered pixel offsets (x and y in [0,1)) of a rays scene with jitter";
    "rays.rng_table" CpuGpuF32 rng_table ["seeds", "pixels", "samples", "dims", "sampler"]
        "params.sampler's words and floats (default rand_u32, rand_f32) for seeds x pixels x samples x dims";
    "rays.expm1_table" CpuGpuF32 expm1_table ["xs"]
        "expm1(x) for x in params.xs: CPU f32/f64 libm, GPU common.wgsl expm1_f32";
    "const" Any constant ["tensors"] "tensors given literally in params.tensors: {name: {dtype, shape, data}}";
}

fn view(ctx: &OpCtx) -> Result<(Camera, RayGen)> {
    crate::scene::rays::parse(ctx.scene()?)?.build()
}

/// Camera rays (or, with `render --rays`, the replayed rays re-clipped to
/// the scene's box), timed: `time_s`, `mrays_per_s`, the ray outputs.
fn generate_in<F: Real>(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    let (cam, gen) = view(ctx)?;
    let t = std::time::Instant::now();
    let (r, shape) = match ctx.rays {
        None => (f_ray::<F>(&cam, &gen, &ctx.budget)?, gen.shape().to_vec()),
        Some(t) => {
            let mut r = Rays::<F>::from_tensor(t, "--rays")?;
            r.clip_to(&gen);
            let n = r.len();
            (r, vec![n])
        }
    };
    let s = t.elapsed().as_secs_f64();
    out.metric("time_s", s)
        .metric("mrays_per_s", r.len() as f64 / s / 1e6);
    if ctx.dump {
        out.tensor("rays", r.to_tensor()?);
    }
    r.to_outputs(&shape, out)
}

fn generate(ctx: &OpCtx) -> Result<Outputs> {
    let mut out = Outputs::default();
    if ctx.backend == BackendKind::Gpu {
        if ctx.rays.is_some() {
            return Err(Error::NotSupported(format!(
                "{}: replaying --rays runs on the CPU only",
                ctx.case_id
            )));
        }
        let (cam, gen) = view(ctx)?;
        let (r, s) = gpu::rays::f_ray(gpu::GpuContext::get()?, &cam, &gen, &ctx.budget)?;
        out.metric("time_s", s)
            .metric("mrays_per_s", r.len() as f64 / s / 1e6);
        r.to_outputs(&gen.shape(), &mut out)?;
        return Ok(out);
    }
    by_precision!(ctx, generate_in(ctx, &mut out))?;
    Ok(out)
}

fn pinhole_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    crate::rays::referee_pinhole::pinhole_reference(ctx.scene()?)
}

fn clip_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen) = view(ctx)?;
    clip_reference(&cam, &gen).to_outputs(&gen.shape())
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxParam {
    min: [f64; 3],
    max: [f64; 3],
}

/// `params.rays` (finite, d != 0), `params.aabb` (default the unit box), near, far.
fn listed(ctx: &OpCtx) -> Result<(Vec<[f64; 6]>, Aabb, f64, f64)> {
    let rays = ctx.listed_rays("rays")?;
    let b = ctx.param::<BoxParam>("aabb")?.map_or(Aabb::UNIT, |b| Aabb {
        min: b.min,
        max: b.max,
    });
    b.validate()?;
    Ok((
        rays,
        b,
        ctx.param_or("near", 0.0)?,
        ctx.param_or("far", f64::INFINITY)?,
    ))
}

fn clip_list_op(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, b, near, far) = listed(ctx)?;
    by_precision!(ctx, clip_list_in(&rays, &b, near, far))
}

fn clip_list_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, b, near, far) = listed(ctx)?;
    clip_list_outputs(clip_list_reference(&rays, &b, near, far))
}

fn jitter_offsets(ctx: &OpCtx) -> Result<Outputs> {
    let (_, gen) = view(ctx)?;
    let at = ctx.scene()?.at();
    let (x, y) = gen
        .jitter_offsets()
        .ok_or_else(|| Error::invalid(at, "this operation needs `jitter:`"))?;
    let mut out = Outputs::default();
    out.tensor("jitter_x", Tensor::real(&[x.len()], x)?)
        .tensor("jitter_y", Tensor::real(&[y.len()], y)?);
    Ok(out)
}

fn rng_table(ctx: &OpCtx) -> Result<Outputs> {
    let axes: Vec<Vec<u32>> = ["seeds", "pixels", "samples", "dims"]
        .iter()
        .map(|k| ctx.param_req(k))
        .collect::<Result<_>>()?;
    let shape = axes.iter().map(Vec::len).collect::<Vec<_>>();
    let keys = table_keys([&axes[0], &axes[1], &axes[2], &axes[3]]);
    let smp: Sampler = ctx.param_or("sampler", Sampler::Independent)?;
    let (words, floats) = match ctx.backend {
        BackendKind::Gpu => gpu::math::rng_table(gpu::GpuContext::get()?, &keys, smp.gpu_code())?,
        BackendKind::Cpu => smp.table(&keys),
    };
    let mut out = Outputs::default();
    out.tensor("words", Tensor::from_shape_vec(&shape, words)?)
        .tensor("floats", Tensor::from_shape_vec(&shape, floats)?);
    Ok(out)
}

/// `expm1(x)` of finite `params.xs` (f32-rounded): CPU libm in the case's
/// precision, GPU `common.wgsl` `expm1_f32`. Output `y`.
fn expm1_table(ctx: &OpCtx) -> Result<Outputs> {
    let xs: Vec<f64> = ctx.param_req("xs")?;
    if xs.iter().any(|x| !x.is_finite()) {
        return Err(ctx.bad("xs", "every x must be finite"));
    }
    let n = [xs.len()];
    let x32 = xs.iter().map(|&x| x as f32);
    let y = match (ctx.backend, ctx.precision) {
        (BackendKind::Gpu, _) => Tensor::real(
            &n,
            gpu::math::expm1_table(gpu::GpuContext::get()?, &x32.collect::<Vec<_>>())?,
        ),
        (BackendKind::Cpu, Precision::F32) => Tensor::real(&n, x32.map(f32::exp_m1).collect()),
        (BackendKind::Cpu, Precision::F64) => {
            Tensor::real(&n, x32.map(|x| (x as f64).exp_m1()).collect())
        }
    }?;
    let mut out = Outputs::default();
    out.tensor("y", y);
    Ok(out)
}

fn constant(ctx: &OpCtx) -> Result<Outputs> {
    let tensors: std::collections::BTreeMap<String, ListedTensor> = ctx.param_req("tensors")?;
    let mut out = Outputs::default();
    for (name, c) in tensors {
        let t = Tensor::from_listed(c).map_err(|e| ctx.bad(&format!("tensors.{name}"), e))?;
        out.tensor(&name, t);
    }
    Ok(out)
}
