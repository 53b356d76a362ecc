//! The packet path: camera paths traced eight at a time, their rays
//! tested eight at a time ([`super::soa8`]), each vertex shaded by the same
//! per-path steps as the scalar [`super::integrator::trace`]
//! ([`PathState`]), which stays the referee: the same random numbers and
//! the same operations give the same radiance per path, bit for bit (unit
//! test below; case `pt_packet_equals_scalar`).
//!
//! Lanes are refilled: when a lane's path ends (a miss, a light, Russian
//! roulette, the bounce limit) the next path of the caller's list starts in
//! that lane at once, so every packet test runs on (almost) eight live rays
//! instead of waiting for the longest path of a group of eight. Paths end
//! in any order; each writes its radiance to its own slot, and the caller
//! sums the slots in sample order (the scalar path's order).

use glam::Vec3A;

use super::integrator::{light_sample, PathState, Scene, Vertex};
use super::sampler::PathRng;
use super::soa8::{lane, Rays8, LANES};

/// Lane `k` of `r` set to the ray `o + t d`.
#[inline]
fn set_lane(r: &mut Rays8, k: usize, o: Vec3A, d: Vec3A) {
    for a in 0..3 {
        r.o[a][k] = o[a];
        r.d[a][k] = d[a];
    }
}

/// Radiance of the camera paths `0..out.len()`: path `j` starts as
/// `start(j)` (camera ray origin, unit direction, random numbers) and its
/// radiance goes to `out[j]`.
pub fn trace_paths8(
    scene: &Scene,
    start: impl Fn(usize) -> (Vec3A, Vec3A, PathRng),
    max_bounces: u32,
    rr_depth: u32,
    out: &mut [Vec3A],
) {
    let soa = scene.soa();
    let mut st = [PathState::new(Vec3A::ZERO, Vec3A::Z); LANES];
    let mut rngs = [PathRng::new(0, 0, 0); LANES];
    let mut job = [0usize; LANES];
    let (mut next, mut active) = (0usize, 0u8);
    let mut rays = Rays8::default();
    loop {
        for k in 0..LANES {
            if !lane(active, k) && next < out.len() {
                let (o, d, r) = start(next);
                st[k] = PathState::new(o, d);
                rngs[k] = r;
                job[k] = next;
                next += 1;
                active |= 1 << k;
            }
            if lane(active, k) {
                set_lane(&mut rays, k, st[k].o, st[k].d);
            }
        }
        if active == 0 {
            return;
        }
        let (t, id) = soa.intersect8(&rays, active);
        let mut verts: [Option<Vertex>; LANES] = [None; LANES];
        let mut shadow = [None; LANES];
        let (mut smask, mut tmax, mut sr) = (0u8, [0.0f32; LANES], Rays8::default());
        let live = active;
        for k in (0..LANES).filter(|&k| lane(live, k)) {
            let v = if id[k] == u32::MAX {
                st[k].miss(scene);
                None
            } else {
                st[k].hit(scene, t[k], id[k] as usize, max_bounces)
            };
            let Some(v) = v else {
                out[job[k]] = st[k].l;
                active &= !(1 << k);
                continue;
            };
            if PathState::samples_light(scene, &v) {
                // Some(None): the sample is worth 0 whatever blocks it.
                let ls = light_sample(scene, &v, &rngs[k]);
                if let Some(ls) = ls {
                    smask |= 1 << k;
                    tmax[k] = ls.tmax;
                    set_lane(&mut sr, k, ls.o, ls.wi);
                }
                shadow[k] = Some(ls);
            }
            verts[k] = Some(v);
        }
        let occ = if smask != 0 {
            soa.occluded8(&sr, &tmax, smask)
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
                out[job[k]] = st[k].l;
                active &= !(1 << k);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use crate::pathtrace::integrator::Tracer;
    use crate::pathtrace::lane_referee_tests::assert_renders_as_scalar;

    #[test]
    fn packet_render_equals_the_scalar_render_bit_for_bit() {
        assert_renders_as_scalar(Tracer::Packet);
    }
}
