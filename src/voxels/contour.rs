//! Contours (Laine & Karras 2010, seed 003): a plane per surface voxel, 32
//! bits, that the cast intersects to tighten the hit inside the voxel.
//!
//! # Encoding
//!
//! With `s` the voxel's edge length and `c` its centre, a contour is the slab
//! `|n . (x - c) - p s| <= h s` (n unit). In 32 bits:
//!
//! | bits | field | value |
//! | --- | --- | --- |
//! | 26..32 | nx | 6-bit two's complement q, component q / 31 |
//! | 20..26 | ny | likewise |
//! | 14..20 | nz | likewise (the decoded vector is normalised) |
//! | 7..14 | p | 7-bit two's complement q, `p = q / 63 * sqrt(3) / 2` |
//! | 0..7 | h | 7-bit unsigned q, `h = q / 127 * sqrt(3) / 2` |
//!
//! The value 0 (a zero normal) means "no contour". Offsets and
//! thicknesses span half the voxel's diagonal, so every slab that meets the
//! voxel is expressible.
//!
//! # Fit
//!
//! For the SDF shapes (the sphere): n is the SDF gradient at the voxel
//! centre, quantised first; p and h are the midpoint and half-range of
//! `n . (x - c) / s` over surface points in the voxel (a 5^3 grid of the
//! box projected onto the surface, plus the surface point nearest the
//! centre), p rounded and h rounded up past the rounding of p plus one step,
//! so the slab holds every sampled surface point.

use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::real::Real;

use super::octree::Octree;
use super::shape::Shape;

const HALF_DIAG: f64 = 0.866_025_403_784_438_6;
const P_STEP: f64 = HALF_DIAG / 63.0;
const H_STEP: f64 = HALF_DIAG / 127.0;

fn q6(x: f64) -> u32 {
    ((x * 31.0).round().clamp(-31.0, 31.0) as i32 as u32) & 0x3F
}

fn s6(b: u32) -> f64 {
    ((b << 26) as i32 >> 26) as f64 / 31.0
}

/// The quantised unit normal that `n` encodes to.
pub fn quantised_normal(n: [f64; 3]) -> [f64; 3] {
    let q = n.map(|x| s6(q6(x)));
    let l = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2]).sqrt();
    q.map(|x| x / l)
}

/// Packs a contour; `n` is used as [`quantised_normal`] gives it, `p` is
/// rounded, `h` rounded up (both clamped to their ranges).
pub fn encode(n: [f64; 3], p: f64, h: f64) -> u32 {
    let pq = ((p / P_STEP).round().clamp(-63.0, 63.0) as i32 as u32) & 0x7F;
    let hq = (h / H_STEP).ceil().clamp(0.0, 127.0) as u32;
    q6(n[0]) << 26 | q6(n[1]) << 20 | q6(n[2]) << 14 | pq << 7 | hq
}

/// Unpacks `(n, p, h)` (see the module doc) in precision `F`.
pub fn decode<F: Real>(v: u32) -> ([F; 3], F, F) {
    let n = quantised_normal([s6(v >> 26), s6(v >> 20), s6(v >> 14)].map(|x| x.clamp(-1.0, 1.0)));
    let p = ((v << 18) as i32 >> 25) as f64 * P_STEP;
    let h = (v & 0x7F) as f64 * H_STEP;
    (n.map(F::of), F::of(p), F::of(h))
}

/// Contour of the depth-`depth` voxel `v` for the sphere of `radius` about
/// the origin, `None` when the voxel's box lies inside the sphere (no
/// surface there).
pub fn fit_sphere(radius: f64, depth: u32, v: [u32; 3]) -> Option<u32> {
    let s = 2.0 / (1u64 << depth) as f64;
    let lo = v.map(|i| -1.0 + i as f64 * s);
    let c = lo.map(|x| x + 0.5 * s);
    let far = (0..3)
        .map(|a| {
            let m = lo[a].abs().max((lo[a] + s).abs());
            m * m
        })
        .sum::<f64>();
    let cl = (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt();
    if far <= radius * radius || cl == 0.0 {
        return None;
    }
    let n = quantised_normal(c.map(|x| x / cl));
    let f = |x: [f64; 3]| (0..3).map(|a| n[a] * (x[a] - c[a])).sum::<f64>() / s;
    let mut lo_f = f(c.map(|x| x * radius / cl));
    let mut hi_f = lo_f;
    const K: usize = 5;
    for i in 0..K * K * K {
        let g = [i % K, i / K % K, i / (K * K)].map(|k| k as f64 / (K - 1) as f64);
        let x: [f64; 3] = [0, 1, 2].map(|a| lo[a] + g[a] * s);
        let l = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
        if l == 0.0 {
            continue;
        }
        let y = x.map(|e| e * radius / l);
        if (0..3).all(|a| y[a] >= lo[a] && y[a] <= lo[a] + s) {
            let v = f(y);
            lo_f = lo_f.min(v);
            hi_f = hi_f.max(v);
        }
    }
    let p = 0.5 * (lo_f + hi_f);
    let pr = (p / P_STEP).round().clamp(-63.0, 63.0) * P_STEP;
    let h = 0.5 * (hi_f - lo_f) + (p - pr).abs() + H_STEP;
    Some(encode(n, p, h))
}

/// Contours of every leaf of `tree` (index = attribute index, 0 = none):
/// finest-level leaves on the surface of an SDF shape get one.
pub fn fit_all(shape: &Shape, tree: &Octree) -> Result<Vec<u32>> {
    let Shape::Sphere { radius } = *shape else {
        return Err(Error::invalid(
            "contours",
            "contours are fitted from an SDF: only `shape: {type: sphere}` has one",
        ));
    };
    let leaves = tree.leaves();
    let depth = tree.depth;
    Ok(par_collect("voxels.contours", leaves.len(), |i| {
        let (level, lo) = leaves[i];
        if level == depth {
            fit_sphere(radius, depth, lo).unwrap_or(0)
        } else {
            0
        }
    }))
}

/// The t interval in which `o + t d` is inside the slab of contour `v` of
/// the voxel with centre `c` and edge `s`: `(t0, t1)`, empty when t0 > t1.
pub fn slab_interval<F: Real>(v: u32, c: [F; 3], s: F, o: [F; 3], d: [F; 3]) -> (F, F) {
    let (n, p, h) = decode::<F>(v);
    let s0 = n[0] * (o[0] - c[0]) + n[1] * (o[1] - c[1]) + n[2] * (o[2] - c[2]) - p * s;
    let nd = n[0] * d[0] + n[1] * d[1] + n[2] * d[2];
    let th = h * s;
    let big = F::of(f64::MAX);
    if nd == F::zero() {
        return if s0.abs() <= th {
            (-big, big)
        } else {
            (big, -big)
        };
    }
    let a = (-th - s0) / nd;
    let b = (th - s0) / nd;
    if a < b {
        (a, b)
    } else {
        (b, a)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn encode_decode_round_trips_within_one_step() {
        let n = [0.36f64, -0.48, 0.8];
        let v = encode(n, 0.21, 0.05);
        let (m, p, h) = decode::<f64>(v);
        let dot = m[0] * n[0] + m[1] * n[1] + m[2] * n[2];
        assert!(dot > 0.999, "{m:?}");
        assert!((p - 0.21).abs() <= 0.5 * P_STEP + 1e-12, "{p}");
        assert!((0.05..=0.05 + H_STEP).contains(&h), "{h}");
        assert_eq!(
            decode::<f64>(encode([0.0, 0.0, -1.0], -0.5, 0.0)).0,
            [0.0, 0.0, -1.0]
        );
        assert!(encode([0.0, 0.0, 1.0], 0.0, 0.0) != 0);
    }

    #[test]
    fn sphere_slabs_hold_the_surface_points_of_their_voxels() {
        let (r, depth) = (0.8, 6);
        let s = 2.0 / 64.0;
        let mut fitted = 0;
        for i in 0..64u32 {
            for j in [5u32, 20, 32, 40] {
                for k in 0..64u32 {
                    let Some(v) = fit_sphere(r, depth, [i, j, k]) else {
                        continue;
                    };
                    fitted += 1;
                    let (n, p, h) = decode::<f64>(v);
                    let lo = [i, j, k].map(|x| -1.0 + x as f64 * s);
                    let c = lo.map(|x| x + 0.5 * s);
                    // Dense surface samples in the box lie in the slab.
                    for u in 0..11 {
                        for w in 0..11 {
                            for z in 0..11 {
                                let x = [u, w, z].map(|g| g as f64 / 10.0);
                                let x = [0, 1, 2].map(|a| lo[a] + x[a] * s);
                                let l = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]).sqrt();
                                let y = x.map(|e| e * r / l);
                                if (0..3).all(|a| y[a] >= lo[a] && y[a] <= lo[a] + s) {
                                    let f = (0..3).map(|a| n[a] * (y[a] - c[a])).sum::<f64>() / s;
                                    assert!((f - p).abs() <= h + 1e-9, "{i} {j} {k}: {f} {p} {h}");
                                }
                            }
                        }
                    }
                }
            }
        }
        assert!(fitted > 100);
        assert_eq!(fit_sphere(r, depth, [32, 32, 32]), None);
    }

    #[test]
    fn slab_interval_of_an_axis_plane() {
        let v = encode([0.0, 0.0, 1.0], 0.0, 0.1);
        let (_, _, h) = decode::<f64>(v);
        let (a, b) = slab_interval(v, [0.0, 0.0, 0.5], 1.0, [0.0, 0.0, 0.0], [0.0, 0.0, 1.0]);
        assert!((a - (0.5 - h)).abs() < 1e-12 && (b - (0.5 + h)).abs() < 1e-12);
        let (a, b) = slab_interval(v, [0.0, 0.0, 0.5], 1.0, [0.0, 0.0, 0.0], [1.0, 0.0, 0.0]);
        assert!(a > b, "parallel ray outside the slab misses");
    }
}
