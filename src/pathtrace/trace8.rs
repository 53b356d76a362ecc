//! The packet path: eight samples of one pixel traced in lockstep, their
//! rays tested eight at a time ([`super::soa8`]), each vertex shaded by the
//! same per-path steps as the scalar [`super::integrator::trace`]
//! ([`PathState`]), which stays the referee: the same random numbers and
//! the same operations give the same image, bit for bit (unit test below;
//! case `pt_packet_equals_scalar`).

use glam::Vec3A;

use super::integrator::{light_sample, PathRng, PathState, Scene, Vertex};
use super::soa8::{lane, Rays8, LANES};

fn pack(st: &[PathState; LANES], active: u8, f: impl Fn(&PathState) -> (Vec3A, Vec3A)) -> Rays8 {
    let mut r = Rays8::default();
    for (k, s) in st.iter().enumerate().filter(|(k, _)| lane(active, *k)) {
        let (o, d) = f(s);
        for a in 0..3 {
            r.o[a][k] = o[a];
            r.d[a][k] = d[a];
        }
    }
    r
}

/// Radiance of up to eight camera paths (`n` of them, lanes `0..n`):
/// `rays[k]` with random numbers `rngs[k]`.
pub fn trace8(
    scene: &Scene,
    rays: &[(Vec3A, Vec3A); LANES],
    rngs: &[PathRng; LANES],
    n: usize,
    max_bounces: u32,
    rr_depth: u32,
) -> [Vec3A; LANES] {
    let mut st = rays.map(|(o, d)| PathState::new(o, d));
    let mut active: u8 = if n >= LANES { 0xff } else { (1u8 << n) - 1 };
    let mut verts: [Option<Vertex>; LANES] = [None; LANES];
    while active != 0 {
        let (t, id) = scene
            .soa()
            .intersect8(&pack(&st, active, |s| (s.o, s.d)), active);
        let mut shadow = [None; LANES];
        for k in 0..LANES {
            verts[k] = None;
            if !lane(active, k) {
                continue;
            }
            if id[k] == u32::MAX {
                st[k].miss(scene);
                active &= !(1 << k);
                continue;
            }
            match st[k].hit(scene, t[k], id[k] as usize, max_bounces) {
                None => active &= !(1 << k),
                Some(v) => {
                    if PathState::samples_light(scene, &v) {
                        // Some(None): the sample is worth 0 whatever blocks it.
                        shadow[k] = Some(light_sample(scene, &v, &rngs[k]));
                    }
                    verts[k] = Some(v);
                }
            }
        }
        let mut smask = 0u8;
        let mut tmax = [0.0f32; LANES];
        let mut sr = Rays8::default();
        for k in 0..LANES {
            if let Some(Some(ls)) = shadow[k] {
                smask |= 1 << k;
                tmax[k] = ls.tmax;
                for a in 0..3 {
                    sr.o[a][k] = ls.o[a];
                    sr.d[a][k] = ls.wi[a];
                }
            }
        }
        let occ = if smask != 0 {
            scene.soa().occluded8(&sr, &tmax, smask)
        } else {
            0
        };
        for k in 0..LANES {
            let Some(v) = verts[k] else { continue };
            match shadow[k] {
                Some(Some(ls)) if !lane(occ, k) => st[k].add_light(ls.value),
                Some(_) => st[k].add_light(Vec3A::ZERO),
                None => {}
            }
            if !st[k].scatter(&v, &rngs[k], rr_depth) {
                active &= !(1 << k);
            }
        }
    }
    st.map(|s| s.l)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::camera::Camera;
    use crate::pathtrace::bsdf::Material;
    use crate::pathtrace::integrator::{render, RenderParams};
    use crate::pathtrace::shapes::{Quad, Shape, Sphere};

    /// A light, a floor, a metal and a glass sphere; 13 spp leaves a
    /// packet of five lanes.
    #[test]
    fn packet_render_equals_the_scalar_render_bit_for_bit() {
        let v = Vec3A::new;
        let quad = |c, u, w| Shape::Quad(Quad::new(c, u, w).unwrap());
        let ball = |c, r| {
            Shape::Sphere(Sphere {
                centre: c,
                radius: r,
            })
        };
        let objs = [
            (
                quad(v(-0.3, 1.5, -0.3), v(0.6, 0.0, 0.0), v(0.0, 0.0, 0.6)),
                1,
            ),
            (
                quad(v(-2.0, -1.0, -2.0), v(0.0, 0.0, 4.0), v(4.0, 0.0, 0.0)),
                0,
            ),
            (ball(v(-0.5, 0.0, 0.0), 0.5), 2),
            (ball(v(0.6, -0.3, 0.2), 0.4), 3),
        ];
        let mats = vec![
            Material::Lambertian {
                albedo: Vec3A::splat(0.7),
            },
            Material::Emitter {
                radiance: Vec3A::splat(10.0),
            },
            Material::RoughConductor {
                alpha: 0.1,
                reflectance: v(0.8, 0.8, 0.9),
            },
            Material::Dielectric { ior: 1.5 },
        ];
        let scene = Scene::new(&objs, mats, [0.1, 0.1, 0.1]).unwrap();
        let cam = Camera::pinhole_look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 24, 24)
            .unwrap()
            .to_real(24, 24);
        let mut p = RenderParams {
            width: 24,
            height: 24,
            spp: 13,
            seed: 3,
            max_bounces: 64,
            rr_depth: 2,
            packet: true,
        };
        let b = MemBudget::fixed(1 << 30);
        let a = render(&scene, &cam, &p, &b).unwrap();
        p.packet = false;
        let s = render(&scene, &cam, &p, &b).unwrap();
        assert_eq!(a.rgb, s.rgb);
        assert_eq!(a.variance, s.variance);
        assert!(a.rgb.iter().any(|x| x[0] > 0.0));
    }
}
