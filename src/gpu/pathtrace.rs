//! The path tracer on the GPU (`kernels/pathtrace.wgsl`, entry `pt_render`).
//! CPU twin: `src/pathtrace/integrator.rs` `render` (per path `trace`);
//! parity cases `pt_gpu_*` in `TESTS/pathtrace/manifest_gpu.yaml`.
//!
//! [`PathtracePipeline`] is built once per scene (pipeline from the kernel
//! registry, scene buffers uploaded once) and renders progressively: each
//! submit runs a few samples per pixel over a block of pixels and folds them
//! into a per-pixel running mean and M2 (Welford) kept on the GPU, so no
//! submit runs long (drivers kill long kernels) and only the final
//! accumulator is read back. Inputs are the kernel's own typed structs,
//! made by `src/pathtrace/gpu.rs`, so this module imports no renderer.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use super::rays::RayParams;
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::{Jitter, RayGen};

/// Shape kind codes (`SHAPE_*` in the kernel).
pub const SHAPE_SPHERE: u32 = 0;
pub const SHAPE_QUAD: u32 = 1;
/// Material kind codes (`MAT_*` in the kernel).
pub const MAT_LAMBERTIAN: u32 = 0;
pub const MAT_CONDUCTOR: u32 = 1;
pub const MAT_DIELECTRIC: u32 = 2;
pub const MAT_EMITTER: u32 = 3;

/// One shape (`struct PtShape` of the kernel, keep in sync; 112 bytes).
/// Sphere: `a = (centre, radius)`. Quad: `a = (corner, area)`, edges `u`,
/// `v`, unit normal `n`, dual edge vectors `ua`, `vb`, `axis` 0..2 when
/// the normal is `+-e_axis`, else 3.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PtShape {
    pub a: [f32; 4],
    pub u: [f32; 4],
    pub v: [f32; 4],
    pub n: [f32; 4],
    pub ua: [f32; 4],
    pub vb: [f32; 4],
    pub kind: u32,
    pub material: u32,
    pub axis: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<PtShape>() == 112);

/// One material (`struct PtMaterial`, keep in sync; 32 bytes): `c.rgb` is
/// the albedo, reflectance or radiance, `c.w` the GGX alpha or the IOR.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct PtMaterial {
    pub c: [f32; 4],
    pub kind: u32,
    pub _pad: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<PtMaterial>() == 32);

/// The kernel's uniform (`struct PtParams`, keep in sync; 208 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct PtParams {
    cam: RayParams,
    env: [f32; 4],
    seed: u32,
    max_bounces: u32,
    rr_depth: u32,
    n_shapes: u32,
    n_lights: u32,
    sample0: u32,
    samples: u32,
    pixel0: u32,
    pixels: u32,
    sampler: u32,
    /// Russian roulette's scale and cap ([`PtRender`]).
    rr_scale: f32,
    rr_cap: f32,
}
const _: () = assert!(std::mem::size_of::<PtParams>() == 208);

/// A scene in the kernel's terms.
#[derive(Clone, Copy, Debug)]
pub struct PtScene<'a> {
    pub shapes: &'a [PtShape],
    pub materials: &'a [PtMaterial],
    /// Indices into `shapes` of the emitting quads.
    pub lights: &'a [u32],
    pub environment: [f32; 3],
}

/// How to render: the fields of `pathtrace::RenderParams`.
#[derive(Clone, Copy, Debug)]
pub struct PtRender {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u32,
    pub max_bounces: u32,
    pub rr_depth: u32,
    /// `pathtrace::sampler::Sampler::gpu_code` (0 independent, 1 Sobol').
    pub sampler: u32,
    /// Russian roulette's survival `min(rr_scale max(beta eta^2), rr_cap)`
    /// (`pathtrace::integrator::survival`'s constants).
    pub rr_scale: f32,
    pub rr_cap: f32,
}

/// Per pixel (row-major): mean radiance, M2 (sum of squared deviations),
/// non-finite samples (counted as 0); the GPU seconds and the submits.
#[derive(Clone, Debug)]
pub struct PtOutput {
    pub mean: Vec<[f32; 3]>,
    pub m2: Vec<[f32; 3]>,
    pub nonfinite: u64,
    pub gpu_s: f64,
    pub submits: u32,
}

/// Samples per pixel and pixels per submit.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Chunks {
    pub samples: u32,
    pub pixels: u32,
}

/// Loop back-edges one path may take in `pt_render`: per vertex the
/// intersection loop and the shadow-ray loop over all shapes plus the
/// bounce loop itself, `max_bounces + 1` vertices; plus the sample loop
/// and `camera_ray`'s three-axis clip loop.
pub fn loop_iters_per_sample(n_shapes: u32, max_bounces: u32) -> u64 {
    (max_bounces as u64 + 1) * (2 * n_shapes as u64 + 1) + 4
}

/// Splits a render into submits of at most `paths_per_submit` paths: as
/// many samples per pixel as fit over all pixels (at least 1, at most
/// `spp`), and pixel blocks when one sample over all pixels is already
/// more. Where the driver caps loop iterations per invocation (`loop_cap`),
/// samples per submit stay under `cap / loop_iters_per_sample`; a path
/// that alone could exceed the cap is refused rather than cut short.
pub fn plan_chunks(
    pixels: u32,
    spp: u32,
    n_shapes: u32,
    max_bounces: u32,
    loop_cap: Option<u64>,
    paths_per_submit: u64,
) -> Result<Chunks> {
    let per = loop_iters_per_sample(n_shapes, max_bounces);
    let cap_samples = match loop_cap {
        Some(cap) if cap / per == 0 => {
            return Err(Error::NotSupported(format!(
                "a path of up to {} bounces over {n_shapes} shapes may take {per} loop iterations, \
                 over this driver's cap of {cap} per invocation (Mesa llvmpipe)",
                max_bounces
            )))
        }
        Some(cap) => cap / per,
        None => u64::MAX,
    };
    let px = pixels.max(1) as u64;
    let samples = (paths_per_submit / px)
        .min(cap_samples)
        .min(spp as u64)
        .max(1);
    let block = (paths_per_submit / samples).clamp(1, px);
    Ok(Chunks {
        samples: samples as u32,
        pixels: block as u32,
    })
}

/// Checks what the kernel assumes of a scene.
fn validate(s: &PtScene) -> Result<()> {
    let at = "gpu pathtrace scene";
    let n = s.shapes.len();
    if s.shapes
        .iter()
        .any(|x| x.material as usize >= s.materials.len())
    {
        return Err(Error::invalid(
            at,
            "a shape's material index is out of range",
        ));
    }
    for &l in s.lights {
        let ok = s.shapes.get(l as usize).is_some_and(|q| {
            q.kind == SHAPE_QUAD && s.materials[q.material as usize].kind == MAT_EMITTER
        });
        if !ok {
            return Err(Error::invalid(
                at,
                format!("light {l} is not an emitting quad of {n} shapes"),
            ));
        }
    }
    if u32::try_from(n).is_err() {
        return Err(Error::NotSupported(format!("{n} shapes")));
    }
    Ok(())
}

/// The `pt_render` pipeline and one scene's buffers, built once.
pub struct PathtracePipeline {
    pipeline: wgpu::ComputePipeline,
    shapes: wgpu::Buffer,
    materials: wgpu::Buffer,
    lights: wgpu::Buffer,
    params: wgpu::Buffer,
    n_shapes: u32,
    n_lights: u32,
    environment: [f32; 3],
}

impl PathtracePipeline {
    pub fn new(ctx: &GpuContext, scene: &PtScene) -> Result<PathtracePipeline> {
        validate(scene)?;
        let params = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("pt_render params"),
            size: std::mem::size_of::<PtParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        Ok(PathtracePipeline {
            pipeline: pipeline(ctx, "pathtrace", "pt_render")?,
            shapes: storage_in(ctx, "pt_render shapes", scene.shapes)?,
            materials: storage_in(ctx, "pt_render materials", scene.materials)?,
            lights: storage_in(ctx, "pt_render lights", scene.lights)?,
            params,
            n_shapes: scene.shapes.len() as u32,
            n_lights: scene.lights.len() as u32,
            environment: scene.environment,
        })
    }

    /// Renders `r` seen by `cam`, `paths_per_submit` paths per submit at
    /// most (see [`plan_chunks`]).
    pub fn render(
        &self,
        ctx: &GpuContext,
        cam: &Camera,
        r: &PtRender,
        paths_per_submit: u64,
        budget: &MemBudget,
    ) -> Result<PtOutput> {
        cam.validate()?;
        let gen = RayGen {
            jitter: Some(Jitter {
                seed: r.seed,
                sample: 0,
            }),
            ..RayGen::new(r.width, r.height)
        };
        gen.validate()?;
        if r.spp == 0 {
            return Err(Error::invalid("spp", "must be >= 1"));
        }
        let npix = r
            .width
            .checked_mul(r.height)
            .ok_or_else(|| Error::invalid("width/height", "more than 2^32 pixels"))?;
        // Accumulator (32 B a pixel), its readback, and the host image.
        budget.check("gpu pathtrace accumulator", bytes_for(npix as u64, 32 * 3))?;
        let chunks = plan_chunks(
            npix,
            r.spp,
            self.n_shapes,
            r.max_bounces,
            ctx.max_loop_iterations(),
            paths_per_submit,
        )?;
        let accum = storage_out(ctx, "pt_render accumulator", npix as u64 * 32)?;
        let e = self.environment;
        let mut p = PtParams {
            cam: RayParams::new(cam, &gen),
            env: [e[0], e[1], e[2], 0.0],
            seed: r.seed,
            max_bounces: r.max_bounces,
            rr_depth: r.rr_depth,
            n_shapes: self.n_shapes,
            n_lights: self.n_lights,
            sample0: 0,
            samples: 0,
            pixel0: 0,
            pixels: 0,
            sampler: r.sampler,
            rr_scale: r.rr_scale,
            rr_cap: r.rr_cap,
        };
        if r.sampler == 1 {
            // The camera jitter is the Sobol' pair 0 (common.wgsl `camera_ray`).
            p.cam.jitter = 2;
        }
        let (mut gpu_s, mut submits) = (0.0, 0u32);
        let mut s0 = 0u32;
        while s0 < r.spp {
            p.sample0 = s0;
            p.samples = chunks.samples.min(r.spp - s0);
            let mut px0 = 0u32;
            while px0 < npix {
                p.pixel0 = px0;
                p.pixels = chunks.pixels.min(npix - px0);
                ctx.queue
                    .write_buffer(&self.params, 0, bytemuck::bytes_of(&p));
                let pass = Pass {
                    label: "pt_render",
                    pipeline: &self.pipeline,
                    buffers: &[
                        (0, &self.params),
                        (1, &self.shapes),
                        (2, &self.materials),
                        (3, &self.lights),
                        (4, &accum),
                    ],
                    n: p.pixels as u64,
                    wg: 64,
                };
                gpu_s += run(ctx, "pt_render", &[pass], &[])?.gpu_s;
                submits += 1;
                px0 += p.pixels;
            }
            s0 += p.samples;
        }
        let rb = run(ctx, "pt_render readback", &[], &[&accum])?;
        gpu_s += rb.gpu_s;
        let acc: Vec<[f32; 4]> = rb.take(0, 2 * npix as usize)?;
        let mut out = PtOutput {
            mean: Vec::with_capacity(npix as usize),
            m2: Vec::with_capacity(npix as usize),
            nonfinite: 0,
            gpu_s,
            submits,
        };
        for pair in acc.chunks_exact(2) {
            out.mean.push([pair[0][0], pair[0][1], pair[0][2]]);
            out.m2.push([pair[1][0], pair[1][1], pair[1][2]]);
            out.nonfinite += pair[0][3] as u64;
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn chunks_fill_a_submit_and_respect_the_loop_cap() {
        // 512 x 512 at 2^20 paths a submit: 4 samples over all pixels.
        let c = plan_chunks(512 * 512, 64, 9, 64, None, 1 << 20).unwrap();
        assert_eq!(
            c,
            Chunks {
                samples: 4,
                pixels: 512 * 512
            }
        );
        // Small images: at most spp, and under llvmpipe's cap (65535 / 1239 = 52).
        let c = plan_chunks(64, 1024, 9, 64, Some(65_535), 1 << 20).unwrap();
        assert_eq!(loop_iters_per_sample(9, 64), 1239);
        assert_eq!(c.samples, 52);
        let c = plan_chunks(64, 16, 9, 64, None, 1 << 20).unwrap();
        assert_eq!(c.samples, 16);
        // Huge images: one sample, pixel blocks.
        let c = plan_chunks(4096 * 4096, 4, 9, 64, None, 1 << 20).unwrap();
        assert_eq!(
            c,
            Chunks {
                samples: 1,
                pixels: 1 << 20
            }
        );
        // A path that alone could pass the cap is refused.
        assert!(plan_chunks(64, 4, 9, 1 << 20, Some(65_535), 1 << 20).is_err());
    }
}
