//! `f_ray` on the GPU. Kernel: `kernels/rays.wgsl` entry `f_ray`; CPU twin:
//! [`crate::rays::f_ray`]; parity cases `gpu_rays_*_parity` in
//! `TESTS/gpu/manifest.yaml`. Float32 only (the GPU's precision).

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{RayGen, Rays};

/// Camera uniform of `kernels/rays.wgsl` and `kernels/volume.wgsl` (keep in
/// sync with `struct CamParams` in `kernels/common.wgsl`): 6 vec4 then 12
/// u32, 144 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct RayParams {
    pub rot: [[f32; 4]; 3],
    pub model: [f32; 4],
    pub bmin_near: [f32; 4],
    pub bmax_far: [f32; 4],
    pub kind: u32,
    pub width: u32,
    pub roi_x: u32,
    pub roi_y: u32,
    pub roi_w: u32,
    pub n: u32,
    pub jitter: u32,
    pub seed: u32,
    pub sample: u32,
    pub _pad: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<RayParams>() == 144);

impl RayParams {
    /// The kernel's parameters for `cam` and `gen` (validated by the caller).
    /// `far` is clamped to `f32::MAX`: WGSL may assume no infinities, and a
    /// unit direction always leaves the box before that.
    pub fn new(cam: &Camera, gen: &RayGen) -> RayParams {
        let c = cam.c2w();
        let row = |r: usize| {
            [
                c[r][0] as f32,
                c[r][1] as f32,
                c[r][2] as f32,
                c[r][3] as f32,
            ]
        };
        let (kind, model) = match cam {
            Camera::Pinhole { k, .. } => (0, [k.fx as f32, k.fy as f32, k.cx as f32, k.cy as f32]),
            Camera::Orthographic {
                half_width,
                half_height,
                ..
            } => (
                1,
                [
                    *half_width as f32,
                    *half_height as f32,
                    gen.width as f32,
                    gen.height as f32,
                ],
            ),
        };
        let roi = gen.region();
        let (a, b) = (gen.aabb.min, gen.aabb.max);
        let (jitter, seed, sample) = gen.jitter.map_or((0, 0, 0), |j| (1, j.seed, j.sample));
        RayParams {
            rot: [row(0), row(1), row(2)],
            model,
            bmin_near: [a[0] as f32, a[1] as f32, a[2] as f32, gen.near as f32],
            bmax_far: [
                b[0] as f32,
                b[1] as f32,
                b[2] as f32,
                (gen.far as f32).min(f32::MAX),
            ],
            kind,
            width: gen.width,
            roi_x: roi.x,
            roi_y: roi.y,
            roi_w: roi.width,
            n: roi.width * roi.height,
            jitter,
            seed,
            sample,
            _pad: [0; 3],
        }
    }
}

/// `f_ray` on the GPU: the same rays as [`crate::rays::f_ray::<f32>`] (to
/// f32 rounding of the division and square root), and the seconds the
/// kernel and readback took.
pub fn f_ray(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    budget: &MemBudget,
) -> Result<(Rays<f32>, f64)> {
    gen.validate()?;
    cam.validate()?;
    let roi = gen.region();
    let n = roi.width as u64 * roi.height as u64;
    // Host copies: the readback bytes and the SoA result.
    budget.check(
        "gpu f_ray rays",
        bytes_for(n, 2 * Rays::<f32>::BYTES_PER_RAY),
    )?;
    let p = RayParams::new(cam, gen);
    let pipe = pipeline(ctx, "rays", "f_ray")?;
    let u = uniform(ctx, "f_ray params", &p);
    let o = storage_out(ctx, "f_ray o", n * 12)?;
    let d = storage_out(ctx, "f_ray d", n * 12)?;
    let t0 = storage_out(ctx, "f_ray t0", n * 4)?;
    let t1 = storage_out(ctx, "f_ray t1", n * 4)?;
    let px = storage_out(ctx, "f_ray pixel", n * 4)?;
    let pass = Pass {
        label: "f_ray",
        pipeline: &pipe,
        buffers: &[(0, &u), (1, &o), (2, &d), (3, &t0), (4, &t1), (5, &px)],
        n,
        wg: 64,
    };
    let rb = run(ctx, "f_ray", &[pass], &[&o, &d, &t0, &t1, &px])?;
    let n = n as usize;
    let of: Vec<f32> = rb.take(0, 3 * n)?;
    let df: Vec<f32> = rb.take(1, 3 * n)?;
    let rays = Rays {
        o: of.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        d: df.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect(),
        t0: rb.take(2, n)?,
        t1: rb.take(3, n)?,
        pixel: rb.take(4, n)?,
    };
    Ok((rays, rb.gpu_s))
}
