//! Padded 2-D Owen-scrambled Sobol' points after Burley 2020, "Practical
//! Hash-based Owen Scrambling" (JCGT 9(4)). Pure functions of
//! `(pixel key, sample index, dimension)`; WGSL twins in
//! `kernels/common.wgsl` (`sobol2`, `sobol1`), parity case
//! `gpu_sobol_matches_cpu` in TESTS/gpu/manifest.yaml.
//!
//! Values are 32-bit fixed-point fractions, most significant digit first.
//! - Sobol' dimension 0 of index `i` is `reverse_bits(i)` (van der Corput);
//!   dimension 1 is `reverse_bits(zeta(i))` with `zeta` the generator
//!   matrix of that dimension, the Pascal matrix mod 2: digit `j` is the
//!   xor of the index bits `k` whose bit set contains `j`'s (Lucas).
//! - Owen scrambling of a value `v` with seed `s`:
//!   `reverse_bits(lk(reverse_bits(v), s))` ([`owen`]). [`lk`] (Burley's
//!   Laine-Karras-style hash) flips each bit by a function of the bits
//!   below it only, so after the reversal each digit is flipped by a
//!   function of the digits before it: a nested uniform scramble of the
//!   digit tree, which keeps every elementary-interval property.
//! - Padding: per dimension pair the sample index is first shuffled by the
//!   same nested scramble (so the first `2^m` samples are a scrambled
//!   aligned block of `2^m` Sobol' points, still a (0, m, 2)-net), with a
//!   seed per pair, so pairs are decorrelated from each other.
//!
//! Seeds come from the project's counter-based hash: for the pair (or
//! single dimension) starting at `dim`, its key is `h = pcg(pk ^ dim)` with
//! `pk = pcg(pcg(seed) ^ pixel)` ([`pixel_key`]), i.e. the per-sample key
//! of `rand(seed, pixel, sample, dim)` with `dim` in the sample slot. `h`
//! shuffles the index; `h * 0x9e37_79b9` and `h * 0x85eb_ca6b` (odd
//! multipliers: distinct seeds, one multiply each instead of a hash)
//! scramble the two coordinates.

use super::pcg;

/// `pcg(pcg(seed) ^ pixel)`: the first two hashes of `rand_u32`.
#[inline]
pub fn pixel_key(seed: u32, pixel: u32) -> u32 {
    pcg(pcg(seed) ^ pixel)
}

/// Burley's hash permutation: bit `k` of the result is bit `k` of `x`
/// flipped by a function of `seed` and bits `0..k` of `x` (an add and four
/// xors with multiples by even constants).
#[inline(always)]
pub fn lk(x: u32, seed: u32) -> u32 {
    let mut x = x.wrapping_add(seed);
    x ^= x.wrapping_mul(0x6c50_b47c);
    x ^= x.wrapping_mul(0xb82f_1e52);
    x ^= x.wrapping_mul(0xc7af_e638);
    x ^= x.wrapping_mul(0x8d22_f6e6);
    x
}

/// Nested uniform (Owen) scramble of the fraction `v` (MSB first).
#[inline(always)]
pub fn owen(v: u32, seed: u32) -> u32 {
    lk(v.reverse_bits(), seed).reverse_bits()
}

/// The generator matrix of Sobol' dimension 1 applied to `i`, digits in
/// index order (bit `j` = digit `j + 1` after the point): bit `j` is the
/// xor of the bits `k` of `i` with `k & j == j`, five shift-xor steps.
#[inline(always)]
pub fn zeta(i: u32) -> u32 {
    let mut y = i;
    y ^= (y >> 1) & 0x5555_5555;
    y ^= (y >> 2) & 0x3333_3333;
    y ^= (y >> 4) & 0x0f0f_0f0f;
    y ^= (y >> 8) & 0x00ff_00ff;
    y ^= (y >> 16) & 0x0000_ffff;
    y
}

/// Seed multipliers of the first and second coordinate.
const SEED_X: u32 = 0x9e37_79b9;
const SEED_Y: u32 = 0x85eb_ca6b;

/// The shuffled index of the sample whose index reversed is `rindex`, for
/// the pair at `dim` (`owen(index, h)`), and the pair's key
/// `h = pcg(pk ^ dim)`.
#[inline(always)]
fn shuffled(pk: u32, rindex: u32, dim: u32) -> (u32, u32) {
    let h = pcg(pk ^ dim);
    (lk(rindex, h).reverse_bits(), h)
}

/// The padded, scrambled 2-D point of sample `index` for the dimension
/// pair `(dim, dim + 1)` of the pixel with key `pk`.
#[inline(always)]
pub fn sobol2(pk: u32, index: u32, dim: u32) -> [u32; 2] {
    sobol2_rev(pk, index.reverse_bits(), dim)
}

/// [`sobol2`] of the sample whose index reversed is `rindex` (samplers
/// reverse a sample's index once for all its dimensions).
#[inline(always)]
pub fn sobol2_rev(pk: u32, rindex: u32, dim: u32) -> [u32; 2] {
    let (i, h) = shuffled(pk, rindex, dim);
    // owen(reverse(i)) and owen(reverse(zeta(i))), the reversals cancelled.
    [
        lk(i, h.wrapping_mul(SEED_X)).reverse_bits(),
        lk(zeta(i), h.wrapping_mul(SEED_Y)).reverse_bits(),
    ]
}

/// The padded, scrambled 1-D point (van der Corput) of sample `index` for
/// the single dimension `dim`.
#[inline(always)]
pub fn sobol1(pk: u32, index: u32, dim: u32) -> u32 {
    sobol1_rev(pk, index.reverse_bits(), dim)
}

/// [`sobol1`] of the sample whose index reversed is `rindex`.
#[inline(always)]
pub fn sobol1_rev(pk: u32, rindex: u32, dim: u32) -> u32 {
    let (i, h) = shuffled(pk, rindex, dim);
    lk(i, h.wrapping_mul(SEED_X)).reverse_bits()
}

/// A 32-bit fraction as f32 in [0, 1): `(x >> 8) 2^-24`, exact.
#[inline(always)]
pub fn unit_f32(x: u32) -> f32 {
    (x >> 8) as f32 * (1.0 / 16_777_216.0)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rand_u32;

    /// Sobol' dimension 1 from its direction numbers `v_1 = 2^31`,
    /// `v_{k+1} = v_k ^ (v_k >> 1)` (the textbook construction).
    fn sobol_dim1_by_directions(mut i: u32) -> u32 {
        let (mut v, mut x) = (1u32 << 31, 0u32);
        while i != 0 {
            if i & 1 == 1 {
                x ^= v;
            }
            i >>= 1;
            v ^= v >> 1;
        }
        x
    }

    #[test]
    fn zeta_is_the_direction_number_construction_of_dimension_one() {
        for i in (0..70_000u32).chain([u32::MAX, 0x8000_0000, 0xdead_beef]) {
            assert_eq!(zeta(i).reverse_bits(), sobol_dim1_by_directions(i), "{i}");
        }
    }

    /// The pair key is `rand`'s per-sample key with `dim` as the sample:
    /// `rand_u32(seed, pixel, dim, d) = pcg(h ^ d)`.
    #[test]
    fn pair_key_is_the_counter_based_key_of_seed_pixel_dim() {
        let (seed, pixel, dim) = (7, 1234, 9);
        let h = pcg(pixel_key(seed, pixel) ^ dim);
        assert_eq!(pcg(h ^ 5), rand_u32(seed, pixel, dim, 5));
        let i = owen(3, h);
        assert_eq!(
            sobol1(pixel_key(seed, pixel), 3, dim),
            lk(i, h.wrapping_mul(SEED_X)).reverse_bits()
        );
    }

    /// Every elementary interval `2^-a x 2^-(m-a)` holds exactly one of the
    /// first `2^m` points: the (0, m, 2)-net property that the scrambles
    /// and the index shuffle keep. Many pixels, pairs and `m`.
    #[test]
    fn first_two_to_the_m_points_fill_every_elementary_interval_once() {
        for pixel in 0..40u32 {
            let pk = pixel_key(3, pixel);
            for dim in [0u32, 3, 6, 11, 1000] {
                for m in 0..=10u32 {
                    let pts: Vec<[u32; 2]> = (0..1u32 << m).map(|i| sobol2(pk, i, dim)).collect();
                    for a in 0..=m {
                        let mut seen = vec![false; 1 << m];
                        for p in &pts {
                            let cx = if a == 0 { 0 } else { p[0] >> (32 - a) };
                            let cy = if a == m { 0 } else { p[1] >> (32 - (m - a)) };
                            let cell = ((cx << (m - a)) | cy) as usize;
                            assert!(!seen[cell], "pixel {pixel} dim {dim} m {m} a {a}");
                            seen[cell] = true;
                        }
                    }
                }
            }
        }
    }

    #[test]
    fn one_dimensional_points_stratify_every_power_of_two() {
        for pixel in 0..40u32 {
            let pk = pixel_key(11, pixel);
            for m in 0..=12u32 {
                let mut seen = vec![false; 1 << m];
                for i in 0..1u32 << m {
                    let c = if m == 0 {
                        0
                    } else {
                        sobol1(pk, i, 5) >> (32 - m)
                    } as usize;
                    assert!(!seen[c], "pixel {pixel} m {m}");
                    seen[c] = true;
                }
            }
        }
    }

    /// Pixels and pairs get different scrambles (so no two pixels share a
    /// pattern), and the floats lie in [0, 1).
    #[test]
    fn pixels_and_pairs_are_scrambled_apart_and_floats_are_in_unit_interval() {
        let a = sobol2(pixel_key(1, 0), 0, 0);
        assert_ne!(a, sobol2(pixel_key(1, 1), 0, 0));
        assert_ne!(a, sobol2(pixel_key(1, 0), 0, 2));
        assert_ne!(sobol1(pixel_key(1, 0), 0, 2), sobol1(pixel_key(1, 0), 0, 3));
        for i in 0..20_000u32 {
            let [x, y] = sobol2(pixel_key(2, i / 64), i % 64, i % 7);
            for v in [x, y, sobol1(pixel_key(2, i), i, 4), u32::MAX] {
                assert!((0.0..1.0).contains(&unit_f32(v)));
            }
        }
    }

    /// Across pixels the first sample's coordinates are uniform (a
    /// chi-square-free count: each of 16 bins gets 1/16 of 16,384 pixels
    /// within 5 sigma), so the per-pixel scramble randomises the point.
    #[test]
    fn first_samples_across_pixels_are_uniform() {
        let mut bins = [[0u32; 16]; 3];
        let n = 16_384u32;
        for p in 0..n {
            let pk = pixel_key(5, p);
            let [x, y] = sobol2(pk, 0, 2);
            for (b, v) in bins.iter_mut().zip([x, y, sobol1(pk, 0, 4)]) {
                b[(v >> 28) as usize] += 1;
            }
        }
        let (mean, sd) = (n as f64 / 16.0, (n as f64 / 16.0 * 15.0 / 16.0).sqrt());
        for b in bins.iter().flatten() {
            assert!((*b as f64 - mean).abs() < 5.0 * sd, "{bins:?}");
        }
    }
}
