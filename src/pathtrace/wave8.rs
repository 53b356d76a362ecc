//! The whole-vertex packet path: eight camera paths at a time, every stage
//! of a vertex done for the eight lanes at once (a wavefront inside one
//! packet): the nearest-hit test ([`super::soa8`]), the surface point and
//! shading frame, emission with its MIS weight, the light sample (uniform
//! light choice and point, `eval`, `pdf`, power heuristic), the eight
//! shadow rays ([`super::soa8`]), BSDF sampling per material under masks
//! ([`super::bsdf8`]), the counter-based random numbers
//! `rand(seed, pixel, sample, dim)` as eight-lane hashes, and Russian
//! roulette. A lane whose path ends takes the caller's next path at once
//! (refill), as in [`super::trace8`].
//!
//! Referee: the scalar [`super::integrator::trace`]. Each lane runs its
//! operations in the same order ([`super::lanes`]), so the image equals
//! the scalar image bit for bit (unit tests below; case
//! `pt_wavefront_equals_scalar`). AVX2 + FMA chosen at run time
//! (`is_x86_feature_detected!`), with AVX-512VL's 32 registers where the
//! CPU has them ([`Isa`]), the same code without them elsewhere.

use glam::Vec3A;

use super::bsdf8::{self, Frame8, Mat8, GLASS, LIGHT};
use super::integrator::{Scene, RR_CAP, RR_SCALE};
use super::lanes::{Column, F8, LANES, M8, U8, V8};
use super::sampler::{dims, PathRng, Rng8, Sampler};
use super::shapes::{Quad, Shape, OFFSET_REL};
use super::soa8::{Isa, Rays8, Soa8};
use crate::pathtrace::bsdf::Material;

/// One shape and its material as `bsdf8` codes: kind, colour, scalar.
type Shading = (Shape, u32, [f32; 3], f32);

/// The scene's shading rows as columns, read per lane by shape index.
struct Rows {
    sphere: Column,
    centre: [Column; 3],
    radius: Column,
    normal: [Column; 3],
    area: Column,
    kind: Column,
    rgb: [Column; 3],
    a: Column,
}

impl Rows {
    /// Per shape: sphere flag, centre and radius (spheres), normal and
    /// area (quads), material kind, its colour and scalar (`bsdf8` codes).
    fn new(scene: &Scene) -> Rows {
        let rows: Vec<Shading> = (0..scene.shapes().len())
            .map(|i| {
                let (kind, rgb, a) = match scene.material(i) {
                    Material::Lambertian { albedo } => (bsdf8::LAMBERT, albedo, 0.0),
                    Material::RoughConductor { alpha, reflectance } => {
                        (bsdf8::METAL, reflectance, alpha)
                    }
                    Material::Dielectric { ior } => (GLASS, Vec3A::ZERO, ior),
                    Material::Emitter { radiance } => (LIGHT, radiance, 0.0),
                };
                (scene.shapes()[i], kind, rgb.to_array(), a)
            })
            .collect();
        let f = |g: &dyn Fn(&Shading) -> f32| Column::of_f32(rows.iter().map(g));
        let sphere = |r: &Shading| match r.0 {
            Shape::Sphere(s) => Some(s),
            Shape::Quad(_) => None,
        };
        let quad = |r: &Shading| match r.0 {
            Shape::Quad(q) => Some(q),
            Shape::Sphere(_) => None,
        };
        Rows {
            sphere: Column::new(
                rows.iter()
                    .map(|r| if sphere(r).is_some() { u32::MAX } else { 0 }),
            ),
            centre: [0, 1, 2].map(|k| f(&|r| sphere(r).map_or(0.0, |s| s.centre[k]))),
            radius: f(&|r| sphere(r).map_or(0.0, |s| s.radius)),
            normal: [0, 1, 2].map(|k| f(&|r| quad(r).map_or(0.0, |q| q.normal()[k]))),
            area: f(&|r| quad(r).map_or(0.0, |q| q.area())),
            kind: Column::new(rows.iter().map(|r| r.1)),
            rgb: [0, 1, 2].map(|k| f(&|r| r.2[k])),
            a: f(&|r| r.3),
        }
    }
}

/// The light quads as columns, read per lane by light index.
struct Lights {
    corner: [Column; 3],
    u: [Column; 3],
    v: [Column; 3],
    normal: [Column; 3],
    area: Column,
    radiance: [Column; 3],
}

impl Lights {
    /// The columns of the light quads and their radiances.
    fn new(quads: &[(Quad, Vec3A)]) -> Lights {
        let f = |g: &dyn Fn(&(Quad, Vec3A)) -> f32| Column::of_f32(quads.iter().map(g));
        Lights {
            corner: [0, 1, 2].map(|a| f(&|(q, _)| q.corner[a])),
            u: [0, 1, 2].map(|a| f(&|(q, _)| q.u[a])),
            v: [0, 1, 2].map(|a| f(&|(q, _)| q.v[a])),
            normal: [0, 1, 2].map(|a| f(&|(q, _)| q.normal()[a])),
            area: f(&|(q, _)| q.area()),
            radiance: [0, 1, 2].map(|a| f(&|(_, r)| r[a])),
        }
    }
}

/// Three columns read at the same lane indices.
#[inline(always)]
fn get3(c: &[Column; 3], idx: U8, avx2: bool) -> V8 {
    V8::new(
        c[0].get_f(idx, avx2),
        c[1].get_f(idx, avx2),
        c[2].get_f(idx, avx2),
    )
}

/// The scene as columns for lane reads.
struct Tables {
    rows: Rows,
    lights: Lights,
    nl: usize,
    env: [f32; 3],
}

impl Tables {
    fn new(scene: &Scene) -> Tables {
        let lights: Vec<(Quad, Vec3A)> = scene
            .lights()
            .iter()
            .filter_map(
                |&i| match (scene.shapes()[i as usize], scene.material(i as usize)) {
                    (Shape::Quad(q), Material::Emitter { radiance }) => Some((q, radiance)),
                    _ => None,
                },
            )
            .collect();
        Tables {
            rows: Rows::new(scene),
            lights: Lights::new(&lights),
            nl: lights.len(),
            env: scene.environment().to_array(),
        }
    }
}

/// The eight lanes' path states (`integrator::PathState` per lane).
#[derive(Clone, Copy, Debug, Default)]
struct Paths {
    o: V8,
    d: V8,
    l: V8,
    beta: V8,
    eta2: F8,
    prev_pdf: F8,
    prev_delta: M8,
    bounces: U8,
    rng: Rng8,
}

impl Paths {
    /// Lane `k` starts a camera path.
    #[inline(always)]
    fn start(&mut self, k: usize, o: Vec3A, d: Vec3A, rng: PathRng) {
        self.o.set_lane(k, o.to_array());
        self.d.set_lane(k, d.to_array());
        self.l.set_lane(k, [0.0; 3]);
        self.beta.set_lane(k, [1.0; 3]);
        self.eta2.0[k] = 1.0;
        self.prev_pdf.0[k] = 0.0;
        self.prev_delta.0[k] = u32::MAX;
        self.bounces.0[k] = 0;
        self.rng.set_lane(k, &rng);
    }

    fn rays(&self) -> Rays8 {
        Rays8 {
            o: [self.o.x.0, self.o.y.0, self.o.z.0],
            d: [self.d.x.0, self.d.y.0, self.d.z.0],
        }
    }
}

/// `integrator::power` per lane.
#[inline(always)]
fn power(a: F8, b: F8) -> F8 {
    let (a2, b2) = (a * a, b * b);
    (a2 + b2)
        .gt(F8::splat(0.0))
        .select(a2 / (a2 + b2), F8::splat(0.0))
}

/// `shapes::spawn_origin` per lane.
#[inline(always)]
fn spawn(p: V8, n: V8, w: V8) -> V8 {
    let eps = F8::splat(OFFSET_REL) * (F8::splat(1.0) + p.abs().max_element());
    w.dot(n)
        .ge(F8::splat(0.0))
        .select_v(p + n.scale(eps), p - n.scale(eps))
}

/// `integrator::light_sample` per lane for the lanes of `m`: `(ok, shadow
/// origin, direction, tmax, value)`, `ok` false where the sample is worth 0.
#[inline(always)]
fn light_sample(
    tab: &Tables,
    m: M8,
    (p, n, fr, wo): (V8, V8, &Frame8, V8),
    mat: &Mat8,
    (rng, sobol, base): (&Rng8, bool, U8),
    (ua, vb): (F8, F8),
    avx2: bool,
) -> (M8, V8, V8, F8, V8) {
    let nl = tab.nl;
    let nlf = F8::splat(nl as f32);
    // One light: every choice picks it (the number is not drawn).
    let pick = match nl {
        1 => U8::splat(0),
        _ => (rng.f(sobol, base + U8::splat(dims::LIGHT_CHOICE)) * nlf)
            .to_i32()
            .min(U8::splat(nl as u32 - 1)),
    };
    let lt = &tab.lights;
    let (c, eu, ev, ln) = (
        get3(&lt.corner, pick, avx2),
        get3(&lt.u, pick, avx2),
        get3(&lt.v, pick, avx2),
        get3(&lt.normal, pick, avx2),
    );
    let (area, rad) = (lt.area.get_f(pick, avx2), get3(&lt.radiance, pick, avx2));
    let x = c + eu.scale(ua) + ev.scale(vb);
    let to = x - p;
    let dist2 = to.dot(to);
    let zero = F8::splat(0.0);
    let wi = to.div(dist2.sqrt());
    let cos_l = -wi.dot(ln);
    let wl = fr.to_local(wi);
    let f = bsdf8::eval(mat, wo, wl);
    let ok = m & !dist2.eq(zero) & !cos_l.le(zero) & !f.is_zero();
    let o = spawn(p, n, wi);
    let pl = dist2 / (cos_l * area * nlf);
    let w = power(pl, bsdf8::pdf(mat, wo, wl));
    let tmax = (x - o).length() * F8::splat(1.0 - 1e-4);
    let value = f.scale(wl.z.abs() * w / pl) * rad;
    (ok, o, wi, tmax, value)
}

/// Radiance of the camera paths `0..out.len()`, as
/// [`super::trace8::trace_paths8`] (same arguments, same results).
pub fn trace_paths_wave8(
    scene: &Scene,
    start: impl Fn(usize) -> (Vec3A, Vec3A, PathRng),
    limits: (u32, u32),
    sampler: Sampler,
    out: &mut [Vec3A],
) {
    trace_on(scene, scene.soa(), &start, (limits, sampler), out)
}

/// [`trace_paths_wave8`] with the shape tests `soa`, the loop compiled for
/// `soa`'s instruction set (the tests pass each set this CPU has).
fn trace_on<F: Fn(usize) -> (Vec3A, Vec3A, PathRng)>(
    scene: &Scene,
    soa: &Soa8,
    start: &F,
    limits: ((u32, u32), Sampler),
    out: &mut [Vec3A],
) {
    let tab = Tables::new(scene);
    // SAFETY: `Soa8::new` keeps its set within what this CPU has.
    #[cfg(target_arch = "x86_64")]
    match soa.isa() {
        Isa::Avx512 => return unsafe { run_avx512(soa, &tab, start, limits, out) },
        Isa::Avx2 => return unsafe { run_avx2(soa, &tab, start, limits, out) },
        Isa::Portable => {}
    }
    run::<false, _>(soa, &tab, start, limits, out)
}

/// [`run`] compiled for AVX2 + FMA.
///
/// # Safety
/// The CPU must have AVX2 and FMA.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_avx2<F: Fn(usize) -> (Vec3A, Vec3A, PathRng)>(
    soa: &Soa8,
    tab: &Tables,
    start: &F,
    limits: ((u32, u32), Sampler),
    out: &mut [Vec3A],
) {
    run::<true, F>(soa, tab, start, limits, out)
}

/// [`run`] compiled with AVX-512F/VL/DQ/BW and GFNI as well: still eight
/// lanes and the same IEEE operations (no FMA formed), but 32 vector
/// registers, so the path state spills less (Zen 4: 0.89 vs 0.99 CPU-s,
/// docs/PERF.md), and `u32::reverse_bits` (the Sobol' sampler's digit
/// reversals) is a byte shuffle and one `vgf2p8affineqb` instead of seven
/// instructions.
///
/// # Safety
/// The CPU must have AVX2, FMA, AVX-512F/VL/DQ/BW and GFNI.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma,avx512f,avx512vl,avx512dq,avx512bw,gfni")]
unsafe fn run_avx512<F: Fn(usize) -> (Vec3A, Vec3A, PathRng)>(
    soa: &Soa8,
    tab: &Tables,
    start: &F,
    limits: ((u32, u32), Sampler),
    out: &mut [Vec3A],
) {
    run::<true, F>(soa, tab, start, limits, out)
}

/// The wavefront loop: refill, intersect, shade, shadow-test, scatter;
/// `AVX2`: table reads by lane permutes (only where AVX2 was detected).
#[inline(always)]
fn run<const AVX2: bool, F: Fn(usize) -> (Vec3A, Vec3A, PathRng)>(
    soa: &Soa8,
    tab: &Tables,
    start: &F,
    ((max_bounces, rr_depth), sampler): ((u32, u32), Sampler),
    out: &mut [Vec3A],
) {
    let sobol = sampler == Sampler::Sobol;
    let mut s = Paths::default();
    let mut job = [0usize; LANES];
    let (mut next, mut active) = (0usize, 0u8);
    let (zero, one) = (F8::splat(0.0), F8::splat(1.0));
    let nlf = F8::splat(tab.nl as f32);
    loop {
        for (k, j) in job.iter_mut().enumerate() {
            if active & (1 << k) == 0 && next < out.len() {
                let (o, d, rng) = start(next);
                s.start(k, o, d, rng);
                *j = next;
                next += 1;
                active |= 1 << k;
            }
        }
        if active == 0 {
            return;
        }
        // The vertex's 2-D numbers, drawn before the intersection test
        // (they depend on the path only) so their hash chains overlap it.
        let base = U8::splat(dims::FIRST_VERTEX) + U8::splat(dims::STRIDE).mul(s.bounces);
        let light_uv = s.rng.f2(sobol, base + U8::splat(dims::LIGHT_U));
        let (bu, bv) = s.rng.f2(sobol, base + U8::splat(dims::BSDF_U));
        let (t, id) = soa.intersect8(&s.rays(), active);
        let act = M8::from_bits(active);
        let hit = act & !U8(id).eq(U8::splat(u32::MAX));
        let miss = act & !hit;
        s.l = miss.select_v(s.l + s.beta * V8::splat(tab.env), s.l);
        // The shapes and materials that the lanes hit (row 0 on a miss).
        let idx = U8(id);
        let rw = &tab.rows;
        let sph = M8(rw.sphere.get(idx, AVX2).0);
        let (c, rad) = (get3(&rw.centre, idx, AVX2), rw.radius.get_f(idx, AVX2));
        let (qn, area) = (get3(&rw.normal, idx, AVX2), rw.area.get_f(idx, AVX2));
        let mat = Mat8 {
            kind: rw.kind.get(idx, AVX2),
            rgb: get3(&rw.rgb, idx, AVX2),
            a: rw.a.get_f(idx, AVX2),
        };
        // Surface point and normal (`Shape::surface`), frame, wo.
        let t = F8(t);
        let p = s.o + s.d.scale(t);
        let rs = p - c;
        let ns = rs.div(rs.length());
        let n = sph.select_v(ns, qn);
        let p = sph.select_v(c + ns.scale(rad), p);
        let fr = Frame8::new(n);
        let wo = fr.to_local(-s.d);
        // Emitters (`PathState::hit`): one-sided, MIS after a non-delta bounce.
        let emit = hit & mat.is(LIGHT);
        let w_l = power(s.prev_pdf, t * t / (wo.z * area * nlf));
        let w = s.prev_delta.select(one, w_l);
        let front = emit & wo.z.gt(zero);
        s.l = front.select_v(s.l + (s.beta * mat.rgb).scale(w), s.l);
        let deep = hit & !emit & s.bounces.ge(U8::splat(max_bounces));
        let vert = hit & !emit & !deep;
        // Light sampling and the eight shadow rays.
        let nee = vert & !mat.is(GLASS);
        if tab.nl > 0 && nee.any() {
            let (ok, so, swi, tmax, value) = light_sample(
                tab,
                nee,
                (p, n, &fr, wo),
                &mat,
                (&s.rng, sobol, base),
                light_uv,
                AVX2,
            );
            let shadow = Rays8 {
                o: [so.x.0, so.y.0, so.z.0],
                d: [swi.x.0, swi.y.0, swi.z.0],
            };
            let occ = if ok.any() {
                M8::from_bits(soa.occluded8(&shadow, &tmax.0, ok.bits()))
            } else {
                M8::default()
            };
            let add = (ok & !occ).select_v(value, V8::default());
            s.l = nee.select_v(s.l + s.beta * add, s.l);
        }
        // BSDF sampling (`PathState::scatter`) and Russian roulette.
        let rng = s.rng;
        let r = |d: u32| base + U8::splat(d);
        let lobe = || rng.f(sobol, r(dims::LOBE));
        let bs = bsdf8::sample(&mat, vert, wo, lobe, bu, bv);
        let go = vert & bs.ok;
        s.beta = go.select_v(s.beta * bs.weight, s.beta);
        s.eta2 = go.select(s.eta2 * bs.eta2, s.eta2);
        s.prev_pdf = go.select(bs.pdf, s.prev_pdf);
        s.prev_delta = go.select_m(bs.delta, s.prev_delta);
        let d = fr.to_world(bs.wi).normalize();
        s.d = go.select_v(d, s.d);
        s.o = go.select_v(spawn(p, n, d), s.o);
        s.bounces = go.select_u(s.bounces + U8::splat(1), s.bounces);
        let rr = go & s.bounces.ge(U8::splat(rr_depth));
        // `integrator::survival`, lane by lane.
        let m = s.beta.scale(s.eta2).max_element();
        let q = (F8::splat(RR_SCALE) * m).min(F8::splat(RR_CAP));
        let live = match rr.any() {
            true => rr & rng.f(sobol, r(dims::ROULETTE)).lt(q),
            false => M8::default(),
        };
        s.beta = live.select_v(s.beta.div(q), s.beta);
        let ended = (act & !go) | (rr & !live);
        let bits = ended.bits();
        for (k, &j) in job.iter().enumerate() {
            if bits & (1 << k) != 0 {
                out[j] = Vec3A::from_array(s.l.lane(k));
            }
        }
        active &= !bits;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::pathtrace::integrator::Tracer;
    use crate::pathtrace::lane_referee_tests::{assert_renders_as_scalar, test_scene};

    /// A light, a floor, a metal, a glass and a diffuse sphere: the
    /// wavefront render equals the scalar render bit for bit with the
    /// widest instruction set of this CPU, and the loop compiled for every
    /// set this CPU has (portable, AVX2, AVX-512) renders the same paths.
    #[test]
    fn wavefront_render_equals_the_scalar_render_bit_for_bit() {
        assert_renders_as_scalar(Tracer::Wavefront);
        let scene = test_scene();
        let cam = Camera::pinhole_look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 8)
            .unwrap()
            .to_real(8, 8);
        let start = |j: usize| {
            let rng = PathRng::new(5, j as u32 / 7, j as u32 % 7);
            let (o, d) = cam.ray(0.5 + (j / 7 % 8) as f32, 0.5 + (j / 56) as f32);
            (Vec3A::from_array(o), Vec3A::from_array(d), rng)
        };
        let mut a = vec![Vec3A::ZERO; 448];
        trace_paths_wave8(&scene, start, (64, 2), Sampler::Independent, &mut a);
        assert!(a.iter().any(|x| x.x > 0.0));
        for isa in Isa::available() {
            let soa = Soa8::new(scene.shapes(), isa);
            assert_eq!(soa.isa(), isa);
            let mut b = vec![Vec3A::ZERO; 448];
            trace_on(
                &scene,
                &soa,
                &start,
                ((64, 2), Sampler::Independent),
                &mut b,
            );
            assert_eq!(a, b, "{}", isa.name());
        }
    }
}
