//! Where the path tracer's random numbers come from: `sampler:` of a scene
//! (a closed enum). Both are pure functions of `(seed, pixel, sample,
//! dim)` with the dimensions laid out in [`dims`], so renders are
//! bit-identical across runs, thread counts and tracers, and the GPU
//! (`kernels/common.wgsl` `sampler_u32`, `pathtrace.wgsl` `rnd`/`rnd2`)
//! draws the same numbers (parity case `gpu_sobol_matches_cpu`).
//! - [`Sampler::Independent`] (default): `rand(seed, pixel, sample, dim)`
//!   of SCENES.md, one PCG hash chain per dimension.
//! - [`Sampler::Sobol`]: padded 2-D Owen-scrambled Sobol' points
//!   (`crate::rng::sobol`, Burley 2020): the pixel jitter, each vertex's
//!   light point (u, v) and BSDF direction (u, v) are 2-D pairs; the light
//!   choice, lobe and roulette dimensions are 1-D scrambled van der Corput.

use serde::Deserialize;

use super::lanes::{F8, LANES, U8};
use crate::rng::sobol::{pixel_key, sobol1, sobol1_rev, sobol2, sobol2_rev, unit_f32};
use crate::rng::{pcg, rand_table};

/// Which random dimension each decision uses. Dimensions 0 and 1 jitter the
/// pixel position; vertex `k` (bounces behind it) uses `2 + STRIDE k + i`.
pub mod dims {
    pub const JITTER_X: u32 = 0;
    pub const JITTER_Y: u32 = 1;
    pub const FIRST_VERTEX: u32 = 2;
    pub const STRIDE: u32 = 8;
    pub const LIGHT_CHOICE: u32 = 0;
    pub const LIGHT_U: u32 = 1;
    pub const LIGHT_V: u32 = 2;
    pub const LOBE: u32 = 3;
    pub const BSDF_U: u32 = 4;
    pub const BSDF_V: u32 = 5;
    pub const ROULETTE: u32 = 6;
}

/// A scene's `sampler:` (`{type: independent}` or `{type: sobol}`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum Sampler {
    /// `rand(seed, pixel, sample, dim)`: one hash per dimension.
    #[default]
    Independent,
    /// Padded 2-D Owen-scrambled Sobol' (Burley 2020).
    Sobol,
}

impl Sampler {
    /// The kernels' code of the sampler (`PtParams::sampler`, `TableParams`).
    pub fn gpu_code(self) -> u32 {
        self as u32
    }

    /// The sampler's word of every key `[seed, pixel, sample, dim]` and its
    /// float `(word >> 8) 2^-24` (the CPU side of the GPU parity tables).
    pub fn table(self, keys: &[[u32; 4]]) -> (Vec<u32>, Vec<f32>) {
        match self {
            Sampler::Independent => rand_table(keys),
            Sampler::Sobol => keys
                .iter()
                .map(|&[s, p, k, d]| {
                    let w = sobol_u32(s, p, k, d);
                    (w, unit_f32(w))
                })
                .unzip(),
        }
    }
}

/// How [`Sampler::Sobol`] draws dimension `dim`: the first dimension of
/// its 2-D pair and the coordinate (0 or 1), or `None` for a 1-D dimension.
pub fn sobol_pair(dim: u32) -> Option<(u32, usize)> {
    if dim < dims::FIRST_VERTEX {
        return Some((dims::JITTER_X, dim as usize));
    }
    match (dim - dims::FIRST_VERTEX) % dims::STRIDE {
        dims::LIGHT_U | dims::BSDF_U => Some((dim, 0)),
        dims::LIGHT_V | dims::BSDF_V => Some((dim - 1, 1)),
        _ => None,
    }
}

/// [`Sampler::Sobol`]'s word for `(seed, pixel, sample, dim)`.
pub fn sobol_u32(seed: u32, pixel: u32, sample: u32, dim: u32) -> u32 {
    let pk = pixel_key(seed, pixel);
    match sobol_pair(dim) {
        Some((d, c)) => sobol2(pk, sample, d)[c],
        None => sobol1(pk, sample, dim),
    }
}

/// One sample's random numbers with the per-sample hashes done once:
/// independent `key = pcg(pcg(pcg(seed) ^ pixel) ^ sample)`, `rand =
/// pcg(key ^ dim)`; Sobol' the pixel key `pcg(pcg(seed) ^ pixel)` and the
/// sample index reversed. Floats `(word >> 8) 2^-24`.
#[derive(Clone, Copy, Debug)]
pub struct PathRng {
    key: u32,
    pk: u32,
    rindex: u32,
    sobol: bool,
}

impl PathRng {
    /// The independent sampler's numbers of one sample.
    #[inline]
    pub fn new(seed: u32, pixel: u32, sample: u32) -> PathRng {
        PathRng::of(Sampler::Independent, seed, pixel, sample)
    }
    #[inline]
    pub fn of(sampler: Sampler, seed: u32, pixel: u32, sample: u32) -> PathRng {
        PathRng::keyed(sampler, pixel_key(seed, pixel), sample)
    }
    /// [`PathRng::of`] with the pixel key `pk = pixel_key(seed, pixel)`
    /// given (a renderer hashes it once per pixel, not per sample).
    #[inline]
    pub fn keyed(sampler: Sampler, pk: u32, sample: u32) -> PathRng {
        PathRng {
            key: pcg(pk ^ sample),
            pk,
            rindex: sample.reverse_bits(),
            sobol: sampler == Sampler::Sobol,
        }
    }
    /// The value of dimension `dim` (either sampler, any dimension).
    #[inline]
    pub fn f(&self, dim: u32) -> f32 {
        if !self.sobol {
            return unit_f32(pcg(self.key ^ dim));
        }
        match sobol_pair(dim) {
            Some((d, c)) => unit_f32(sobol2_rev(self.pk, self.rindex, d)[c]),
            None => unit_f32(sobol1_rev(self.pk, self.rindex, dim)),
        }
    }
    /// The values of dimensions `dim` and `dim + 1`, a Sobol' pair.
    #[inline]
    pub fn f2(&self, dim: u32) -> [f32; 2] {
        if !self.sobol {
            return [self.f(dim), self.f(dim + 1)];
        }
        sobol2_rev(self.pk, self.rindex, dim).map(unit_f32)
    }
}

/// [`PathRng`] for eight lanes (one sampler for all).
#[derive(Clone, Copy, Debug, Default)]
pub struct Rng8 {
    key: U8,
    pk: U8,
    rindex: U8,
}

impl Rng8 {
    /// Lane `k` takes `r`'s numbers.
    #[inline(always)]
    pub fn set_lane(&mut self, k: usize, r: &PathRng) {
        (self.key.0[k], self.pk.0[k], self.rindex.0[k]) = (r.key, r.pk, r.rindex);
    }
    /// [`PathRng::f`] per lane for a 1-D dimension `dim`.
    #[inline(always)]
    pub fn f(&self, sobol: bool, dim: U8) -> F8 {
        if !sobol {
            return self.key.rand(dim);
        }
        let mut r = F8::default();
        for k in 0..LANES {
            r.0[k] = unit_f32(sobol1_rev(self.pk.0[k], self.rindex.0[k], dim.0[k]));
        }
        r
    }
    /// [`PathRng::f2`] per lane.
    #[inline(always)]
    pub fn f2(&self, sobol: bool, dim: U8) -> (F8, F8) {
        if !sobol {
            return (self.key.rand(dim), self.key.rand(dim + U8::splat(1)));
        }
        let (mut a, mut b) = (F8::default(), F8::default());
        for k in 0..LANES {
            let [x, y] = sobol2_rev(self.pk.0[k], self.rindex.0[k], dim.0[k]);
            (a.0[k], b.0[k]) = (unit_f32(x), unit_f32(y));
        }
        (a, b)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rand_f32;

    #[test]
    fn independent_numbers_are_the_scenes_md_function() {
        for i in 0..5000u32 {
            let r = PathRng::new(7, i, i / 7);
            for d in [0, 1, 2, 77, 400] {
                assert_eq!(r.f(d), rand_f32(7, i, i / 7, d));
                assert_eq!(
                    r.f2(d),
                    [rand_f32(7, i, i / 7, d), rand_f32(7, i, i / 7, d + 1)]
                );
            }
        }
    }

    /// The fast paths (pairs drawn together, lanes) give the table's
    /// value of every dimension, for both samplers.
    #[test]
    fn pairs_lanes_and_table_agree_for_both_samplers() {
        for sampler in [Sampler::Independent, Sampler::Sobol] {
            let keys: Vec<[u32; 4]> = (0..4000u32).map(|i| [3, i / 40, i % 40, i % 37]).collect();
            let (_, floats) = sampler.table(&keys);
            let mut lanes = Rng8::default();
            for (j, (&[s, p, k, d], &v)) in keys.iter().zip(&floats).enumerate() {
                let r = PathRng::of(sampler, s, p, k);
                assert_eq!(r.f(d), v, "{sampler:?} {d}");
                if let Some((d0, c)) = sobol_pair(d) {
                    assert_eq!(r.f2(d0)[c], v, "{sampler:?} {d}");
                }
                lanes.set_lane(j % LANES, &r);
                let sobol = sampler == Sampler::Sobol;
                let l1 = lanes.f(sobol, U8::splat(d)).0[j % LANES];
                let (a, b) = lanes.f2(sobol, U8::splat(d));
                if sobol_pair(d).is_none() {
                    assert_eq!(l1, v);
                }
                assert_eq!([a.0[j % LANES], b.0[j % LANES]], r.f2(d));
            }
        }
    }

    #[test]
    fn sobol_pairs_are_jitter_light_point_and_bsdf_direction() {
        use dims::*;
        let v = FIRST_VERTEX + 3 * STRIDE;
        assert_eq!(sobol_pair(JITTER_Y), Some((JITTER_X, 1)));
        assert_eq!(sobol_pair(v + LIGHT_U), Some((v + LIGHT_U, 0)));
        assert_eq!(sobol_pair(v + LIGHT_V), Some((v + LIGHT_U, 1)));
        assert_eq!(sobol_pair(v + BSDF_V), Some((v + BSDF_U, 1)));
        for d in [LIGHT_CHOICE, LOBE, ROULETTE, 7] {
            assert_eq!(sobol_pair(v + d), None);
        }
    }
}
