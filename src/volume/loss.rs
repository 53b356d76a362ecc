//! The loss of the backward pass and its probes: descriptions shared by
//! `f_diff`'s caller and the finite-difference referee, so both judge the
//! same `L` at the same grid nodes.
//!
//! `L = sum_p W_p . rgb_p + w_depth sum_p depth_p + w_opacity sum_p
//! opacity_p`. Probes: grid nodes drawn from the middle half of each axis,
//! where the camera's rays cross, with `rand(seed, q, stream, axis)`; colour
//! probes also draw a channel.

use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::real::Real;
use crate::rng::rand_f64;
use crate::tensor::Tensor;

use super::diff::Upstream;

/// The loss weights of a case, f64, one per ray of the region.
#[derive(Clone, Debug)]
pub struct LossWeights {
    pub rgb: Vec<[f64; 3]>,
    pub depth: f64,
    pub opacity: f64,
}

impl LossWeights {
    /// `W` from an (h, w, 3) float32/float64 `.npy` (`--grad-from`), every
    /// value finite.
    pub fn read_rgb(path: &std::path::Path, h: usize, w: usize) -> Result<Vec<[f64; 3]>> {
        let dims = [Some(h), Some(w), Some(3)];
        let v = Tensor::read_npy_checked(path, &["float32", "float64"], &dims)?.to_f64_vec();
        if let Some(i) = v.iter().position(|x| !x.is_finite()) {
            let why = format!("value at flat index {i} is not finite");
            return Err(Error::invalid(path.display().to_string(), why));
        }
        Ok(v.chunks(3).map(|c| [c[0], c[1], c[2]]).collect())
    }

    /// `W = rand(seed, pixel, 0, ch) - 0.5` for every pixel of `gen`'s
    /// region (SCENES.md RNG), no depth or opacity terms.
    pub fn seeded(gen: &RayGen, seed: u32) -> Vec<[f64; 3]> {
        let roi = gen.region();
        let (h, w) = (roi.height as usize, roi.width as usize);
        (0..h * w)
            .map(|i| {
                let (u, v) = (roi.x + (i % w) as u32, roi.y + (i / w) as u32);
                let px = v * gen.width + u;
                [0, 1, 2].map(|ch| rand_f64(seed, px, 0, ch) - 0.5)
            })
            .collect()
    }

    /// `f_diff`'s upstream gradient for this loss, in precision `F`.
    pub fn upstream<F: Real>(&self) -> Upstream<F> {
        let n = self.rgb.len();
        Upstream {
            rgb: self.rgb.iter().map(|c| c.map(F::of)).collect(),
            depth: (self.depth != 0.0).then(|| vec![F::of(self.depth); n]),
            opacity: (self.opacity != 0.0).then(|| vec![F::of(self.opacity); n]),
        }
    }
}

/// How many grid nodes to probe (`params.probes`).
#[derive(Clone, Copy, Debug, Default, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ProbeSpec {
    #[serde(default)]
    pub sigma: u32,
    #[serde(default)]
    pub color: u32,
    #[serde(default)]
    pub seed: u32,
}

pub const MAX_PROBES: u32 = 4096;

/// Flat node indices of `count` probes of an (nz, ny, nx) grid: each axis
/// drawn from its middle half, `rand(seed, q, stream, axis)`.
pub fn probe_nodes(shape: [usize; 3], count: u32, seed: u32, stream: u32) -> Vec<usize> {
    let [nz, ny, nx] = shape;
    let pick = |n: usize, q: u32, a: u32| {
        let lo = n / 4;
        let span = (n - 2 * lo).max(1);
        lo + ((rand_f64(seed, q, stream, a) * span as f64) as usize).min(span - 1)
    };
    (0..count)
        .map(|q| {
            let (i, j, k) = (pick(nx, q, 0), pick(ny, q, 1), pick(nz, q, 2));
            (k * ny + j) * nx + i
        })
        .collect()
}

/// Flat (node * 3 + channel) indices of colour probes.
pub fn probe_colors(shape: [usize; 3], count: u32, seed: u32) -> Vec<usize> {
    probe_nodes(shape, count, seed, 1)
        .into_iter()
        .enumerate()
        .map(|(q, n)| n * 3 + ((rand_f64(seed, q as u32, 1, 3) * 3.0) as usize).min(2))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn probes_fall_in_the_middle_half_and_repeat() {
        let a = probe_nodes([64, 64, 64], 50, 3, 0);
        assert_eq!(a, probe_nodes([64, 64, 64], 50, 3, 0));
        for n in a {
            let (i, j, k) = (n % 64, n / 64 % 64, n / 4096);
            assert!((16..48).contains(&i) && (16..48).contains(&j) && (16..48).contains(&k));
        }
        assert!(probe_colors([4, 4, 4], 20, 1,)
            .iter()
            .all(|&c| c < 4 * 4 * 4 * 3));
    }
}
