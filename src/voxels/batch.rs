//! A batch of rays for the voxel casts, in the cast's precision, with the
//! shape of its per-ray outputs and its `[near, far]`: camera rays (shaped
//! (H, W)), the hard and incoherent sets of `raysets` (shaped (N,), hard
//! rays with their `kind`), or replayed rays. The referee widens the same
//! rays to f64, so it judges exactly the rays the cast saw.
//!
//! Ray sources of the voxel ops (`params.rays`): `camera` (default: the scene's camera, tensors
//! shaped (H, W)), `hard` (`count` rays of each hard kind, shaped (N,), plus
//! `kind` (int32)), `incoherent` (`count` rays, origins uniform in the box,
//! uniform directions); `render --rays FILE` replays dumped rays (shape
//! (N,)), and `--dump-failing` adds `rays` (N, 9). `seed` defaults to the
//! run seed. Rays are made in the run's precision (`voxels::batch`).

use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;

use super::cast::CastParams;
use super::raysets::{hard, incoherent, Ray64, HARD_KINDS};
use super::shape::Shape;

/// The generated ray sets a voxel case draws from (`params.rays`).
#[derive(Clone, Copy, Debug, serde::Deserialize, PartialEq)]
#[serde(rename_all = "snake_case")]
pub enum RaySource {
    /// The scene's camera (tensors shaped (H, W)).
    Camera,
    /// `count` rays of each hard kind (shaped (N,), plus `kind`).
    Hard,
    /// `count` rays, origins uniform in the box, uniform directions.
    Incoherent,
}

/// Rays in precision `F` and the shape of their per-ray tensors.
pub struct Batch<F> {
    pub o: Vec<[F; 3]>,
    pub d: Vec<[F; 3]>,
    pub shape: Vec<usize>,
    pub near: f64,
    pub far: f64,
    /// Per ray, the index of its kind in [`HARD_KINDS`] (hard rays only).
    pub kind: Option<Vec<i32>>,
}

/// Origins and directions rounded to `F`.
pub fn from64<F: Real>(rays: Vec<Ray64>) -> (Vec<[F; 3]>, Vec<[F; 3]>) {
    rays.into_iter()
        .map(|(o, d)| (o.map(F::of), d.map(F::of)))
        .unzip()
}

impl<F: Real> Batch<F> {
    /// The camera's rays over `gen`'s region.
    pub fn camera(cam: &Camera, gen: &RayGen, budget: &MemBudget) -> Result<Batch<F>> {
        let r = f_ray::<F>(cam, gen, budget)?;
        let shape = gen.shape().to_vec();
        Ok(Batch {
            o: r.o,
            d: r.d,
            shape,
            near: gen.near,
            far: gen.far,
            kind: None,
        })
    }

    /// Replayed rays (their t0/t1 columns are ignored; `[near, far]` applies).
    pub fn replay(r: Rays<F>, near: f64, far: f64) -> Batch<F> {
        let n = r.len();
        Batch {
            o: r.o,
            d: r.d,
            shape: vec![n],
            near,
            far,
            kind: None,
        }
    }

    /// `count` incoherent rays (`raysets::incoherent`), over `[0, inf)`.
    pub fn incoherent(count: u32, seed: u32) -> Batch<F> {
        let (o, d) = from64::<F>(incoherent(count, seed));
        let shape = vec![count as usize];
        Batch {
            o,
            d,
            shape,
            near: 0.0,
            far: f64::INFINITY,
            kind: None,
        }
    }

    /// `count` rays of each hard kind (`raysets::hard`), over `[0, inf)`.
    pub fn hard(shape: &Shape, depth: u32, count: u32, seed: u32) -> Batch<F> {
        let h = hard(shape, depth, count, seed);
        let kind = h
            .iter()
            .map(|(_, k)| HARD_KINDS.iter().position(|x| x == k).unwrap_or(0) as i32)
            .collect();
        let (o, d) = from64::<F>(h.into_iter().map(|(r, _)| r).collect());
        let shape = vec![o.len()];
        Batch {
            o,
            d,
            shape,
            near: 0.0,
            far: f64::INFINITY,
            kind: Some(kind),
        }
    }

    /// Checks the budget for `count` rays of a generated set (`per_kind`
    /// sets of them) before drawing them.
    pub fn check_budget(count: u32, per_kind: bool, budget: &MemBudget) -> Result<()> {
        let total = count as u64 * if per_kind { HARD_KINDS.len() as u64 } else { 1 };
        budget.check("voxel rays", bytes_for(total, 2 * 24 + 64))
    }

    /// The cast parameters of this batch's interval.
    pub fn params(&self, lod: Option<super::cast::Lod>, max_iter: u32) -> CastParams {
        CastParams {
            near: self.near,
            far: self.far,
            lod,
            max_iter,
        }
    }

    /// The rays in f64.
    pub fn widen(&self) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
        (
            self.o.iter().map(|v| v.map(|x| x.f64())).collect(),
            self.d.iter().map(|v| v.map(|x| x.f64())).collect(),
        )
    }

    /// The batch in the (N, 9) dump layout of `Rays::to_tensor`
    /// (`--dump-failing`; `render --rays` replays it). An infinite far is
    /// written as 1e30.
    pub fn to_rays(&self) -> Rays<F> {
        let n = self.o.len();
        let far = if self.far.is_finite() { self.far } else { 1e30 };
        Rays {
            o: self.o.clone(),
            d: self.d.clone(),
            t0: vec![F::of(self.near); n],
            t1: vec![F::of(far); n],
            pixel: (0..n as u32).collect(),
        }
    }
}
