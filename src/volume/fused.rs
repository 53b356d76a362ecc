//! `f_fused`: ray generation, sampling, field query and integration in one
//! pass per ray, with no per-sample buffers (seed 000, module 5).
//!
//! [`march_ray`] is the whole per-ray loop as a pure function; its GPU twin
//! is `kernels/volume.wgsl` entry `f_fused` (parity cases
//! `gpu_vol_*_parity`). It walks the lattice of `sample.rs` (`walk_lattice`)
//! and drives the same [`RayAcc`] as `f_int`, so the fused and unfused
//! chains perform the same operations on the same numbers: bit-identical in
//! f32 and f64.
//!
//! Rays are processed in 8 x 8 pixel tiles (neighbouring rays touch the same
//! grid cells, so the dense grid stays in cache), tiles in parallel. Where
//! `fused_lanes` covers the render (f32 packed grid, AVX2), each tile row
//! of 8 rays marches in 8 SIMD lanes, bit-identical to [`march_ray`].

use crate::budget::{bytes_for, MemBudget};
use crate::camera::{Camera, RealCamera};
use crate::error::Result;
use crate::parallel::par_collect;
use crate::rays::{clip_aabb, RayGen};
use crate::real::Real;
use crate::rng::rand_f64;

use super::field::Medium;
use super::fused_lanes::{query_of, LaneMarch, LaneRay};
use super::integrate::{RayAcc, RayOut};
use super::occupancy::Occupancy;
use super::sample::{walk_lattice, March, TransPath};

/// The per-ray loop: returns the ray's result and the lattice points the
/// occupancy bitfield skipped.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn march_ray<F: Real>(
    o: [F; 3],
    d: [F; 3],
    t0: F,
    t1: F,
    pixel: u32,
    medium: &Medium<F>,
    m: &March<F>,
    occ: Option<&Occupancy<F>>,
) -> (RayOut<F>, u64) {
    match m.path {
        TransPath::Product => march_ray_path::<F, false>(o, d, t0, t1, pixel, medium, m, occ),
        TransPath::Log => march_ray_path::<F, true>(o, d, t0, t1, pixel, medium, m, occ),
    }
}

#[inline]
#[allow(clippy::too_many_arguments)]
fn march_ray_path<F: Real, const LOG: bool>(
    o: [F; 3],
    d: [F; 3],
    t0: F,
    t1: F,
    pixel: u32,
    medium: &Medium<F>,
    m: &March<F>,
    occ: Option<&Occupancy<F>>,
) -> (RayOut<F>, u64) {
    let mut acc = RayAcc::default();
    let (flags, skipped) = walk_lattice(o, d, t0, t1, pixel, m, occ, |_, t, h, x| {
        let tk = acc.transmittance::<LOG>();
        if tk < m.early_stop {
            return false;
        }
        let (sigma, c) = medium.query(x);
        acc.step(tk, sigma, c, t, h);
        true
    });
    (acc.finish::<LOG>(m.background, flags), skipped)
}

/// Tile side in pixels.
pub const TILE: u32 = 8;

/// `f_fused` output: per-ray results in region order (row-major over the
/// region, as `f_ray` orders rays) and their pixel ids.
#[derive(Clone, Debug, PartialEq)]
pub struct Fused<F> {
    pub rays: Vec<RayOut<F>>,
    pub pixel: Vec<u32>,
    pub skipped: u64,
}

/// Bytes per ray of the fused plan (results + pixel ids).
pub fn fused_bytes_per_ray<F: Real>() -> u64 {
    (std::mem::size_of::<RayOut<F>>() + 4) as u64
}

/// The camera ray of pixel (u, v), clipped: the same operations as `f_ray`.
#[inline]
#[allow(clippy::type_complexity)]
fn camera_ray<F: Real>(
    rc: &RealCamera<F>,
    gen: &RayGen,
    u: u32,
    v: u32,
    bmin: [F; 3],
    bmax: [F; 3],
) -> ([F; 3], [F; 3], F, F, u32) {
    let pixel = v * gen.width + u;
    let (jx, jy) = match gen.jitter {
        Some(j) => (
            rand_f64(j.seed, pixel, j.sample, 0),
            rand_f64(j.seed, pixel, j.sample, 1),
        ),
        None => (0.5, 0.5),
    };
    let (o, d) = rc.ray(F::of(u as f64 + jx), F::of(v as f64 + jy));
    let (t0, t1) = clip_aabb(o, d, bmin, bmax, F::of(gen.near), F::of(gen.far));
    (o, d, t0, t1, pixel)
}

/// `f_fused`: renders the region of `gen` through `cam`.
pub fn f_fused<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    medium: &Medium<F>,
    m: &March<F>,
    occ: Option<&Occupancy<F>>,
    budget: &MemBudget,
) -> Result<Fused<F>> {
    gen.validate()?;
    cam.validate()?;
    m.validate()?;
    let roi = gen.region();
    let n = roi.width as u64 * roi.height as u64;
    budget.check("f_fused rays", bytes_for(n, fused_bytes_per_ray::<F>()))?;
    let rc = cam.to_real::<F>(gen.width, gen.height);
    let (bmin, bmax) = (gen.aabb.min.map(F::of), gen.aabb.max.map(F::of));
    let (tw, th) = (roi.width.div_ceil(TILE), roi.height.div_ceil(TILE));
    let lanes = LaneMarch::new(medium, m, occ);
    let query = query_of(medium);
    let tiles = par_collect("f_fused", (tw * th) as usize, |ti| {
        let (tx, ty) = (ti as u32 % tw, ti as u32 / tw);
        let mut out = Vec::with_capacity((TILE * TILE) as usize);
        for dy in 0..TILE {
            let rv = ty * TILE + dy;
            let row: Vec<_> = (0..TILE)
                .map(|dx| tx * TILE + dx)
                .filter(|&ru| ru < roi.width && rv < roi.height)
                .map(|ru| (ru, camera_ray(&rc, gen, roi.x + ru, roi.y + rv, bmin, bmax)))
                .collect();
            if let Some(lm) = &lanes {
                let f = |v: F| v.f64() as f32;
                let rays: Vec<LaneRay> = row
                    .iter()
                    .map(|(_, (o, d, t0, t1, _))| LaneRay {
                        o: o.map(f),
                        d: d.map(f),
                        t0: f(*t0),
                        t1: f(*t1),
                    })
                    .collect();
                let res = lm.march8(&rays, &query);
                for ((ru, (.., pixel)), (acc, flags)) in row.iter().zip(res) {
                    let r = acc.finish::<false>(lm.background(), flags);
                    out.push(((rv * roi.width + ru) as usize, r.to_real(), 0, *pixel));
                }
                continue;
            }
            for (ru, (o, d, t0, t1, pixel)) in row {
                let (r, s) = march_ray(o, d, t0, t1, pixel, medium, m, occ);
                out.push(((rv * roi.width + ru) as usize, r, s, pixel));
            }
        }
        out
    });
    let blank = RayAcc::default().finish::<false>(m.background, 0);
    let mut f = Fused {
        rays: vec![blank; n as usize],
        pixel: vec![0; n as usize],
        skipped: 0,
    };
    for (i, r, s, p) in tiles.into_iter().flatten() {
        f.rays[i] = r;
        f.pixel[i] = p;
        f.skipped += s;
    }
    Ok(f)
}
