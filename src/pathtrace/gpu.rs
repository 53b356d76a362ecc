//! The path tracer's GPU backend: [`render_gpu`] takes what
//! [`super::render`] takes and returns the same [`Image`], computed by
//! `kernels/pathtrace.wgsl` through `crate::gpu::pathtrace` (the scene
//! converted here to the kernel's typed structs). Parity cases `pt_gpu_*`
//! in `TESTS/pathtrace/manifest_gpu.yaml`.

use super::bsdf::Material;
use super::integrator::{Image, RenderParams, Scene, RR_CAP, RR_SCALE};
use super::shapes::Shape;
use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::pathtrace::{
    PathtracePipeline, PtMaterial, PtRender, PtScene, PtShape, MAT_CONDUCTOR, MAT_DIELECTRIC,
    MAT_EMITTER, MAT_LAMBERTIAN, SHAPE_QUAD, SHAPE_SPHERE,
};
use crate::gpu::GpuContext;

/// Paths per submit (about a second on lavapipe, milliseconds on a GPU).
pub const PATHS_PER_SUBMIT: u64 = 1 << 20;

fn v4(v: glam::Vec3A, w: f32) -> [f32; 4] {
    [v.x, v.y, v.z, w]
}

/// The scene's shapes and materials as the kernel reads them.
pub fn gpu_scene(scene: &Scene) -> (Vec<PtShape>, Vec<PtMaterial>) {
    let shapes = scene
        .shapes()
        .iter()
        .enumerate()
        .map(|(i, s)| {
            let material = scene.material_index(i);
            match s {
                Shape::Sphere(sp) => PtShape {
                    a: v4(sp.centre, sp.radius),
                    kind: SHAPE_SPHERE,
                    material,
                    ..PtShape::default()
                },
                Shape::Quad(q) => {
                    let (ua, vb) = q.dual();
                    PtShape {
                        a: v4(q.corner, q.area()),
                        u: v4(q.u, 0.0),
                        v: v4(q.v, 0.0),
                        n: v4(q.normal(), 0.0),
                        ua: v4(ua, 0.0),
                        vb: v4(vb, 0.0),
                        kind: SHAPE_QUAD,
                        material,
                        axis: q.axis() as u32,
                        _pad: 0,
                    }
                }
            }
        })
        .collect();
    let materials = scene
        .materials()
        .iter()
        .map(|m| {
            let (kind, c) = match *m {
                Material::Lambertian { albedo } => (MAT_LAMBERTIAN, v4(albedo, 0.0)),
                Material::RoughConductor { alpha, reflectance } => {
                    (MAT_CONDUCTOR, v4(reflectance, alpha))
                }
                Material::Dielectric { ior } => (MAT_DIELECTRIC, [0.0, 0.0, 0.0, ior]),
                Material::Emitter { radiance } => (MAT_EMITTER, v4(radiance, 0.0)),
            };
            PtMaterial {
                c,
                kind,
                _pad: [0; 3],
            }
        })
        .collect();
    (shapes, materials)
}

/// Renders on the GPU: the same image statistics as [`super::render`]
/// (mean, variance of the mean, non-finite samples) and the GPU seconds.
pub fn render_gpu(
    ctx: &GpuContext,
    scene: &Scene,
    cam: &Camera,
    p: &RenderParams,
    budget: &MemBudget,
) -> Result<(Image, f64)> {
    p.validate()?;
    let (shapes, materials) = gpu_scene(scene);
    let pt = PtScene {
        shapes: &shapes,
        materials: &materials,
        lights: scene.lights(),
        environment: scene.environment().to_array(),
    };
    let pipe = PathtracePipeline::new(ctx, &pt)?;
    let r = PtRender {
        width: p.width,
        height: p.height,
        spp: p.spp,
        seed: p.seed,
        max_bounces: p.max_bounces,
        rr_depth: p.rr_depth,
        sampler: p.sampler.gpu_code(),
        rr_scale: RR_SCALE,
        rr_cap: RR_CAP,
    };
    let out = pipe.render(ctx, cam, &r, PATHS_PER_SUBMIT, budget)?;
    let k = p.spp as f32;
    let variance = out
        .m2
        .iter()
        .map(|m| {
            if p.spp > 1 {
                m.map(|x| x.max(0.0) / (k * (k - 1.0)))
            } else {
                [0.0; 3]
            }
        })
        .collect();
    Ok((
        Image {
            width: p.width,
            height: p.height,
            rgb: out.mean,
            variance,
            nonfinite: out.nonfinite,
        },
        out.gpu_s,
    ))
}
