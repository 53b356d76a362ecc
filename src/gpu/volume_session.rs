//! A steady-state volume frame on the GPU (issue 19): [`VolumeSession`]
//! builds its pipelines, buffers and bind groups once for a scene, then each
//! [`VolumeSession::frame`] writes the camera uniform and encodes the whole
//! frame (`f_fused`, which generates its rays with common.wgsl's
//! `camera_ray`, the `f_ray` twin; then `f_img`) into ONE command buffer
//! with the image readback copy: one submit, one wait. The per-stage path
//! ([`super::volume::f_fused`] plus the host's `f_img`) builds its buffers
//! every call; the session's latency is measured against it.
//!
//! CPU twins: `src/volume/fused.rs` `march_ray`, `src/volume/compose.rs`
//! `f_img`; parity case `gpu_vol_session_frame_equals_stages`.

use std::time::Instant;

use bytemuck::{Pod, Zeroable};

use super::buffers::{bind_group, storage_out, uniform};
use super::context::{Dispatch, GpuContext};
use super::kernels::pipeline;
use super::rays::RayParams;
use super::volume::{
    check_loop_cap, ray_count, refuse_hash, validate, FieldBuffers, VolParams, VolumeInput,
};
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;

/// One pixel of the frame (`struct Pixel` of `kernels/volume.wgsl`; 40 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuPixel {
    pub rgb: [f32; 3],
    pub trans: f32,
    pub logtrans: f32,
    pub depth: f32,
    pub opacity: f32,
    pub nsamples: u32,
    pub hit: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<GpuPixel>() == 40);

/// Pipelines, buffers and bind groups of one scene's frames.
pub struct VolumeSession {
    gen: RayGen,
    n: u32,
    cam_u: wgpu::Buffer,
    image: wgpu::Buffer,
    staging: wgpu::Buffer,
    fused: wgpu::ComputePipeline,
    img: wgpu::ComputePipeline,
    bg_fused: wgpu::BindGroup,
    bg_img: wgpu::BindGroup,
    plan: Dispatch,
}

impl VolumeSession {
    /// Builds everything the frames of `v` seen through `gen` (camera
    /// `cam`, replaceable per frame) reuse.
    pub fn new(
        ctx: &GpuContext,
        cam: &Camera,
        gen: &RayGen,
        v: &VolumeInput,
        budget: &MemBudget,
    ) -> Result<VolumeSession> {
        gen.validate()?;
        cam.validate()?;
        validate(v)?;
        check_loop_cap(ctx, gen, v)?;
        refuse_hash(v, "volume session")?;
        let n = ray_count(gen)?;
        let px = std::mem::size_of::<GpuPixel>() as u64;
        budget.check("gpu session frame", bytes_for(n as u64, 48 + 2 * px))?;
        let fused = pipeline(ctx, "volume", "f_fused")?;
        let img = pipeline(ctx, "volume", "f_img")?;
        let cam_u = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("session camera"),
            size: std::mem::size_of::<RayParams>() as u64,
            usage: wgpu::BufferUsages::UNIFORM | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        ctx.queue
            .write_buffer(&cam_u, 0, bytemuck::bytes_of(&RayParams::new(cam, gen)));
        let vol_u = uniform(ctx, "session volume", &VolParams::new(v));
        let fb = FieldBuffers::new(ctx, v)?;
        let rays = storage_out(ctx, "session rays", n as u64 * 48)?;
        let image = storage_out(ctx, "session image", n as u64 * px)?;
        let staging = ctx.device.create_buffer(&wgpu::BufferDescriptor {
            label: Some("session readback"),
            size: image.size(),
            usage: wgpu::BufferUsages::MAP_READ | wgpu::BufferUsages::COPY_DST,
            mapped_at_creation: false,
        });
        let bg_fused = bind_group(
            ctx,
            "session f_fused",
            &fused,
            &[
                (0, &cam_u),
                (1, &vol_u),
                (2, &fb.slabs),
                (3, &fb.sgrid),
                (4, &fb.cgrid),
                (5, &fb.occ),
                (6, &rays),
            ],
        );
        let bg_img = bind_group(
            ctx,
            "session f_img",
            &img,
            &[(0, &cam_u), (6, &rays), (16, &image)],
        );
        Ok(VolumeSession {
            gen: gen.clone(),
            n,
            cam_u,
            image,
            staging,
            fused,
            img,
            bg_fused,
            bg_img,
            plan: ctx.dispatch("session frame", n as u64, 64)?,
        })
    }

    /// One frame through `cam`: the pixels of the region (region order) and
    /// the seconds from the camera write to the mapped readback.
    pub fn frame(&self, ctx: &GpuContext, cam: &Camera) -> Result<(Vec<GpuPixel>, f64)> {
        cam.validate()?;
        let t = Instant::now();
        let dev = &ctx.device;
        let val = dev.push_error_scope(wgpu::ErrorFilter::Validation);
        ctx.queue.write_buffer(
            &self.cam_u,
            0,
            bytemuck::bytes_of(&RayParams::new(cam, &self.gen)),
        );
        let mut enc = dev.create_command_encoder(&wgpu::CommandEncoderDescriptor {
            label: Some("session frame"),
        });
        for (p, bg) in [(&self.fused, &self.bg_fused), (&self.img, &self.bg_img)] {
            let mut cp = enc.begin_compute_pass(&wgpu::ComputePassDescriptor {
                label: Some("session pass"),
                timestamp_writes: None,
            });
            cp.set_pipeline(p);
            cp.set_bind_group(0, bg, &[]);
            cp.dispatch_workgroups(self.plan.groups_x, self.plan.groups_y, 1);
        }
        enc.copy_buffer_to_buffer(&self.image, 0, &self.staging, 0, self.image.size());
        ctx.queue.submit([enc.finish()]);
        self.staging
            .slice(..)
            .map_async(wgpu::MapMode::Read, |_| {});
        dev.poll(wgpu::PollType::wait_indefinitely())
            .map_err(|e| Error::Gpu(format!("session frame: waiting for the GPU: {e}")))?;
        if let Some(e) = pollster::block_on(val.pop()) {
            return Err(Error::Gpu(format!("session frame: {e}")));
        }
        let view = self
            .staging
            .slice(..)
            .get_mapped_range()
            .map_err(|e| Error::Gpu(format!("session frame: mapping the readback: {e}")))?;
        let mut px: Vec<GpuPixel> = bytemuck::pod_collect_to_vec(&view);
        drop(view);
        self.staging.unmap();
        px.truncate(self.n as usize);
        Ok((px, t.elapsed().as_secs_f64()))
    }
}
