//! `f_samp`: the sample lattice and field query (seed 000, module 2;
//! SCENES.md "Fixed sampling" / "Stratified sampling").
//!
//! Interval k of a ray is `[a_k, b_k]`, `a_k = t0 + k dt` (a product, never
//! a running sum), `b_k = min(t0 + (k + 1) dt, t1)`, for `k < max_steps`
//! while `a_k < t1`. The sample sits at `t_k = (a_k + b_k) / 2` (fixed) or
//! `a_k + u_k (b_k - a_k)` with `u_k = rand(seed, pixel, 0, k)` (stratified);
//! `dt_k = b_k - a_k`; its position is `x = o + t_k d`.
//!
//! Output layout (shared with the backward pass, issue 4, and the GPU twin,
//! issue 5): samples packed ray after ray, `off[r]..off[r + 1]` the samples of
//! ray r (`off[0] = 0`, `off[n] = m`), `ray_id` per sample, then `t`, `dt`,
//! `sigma`, `color`. Positions are not stored: `sample_pos(o, d, t)` recomputes
//! them bit for bit.
//!
//! GPU twin: `kernels/volume.wgsl` entries `f_samp_count` and `f_samp_fill`
//! (parity cases `gpu_vol_*_unfused_parity`).

use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::gpu::codes;
use crate::parallel::{par_collect, par_each};
use crate::rays::Rays;
use crate::real::Real;
use crate::rng::rand_f64;

use super::field::{fmin, Medium};
use super::occupancy::Occupancy;

/// Largest `max_steps`: keeps `k` exact as an f32.
pub const MAX_STEPS_LIMIT: u32 = 1 << 24;

/// Where in its interval a sample sits.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Sampling {
    Fixed,
    Stratified { seed: u32 },
}

/// How transmittance is carried along a ray (both carry `log T` too).
/// `Product`: `T_{k+1} = T_k (1 - alpha_k)`. `Log`: `T_k = exp(log T_k)`
/// with `log T_{k+1} = log T_k - sigma_k dt_k` (compensated sum).
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TransPath {
    Product = 0,
    Log = 1,
}

/// Marching parameters of a render, in precision `F`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct March<F> {
    pub dt: F,
    pub max_steps: u32,
    /// Stop before sample k when `T_k < early_stop` (0 disables).
    pub early_stop: F,
    pub sampling: Sampling,
    pub path: TransPath,
    pub background: [F; 3],
}

impl<F: Real> March<F> {
    /// Checks the parameters (as given in f64 before rounding is fine too).
    pub fn validate(&self) -> Result<()> {
        if !(self.dt.is_finite() && self.dt > F::zero() && self.dt.f64() <= 1e3) {
            return Err(Error::invalid(
                "dt",
                format!("{} is not in (0, 1000]", self.dt),
            ));
        }
        if self.max_steps == 0 || self.max_steps > MAX_STEPS_LIMIT {
            return Err(Error::invalid(
                "max_steps",
                format!("{} is not in 1..={MAX_STEPS_LIMIT}", self.max_steps),
            ));
        }
        if !(self.early_stop >= F::zero() && self.early_stop < F::one()) {
            return Err(Error::invalid(
                "early_stop",
                format!("{} is not in [0, 1)", self.early_stop),
            ));
        }
        if self.background.iter().any(|c| !c.is_finite()) {
            return Err(Error::invalid("background", "must be finite"));
        }
        Ok(())
    }
}

/// Sample k of the ray `[t0, t1]`: `Some((t_k, dt_k))`, or `None` past the
/// end (`a_k >= t1`, or no progress because `dt` is below the spacing of
/// floats at `t`). The caller enforces `k < max_steps`.
#[inline]
pub fn sample_k<F: Real>(
    t0: F,
    t1: F,
    dt: F,
    k: u32,
    sampling: Sampling,
    pixel: u32,
) -> Option<(F, F)> {
    let a = t0 + F::of(k as f64) * dt;
    let b = fmin(t0 + F::of((k + 1) as f64) * dt, t1);
    if !(a < t1 && b > a) {
        return None;
    }
    let h = b - a;
    let t = match sampling {
        Sampling::Fixed => (a + b) * F::of(0.5),
        Sampling::Stratified { seed } => a + F::of(rand_f64(seed, pixel, 0, k)) * h,
    };
    Some((t, h))
}

/// `o + t d`.
#[inline]
pub fn sample_pos<F: Real>(o: [F; 3], d: [F; 3], t: F) -> [F; 3] {
    [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]]
}

/// Per-ray flag bits (in [`Samples::flags`] and `RayOut::flags`), the
/// values of `src/gpu/codes.rs` shared with the kernels.
pub const FLAG_HIT: u8 = codes::FLAG_HIT as u8;
pub const FLAG_STOPPED: u8 = codes::FLAG_STOPPED as u8;
pub const FLAG_TRUNCATED: u8 = codes::FLAG_TRUNCATED as u8;

/// `f_samp` output: packed samples (see the module doc).
#[derive(Clone, Debug, PartialEq)]
pub struct Samples<F> {
    pub off: Vec<u32>,
    pub ray_id: Vec<u32>,
    pub t: Vec<F>,
    pub dt: Vec<F>,
    pub sigma: Vec<F>,
    pub color: Vec<[F; 3]>,
    /// Per ray: [`FLAG_HIT`] when `t1 > t0`, [`FLAG_TRUNCATED`] when the
    /// lattice was cut by `max_steps`.
    pub flags: Vec<u8>,
    /// Lattice points skipped by the occupancy bitfield.
    pub skipped: u64,
}

impl<F: Real> Samples<F> {
    /// Bytes per sample in this layout.
    pub const BYTES_PER_SAMPLE: u64 = (4 + 6 * std::mem::size_of::<F>()) as u64;

    pub fn len(&self) -> usize {
        self.t.len()
    }

    pub fn is_empty(&self) -> bool {
        self.t.is_empty()
    }
}

/// The lattice of one ray: calls `each(k, t_k, dt_k, x)` for every sample
/// not skipped by `occ` until `each` returns false (early stop). Returns
/// (flags, skipped): [`FLAG_HIT`] when `t1 > t0`, [`FLAG_STOPPED`] when
/// `each` stopped the walk, [`FLAG_TRUNCATED`] when the lattice goes on past
/// `max_steps` (a property of the lattice, set whether or not the walk
/// stopped earlier).
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn walk_lattice<F: Real>(
    o: [F; 3],
    d: [F; 3],
    t0: F,
    t1: F,
    pixel: u32,
    m: &March<F>,
    occ: Option<&Occupancy<F>>,
    mut each: impl FnMut(u32, F, F, [F; 3]) -> bool,
) -> (u8, u64) {
    if t1 <= t0 {
        return (0, 0);
    }
    let mut skipped = 0;
    let mut flags = FLAG_HIT;
    // Inline [`sample_k`], with `t0 + (k + 1) dt` computed once and reused as
    // the next `a`: the same expressions, so the same bits.
    let mut a = t0;
    for k in 0..m.max_steps {
        let a_next = t0 + F::of((k + 1) as f64) * m.dt;
        let b = fmin(a_next, t1);
        if !(a < t1 && b > a) {
            return (flags, skipped);
        }
        let h = b - a;
        let t = match m.sampling {
            Sampling::Fixed => (a + b) * F::of(0.5),
            Sampling::Stratified { seed } => a + F::of(rand_f64(seed, pixel, 0, k)) * h,
        };
        a = a_next;
        let x = sample_pos(o, d, t);
        if occ.is_some_and(|o| !o.occupied(x)) {
            skipped += 1;
            continue;
        }
        if !each(k, t, h, x) {
            flags |= FLAG_STOPPED;
            break;
        }
    }
    if sample_k(t0, t1, m.dt, m.max_steps, m.sampling, pixel).is_some() {
        flags |= FLAG_TRUNCATED;
    }
    (flags, skipped)
}

/// Rays per parallel tile in the unfused stages.
pub const TILE_RAYS: usize = 256;

struct SampTile<'a, F> {
    first_ray: usize,
    ray_id: &'a mut [u32],
    t: &'a mut [F],
    dt: &'a mut [F],
    sigma: &'a mut [F],
    color: &'a mut [[F; 3]],
}

/// `f_samp`: every lattice sample of every ray, with sigma and colour
/// queried at it. Two passes (count, then fill); refuses plans over the
/// memory budget before the per-sample allocation.
pub fn f_samp<F: Real>(
    rays: &Rays<F>,
    medium: &Medium<F>,
    m: &March<F>,
    occ: Option<&Occupancy<F>>,
    budget: &MemBudget,
) -> Result<Samples<F>> {
    m.validate()?;
    let n = rays.len();
    let counts: Vec<(u32, u8, u64)> = par_collect("f_samp_count", n, |r| {
        let mut c = 0u32;
        let (f, s) = walk_lattice(
            rays.o[r],
            rays.d[r],
            rays.t0[r],
            rays.t1[r],
            rays.pixel[r],
            m,
            occ,
            |_, _, _, _| {
                c += 1;
                true
            },
        );
        (c, f, s)
    });
    let mut off = Vec::with_capacity(n + 1);
    off.push(0u32);
    let mut total: u64 = 0;
    for c in &counts {
        total += c.0 as u64;
        if total > u32::MAX as u64 {
            return Err(Error::invalid(
                "f_samp",
                format!(
                    "more than {} samples; use fewer rays or a larger dt",
                    u32::MAX
                ),
            ));
        }
        off.push(total as u32);
    }
    budget.check(
        "f_samp samples",
        bytes_for(total, Samples::<F>::BYTES_PER_SAMPLE),
    )?;
    let mtot = total as usize;
    let mut s = Samples {
        off,
        ray_id: vec![0; mtot],
        t: vec![F::zero(); mtot],
        dt: vec![F::zero(); mtot],
        sigma: vec![F::zero(); mtot],
        color: vec![[F::zero(); 3]; mtot],
        flags: counts.iter().map(|c| c.1).collect(),
        skipped: counts.iter().map(|c| c.2).sum(),
    };
    let mut tiles = Vec::with_capacity(n.div_ceil(TILE_RAYS));
    {
        let (mut ri, mut ti, mut dti, mut si, mut ci) = (
            &mut s.ray_id[..],
            &mut s.t[..],
            &mut s.dt[..],
            &mut s.sigma[..],
            &mut s.color[..],
        );
        for first in (0..n).step_by(TILE_RAYS) {
            let last = (first + TILE_RAYS).min(n);
            let len = (s.off[last] - s.off[first]) as usize;
            let (a, b) = std::mem::take(&mut ri).split_at_mut(len);
            ri = b;
            let (t, b) = std::mem::take(&mut ti).split_at_mut(len);
            ti = b;
            let (dtt, b) = std::mem::take(&mut dti).split_at_mut(len);
            dti = b;
            let (sg, b) = std::mem::take(&mut si).split_at_mut(len);
            si = b;
            let (cc, b) = std::mem::take(&mut ci).split_at_mut(len);
            ci = b;
            tiles.push(SampTile {
                first_ray: first,
                ray_id: a,
                t,
                dt: dtt,
                sigma: sg,
                color: cc,
            });
        }
    }
    par_each("f_samp_fill", tiles, |_, tile| {
        let mut j = 0usize;
        let last = (tile.first_ray + TILE_RAYS).min(n);
        for r in tile.first_ray..last {
            walk_lattice(
                rays.o[r],
                rays.d[r],
                rays.t0[r],
                rays.t1[r],
                rays.pixel[r],
                m,
                occ,
                |_, t, h, x| {
                    tile.ray_id[j] = r as u32;
                    tile.t[j] = t;
                    tile.dt[j] = h;
                    (tile.sigma[j], tile.color[j]) = medium.query(x);
                    j += 1;
                    true
                },
            );
        }
    });
    Ok(s)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn march(dt: f64, max_steps: u32) -> March<f64> {
        March {
            dt,
            max_steps,
            early_stop: 0.0,
            sampling: Sampling::Fixed,
            path: TransPath::Product,
            background: [0.0; 3],
        }
    }

    #[test]
    fn fixed_lattice_is_midpoints_with_a_clipped_last_interval() {
        let m = march(0.3, 100);
        let mut got = vec![];
        let (f, _) = walk_lattice(
            [0.0; 3],
            [1.0, 0.0, 0.0],
            0.0,
            1.0,
            0,
            &m,
            None,
            |k, t, h, _| {
                got.push((k, t, h));
                true
            },
        );
        assert_eq!(f, FLAG_HIT);
        assert_eq!(got.len(), 4);
        assert!((got[3].1 - 0.95).abs() < 1e-15 && (got[3].2 - 0.1).abs() < 1e-15);
        assert_eq!(got[1].1, (0.3 + 0.6) * 0.5);
    }

    #[test]
    fn walk_lattice_visits_exactly_the_sample_k_lattice_in_f32() {
        for i in 0..200u32 {
            let r = |d| crate::rng::rand_f32(4, i, 0, d);
            let (t0, len, dt) = (r(0) * 3.0, r(1) * 2.0, 0.001 + r(2) * 0.05);
            let sampling = if i % 2 == 0 {
                Sampling::Fixed
            } else {
                Sampling::Stratified { seed: i }
            };
            let m = March {
                dt,
                max_steps: 1024,
                early_stop: 0.0,
                sampling,
                path: TransPath::Product,
                background: [0.0; 3],
            };
            let mut got = vec![];
            walk_lattice(
                [0.0f32; 3],
                [1.0, 0.0, 0.0],
                t0,
                t0 + len,
                i,
                &m,
                None,
                |k, t, h, _| {
                    got.push((k, t, h));
                    true
                },
            );
            let want: Vec<(u32, f32, f32)> = (0..1024)
                .map_while(|k| sample_k(t0, t0 + len, dt, k, sampling, i).map(|(t, h)| (k, t, h)))
                .collect();
            assert_eq!(got, want);
        }
    }

    #[test]
    fn max_steps_truncates_and_flags_the_ray() {
        let m = march(0.01, 10);
        let mut n = 0;
        let (f, _) = walk_lattice(
            [0.0; 3],
            [1.0, 0.0, 0.0],
            0.0,
            1.0,
            0,
            &m,
            None,
            |_, _, _, _| {
                n += 1;
                true
            },
        );
        assert_eq!((n, f), (10, FLAG_HIT | FLAG_TRUNCATED));
    }

    #[test]
    fn stratified_samples_stay_inside_their_intervals() {
        let m = March {
            sampling: Sampling::Stratified { seed: 3 },
            ..march(0.1, 100)
        };
        let mut last = -1.0;
        walk_lattice(
            [0.0; 3],
            [1.0, 0.0, 0.0],
            0.25,
            1.0,
            7,
            &m,
            None,
            |k, t, h, _| {
                let a = 0.25 + k as f64 * 0.1;
                assert!(t >= a && t < a + h && t > last);
                last = t;
                true
            },
        );
    }

    #[test]
    fn f_samp_packs_offsets_and_ray_ids() {
        use crate::volume::field::Analytic;
        use crate::volume::field::{ColorDesc, FieldDesc};
        let rays = Rays {
            o: vec![[0.0; 3]; 3],
            d: vec![[1.0, 0.0, 0.0]; 3],
            t0: vec![0.0, 0.5, 0.0],
            t1: vec![1.0, 0.5, 0.25],
            pixel: vec![0, 1, 2],
        };
        let medium = Medium::new(
            &FieldDesc::Analytic(Analytic::Constant { s: 2.0 }),
            &ColorDesc::Constant([1.0, 0.5, 0.25]),
        );
        let s = f_samp(
            &rays,
            &medium,
            &march(0.1, 100),
            None,
            &MemBudget::fixed(1 << 20),
        )
        .unwrap();
        assert_eq!(s.off, vec![0, 10, 10, 13]);
        assert_eq!(&s.ray_id[9..], &[0, 2, 2, 2]);
        assert_eq!(s.flags, vec![FLAG_HIT, 0, FLAG_HIT]);
        assert!(s.sigma.iter().all(|&v| v == 2.0));
    }
}
