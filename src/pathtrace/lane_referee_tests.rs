//! Shared by the packet and wavefront unit tests: a scene that exercises
//! every material and two lights, and the check that a lane tracer renders
//! it as the scalar path does, bit for bit.

use glam::Vec3A;

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::pathtrace::bsdf::Material;
use crate::pathtrace::integrator::{render, RenderParams, Scene, Tracer};
use crate::pathtrace::sampler::Sampler;
use crate::pathtrace::shapes::{Quad, Shape, Sphere};

/// Two lights (one coloured), a floor, a metal, a glass and a diffuse
/// sphere, a coloured environment.
pub fn test_scene() -> Scene {
    let v = Vec3A::new;
    let quad = |c, u, w| Shape::Quad(Quad::new(c, u, w).unwrap());
    let ball = |centre, radius| Shape::Sphere(Sphere { centre, radius });
    let objs = [
        (
            quad(v(-0.3, 1.5, -0.3), v(0.6, 0.0, 0.0), v(0.0, 0.0, 0.6)),
            1,
        ),
        (
            quad(v(0.4, 1.2, 0.3), v(0.3, 0.0, 0.0), v(0.0, 0.0, 0.3)),
            4,
        ),
        (
            quad(v(-2.0, -1.0, -2.0), v(0.0, 0.0, 4.0), v(4.0, 0.0, 0.0)),
            0,
        ),
        (ball(v(-0.5, 0.0, 0.0), 0.5), 2),
        (ball(v(0.6, -0.3, 0.2), 0.4), 3),
        (ball(v(0.1, -0.7, 0.9), 0.3), 0),
    ];
    let mats = vec![
        Material::Lambertian {
            albedo: v(0.7, 0.5, 0.3),
        },
        Material::Emitter {
            radiance: Vec3A::splat(10.0),
        },
        Material::RoughConductor {
            alpha: 0.1,
            reflectance: v(0.8, 0.8, 0.9),
        },
        Material::Dielectric { ior: 1.5 },
        Material::Emitter {
            radiance: v(2.0, 4.0, 6.0),
        },
    ];
    Scene::new(&objs, mats, [0.1, 0.2, 0.3]).unwrap()
}

/// `tracer` renders [`test_scene`] as the scalar path does, bit for bit,
/// with each sampler.
/// 24 x 24 at 13 spp: a partial tile, packets spanning pixels, a last packet
/// of fewer than eight paths; 17 x 2 at 300 spp: a batch of BATCH paths ends
/// inside a pixel (16 x 300 > 4096).
pub fn assert_renders_as_scalar(tracer: Tracer) {
    let scene = test_scene();
    let samplers = [Sampler::Independent, Sampler::Sobol];
    for ((w, h, spp), sampler) in [(24, 24, 13), (17, 2, 300)]
        .into_iter()
        .flat_map(|c| samplers.map(|s| (c, s)))
    {
        let cam = Camera::pinhole_look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, w, h)
            .unwrap()
            .to_real(w, h);
        let mut p = RenderParams {
            width: w,
            height: h,
            spp,
            seed: 3,
            max_bounces: 64,
            rr_depth: 2,
            tracer,
            sampler,
        };
        let b = MemBudget::fixed(1 << 30);
        let a = render(&scene, &cam, &p, &b).unwrap();
        p.tracer = Tracer::Scalar;
        let s = render(&scene, &cam, &p, &b).unwrap();
        assert_eq!(a.rgb, s.rgb);
        assert_eq!(a.variance, s.variance);
        assert!(a.rgb.iter().any(|x| x[0] > 0.0));
    }
}
