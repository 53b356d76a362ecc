//! `f_ray`: ray generation and AABB clipping (seed 000, module 1; SCENES.md
//! "Camera" and "World box"). Output is a structure of arrays:
//! `Rays { o, d, t0, t1, pixel }`. A ray that misses the box has `t1 <= t0`
//! (both set to `near`); no NaN or Inf ever leaves this stage. Its referee
//! (f64 rays from K and C2W, face-plane clipping) is [`referee`].

pub mod referee;
pub mod referee_pinhole;
pub mod thread_order;

use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::real::Real;
use crate::rng::rand_f64;
use crate::tensor::{Outputs, Tensor};

/// Axis-aligned box, closed: a point on a face is inside.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Aabb {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

impl Aabb {
    /// The default world box [-1, 1]^3.
    pub const UNIT: Aabb = Aabb {
        min: [-1.0; 3],
        max: [1.0; 3],
    };

    pub fn validate(&self) -> Result<()> {
        for a in 0..3 {
            if !(self.min[a].is_finite() && self.max[a].is_finite() && self.min[a] < self.max[a]) {
                return Err(Error::invalid(
                    "aabb",
                    format!("axis {a}: need finite min < max, got {:?}", self),
                ));
            }
        }
        Ok(())
    }
}

/// Region of interest in pixels: columns `x .. x + width`, rows `y .. y + height`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Roi {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

/// Anti-aliasing jitter: pixel position `(u + rand(seed, pixel, sample, 0),
/// v + rand(seed, pixel, sample, 1))` instead of the pixel centre.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Jitter {
    pub seed: u32,
    pub sample: u32,
}

/// Everything `f_ray` needs besides the camera.
#[derive(Clone, Debug, PartialEq)]
pub struct RayGen {
    pub width: u32,
    pub height: u32,
    pub roi: Option<Roi>,
    pub aabb: Aabb,
    pub near: f64,
    pub far: f64,
    pub jitter: Option<Jitter>,
}

/// The largest image side accepted (a sanity bound; memory is checked separately).
pub const MAX_SIDE: u32 = 1 << 16;

impl RayGen {
    /// A plain generator: whole image, box [-1, 1]^3, near 0, far infinity, no jitter.
    pub fn new(width: u32, height: u32) -> Self {
        RayGen {
            width,
            height,
            roi: None,
            aabb: Aabb::UNIT,
            near: 0.0,
            far: f64::INFINITY,
            jitter: None,
        }
    }

    /// The pixel rectangle rays are made for.
    /// The jittered pixel offsets (x, y in [0, 1)) of every pixel of the
    /// region, row-major, as `f_ray` draws them; `None` without jitter.
    pub fn jitter_offsets(&self) -> Option<(Vec<f64>, Vec<f64>)> {
        let j = self.jitter?;
        let roi = self.region();
        let n = roi.width as usize * roi.height as usize;
        let (mut x, mut y) = (Vec::with_capacity(n), Vec::with_capacity(n));
        for i in 0..n as u32 {
            let pixel = (roi.y + i / roi.width) * self.width + roi.x + i % roi.width;
            x.push(rand_f64(j.seed, pixel, j.sample, 0));
            y.push(rand_f64(j.seed, pixel, j.sample, 1));
        }
        Some((x, y))
    }

    /// `[height, width]` of the region: the shape of per-pixel outputs.
    pub fn shape(&self) -> [usize; 2] {
        let r = self.region();
        [r.height as usize, r.width as usize]
    }

    pub fn region(&self) -> Roi {
        self.roi.unwrap_or(Roi {
            x: 0,
            y: 0,
            width: self.width,
            height: self.height,
        })
    }

    pub fn validate(&self) -> Result<()> {
        for (k, v) in [("width", self.width), ("height", self.height)] {
            if v == 0 || v > MAX_SIDE {
                return Err(Error::invalid(k, format!("{v} is not in 1..={MAX_SIDE}")));
            }
        }
        if let Some(r) = self.roi {
            let inside = r.width > 0
                && r.height > 0
                && r.x.checked_add(r.width).is_some_and(|e| e <= self.width)
                && r.y.checked_add(r.height).is_some_and(|e| e <= self.height);
            if !inside {
                return Err(Error::invalid(
                    "roi",
                    format!(
                        "{r:?} is empty or not inside {}x{}",
                        self.width, self.height
                    ),
                ));
            }
        }
        self.aabb.validate()?;
        if !(self.near >= 0.0 && self.near.is_finite() && self.far > self.near) {
            return Err(Error::invalid(
                "near/far",
                format!("need 0 <= near < far, got {} and {}", self.near, self.far),
            ));
        }
        Ok(())
    }
}

/// A batch of rays as separate arrays. `pixel[i]` is the linear index
/// `v * W + u` of the full image.
#[derive(Clone, Debug, PartialEq)]
pub struct Rays<F> {
    pub o: Vec<[F; 3]>,
    pub d: Vec<[F; 3]>,
    pub t0: Vec<F>,
    pub t1: Vec<F>,
    pub pixel: Vec<u32>,
}

impl<F: Real> Rays<F> {
    /// An empty batch with room for `n` rays.
    pub fn with_capacity(n: usize) -> Self {
        Rays {
            o: Vec::with_capacity(n),
            d: Vec::with_capacity(n),
            t0: Vec::with_capacity(n),
            t1: Vec::with_capacity(n),
            pixel: Vec::with_capacity(n),
        }
    }

    /// Appends one ray.
    pub fn push(&mut self, o: [F; 3], d: [F; 3], t0: F, t1: F, pixel: u32) {
        self.o.push(o);
        self.d.push(d);
        self.t0.push(t0);
        self.t1.push(t1);
        self.pixel.push(pixel);
    }

    /// Bytes one ray takes in this layout.
    pub const BYTES_PER_RAY: u64 = (8 * std::mem::size_of::<F>() + 4) as u64;

    pub fn len(&self) -> usize {
        self.pixel.len()
    }

    pub fn is_empty(&self) -> bool {
        self.pixel.is_empty()
    }

    /// Whether ray `i` meets the box (`t1 > t0`).
    pub fn hits(&self, i: usize) -> bool {
        self.t1[i] > self.t0[i]
    }

    /// The rays as one (N, 9) float64 array `ox oy oz dx dy dz t0 t1 pixel`:
    /// the format `--dump-failing` writes and `render --rays` replays.
    pub fn to_tensor(&self) -> Result<Tensor> {
        let mut v = Vec::with_capacity(self.len() * 9);
        for i in 0..self.len() {
            v.extend(self.o[i].iter().map(|x| x.f64()));
            v.extend(self.d[i].iter().map(|x| x.f64()));
            v.extend([self.t0[i].f64(), self.t1[i].f64(), self.pixel[i] as f64]);
        }
        Tensor::from_shape_vec(&[self.len(), 9], v)
    }

    /// Reads rays from the (N, 9) layout of [`Rays::to_tensor`]; `at` names
    /// the source for errors. Directions must be unit length (within 1e-6).
    pub fn from_tensor(t: &Tensor, at: &str) -> Result<Rays<F>> {
        let s = t.shape();
        if !t.is_float() || s.len() != 2 || s[1] != 9 {
            return Err(Error::invalid(
                at,
                format!("rays must be float (N, 9), got {} {:?}", t.dtype(), s),
            ));
        }
        let v = t.to_f64_vec();
        let n = s[0];
        let mut r = Rays::with_capacity(n);
        for i in 0..n {
            let row = &v[i * 9..i * 9 + 9];
            if row.iter().any(|x| !x.is_finite()) {
                return Err(Error::invalid(
                    at,
                    format!("ray {i} has a non-finite value"),
                ));
            }
            let dl = (row[3] * row[3] + row[4] * row[4] + row[5] * row[5]).sqrt();
            if (dl - 1.0).abs() > 1e-6 {
                return Err(Error::invalid(at, format!("ray {i}: |d| = {dl}, not 1")));
            }
            if row[8] < 0.0 || row[8] > u32::MAX as f64 || row[8].fract() != 0.0 {
                return Err(Error::invalid(
                    at,
                    format!("ray {i}: pixel {} is not a u32", row[8]),
                ));
            }
            let o = [F::of(row[0]), F::of(row[1]), F::of(row[2])];
            let d = [F::of(row[3]), F::of(row[4]), F::of(row[5])];
            r.push(o, d, F::of(row[6]), F::of(row[7]), row[8] as u32);
        }
        Ok(r)
    }

    /// The SCENES.md ray outputs, shaped `shape`: o, d, t0, t1, hit (uint8),
    /// pixel (int32); counters rays, hits.
    pub fn to_outputs(&self, shape: &[usize], out: &mut Outputs) -> Result<()> {
        out.tensor("o", Tensor::real3(shape, &self.o)?);
        out.tensor("d", Tensor::real3(shape, &self.d)?);
        out.tensor("t0", Tensor::real(shape, self.t0.clone())?);
        out.tensor("t1", Tensor::real(shape, self.t1.clone())?);
        let hit: Vec<u8> = (0..self.len()).map(|i| self.hits(i) as u8).collect();
        let hits = hit.iter().filter(|&&h| h == 1).count() as u64;
        out.tensor("hit", Tensor::from_shape_vec(shape, hit)?);
        let pixel: Vec<i32> = self.pixel.iter().map(|&p| p as i32).collect();
        out.tensor("pixel", Tensor::from_shape_vec(shape, pixel)?);
        out.counter("rays", self.len() as u64).counter("hits", hits);
        Ok(())
    }

    /// Re-clips every ray to `gen`'s box and `[near, far]` (replayed rays).
    pub fn clip_to(&mut self, gen: &RayGen) {
        let (bmin, bmax) = (gen.aabb.min.map(F::of), gen.aabb.max.map(F::of));
        let (near, far) = (F::of(gen.near), F::of(gen.far));
        for i in 0..self.len() {
            (self.t0[i], self.t1[i]) = clip_aabb(self.o[i], self.d[i], bmin, bmax, near, far);
        }
    }
}

/// `(t0, t1, hit)` of rays listed as `[ox, oy, oz, dx, dy, dz]` (d
/// normalised in f64 first) clipped to `b` in precision `F`.
pub fn clip_list<F: Real>(
    rays: &[[f64; 6]],
    b: &Aabb,
    near: f64,
    far: f64,
) -> (Vec<F>, Vec<F>, Vec<u8>) {
    let (mut t0, mut t1, mut hit) = (vec![], vec![], vec![]);
    for r in rays {
        let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
        let (o, d) = ([r[0], r[1], r[2]], [r[3] / n, r[4] / n, r[5] / n]);
        let (a, c) = clip_aabb(
            o.map(F::of),
            d.map(F::of),
            b.min.map(F::of),
            b.max.map(F::of),
            F::of(near),
            F::of(far),
        );
        t0.push(a);
        t1.push(c);
        hit.push((c > a) as u8);
    }
    (t0, t1, hit)
}

/// [`clip_list`] in `F`, as outputs t0, t1, hit.
pub fn clip_list_in<F: Real>(rays: &[[f64; 6]], b: &Aabb, near: f64, far: f64) -> Result<Outputs> {
    clip_list_outputs(clip_list::<F>(rays, b, near, far))
}

/// Outputs t0, t1, hit of a listed clip ([`clip_list`] or its referee).
pub fn clip_list_outputs<F: Real>((t0, t1, hit): (Vec<F>, Vec<F>, Vec<u8>)) -> Result<Outputs> {
    let n = [hit.len()];
    let mut out = Outputs::default();
    out.tensor("t0", Tensor::real(&n, t0)?)
        .tensor("t1", Tensor::real(&n, t1)?);
    out.tensor("hit", Tensor::from_shape_vec(&n, hit)?);
    Ok(out)
}

/// Clips the ray `o + t d` to the closed box, starting from `[near, far]`.
/// Slab method with the axis-parallel case handled explicitly (no 0 * inf).
/// Returns `(t0, t1)`; on a miss `t0 = t1 = near`.
#[inline]
pub fn clip_aabb<F: Real>(
    o: [F; 3],
    d: [F; 3],
    bmin: [F; 3],
    bmax: [F; 3],
    near: F,
    far: F,
) -> (F, F) {
    let mut lo = near;
    let mut hi = far;
    for a in 0..3 {
        if d[a] == F::zero() {
            if o[a] < bmin[a] || o[a] > bmax[a] {
                return (near, near);
            }
            continue;
        }
        let inv = F::one() / d[a];
        let ta = (bmin[a] - o[a]) * inv;
        let tb = (bmax[a] - o[a]) * inv;
        lo = lo.max(ta.min(tb));
        hi = hi.min(ta.max(tb));
    }
    if hi > lo {
        (lo, hi)
    } else {
        (near, near)
    }
}

/// `f_ray`: one ray per pixel of the region, clipped to the box. Pixel
/// positions are centres, or jittered with [`Jitter`]. Refuses plans over
/// the memory budget before allocating. GPU twin: `kernels/rays.wgsl` entry
/// `f_ray` (host side `src/gpu/rays.rs`; parity cases `gpu_rays_*_parity`).
pub fn f_ray<F: Real>(cam: &Camera, gen: &RayGen, budget: &MemBudget) -> Result<Rays<F>> {
    gen.validate()?;
    cam.validate()?;
    let roi = gen.region();
    let n = roi.width as u64 * roi.height as u64;
    budget.check("f_ray rays", bytes_for(n, Rays::<F>::BYTES_PER_RAY))?;
    let rc = cam.to_real::<F>(gen.width, gen.height);
    let (bmin, bmax) = (gen.aabb.min.map(F::of), gen.aabb.max.map(F::of));
    let (near, far) = (F::of(gen.near), F::of(gen.far));
    let (w, rw) = (gen.width, roi.width);
    let one_ray = |i: usize| {
        let u = roi.x + (i as u32 % rw);
        let v = roi.y + (i as u32 / rw);
        let pixel = v * w + u;
        let (jx, jy) = match gen.jitter {
            Some(j) => (
                rand_f64(j.seed, pixel, j.sample, 0),
                rand_f64(j.seed, pixel, j.sample, 1),
            ),
            None => (0.5, 0.5),
        };
        let (o, d) = rc.ray(F::of(u as f64 + jx), F::of(v as f64 + jy));
        let (t0, t1) = clip_aabb(o, d, bmin, bmax, near, far);
        (o, d, t0, t1, pixel)
    };
    // Tiles of rays computed in parallel, then concatenated with memcpy.
    const TILE: usize = 4096;
    let n = n as usize;
    let tiles = par_collect("f_ray", n.div_ceil(TILE), |t| {
        let range = t * TILE..((t + 1) * TILE).min(n);
        let mut r = Rays::with_capacity(range.len());
        for i in range {
            let (o, d, t0, t1, p) = one_ray(i);
            r.push(o, d, t0, t1, p);
        }
        r
    });
    let mut r = Rays::with_capacity(n);
    for t in &tiles {
        r.o.extend_from_slice(&t.o);
        r.d.extend_from_slice(&t.d);
        r.t0.extend_from_slice(&t.t0);
        r.t1.extend_from_slice(&t.t1);
        r.pixel.extend_from_slice(&t.pixel);
    }
    Ok(r)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn axis_parallel_rays_on_a_face_hit_and_beside_it_miss() {
        let (bmin, bmax) = ([-1.0f64; 3], [1.0f64; 3]);
        let (t0, t1) = clip_aabb(
            [1.0, 0.0, 3.0],
            [0.0, 0.0, -1.0],
            bmin,
            bmax,
            0.0,
            f64::INFINITY,
        );
        assert_eq!((t0, t1), (2.0, 4.0));
        let (t0, t1) = clip_aabb(
            [1.0 + 1e-12, 0.0, 3.0],
            [0.0, 0.0, -1.0],
            bmin,
            bmax,
            0.0,
            f64::INFINITY,
        );
        assert!(t1 <= t0);
    }

    #[test]
    fn origin_inside_starts_at_near() {
        let (t0, t1) = clip_aabb(
            [0.0f64; 3],
            [1.0, 0.0, 0.0],
            [-1.0; 3],
            [1.0; 3],
            0.25,
            f64::INFINITY,
        );
        assert_eq!((t0, t1), (0.25, 1.0));
    }

    #[test]
    fn zero_and_oversized_images_are_refused_before_allocating() {
        let cam = Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 4, 4)
            .unwrap();
        let b = MemBudget::fixed(1 << 20);
        assert!(f_ray::<f32>(&cam, &RayGen::new(0, 4), &b).is_err());
        let e = f_ray::<f32>(&cam, &RayGen::new(MAX_SIDE, MAX_SIDE), &b).unwrap_err();
        assert!(matches!(e, Error::OutOfMemory { .. }), "{e}");
    }

    #[test]
    fn roi_pixels_index_the_full_image() {
        let cam = Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6)
            .unwrap();
        let mut g = RayGen::new(8, 6);
        g.roi = Some(Roi {
            x: 2,
            y: 1,
            width: 3,
            height: 2,
        });
        let r = f_ray::<f64>(&cam, &g, &MemBudget::fixed(1 << 20)).unwrap();
        assert_eq!(r.pixel, vec![10, 11, 12, 18, 19, 20]);
    }

    #[test]
    fn rays_survive_the_dump_format() {
        let cam = Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 4, 4)
            .unwrap();
        let r = f_ray::<f64>(&cam, &RayGen::new(4, 4), &MemBudget::fixed(1 << 20)).unwrap();
        let back = Rays::<f64>::from_tensor(&r.to_tensor().unwrap(), "x").unwrap();
        assert_eq!(back, r);
    }
}
