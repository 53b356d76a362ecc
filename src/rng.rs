//! Counter-based random numbers, identical on CPU and GPU (SCENES.md "Random
//! numbers"). Every stochastic choice is `rand(seed, pixel, sample, dim)`;
//! nothing depends on thread scheduling. WGSL twin: `kernels/common.wgsl`
//! `pcg` / `rand_u32` / `rand_f32` (when the GPU layer exists).

pub mod sobol;

/// The 32-bit PCG hash (PCG-RXS-M-XS as used by Jarzynski & Olano 2020):
/// `s = v * 747796405 + 2891336453; w = ((s >> ((s >> 28) + 4)) ^ s) * 277803737;
/// (w >> 22) ^ w`, all in wrapping u32 arithmetic.
#[inline]
pub fn pcg(v: u32) -> u32 {
    let s = v.wrapping_mul(747_796_405).wrapping_add(2_891_336_453);
    let w = ((s >> ((s >> 28) + 4)) ^ s).wrapping_mul(277_803_737);
    (w >> 22) ^ w
}

/// `pcg(pcg(pcg(pcg(seed) ^ pixel) ^ sample) ^ dim)`.
#[inline]
pub fn rand_u32(seed: u32, pixel: u32, sample: u32, dim: u32) -> u32 {
    pcg(pcg(pcg(pcg(seed) ^ pixel) ^ sample) ^ dim)
}

/// A uniform float in [0, 1): `(rand >> 8) * 2^-24`. Exact in f32 (24 bits),
/// so the f64 value is the same number.
#[inline]
pub fn rand_f64(seed: u32, pixel: u32, sample: u32, dim: u32) -> f64 {
    (rand_u32(seed, pixel, sample, dim) >> 8) as f64 * (1.0 / 16_777_216.0)
}

/// [`rand_f64`] as f32 (the same value: 24-bit mantissa, exact).
#[inline]
pub fn rand_f32(seed: u32, pixel: u32, sample: u32, dim: u32) -> f32 {
    (rand_u32(seed, pixel, sample, dim) >> 8) as f32 * (1.0 / 16_777_216.0)
}

/// Every key `[seed, pixel, sample, dim]` of the product of the four axes,
/// `dim` fastest (a C-order table of shape `[seeds, pixels, samples, dims]`).
pub fn table_keys(axes: [&[u32]; 4]) -> Vec<[u32; 4]> {
    let mut keys = vec![];
    for &s in axes[0] {
        for &p in axes[1] {
            for &k in axes[2] {
                keys.extend(axes[3].iter().map(|&d| [s, p, k, d]));
            }
        }
    }
    keys
}

/// [`rand_u32`] and [`rand_f32`] of every key (the CPU side of the RNG
/// table that the GPU's `kernels/common.wgsl` must reproduce).
pub fn rand_table(keys: &[[u32; 4]]) -> (Vec<u32>, Vec<f32>) {
    keys.iter()
        .map(|&[s, p, k, d]| (rand_u32(s, p, k, d), rand_f32(s, p, k, d)))
        .unzip()
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Values worked by hand from the formula (wrapping arithmetic), not by this code.
    #[test]
    fn pcg_of_zero_matches_hand_computation() {
        // s = 2891336453 = 0xAC564B05; s >> 28 = 10; s >> 14 = 0x2B159;
        // w = (0x2B159 ^ 0xAC564B05) * 277803737 mod 2^32; result = (w >> 22) ^ w.
        let s: u64 = 2_891_336_453;
        let x = (s >> 14) ^ s;
        let w = (x * 277_803_737) & 0xFFFF_FFFF;
        let expect = ((w >> 22) ^ w) as u32;
        assert_eq!(pcg(0), expect);
    }

    #[test]
    fn rand_floats_lie_in_unit_interval_and_agree() {
        for i in 0..10_000u32 {
            let a = rand_f32(7, i, i / 3, i % 5);
            let b = rand_f64(7, i, i / 3, i % 5);
            assert!((0.0..1.0).contains(&a));
            assert_eq!(a as f64, b);
        }
    }
}
