//! Steady-state frames of a volume scene on the GPU (issue 19): the scene's
//! fields uploaded once into a `crate::gpu::volume_session::VolumeSession`,
//! then one submit a frame (`f_fused` + `f_img` on the device). [`latency`]
//! times those frames against the per-stage path (`render_gpu`: buffers
//! built per call, one submit for `f_fused`, `f_img` on the host) in one run.

use std::time::Instant;

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::volume_session::{GpuPixel, VolumeSession};
use crate::gpu::GpuContext;
use crate::rays::RayGen;

use super::compose::{Compose, Image};
use super::gpu::{render_gpu, GpuScene};
use super::{Chain, VolumeParams};

/// The image of one session frame (one ray a pixel of the region).
pub fn image_of(px: &[GpuPixel], gen: &RayGen) -> Image<f32> {
    let roi = gen.region();
    Image {
        width: roi.width as usize,
        height: roi.height as usize,
        rgb: px.iter().map(|p| p.rgb).collect(),
        trans: px.iter().map(|p| p.trans).collect(),
        logtrans: px.iter().map(|p| p.logtrans).collect(),
        depth: px.iter().map(|p| p.depth).collect(),
        opacity: px.iter().map(|p| p.opacity).collect(),
        hit: px.iter().map(|p| p.hit as u8).collect(),
        nsamples: px.iter().map(|p| p.nsamples as i32).collect(),
        count: vec![1; px.len()],
    }
}

/// Per-frame seconds of `frames` session frames and of `frames` per-stage
/// renders (interleaved, so load drifts hit both alike; one untimed
/// warm-up of each first), and the last session frame's image.
pub struct Latency {
    pub image: Image<f32>,
    pub session_s: Vec<f64>,
    pub stages_s: Vec<f64>,
}

/// Times `frames` frames of `params` through `cam` both ways.
pub fn latency(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    frames: usize,
    budget: &MemBudget,
) -> Result<Latency> {
    let scene = GpuScene::new(params, gen, budget)?;
    let session = VolumeSession::new(ctx, cam, gen, &scene.input()?, budget)?;
    let (mut session_s, mut stages_s) = (vec![], vec![]);
    let (mut last, _) = session.frame(ctx, cam)?;
    render_gpu(ctx, cam, gen, params, Chain::Fused, Compose::Sorted, budget)?;
    for _ in 0..frames {
        let (px, s) = session.frame(ctx, cam)?;
        session_s.push(s);
        last = px;
        let t = Instant::now();
        render_gpu(ctx, cam, gen, params, Chain::Fused, Compose::Sorted, budget)?;
        stages_s.push(t.elapsed().as_secs_f64());
    }
    Ok(Latency {
        image: image_of(&last, gen),
        session_s,
        stages_s,
    })
}
