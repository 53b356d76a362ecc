//! Operations of the ray stage (`f_ray`) and its references.
//!
//! | op | what |
//! | --- | --- |
//! | `rays.generate` | camera rays of a `renderer: rays` scene: o, d, t0, t1, hit, pixel |
//! | `rays.clip_reference` | the same rays' t0/t1 by an independent f64 closed form |
//! | `rays.clip_list` | t0/t1/hit for rays listed in `params.rays` |
//! | `rays.clip_list_reference` | the f64 closed form for the listed rays |
//! | `rays.jitter_offsets` | the jittered pixel offsets of every pixel (for KS tests) |
//! | `rays.rng_table` | `rand_u32` / `rand_f32` over a grid of keys |
//! | `rays.expm1_table` | `expm1` of `params.xs` (f32 on cpu and gpu, f64 on cpu f64): the alpha kernel |
//! | `const` | tensors written out in `params.tensors` (hand-made expectations) |

use std::time::Instant;

use serde::Deserialize;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::referee::{clip_list_reference, clip_reference};
use crate::rays::{clip_aabb, f_ray, Aabb, RayGen, Rays};
use crate::real::{Precision, Real};
use crate::rng::{rand_f32, rand_f64, rand_u32};
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "rays.generate",
        doc: "f_ray on a rays scene: o, d, t0, t1, hit, pixel; metric mrays_per_s",
        params: &[],
        support: Support::CpuGpuF32,
        run: generate,
    },
    OpEntry {
        name: "rays.render",
        doc: "hpjudge render of a rays scene (same as rays.generate)",
        params: &[],
        support: Support::CpuGpuF32,
        run: generate,
    },
    OpEntry {
        name: "rays.clip_reference",
        doc: "independent f64 rays and box entry/exit by face intersection",
        params: &[],
        support: Support::Any,
        run: clip_reference_op,
    },
    OpEntry {
        name: "rays.clip_list",
        doc: "clip the rays in params.rays ([ox,oy,oz,dx,dy,dz] each) to params.aabb",
        params: &["rays", "aabb", "near", "far"],
        support: Support::Cpu,
        run: clip_list,
    },
    OpEntry {
        name: "rays.clip_list_reference",
        doc: "independent f64 face-intersection clip of params.rays",
        params: &["rays", "aabb", "near", "far"],
        support: Support::Any,
        run: clip_list_reference_op,
    },
    OpEntry {
        name: "rays.jitter_offsets",
        doc: "jittered pixel offsets (x and y in [0,1)) of a rays scene with jitter",
        params: &[],
        support: Support::Cpu,
        run: jitter_offsets,
    },
    OpEntry {
        name: "rays.rng_table",
        doc: "rand_u32 and rand_f32 for seeds x pixels x samples x dims in params",
        params: &["seeds", "pixels", "samples", "dims"],
        support: Support::CpuGpuF32,
        run: rng_table,
    },
    OpEntry {
        name: "rays.expm1_table",
        doc: "expm1(x) for x in params.xs: CPU f32/f64 libm, GPU common.wgsl expm1_f32",
        params: &["xs"],
        support: Support::CpuGpuF32,
        run: expm1_table,
    },
    OpEntry {
        name: "const",
        doc: "tensors given literally in params.tensors: {name: {dtype, shape, data}}",
        params: &["tensors"],
        support: Support::Any,
        run: constant,
    },
];

fn view(ctx: &OpCtx) -> Result<(Camera, RayGen)> {
    let doc = ctx.scene()?;
    crate::scene::rays::parse(doc)?.build()
}

fn image_shape(gen: &RayGen) -> [usize; 2] {
    let r = gen.region();
    [r.height as usize, r.width as usize]
}

fn rays_outputs<F: Real>(r: &Rays<F>, shape: &[usize], out: &mut Outputs) -> Result<()> {
    out.tensor("o", Tensor::real3(shape, &r.o)?);
    out.tensor("d", Tensor::real3(shape, &r.d)?);
    out.tensor("t0", Tensor::real(shape, r.t0.clone())?);
    out.tensor("t1", Tensor::real(shape, r.t1.clone())?);
    let hit: Vec<u8> = (0..r.len()).map(|i| r.hits(i) as u8).collect();
    let hits = hit.iter().filter(|&&h| h == 1).count() as u64;
    out.tensor("hit", Tensor::from_shape_vec(shape, hit)?);
    let pixel: Vec<i32> = r.pixel.iter().map(|&p| p as i32).collect();
    out.tensor("pixel", Tensor::from_shape_vec(shape, pixel)?);
    out.counter("rays", r.len() as u64).counter("hits", hits);
    Ok(())
}

/// Camera rays of the scene, or (with `render --rays`) the replayed rays
/// clipped to the scene's box and interval; with the output shape.
fn rays_in<F: Real>(ctx: &OpCtx, cam: &Camera, gen: &RayGen) -> Result<(Rays<F>, Vec<usize>)> {
    match ctx.rays {
        None => Ok((
            f_ray::<F>(cam, gen, &ctx.budget)?,
            image_shape(gen).to_vec(),
        )),
        Some(t) => {
            let mut r = Rays::<F>::from_tensor(t, "--rays")?;
            let (bmin, bmax) = (gen.aabb.min.map(F::of), gen.aabb.max.map(F::of));
            let (near, far) = (F::of(gen.near), F::of(gen.far));
            for i in 0..r.len() {
                (r.t0[i], r.t1[i]) = clip_aabb(r.o[i], r.d[i], bmin, bmax, near, far);
            }
            let n = r.len();
            Ok((r, vec![n]))
        }
    }
}

fn generate_in<F: Real>(ctx: &OpCtx, out: &mut Outputs) -> Result<()> {
    let (cam, gen) = view(ctx)?;
    let t = Instant::now();
    let (r, shape) = rays_in::<F>(ctx, &cam, &gen)?;
    let s = t.elapsed().as_secs_f64();
    out.metric("time_s", s)
        .metric("mrays_per_s", r.len() as f64 / s / 1e6);
    if ctx.dump {
        out.tensor("rays", r.to_tensor()?);
    }
    rays_outputs(&r, &shape, out)
}

/// The GPU context for a `gpu` run; the GPU computes in f32 only.
fn gpu_f32(ctx: &OpCtx) -> Result<&'static crate::gpu::GpuContext> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU computes in f32 only",
            ctx.case_id
        )));
    }
    crate::gpu::GpuContext::get()
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
        let (r, s) = crate::gpu::rays::f_ray(gpu_f32(ctx)?, &cam, &gen, &ctx.budget)?;
        out.metric("time_s", s)
            .metric("mrays_per_s", r.len() as f64 / s / 1e6);
        rays_outputs(&r, &image_shape(&gen), &mut out)?;
        return Ok(out);
    }
    by_precision!(ctx, generate_in(ctx, &mut out))?;
    Ok(out)
}

/// Independent f64 rays and box entry/exit: `rays::referee`.
fn clip_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (cam, gen) = view(ctx)?;
    clip_reference(&cam, &gen).to_outputs(&image_shape(&gen))
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct BoxParam {
    min: [f64; 3],
    max: [f64; 3],
}

fn listed(ctx: &OpCtx) -> Result<(Vec<[f64; 6]>, Aabb, f64, f64)> {
    let rays: Vec<[f64; 6]> = ctx.param_req("rays")?;
    let b = ctx.param::<BoxParam>("aabb")?.map_or(Aabb::UNIT, |b| Aabb {
        min: b.min,
        max: b.max,
    });
    b.validate()?;
    let near = ctx.param_or("near", 0.0)?;
    let far = ctx.param_or("far", f64::INFINITY)?;
    for (i, r) in rays.iter().enumerate() {
        let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
        if r.iter().any(|x| !x.is_finite()) || n == 0.0 {
            return Err(Error::invalid(
                format!("{} params.rays[{i}]", ctx.case_id),
                "needs finite numbers and d != 0",
            ));
        }
    }
    Ok((rays, b, near, far))
}

fn unit(r: &[f64; 6]) -> ([f64; 3], [f64; 3]) {
    let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
    ([r[0], r[1], r[2]], [r[3] / n, r[4] / n, r[5] / n])
}

fn clip_list_in<F: Real>(rays: &[[f64; 6]], b: &Aabb, near: f64, far: f64) -> Result<Outputs> {
    let (mut t0, mut t1, mut hit) = (vec![], vec![], vec![]);
    for r in rays {
        let (o, d) = unit(r);
        let (a, c) = clip_aabb(
            o.map(F::of),
            d.map(F::of),
            b.min.map(F::of),
            b.max.map(F::of),
            F::of(near),
            F::of(far),
        );
        t0.push(a);
        t1.push(c);
        hit.push((c > a) as u8);
    }
    let n = [rays.len()];
    let mut out = Outputs::default();
    out.tensor("t0", Tensor::real(&n, t0)?)
        .tensor("t1", Tensor::real(&n, t1)?);
    out.tensor("hit", Tensor::from_shape_vec(&n, hit)?);
    Ok(out)
}

fn clip_list(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, b, near, far) = listed(ctx)?;
    by_precision!(ctx, clip_list_in(&rays, &b, near, far))
}

fn clip_list_reference_op(ctx: &OpCtx) -> Result<Outputs> {
    let (rays, b, near, far) = listed(ctx)?;
    let (t0, t1, hit) = clip_list_reference(&rays, &b, near, far);
    let n = [rays.len()];
    let mut out = Outputs::default();
    out.tensor("t0", Tensor::real(&n, t0)?)
        .tensor("t1", Tensor::real(&n, t1)?);
    out.tensor("hit", Tensor::from_shape_vec(&n, hit)?);
    Ok(out)
}

fn jitter_offsets(ctx: &OpCtx) -> Result<Outputs> {
    let (_, gen) = view(ctx)?;
    let at = ctx.scene()?.at();
    let j = gen
        .jitter
        .ok_or_else(|| Error::invalid(at, "this operation needs `jitter:`"))?;
    let roi = gen.region();
    let n = roi.width as usize * roi.height as usize;
    let (mut x, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
    for i in 0..n as u32 {
        let pixel = (roi.y + i / roi.width) * gen.width + roi.x + i % roi.width;
        x.push(rand_f64(j.seed, pixel, j.sample, 0));
        y.push(rand_f64(j.seed, pixel, j.sample, 1));
    }
    let mut out = Outputs::default();
    out.tensor("jitter_x", Tensor::real(&[n], x)?)
        .tensor("jitter_y", Tensor::real(&[n], y)?);
    Ok(out)
}

fn rng_table(ctx: &OpCtx) -> Result<Outputs> {
    let seeds: Vec<u32> = ctx.param_req("seeds")?;
    let pixels: Vec<u32> = ctx.param_req("pixels")?;
    let samples: Vec<u32> = ctx.param_req("samples")?;
    let dims: Vec<u32> = ctx.param_req("dims")?;
    let shape = [seeds.len(), pixels.len(), samples.len(), dims.len()];
    let mut keys = vec![];
    for &s in &seeds {
        for &p in &pixels {
            for &k in &samples {
                for &d in &dims {
                    keys.push([s, p, k, d]);
                }
            }
        }
    }
    let (words, floats) = match ctx.backend {
        BackendKind::Gpu => crate::gpu::math::rng_table(gpu_f32(ctx)?, &keys)?,
        BackendKind::Cpu => keys
            .iter()
            .map(|k| {
                (
                    rand_u32(k[0], k[1], k[2], k[3]),
                    rand_f32(k[0], k[1], k[2], k[3]),
                )
            })
            .unzip(),
    };
    let mut out = Outputs::default();
    out.tensor("words", Tensor::from_shape_vec(&shape, words)?);
    out.tensor("floats", Tensor::from_shape_vec(&shape, floats)?);
    Ok(out)
}

/// `expm1(x)` for every x of `params.xs` (finite numbers): on the CPU in
/// the case's precision (libm), on the GPU by `common.wgsl` `expm1_f32`.
/// Output `y`, same length.
fn expm1_table(ctx: &OpCtx) -> Result<Outputs> {
    let xs: Vec<f64> = ctx.param_req("xs")?;
    if xs.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid(
            format!("{} params.xs", ctx.case_id),
            "every x must be finite",
        ));
    }
    let n = [xs.len()];
    let mut out = Outputs::default();
    match (ctx.backend, ctx.precision) {
        (BackendKind::Gpu, _) => {
            let x32: Vec<f32> = xs.iter().map(|&x| x as f32).collect();
            out.tensor(
                "y",
                Tensor::real(&n, crate::gpu::math::expm1_table(gpu_f32(ctx)?, &x32)?)?,
            );
        }
        (BackendKind::Cpu, Precision::F32) => {
            out.tensor(
                "y",
                Tensor::real(
                    &n,
                    xs.iter()
                        .map(|&x| (x as f32).exp_m1())
                        .collect::<Vec<f32>>(),
                )?,
            );
        }
        (BackendKind::Cpu, Precision::F64) => {
            // The f64 referee evaluates at the f32-rounded argument, so the
            // comparison measures expm1's error, not the argument's rounding.
            out.tensor(
                "y",
                Tensor::real(
                    &n,
                    xs.iter()
                        .map(|&x| (x as f32 as f64).exp_m1())
                        .collect::<Vec<f64>>(),
                )?,
            );
        }
    }
    Ok(out)
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ConstTensor {
    dtype: String,
    #[serde(default)]
    shape: Option<Vec<usize>>,
    data: Vec<f64>,
}

fn constant(ctx: &OpCtx) -> Result<Outputs> {
    let tensors: std::collections::BTreeMap<String, ConstTensor> = ctx.param_req("tensors")?;
    let mut out = Outputs::default();
    for (name, c) in tensors {
        let shape = c.shape.clone().unwrap_or_else(|| vec![c.data.len()]);
        let at = format!("{} params.tensors.{name}", ctx.case_id);
        let t = match c.dtype.as_str() {
            "float32" => Tensor::from_shape_vec(&shape, c.data.iter().map(|&x| x as f32).collect()),
            "float64" => Tensor::from_shape_vec(&shape, c.data),
            "int32" => Tensor::from_shape_vec(&shape, c.data.iter().map(|&x| x as i32).collect()),
            "uint8" => Tensor::from_shape_vec(&shape, c.data.iter().map(|&x| x as u8).collect()),
            other => {
                return Err(Error::invalid(
                    at,
                    format!("dtype {other:?} is not float32, float64, int32 or uint8"),
                ))
            }
        }
        .map_err(|e| Error::invalid(at, e.to_string()))?;
        out.tensor(&name, t);
    }
    Ok(out)
}
