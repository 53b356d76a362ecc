//! Per-ray [`CastHit`]s into [`VoxelHits`] (SCENES.md's per-ray arrays), in
//! parallel chunks: each chunk of rays is cast into a chunk-sized buffer and
//! converted by the thread that cast it, so no `n`-long `CastHit` vector is
//! built and no serial pass runs after the cast. (The serial conversion and
//! the `vec![CastHit; n]` it needed were about a quarter of the lane cast's
//! samples at 2048^2 rays on one thread; 1.0-1.08x wall at 2^18 rays on two:
//! docs/PERF.md, issue 15.)

use std::ops::Range;

use crate::parallel::par_each;

use super::cast::{CastHit, CastReal};
use super::render::VoxelHits;

/// Rays per parallel chunk of the casts (the lane cast streams one chunk
/// through its lanes).
pub(crate) const GRAIN: usize = 2048;

/// One chunk's slots in every output array.
struct Part<'a, F> {
    hit: &'a mut [u8],
    t: &'a mut [F],
    leaf: &'a mut [[i32; 3]],
    normal: &'a mut [[F; 3]],
    iters: &'a mut [i32],
    capped: &'a mut u64,
}

impl<F: CastReal> Part<'_, F> {
    /// Writes `hits` (one per slot, in order) in SCENES.md's conventions
    /// (miss: t = -1, leaf = -1, normal = 0) and counts the capped rays.
    fn write(&mut self, hits: &[CastHit<F>]) {
        for (k, h) in hits.iter().enumerate() {
            self.hit[k] = h.hit as u8;
            self.t[k] = h.t;
            self.leaf[k] = if h.hit {
                h.voxel.map(|v| v as i32)
            } else {
                [-1; 3]
            };
            self.normal[k] = h.normal.map(|v| F::of(v as f64));
            self.iters[k] = h.iters as i32;
        }
        *self.capped = hits.iter().filter(|h| h.capped).count() as u64;
    }
}

/// `f(part_index, part)` over the `grain`-sized parts of a fresh
/// [`VoxelHits`] of `n` rays, in parallel; the capped counts summed.
fn fill<F: CastReal>(
    label: &'static str,
    n: usize,
    grain: usize,
    f: impl Fn(usize, Part<F>) + Sync + Send,
) -> VoxelHits<F> {
    let grain = grain.max(1);
    let mut out = VoxelHits {
        hit: vec![0; n],
        t: vec![F::zero(); n],
        leaf: vec![[0; 3]; n],
        normal: vec![[F::zero(); 3]; n],
        iters: vec![0; n],
        capped: 0,
    };
    let mut capped = vec![0u64; n.div_ceil(grain)];
    let parts: Vec<Part<F>> = (out.hit.chunks_mut(grain))
        .zip(out.t.chunks_mut(grain))
        .zip(out.leaf.chunks_mut(grain))
        .zip(out.normal.chunks_mut(grain))
        .zip(out.iters.chunks_mut(grain))
        .zip(capped.iter_mut())
        .map(|(((((hit, t), leaf), normal), iters), capped)| Part {
            hit,
            t,
            leaf,
            normal,
            iters,
            capped,
        })
        .collect();
    par_each(label, parts, f);
    out.capped = capped.iter().sum();
    out
}

/// Casts rays `0..n` in parallel chunks of `grain`: `cast(rays, hits)`
/// fills `hits[k]` with ray `rays.start + k`'s result.
pub(crate) fn cast_chunks<F: CastReal>(
    label: &'static str,
    n: usize,
    grain: usize,
    cast: impl Fn(Range<usize>, &mut [CastHit<F>]) + Sync + Send,
) -> VoxelHits<F> {
    fill(label, n, grain, |c, mut part| {
        let first = c * grain.max(1);
        let mut buf = vec![CastHit::miss(0, false); part.hit.len()];
        cast(first..first + buf.len(), &mut buf);
        part.write(&buf);
    })
}

/// Rays per part when converting a finished vector ([`collect`]).
const COLLECT_GRAIN: usize = 8192;

/// Per-ray results in [`VoxelHits`] form (converted in parallel).
pub(crate) fn collect<F: CastReal>(res: Vec<CastHit<F>>) -> VoxelHits<F> {
    fill("voxels.collect", res.len(), COLLECT_GRAIN, |c, mut part| {
        let first = c * COLLECT_GRAIN;
        part.write(&res[first..first + part.hit.len()]);
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hits(n: usize) -> Vec<CastHit<f32>> {
        (0..n)
            .map(|i| {
                let mut h = CastHit::miss(i as u32, i % 7 == 3);
                if i % 3 == 0 {
                    h.hit = true;
                    h.t = i as f32 * 0.25;
                    h.voxel = [i as u32, 2 * i as u32, 3];
                    h.normal = [0, -1, (i % 2) as i8];
                }
                h
            })
            .collect()
    }

    #[test]
    fn chunked_conversion_writes_every_ray_in_scenes_conventions() {
        let n = 3 * COLLECT_GRAIN + 5;
        let res = hits(n);
        let v = collect(res.clone());
        let c = cast_chunks("test", n, 100, |r, out| out.copy_from_slice(&res[r]));
        for h in [&v, &c] {
            assert_eq!(h.hit.len(), n);
            assert_eq!(h.capped, (0..n).filter(|i| i % 7 == 3).count() as u64);
            for (i, r) in res.iter().enumerate() {
                assert_eq!(h.hit[i], r.hit as u8, "ray {i}");
                assert_eq!(h.t[i].to_bits(), r.t.to_bits(), "ray {i}");
                let leaf = if r.hit {
                    [i as i32, 2 * i as i32, 3]
                } else {
                    [-1; 3]
                };
                assert_eq!(h.leaf[i], leaf, "ray {i}");
                assert_eq!(h.normal[i], r.normal.map(|v| v as f32), "ray {i}");
                assert_eq!(h.iters[i], i as i32, "ray {i}");
            }
        }
    }
}
