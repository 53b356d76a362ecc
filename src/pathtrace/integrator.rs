//! The path integrator (seed 004 "Path Integrator"): unidirectional path
//! tracing with next-event estimation on one-sided quad lights, combined
//! with BSDF sampling by multiple importance sampling (power heuristic,
//! beta = 2), and throughput-based Russian roulette. One iterative loop per
//! path, no allocation and no recursion, so the WGSL kernel can mirror it
//! line by line (GPU issue to come).
//!
//! Estimator. At a path vertex with `k` bounces behind it:
//! - light seen through BSDF sampling adds `beta Le w_b`, with
//!   `w_b = p_b^2 / (p_b^2 + p_l^2)` after a non-delta bounce and `w_b = 1`
//!   after a delta bounce or for a camera ray (k = 0);
//! - a non-delta vertex also samples a light (uniform choice among `L`
//!   lights, uniform point on its area `A`): `p_l = dist^2 / (cos_l A L)`,
//!   adding `beta f |cos_i| Le w_l / p_l` with `w_l = p_l^2 / (p_l^2 + p_b^2)`;
//! - the environment (uniform radiance, not light-sampled) adds `beta E`.
//!
//! So light reached through glass or in the metal's reflection is counted
//! exactly once. Depth counts bounces: a camera ray that hits the light is
//! depth 0; a vertex scatters (and samples lights) only while
//! `k < max_bounces`, so `max_bounces = 1` is direct lighting. After the
//! bounce that makes `k >= rr_depth`, the path survives with probability
//! `q = min(3 max_channel(beta * eta^2), 0.95)` ([`survival`]) and
//! `beta /= q` (unbiased for any `q` in (0, 1]; `eta^2` undoes the radiance
//! scaling of refraction as Mitsuba 3 does). Mitsuba's rule has no factor 3;
//! on the Cornell box it ends most paths at `rr_depth` (throughput about
//! 0.2 there) and the survivors' weight of 5 was a fifth of the 64-spp
//! variance (docs/PERF.md, issue 13, ninth session).
//!
//! Random numbers: `rand(seed, pixel, sample, dim)` (SCENES.md) with the
//! dimensions laid out in [`dims`], so a render is bit-identical across runs
//! and thread counts. Box pixel filter: one uniformly jittered position per
//! sample.

use glam::Vec3A;

use super::bsdf::{Frame, Material};
use super::packed::Packed;
use super::sampler::{dims, PathRng, Sampler};
use super::shapes::{spawn_origin, Shape};
use super::soa8::{Isa, Soa8};
use super::trace8::trace_paths8;
use super::wave8::trace_paths_wave8;
use crate::budget::{bytes_for, MemBudget};
use crate::camera::RealCamera;
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::rng::sobol::pixel_key;

/// A scene ready to trace: shapes, their materials, the lights (indices of
/// shapes with an emitter material; quads only) and a uniform environment.
#[derive(Clone, Debug)]
pub struct Scene {
    shapes: Vec<Shape>,
    material_of: Vec<u32>,
    materials: Vec<Material>,
    lights: Vec<u32>,
    environment: Vec3A,
    packed: Packed,
    soa: Soa8,
}

impl Scene {
    /// Builds a scene; `objects` pairs each shape with an index into
    /// `materials`. Errors: a material index out of range, a non-finite or
    /// negative parameter, an emitter on a sphere (lights must be quads).
    pub fn new(
        objects: &[(Shape, usize)],
        materials: Vec<Material>,
        environment: [f32; 3],
    ) -> Result<Scene> {
        let mut lights = Vec::new();
        for (i, &(shape, m)) in objects.iter().enumerate() {
            let mat = materials.get(m).ok_or_else(|| {
                Error::invalid(
                    format!("shapes[{i}]"),
                    format!(
                        "material index {m} out of range ({} materials)",
                        materials.len()
                    ),
                )
            })?;
            if let Material::Emitter { .. } = mat {
                match shape {
                    Shape::Quad(_) => lights.push(i as u32),
                    Shape::Sphere(_) => {
                        return Err(Error::NotSupported(format!(
                            "shapes[{i}]: emitters must be quads (no sphere lights)"
                        )))
                    }
                }
            }
            if let Shape::Sphere(s) = shape {
                if !(s.radius > 0.0 && s.radius.is_finite() && s.centre.is_finite()) {
                    return Err(Error::invalid(
                        format!("shapes[{i}]"),
                        "sphere needs a finite centre and radius > 0",
                    ));
                }
            }
        }
        for (i, m) in materials.iter().enumerate() {
            let ok = match *m {
                Material::Lambertian { albedo } => {
                    albedo.is_finite() && albedo.min_element() >= 0.0
                }
                Material::RoughConductor { alpha, reflectance } => {
                    alpha > 0.0
                        && alpha.is_finite()
                        && reflectance.is_finite()
                        && reflectance.min_element() >= 0.0
                }
                Material::Dielectric { ior } => ior > 0.0 && ior.is_finite(),
                Material::Emitter { radiance } => {
                    radiance.is_finite() && radiance.min_element() >= 0.0
                }
            };
            if !ok {
                return Err(Error::invalid(
                    format!("materials[{i}]"),
                    format!("parameters out of range: {m:?}"),
                ));
            }
        }
        let env = Vec3A::from_array(environment);
        if !(env.is_finite() && env.min_element() >= 0.0) {
            return Err(Error::invalid("environment", "must be finite and >= 0"));
        }
        Ok(Scene {
            shapes: objects.iter().map(|o| o.0).collect(),
            material_of: objects.iter().map(|o| o.1 as u32).collect(),
            materials,
            lights,
            environment: env,
            packed: Packed::new(&objects.iter().map(|o| o.0).collect::<Vec<_>>()),
            soa: Soa8::new(
                &objects.iter().map(|o| o.0).collect::<Vec<_>>(),
                Isa::detect(),
            ),
        })
    }

    pub fn shapes(&self) -> &[Shape] {
        &self.shapes
    }

    /// The material of shape `i`.
    #[inline]
    pub fn material(&self, i: usize) -> Material {
        self.materials[self.material_of[i] as usize]
    }

    /// The shapes in SoA form for eight-ray packets.
    pub fn soa(&self) -> &Soa8 {
        &self.soa
    }

    /// The materials, indexed by [`Scene::material_index`].
    pub fn materials(&self) -> &[Material] {
        &self.materials
    }

    /// The index into [`Scene::materials`] of shape `i`'s material.
    pub fn material_index(&self, i: usize) -> u32 {
        self.material_of[i]
    }

    /// Indices of the emitting quads.
    pub fn lights(&self) -> &[u32] {
        &self.lights
    }

    /// Uniform radiance of rays that leave the scene.
    pub fn environment(&self) -> Vec3A {
        self.environment
    }
}

/// How to render: image size, samples, seed and path-length controls.
#[derive(Clone, Copy, Debug)]
pub struct RenderParams {
    pub width: u32,
    pub height: u32,
    pub spp: u32,
    pub seed: u32,
    pub max_bounces: u32,
    pub rr_depth: u32,
    /// Which CPU path traces the samples (the same image from each).
    pub tracer: Tracer,
    /// Where the random numbers come from.
    pub sampler: Sampler,
}

/// The CPU paths of the renderer; each gives the scalar path's image bit
/// for bit (cases `pt_packet_equals_scalar`, `pt_wavefront_equals_scalar`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Tracer {
    /// One path at a time ([`trace`]): the referee.
    Scalar,
    /// Eight paths at a time, rays tested eight at a time, each vertex
    /// shaded one lane at a time ([`trace_paths8`]).
    Packet,
    /// Eight paths at a time, whole vertices in eight lanes
    /// ([`trace_paths_wave8`]).
    #[default]
    Wavefront,
}

impl RenderParams {
    pub fn validate(&self) -> Result<()> {
        for (k, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > crate::rays::MAX_SIDE {
                return Err(Error::invalid(
                    k,
                    format!("{v} is not in 1..={}", crate::rays::MAX_SIDE),
                ));
            }
        }
        if self.spp == 0 {
            return Err(Error::invalid("spp", "must be >= 1"));
        }
        let (w, h, spp) = (self.width as u64, self.height as u64, self.spp as u64);
        let work = [(w, "width"), (h, "height"), (spp, "spp")];
        crate::budget::check_work("spp", &work, "paths per render", MAX_PATHS)?;
        // Dimensions of the deepest vertex must fit in u32.
        if self.max_bounces > 1 << 24 {
            return Err(Error::invalid(
                "max_bounces",
                format!("{} is over 2^24", self.max_bounces),
            ));
        }
        Ok(())
    }
}

/// The work budget of one render: width x height x spp paths, 2^36
/// (6.9e10; about 19 hours at 1e6 paths per second). Larger is refused on
/// load instead of running for days.
pub const MAX_PATHS: u64 = 1 << 36;

/// A rendered image: per-pixel mean radiance and the variance of that mean
/// (unbiased sample variance / spp; 0 when spp = 1), row-major, row 0 on top.
#[derive(Clone, Debug)]
pub struct Image {
    pub width: u32,
    pub height: u32,
    pub rgb: Vec<[f32; 3]>,
    pub variance: Vec<[f32; 3]>,
    /// Samples whose radiance was not finite (dropped as 0; should be 0).
    pub nonfinite: u64,
}

/// Russian roulette's survival probability for a path whose throughput
/// (times `eta^2`) has largest channel `m`: `min(RR_SCALE m, RR_CAP)`.
#[inline(always)]
pub fn survival(m: f32) -> f32 {
    (RR_SCALE * m).min(RR_CAP)
}

/// How many times its throughput a path's survival probability is.
pub const RR_SCALE: f32 = 3.0;

/// The highest survival probability: every path past `rr_depth` may end.
pub const RR_CAP: f32 = 0.95;

/// Power heuristic (beta = 2) weight of the strategy with density `a`.
#[inline]
fn power(a: f32, b: f32) -> f32 {
    let (a2, b2) = (a * a, b * b);
    if a2 + b2 > 0.0 {
        a2 / (a2 + b2)
    } else {
        0.0
    }
}

/// A light sample prepared at a non-delta vertex: the shadow ray (`o`,
/// `wi`, `tmax`) and the `beta`-less contribution `f |cos_i| Le w_l / p_l`
/// it adds when nothing blocks it.
#[derive(Clone, Copy, Debug)]
pub struct LightSample {
    pub o: Vec3A,
    pub wi: Vec3A,
    pub tmax: f32,
    pub value: Vec3A,
}

/// Light sampling at a non-delta vertex up to the shadow test (uniform
/// light choice, uniform point on its area); `None` where the sample is
/// worth 0 whatever blocks it.
#[inline]
pub fn light_sample(scene: &Scene, v: &Vertex, rng: &PathRng) -> Option<LightSample> {
    let nl = scene.lights.len();
    let base = v.base;
    let pick = ((rng.f(base + dims::LIGHT_CHOICE) * nl as f32) as usize).min(nl - 1);
    let li = scene.lights[pick] as usize;
    let Shape::Quad(q) = scene.shapes[li] else {
        return None;
    };
    let Material::Emitter { radiance } = scene.material(li) else {
        return None;
    };
    let [lu, lv] = rng.f2(base + dims::LIGHT_U);
    let x = q.point(lu, lv);
    let to = x - v.p;
    let dist2 = to.length_squared();
    if dist2 == 0.0 {
        return None;
    }
    let dist = dist2.sqrt();
    let wi = to / dist;
    let cos_l = -wi.dot(q.normal());
    if cos_l <= 0.0 {
        return None;
    }
    let wl = v.frame.to_local(wi);
    let f = v.mat.eval(v.wo, wl);
    if f == Vec3A::ZERO {
        return None;
    }
    let o = spawn_origin(v.p, v.n, wi);
    let pl = dist2 / (cos_l * q.area() * nl as f32);
    let w = power(pl, v.mat.pdf(v.wo, wl));
    Some(LightSample {
        o,
        wi,
        tmax: (x - o).length() * (1.0 - 1e-4),
        value: f * (wl.z.abs() * w / pl) * radiance,
    })
}

/// A scattering vertex: hit point, geometric normal, shading frame, `wo`
/// in local space, material and the vertex's first random dimension.
#[derive(Clone, Copy, Debug)]
pub struct Vertex {
    pub p: Vec3A,
    pub n: Vec3A,
    pub frame: Frame,
    pub wo: Vec3A,
    pub mat: Material,
    pub base: u32,
}

/// One path's state between vertices.
#[derive(Clone, Copy, Debug)]
pub struct PathState {
    pub o: Vec3A,
    pub d: Vec3A,
    pub l: Vec3A,
    beta: Vec3A,
    eta2: f32,
    prev_pdf: f32,
    prev_delta: bool,
    bounces: u32,
}

impl PathState {
    /// A camera path along `o + t d` (`d` unit).
    #[inline]
    pub fn new(o: Vec3A, d: Vec3A) -> PathState {
        PathState {
            o,
            d,
            l: Vec3A::ZERO,
            beta: Vec3A::ONE,
            eta2: 1.0,
            prev_pdf: 0.0,
            prev_delta: true,
            bounces: 0,
        }
    }

    /// The ray left the scene: add the environment.
    #[inline]
    pub fn miss(&mut self, scene: &Scene) {
        self.l += self.beta * scene.environment;
    }

    /// The ray met shape `idx` at `t`: adds emission seen through BSDF
    /// sampling (MIS-weighted after a non-delta bounce) and returns the
    /// vertex to scatter from, or `None` when the path ends here (a light,
    /// or `max_bounces` reached).
    #[inline]
    pub fn hit(&mut self, scene: &Scene, t: f32, idx: usize, max_bounces: u32) -> Option<Vertex> {
        let shape = scene.shapes[idx];
        let mat = scene.material(idx);
        let (p, n) = shape.surface(self.o, self.d, t);
        let frame = Frame::new(n);
        let wo = frame.to_local(-self.d);
        if let Material::Emitter { radiance } = mat {
            if wo.z > 0.0 {
                let w = match shape {
                    Shape::Quad(q) if !self.prev_delta => power(
                        self.prev_pdf,
                        t * t / (wo.z * q.area() * scene.lights.len() as f32),
                    ),
                    _ => 1.0,
                };
                self.l += self.beta * radiance * w;
            }
            return None;
        }
        if self.bounces >= max_bounces {
            return None;
        }
        Some(Vertex {
            p,
            n,
            frame,
            wo,
            mat,
            base: dims::FIRST_VERTEX + dims::STRIDE * self.bounces,
        })
    }

    /// Whether vertex `v` samples a light (non-delta, the scene has lights).
    #[inline]
    pub fn samples_light(scene: &Scene, v: &Vertex) -> bool {
        !v.mat.is_delta() && !scene.lights.is_empty()
    }

    /// Adds a light sample's contribution (0 when blocked or worthless).
    #[inline]
    pub fn add_light(&mut self, value: Vec3A) {
        self.l += self.beta * value;
    }

    /// Samples the BSDF at `v` and moves the path on; Russian roulette
    /// after `rr_depth` bounces. `false` when the path ends.
    #[inline]
    pub fn scatter(&mut self, v: &Vertex, rng: &PathRng, rr_depth: u32) -> bool {
        let base = v.base;
        let u = rng.f2(base + dims::BSDF_U);
        let Some(s) = v.mat.sample(v.wo, rng.f(base + dims::LOBE), u) else {
            return false;
        };
        self.beta *= s.weight;
        self.eta2 *= s.eta2;
        self.prev_pdf = s.pdf;
        self.prev_delta = s.delta;
        self.d = v.frame.to_world(s.wi).normalize();
        self.o = spawn_origin(v.p, v.n, self.d);
        self.bounces += 1;
        if self.bounces >= rr_depth {
            let q = survival((self.beta * self.eta2).max_element());
            let u = rng.f(base + dims::ROULETTE);
            if u.partial_cmp(&q) != Some(std::cmp::Ordering::Less) {
                return false;
            }
            self.beta /= q;
        }
        true
    }
}

/// Radiance along the camera ray `o + t d` (`d` unit) for one sample: the
/// scalar path, one ray at a time (the referee of `trace8::trace_paths8`).
#[inline]
pub fn trace(
    scene: &Scene,
    o: Vec3A,
    d: Vec3A,
    rng: &PathRng,
    max_bounces: u32,
    rr_depth: u32,
) -> Vec3A {
    let mut st = PathState::new(o, d);
    loop {
        let Some((t, idx)) = scene.packed.intersect(st.o, st.d, f32::INFINITY) else {
            st.miss(scene);
            break;
        };
        let Some(v) = st.hit(scene, t, idx, max_bounces) else {
            break;
        };
        if PathState::samples_light(scene, &v) {
            let value = match light_sample(scene, &v, rng) {
                Some(ls) if !scene.packed.occluded(ls.o, ls.wi, ls.tmax) => ls.value,
                _ => Vec3A::ZERO,
            };
            st.add_light(value);
        }
        if !st.scatter(&v, rng, rr_depth) {
            break;
        }
    }
    st.l
}

/// Per-pixel sums of sample radiance and its square, f64, added in sample
/// order (so the result does not depend on how work is spread over
/// threads or lanes), and the count of non-finite samples (dropped).
#[derive(Clone, Copy, Debug, Default)]
struct Sums {
    sum: [f64; 3],
    sq: [f64; 3],
    bad: u64,
}

impl Sums {
    #[inline]
    fn add(&mut self, l: Vec3A) {
        if !l.is_finite() {
            self.bad += 1;
            return;
        }
        for c in 0..3 {
            let x = l[c] as f64;
            self.sum[c] += x;
            self.sq[c] += x * x;
        }
    }
}

/// The camera ray of one sample of pixel `(u, v)`: position jittered
/// uniformly in the pixel (box filter).
#[inline]
fn camera_ray(cam: &RealCamera<f32>, u: u32, v: u32, rng: &PathRng) -> (Vec3A, Vec3A) {
    let [jx, jy] = rng.f2(dims::JITTER_X);
    let (px, py) = (u as f32 + jx, v as f32 + jy);
    let (o, d) = cam.ray(px, py);
    (Vec3A::from_array(o), Vec3A::from_array(d))
}

/// Paths traced per packet-path batch (bounds its radiance buffer).
const BATCH: usize = 4096;

/// Sums of the pixels `u0..u1` of row `v`. Packet path: the row's paths
/// (pixel-major, then sample) in batches through [`trace_paths8`], summed
/// in that order; scalar path: one [`trace`] per sample.
fn row_sums(
    scene: &Scene,
    cam: &RealCamera<f32>,
    p: &RenderParams,
    (u0, u1, v): (u32, u32, u32),
) -> Vec<Sums> {
    let spp = p.spp as usize;
    let mut sums = vec![Sums::default(); (u1 - u0) as usize];
    if p.tracer == Tracer::Scalar {
        for (i, s) in sums.iter_mut().enumerate() {
            let u = u0 + i as u32;
            let pk = pixel_key(p.seed, v * p.width + u);
            for k in 0..p.spp {
                let rng = PathRng::keyed(p.sampler, pk, k);
                let (o, d) = camera_ray(cam, u, v, &rng);
                s.add(trace(scene, o, d, &rng, p.max_bounces, p.rr_depth));
            }
        }
        return sums;
    }
    let total = sums.len() * spp;
    let pks: Vec<u32> = (u0..u1)
        .map(|u| pixel_key(p.seed, v * p.width + u))
        .collect();
    let mut buf = vec![Vec3A::ZERO; total.min(BATCH)];
    for b0 in (0..total).step_by(BATCH) {
        let n = (total - b0).min(BATCH);
        let start = |j: usize| {
            let (i, k) = ((b0 + j) / spp, (b0 + j) % spp);
            let u = u0 + i as u32;
            let rng = PathRng::keyed(p.sampler, pks[i], k as u32);
            let (o, d) = camera_ray(cam, u, v, &rng);
            (o, d, rng)
        };
        let out = &mut buf[..n];
        match p.tracer {
            Tracer::Packet => trace_paths8(scene, start, p.max_bounces, p.rr_depth, out),
            _ => trace_paths_wave8(scene, start, (p.max_bounces, p.rr_depth), p.sampler, out),
        }
        for (j, &l) in buf[..n].iter().enumerate() {
            sums[(b0 + j) / spp].add(l);
        }
    }
    sums
}

/// Tile side in pixels (work unit of the thread pool).
pub const TILE: u32 = 16;

/// Renders the image: rayon over `TILE` x `TILE` tiles, each pixel's
/// samples in order. Refuses images over the memory budget.
pub fn render(
    scene: &Scene,
    cam: &RealCamera<f32>,
    p: &RenderParams,
    budget: &MemBudget,
) -> Result<Image> {
    p.validate()?;
    let n = p.width as u64 * p.height as u64;
    // Image + variance (f32 x 3 each) and per-tile f64 sums (x 6 each).
    budget.check("pathtrace image", bytes_for(n, 24 + 48))?;
    let (tw, th) = (p.width.div_ceil(TILE), p.height.div_ceil(TILE));
    let tiles = par_collect("pathtrace.render", (tw * th) as usize, |ti| {
        let (tx, ty) = (ti as u32 % tw, ti as u32 / tw);
        let (u0, u1) = (tx * TILE, ((tx + 1) * TILE).min(p.width));
        let mut out = Vec::with_capacity((TILE * TILE) as usize);
        for v in ty * TILE..((ty + 1) * TILE).min(p.height) {
            let sums = row_sums(scene, cam, p, (u0, u1, v));
            out.extend((u0..u1).map(|u| v * p.width + u).zip(sums));
        }
        out
    });
    let mut rgb = vec![[0.0f32; 3]; n as usize];
    let mut variance = vec![[0.0f32; 3]; n as usize];
    let mut nonfinite = 0;
    let k = p.spp as f64;
    for (pixel, Sums { sum, sq, bad }) in tiles.into_iter().flatten() {
        let i = pixel as usize;
        for c in 0..3 {
            let mean = sum[c] / k;
            rgb[i][c] = mean as f32;
            variance[i][c] = if p.spp > 1 {
                ((sq[c] - k * mean * mean).max(0.0) / (k * (k - 1.0))) as f32
            } else {
                0.0
            };
        }
        nonfinite += bad;
    }
    Ok(Image {
        width: p.width,
        height: p.height,
        rgb,
        variance,
        nonfinite,
    })
}

/// The first surface each pixel centre's camera ray meets: shape index (-1
/// on a miss) and hit point. For judging image features by world position.
pub fn first_hits(
    scene: &Scene,
    cam: &RealCamera<f32>,
    width: u32,
    height: u32,
) -> Vec<(i32, [f32; 3])> {
    par_collect("pathtrace.first_hits", (width * height) as usize, |i| {
        let (u, v) = (i as u32 % width, i as u32 / width);
        let (o, d) = cam.ray(u as f32 + 0.5, v as f32 + 0.5);
        let (o, d) = (Vec3A::from_array(o), Vec3A::from_array(d));
        match scene.packed.intersect(o, d, f32::INFINITY) {
            Some((t, k)) => (k as i32, scene.shapes[k].surface(o, d, t).0.to_array()),
            None => (-1, [0.0; 3]),
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::camera::Camera;
    use crate::pathtrace::shapes::{Quad, Sphere};

    fn furnace(mat: Material) -> (Scene, RealCamera<f32>) {
        let s = Shape::Sphere(Sphere {
            centre: Vec3A::ZERO,
            radius: 1.0,
        });
        let scene = Scene::new(&[(s, 0)], vec![mat], [0.5, 0.5, 0.5]).unwrap();
        let cam = Camera::pinhole_look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 30.0, 16, 16)
            .unwrap();
        (scene, cam.to_real(16, 16))
    }

    fn params(spp: u32) -> RenderParams {
        RenderParams {
            width: 16,
            height: 16,
            spp,
            seed: 1,
            max_bounces: 64,
            rr_depth: 5,
            tracer: Tracer::Wavefront,
            sampler: Sampler::Independent,
        }
    }

    #[test]
    fn survival_is_three_times_the_largest_channel_below_the_cap() {
        assert_eq!(survival(0.0), 0.0);
        assert_eq!(survival(0.2), 3.0 * 0.2);
        assert_eq!(survival(0.3), 3.0 * 0.3);
        assert_eq!(survival(0.5), 0.95);
        assert_eq!(survival(4.0), 0.95);
    }

    #[test]
    fn white_lambertian_sphere_vanishes_in_a_furnace() {
        let (scene, cam) = furnace(Material::Lambertian { albedo: Vec3A::ONE });
        let img = render(&scene, &cam, &params(4), &MemBudget::fixed(1 << 30)).unwrap();
        for px in &img.rgb {
            for c in px {
                assert!((c - 0.5).abs() < 1e-5, "{c}");
            }
        }
    }

    #[test]
    fn glass_sphere_conserves_energy_in_a_furnace() {
        let (scene, cam) = furnace(Material::Dielectric { ior: 1.5 });
        let img = render(&scene, &cam, &params(16), &MemBudget::fixed(1 << 30)).unwrap();
        let mean: f64 = img.rgb.iter().map(|p| p[0] as f64).sum::<f64>() / img.rgb.len() as f64;
        assert!((mean - 0.5).abs() < 0.01, "{mean}");
    }

    /// Each pixel is the mean of `trace` over samples `0..spp` of that
    /// pixel, sample `k` drawing `PathRng::of(sampler, seed, pixel, k)`
    /// (SCENES.md's `rand(seed, pixel, sample, dim)`) and jittered by its
    /// dimensions 0 and 1, bit for bit: the renderer's keys hashed once per
    /// pixel and its reversed sample indices change no number. Both
    /// samplers, the scalar and wavefront tracers, 5 spp (not a power of 2).
    #[test]
    fn every_sample_draws_the_numbers_of_its_own_pixel_and_index() {
        let (scene, cam) = small_scene();
        for sampler in [Sampler::Independent, Sampler::Sobol] {
            for tracer in [Tracer::Scalar, Tracer::Wavefront] {
                let p = RenderParams {
                    sampler,
                    tracer,
                    ..params(5)
                };
                let img = render(&scene, &cam, &p, &MemBudget::fixed(1 << 30)).unwrap();
                for (i, px) in img.rgb.iter().enumerate() {
                    let (u, v) = (i as u32 % p.width, i as u32 / p.width);
                    let mut sum = [0.0f64; 3];
                    for k in 0..p.spp {
                        let rng = PathRng::of(sampler, p.seed, i as u32, k);
                        let [jx, jy] = [rng.f(0), rng.f(1)];
                        let (o, d) = cam.ray(u as f32 + jx, v as f32 + jy);
                        let (o, d) = (Vec3A::from_array(o), Vec3A::from_array(d));
                        let l = trace(&scene, o, d, &rng, p.max_bounces, p.rr_depth);
                        for (s, x) in sum.iter_mut().zip(l.to_array()) {
                            *s += x as f64;
                        }
                    }
                    let want = sum.map(|x| (x / p.spp as f64) as f32);
                    assert_eq!(*px, want, "{sampler:?} {tracer:?} pixel {i}");
                }
            }
        }
    }

    /// A light quad, a floor and a metal sphere seen by a 16x16 camera.
    fn small_scene() -> (Scene, RealCamera<f32>) {
        let q = Quad::new(
            Vec3A::new(-0.3, 1.5, -0.3),
            Vec3A::new(0.6, 0.0, 0.0),
            Vec3A::new(0.0, 0.0, 0.6),
        )
        .unwrap();
        let floor = Quad::new(
            Vec3A::new(-2.0, -1.0, -2.0),
            Vec3A::new(0.0, 0.0, 4.0),
            Vec3A::new(4.0, 0.0, 0.0),
        )
        .unwrap();
        let objs = [
            (Shape::Quad(q), 1),
            (Shape::Quad(floor), 0),
            (
                Shape::Sphere(Sphere {
                    centre: Vec3A::ZERO,
                    radius: 0.5,
                }),
                2,
            ),
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
                reflectance: Vec3A::splat(0.9),
            },
        ];
        let scene = Scene::new(&objs, mats, [0.0; 3]).unwrap();
        let cam = Camera::pinhole_look_at([0.0, 0.0, 4.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 16, 16)
            .unwrap();
        (scene, cam.to_real(16, 16))
    }

    #[test]
    fn renders_are_identical_across_thread_counts() {
        let (scene, cam) = small_scene();
        let b = MemBudget::fixed(1 << 30);
        let a = crate::parallel::with_threads(1, || render(&scene, &cam, &params(8), &b).unwrap());
        let c = crate::parallel::with_threads(3, || render(&scene, &cam, &params(8), &b).unwrap());
        assert_eq!(a.rgb, c.rgb);
        assert_eq!(a.variance, c.variance);
        assert!(a.rgb.iter().any(|p| p[0] > 0.0));
    }

    #[test]
    fn sphere_emitters_and_bad_indices_are_refused() {
        let s = Shape::Sphere(Sphere {
            centre: Vec3A::ZERO,
            radius: 1.0,
        });
        assert!(Scene::new(
            &[(s, 0)],
            vec![Material::Emitter {
                radiance: Vec3A::ONE
            }],
            [0.0; 3]
        )
        .is_err());
        assert!(Scene::new(&[(s, 1)], vec![Material::Dielectric { ior: 1.5 }], [0.0; 3]).is_err());
    }
}
