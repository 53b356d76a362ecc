//! `cast_lanes`: the f32 Laine–Karras loop of [`super::cast::cast_with`]
//! for 8 (AVX2) or 16 (AVX-512) independent rays at once, one ray per
//! vector lane (issue 15, point 3: many rays in flight). The per-ray SSE
//! cast ([`super::cast_sse`]) is bound by the latency of the descriptor
//! load `nodes[2 * parent]`: each iteration waits for it, and the branch on
//! it mispredicts. Here each lane carries its own ESVO state (position,
//! scale, `t_min`/`t_max`, `h`, parent, descriptor, its own stack of
//! `S_MAX + 1` parent slots: POP recomputes `t_max` from the parent's cube
//! instead of reading it back), and one loop iteration advances every live lane:
//! the descriptors of all lanes are one gather (eight or sixteen loads in
//! flight), PUSH, ADVANCE and POP are computed on every lane and blended by
//! masks (no per-lane branch; the step branches only on whether any lane
//! pushes, advances, pops or follows a far pointer), child
//! addresses and POP's stack read are gathers, a PUSH prefetches each
//! pushed lane's child descriptor (the group's next step gathers it after
//! the other group's step has run; on the DAG since the tenth session:
//! incoherent 1.25-1.53x, coherent 0.96-1.00x on an AVX2 box, docs/PERF.md),
//! POP's highest differing bit
//! is the exponent of the bits converted to float (exact: they fit 24 bits
//! whenever the new scale is below [`S_MAX`]). A lane whose ray stops,
//! exits or hits the iteration cap is finished by the scalar
//! [`finish`] and refilled with the next ray of the stream ([`start`]).
//!
//! Every float operation is the scalar loop's on the same operands in the
//! same order (`pos * coef - bias`, `halfs * coef + tc`, `pos ± scale_exp2`,
//! `tc_max * dir_size + orig_size`; `_mm256_min_ps(a, b)` is `a < b ? a :
//! b`, the scalar `fmin`; the compares are the ordered ones), so hit, t,
//! leaf, normal, level, attr and iterations are bit-identical to the
//! per-ray cast, which stays the referee (unit tests below, cases
//! `voxel_lanes_*_identical` in `TESTS/voxels/manifest_packet.yaml`).
//! The instruction set is picked at run time ([`LaneIsa`]): sixteen lanes
//! in AVX-512 registers with mask registers where the CPU has AVX-512F/VL/BW
//! (`cast_lanes/avx512.rs`), else eight in AVX2 registers with masks as
//! all-ones lanes (`cast_lanes/avx2.rs`); both step one frame (lane state,
//! ray queue, groups, answers: `cast_lanes/stream.rs`). Without AVX2, or
//! when the node array is too large for 32-bit gather indices, the SSE
//! per-ray cast runs. No contours (the per-ray cast does them).
//!
//! Sixteen lanes over eight, measured in one run (`hpjudge perf --filter
//! voxels_gpu_sphere_d10` and `voxels_gpu_menger_d10`, Mrays per CPU-s, the
//! same rays through both; 2-core AMD EPYC family 26 with full-width
//! AVX-512, docs/PERF.md fifteenth session): 1.15-1.26x coherent,
//! 1.21-1.36x incoherent, 0 differing rays; the earlier build of the
//! eight-lane loop with AVX-512 enabled read 1.00-1.04x of AVX2 on that box.

use super::cast::{Addressing, CastHit, CastParams};
use super::cast_sse::cast_sse;
use super::hits::{cast_chunks, GRAIN};
use super::render::VoxelHits;

/// What the lane loop is compiled for, picked at run time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum LaneIsa {
    /// No lane loop: the SSE per-ray cast (no AVX2, or a node array too
    /// large for 32-bit gather indices).
    Sse,
    /// The AVX2 lane loop: eight lanes.
    Avx2,
    /// The AVX-512F/VL/BW lane loop: sixteen lanes, mask registers, the
    /// same IEEE operations.
    Avx512,
}

impl LaneIsa {
    /// The widest set this CPU runs for a node array of `len` words.
    pub fn detect(len: usize) -> LaneIsa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && len < (1 << 30) {
                let avx512 = has!("avx512f") && has!("avx512vl") && has!("avx512bw");
                return if avx512 {
                    LaneIsa::Avx512
                } else {
                    LaneIsa::Avx2
                };
            }
        }
        let _ = len;
        LaneIsa::Sse
    }

    /// Every set this CPU runs for `len` words, narrowest first (the
    /// referee tests cast through each).
    pub fn available(len: usize) -> Vec<LaneIsa> {
        let all = [LaneIsa::Sse, LaneIsa::Avx2, LaneIsa::Avx512];
        let top = LaneIsa::detect(len);
        all.into_iter().filter(|&i| i <= top).collect()
    }
}

/// Every ray `(o[i], d[i])` cast through `nodes` (addressing `A`) into
/// `out[i]`, on the widest [`LaneIsa`] this CPU has: the same results as
/// [`super::cast::cast_with`]`::<f32, A>(.., None)` per ray, with `p.near`
/// replaced by `near[i]` when `near` is given (the beam's starts; an
/// infinite one answers a miss at once). Sequential (the caller fans
/// chunks out).
pub fn cast_lanes<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
    near: Option<&[f64]>,
    out: &mut [CastHit<f32>],
) {
    let isa = LaneIsa::detect(nodes.len());
    cast_lanes_on::<A>(isa, nodes, depth, o, d, p, near, out)
}

/// Every ray cast by [`cast_lanes_on`] on `isa`, in parallel chunks (the
/// perf op compares the instruction sets in one run).
pub fn cast_all_lanes_on<A: Addressing>(
    isa: LaneIsa,
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
) -> VoxelHits<f32> {
    cast_chunks("voxels.cast_lanes", o.len(), GRAIN, |r, out| {
        cast_lanes_on::<A>(isa, nodes, depth, &o[r.clone()], &d[r], p, None, out)
    })
}

/// [`cast_lanes`] on `isa`, which must be one of
/// [`LaneIsa::available`]`(nodes.len())` (else the SSE cast runs).
#[allow(clippy::too_many_arguments)]
pub fn cast_lanes_on<A: Addressing>(
    isa: LaneIsa,
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
    near: Option<&[f64]>,
    out: &mut [CastHit<f32>],
) {
    let isa = isa.min(LaneIsa::detect(nodes.len()));
    // SAFETY: `isa` is within what this CPU has, and every node slot fits
    // an i32 gather index (both checked by `LaneIsa::detect`).
    #[cfg(target_arch = "x86_64")]
    match isa {
        LaneIsa::Avx512 => {
            return unsafe { avx512::stream_avx512::<A>(nodes, depth, o, d, p, near, out) }
        }
        LaneIsa::Avx2 => {
            return unsafe { avx2::stream_avx2::<A>(nodes, depth, o, d, p, near, out) }
        }
        LaneIsa::Sse => {}
    }
    let _ = isa;
    for (i, h) in out.iter_mut().enumerate() {
        *h = cast_sse::<A>(nodes, depth, o[i], d[i], &p.for_ray(near, i));
    }
}

#[cfg(target_arch = "x86_64")]
mod avx2;
#[cfg(target_arch = "x86_64")]
mod avx512;
#[cfg(target_arch = "x86_64")]
mod stream;

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::cast::{cast_with, default_max_iter, Absolute, Relative};
    use crate::voxels::dag::build_dag;
    use crate::voxels::fixtures::{hard_rays, lod, scenes};
    use crate::voxels::octree::build;
    use crate::voxels::shape::{Shape, VoxelBox};

    /// The lane cast on every [`LaneIsa`] this CPU has against the per-ray
    /// cast, every field of every ray.
    fn same<A: Addressing>(nodes: &[u32], depth: u32, p: &CastParams, what: &str) {
        let (o, d) = hard_rays(6000, 9);
        for isa in LaneIsa::available(nodes.len()) {
            let mut lanes = vec![CastHit::miss(0, false); o.len()];
            cast_lanes_on::<A>(isa, nodes, depth, &o, &d, p, None, &mut lanes);
            for i in 0..o.len() {
                let a = cast_with::<f32, A>(nodes, depth, o[i], d[i], p, None);
                let b = lanes[i];
                assert_eq!(format!("{a:?}"), format!("{b:?}"), "{what} {isa:?} ray {i}");
            }
        }
    }

    #[test]
    fn lane_cast_is_bit_identical_to_the_per_ray_cast_on_octree_and_dag() {
        let avx2 = std::arch::is_x86_feature_detected!("avx2");
        assert!(LaneIsa::detect(1 << 20) >= LaneIsa::Avx2 || !avx2);
        let interval = CastParams {
            near: 0.5,
            far: 2.5,
            max_iter: default_max_iter(7),
            ..CastParams::default()
        };
        let capped = CastParams {
            max_iter: 9,
            ..CastParams::default()
        };
        for (s, depth) in scenes() {
            let t = build(&s, depth, &MemBudget::fixed(1 << 30)).unwrap();
            let g = build_dag(&t, &MemBudget::fixed(1 << 30)).unwrap();
            for p in [CastParams::default(), lod(0.01), interval, capped] {
                same::<Relative>(&t.nodes, depth, &p, &format!("octree {s:?} {p:?}"));
                same::<Absolute>(&g.nodes, depth, &p, &format!("dag {s:?} {p:?}"));
            }
        }
    }

    /// Streams of fewer rays than a group has lanes (and just over): the
    /// groups start and end with idle lanes.
    #[test]
    fn short_streams_leave_idle_lanes_and_equal_the_per_ray_cast() {
        let (s, depth) = scenes().into_iter().next().unwrap();
        let t = build(&s, depth, &MemBudget::fixed(1 << 30)).unwrap();
        let (o, d) = hard_rays(40, 5);
        let p = CastParams::default();
        for n in [0, 1, 2, 7, 15, 16, 17, 31, 33, 40] {
            for isa in LaneIsa::available(t.nodes.len()) {
                let mut lanes = vec![CastHit::miss(99, true); n];
                cast_lanes_on::<Relative>(
                    isa,
                    &t.nodes,
                    depth,
                    &o[..n],
                    &d[..n],
                    &p,
                    None,
                    &mut lanes,
                );
                for i in 0..n {
                    let a = cast_with::<f32, Relative>(&t.nodes, depth, o[i], d[i], &p, None);
                    assert_eq!(
                        format!("{a:?}"),
                        format!("{:?}", lanes[i]),
                        "{isa:?} n {n} ray {i}"
                    );
                }
            }
        }
    }

    #[test]
    fn lane_cast_follows_far_pointers_at_depth_17() {
        let depth = 17;
        let n = 1u32 << depth;
        let boxes = [
            [5u32, 70_000, 3],
            [n - 1, n - 1, n - 1],
            [65_536, 65_535, 65_536],
        ]
        .iter()
        .map(|&p| VoxelBox { min: p, max: p })
        .chain([VoxelBox {
            min: [1000, 2000, 0],
            max: [1000, 2000, n - 1],
        }])
        .collect();
        let t = build(&Shape::Boxes { boxes }, depth, &MemBudget::fixed(1 << 30)).unwrap();
        let p = CastParams {
            max_iter: default_max_iter(depth),
            ..CastParams::default()
        };
        same::<Relative>(&t.nodes, depth, &p, "points d17");
    }
}
