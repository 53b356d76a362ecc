//! `cast_sse`: the f32 Laine–Karras loop of [`super::cast::cast_with`] with
//! the three axes of `pos`, `coef` and `bias` in one SSE register each
//! (issue 15, point 3: SIMD where it pays, here inside one ray).
//!
//! Every float operation is the scalar loop's, in the same order and on
//! the same operands (`pos * coef - bias`, `halfs * coef + tc`, `pos ±
//! scale_exp2`, `<=` / `>` compares), so every output (hit, t, leaf, normal,
//! level, attr, iterations) is bit-identical to the scalar cast, which stays
//! the referee (cases `voxel_sse_*_identical` in
//! `TESTS/voxels/manifest_packet.yaml`, and the unit test below). What
//! changes is the machine code: the scalar loop keeps `pos` in memory and
//! re-reads it as a vector after per-axis scalar stores (a store-forwarding
//! stall on every iteration); here `pos` lives in a register, the three
//! ray-plane times are one multiply and one subtract, the ADVANCE and PUSH
//! masks are one compare each, and POP's bit search is one XOR and OR
//! reduction. The fourth lane carries `coef = 0`, `bias = -inf`, so its
//! time is `+inf` and it never wins a minimum; masks keep it out of `idx`.
//!
//! `tc_max` is the minimum of the three times taken pairwise in another
//! order than `fmin(fmin(tc0, tc1), tc2)`: that returns the same bits since
//! no time is NaN or `-0` (`pos * coef` is negative and nonzero, and
//! `x - x = +0`). When a node's descriptor is read, its children block is
//! prefetched (a hint; it changes no result). SSE2 is part of x86_64, so no runtime detection is needed;
//! elsewhere the scalar loop runs. No contours (the scalar cast does them).

use super::cast::{finish, start, Addressing, CastHit, CastParams, Stop, S_MAX};

/// The cast of one f32 ray through `nodes` (addressing `A`): the same
/// result as [`super::cast::cast_with`]`::<f32, A>(.., None)`.
#[cfg(not(target_arch = "x86_64"))]
pub fn cast_sse<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: [f32; 3],
    d: [f32; 3],
    p: &CastParams,
) -> CastHit<f32> {
    super::cast::cast_with::<f32, A>(nodes, depth, o, d, p, None)
}

/// The cast of one f32 ray through `nodes` (addressing `A`): the same
/// result as [`super::cast::cast_with`]`::<f32, A>(.., None)`.
#[cfg(target_arch = "x86_64")]
pub fn cast_sse<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: [f32; 3],
    d: [f32; 3],
    p: &CastParams,
) -> CastHit<f32> {
    // SAFETY: SSE2 is part of the x86_64 baseline, so every x86_64 CPU has it.
    unsafe { cast_sse2::<A>(nodes, depth, o, d, p) }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "sse2")]
fn cast_sse2<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: [f32; 3],
    d: [f32; 3],
    p: &CastParams,
) -> CastHit<f32> {
    use std::arch::x86_64::*;

    let half = 0.5f32;
    let Some(st) = start(o, d, p) else {
        return CastHit::miss(0, false);
    };
    let octant = st.octant;
    let (mut t_min, mut t_max, mut h, mut idx) = (st.t_min, st.t_max, st.h, st.idx);
    let coef = _mm_setr_ps(st.coef[0], st.coef[1], st.coef[2], 0.0);
    let bias = _mm_setr_ps(st.bias[0], st.bias[1], st.bias[2], f32::NEG_INFINITY);
    let mut pos = _mm_setr_ps(st.pos[0], st.pos[1], st.pos[2], 1.0);
    let xyz = _mm_castsi128_ps(_mm_setr_epi32(-1, -1, -1, 0));
    let lod = st.lod;
    let mut stack_node = [0u32; S_MAX as usize + 1];
    let mut stack_tmax = [0f32; S_MAX as usize + 1];
    let mut parent = 0usize;
    let mut desc = 0u32;
    let mut scale = S_MAX - 1;
    let mut scale_exp2 = half;
    let mut iters = 0u32;
    let mut stop: Option<bool> = None;
    while scale < S_MAX {
        iters += 1;
        if iters > p.max_iter {
            return CastHit::miss(iters - 1, true);
        }
        if desc == 0 {
            desc = nodes[2 * parent];
            // Start fetching the children block now: a PUSH reads it about
            // twenty instructions later (the loop is load-latency bound).
            let kids = nodes
                .as_ptr()
                .wrapping_add(2 * A::children(nodes, parent, desc));
            _mm_prefetch::<_MM_HINT_T0>(kids as *const i8);
        }
        let tc = _mm_sub_ps(_mm_mul_ps(pos, coef), bias);
        let m = _mm_min_ps(tc, _mm_shuffle_ps::<0b10_11_00_01>(tc, tc));
        let m = _mm_min_ps(m, _mm_shuffle_ps::<0b01_00_11_10>(m, m));
        let tc_max = _mm_cvtss_f32(m);
        let child_shift = idx ^ octant;
        let child_masks = desc << child_shift;
        if child_masks & 0x8000 != 0 && t_min <= t_max {
            if let Some((osz, dsz)) = lod {
                if tc_max * dsz + osz >= scale_exp2 {
                    stop = Some(child_masks & 0x80 == 0);
                    break;
                }
            }
            let tv_max = if t_max < tc_max { t_max } else { tc_max };
            if t_min <= tv_max {
                if child_masks & 0x80 == 0 {
                    stop = Some(true);
                    break;
                }
                // PUSH
                let halfs = scale_exp2 * half;
                if tc_max < h {
                    stack_node[scale as usize] = parent as u32;
                    stack_tmax[scale as usize] = t_max;
                }
                h = tc_max;
                parent = A::child(nodes, parent, desc, child_masks, child_shift ^ 7);
                scale -= 1;
                scale_exp2 = halfs;
                let tcen = _mm_add_ps(_mm_mul_ps(_mm_set1_ps(halfs), coef), tc);
                let up = _mm_and_ps(_mm_cmpgt_ps(tcen, _mm_set1_ps(t_min)), xyz);
                idx = _mm_movemask_ps(up) as u32;
                pos = _mm_add_ps(pos, _mm_and_ps(up, _mm_set1_ps(scale_exp2)));
                t_max = tv_max;
                desc = 0;
                continue;
            }
        }
        // ADVANCE
        let se = _mm_set1_ps(scale_exp2);
        let stepm = _mm_and_ps(_mm_cmple_ps(tc, _mm_set1_ps(tc_max)), xyz);
        let step = _mm_movemask_ps(stepm) as u32;
        let old = pos;
        pos = _mm_sub_ps(pos, _mm_and_ps(stepm, se));
        t_min = tc_max;
        idx ^= step;
        if idx & step != 0 {
            // POP: the highest bit in which the positions before and after differ.
            let x = _mm_and_ps(_mm_xor_ps(pos, old), stepm);
            let x = _mm_or_ps(x, _mm_shuffle_ps::<0b01_00_11_10>(x, x));
            let x = _mm_or_ps(x, _mm_shuffle_ps::<0b10_11_00_01>(x, x));
            let diff = _mm_cvtsi128_si32(_mm_castps_si128(x)) as u32;
            scale = 31 - diff.leading_zeros() as i32;
            if scale >= S_MAX {
                break;
            }
            scale_exp2 = f32::from_bits(((scale - S_MAX + 127) as u32) << 23);
            parent = stack_node[scale as usize] as usize;
            t_max = stack_tmax[scale as usize];
            let cnt = _mm_cvtsi32_si128(scale);
            let sh = _mm_srl_epi32(_mm_castps_si128(pos), cnt);
            pos = _mm_castsi128_ps(_mm_sll_epi32(sh, cnt));
            idx = (_mm_movemask_ps(_mm_castsi128_ps(_mm_slli_epi32::<31>(sh))) & 7) as u32;
            h = 0.0;
            desc = 0;
        }
    }
    let Some(leaf) = stop else {
        return CastHit::miss(iters, false);
    };
    let lane = |v: __m128| -> [f32; 3] {
        [
            _mm_cvtss_f32(v),
            _mm_cvtss_f32(_mm_shuffle_ps::<0x55>(v, v)),
            _mm_cvtss_f32(_mm_shuffle_ps::<0xAA>(v, v)),
        ]
    };
    let stop = Stop {
        leaf,
        pos: lane(pos),
        scale,
        scale_exp2,
        t_min,
        parent,
        desc,
        idx,
        contour_hit: None,
        iters,
    };
    finish::<f32, A>(nodes, depth, o, d, p, &st, &stop)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::cast::{cast_with, Absolute, Relative};
    use crate::voxels::dag::build_dag;
    use crate::voxels::fixtures::{hard_rays, lod, scenes};
    use crate::voxels::octree::build;

    #[test]
    fn sse_cast_is_bit_identical_to_the_scalar_cast_on_octree_and_dag() {
        let (o, d) = hard_rays(4000, 7);
        for (s, depth) in scenes() {
            let t = build(&s, depth, &MemBudget::fixed(1 << 30)).unwrap();
            let g = build_dag(&t, &MemBudget::fixed(1 << 30)).unwrap();
            for p in [CastParams::default(), lod(0.01)] {
                for (&o, &d) in o.iter().zip(&d) {
                    let a = cast_with::<f32, Relative>(&t.nodes, depth, o, d, &p, None);
                    let b = cast_sse::<Relative>(&t.nodes, depth, o, d, &p);
                    assert_eq!(format!("{a:?}"), format!("{b:?}"), "{s:?} {o:?} {d:?}");
                    let a = cast_with::<f32, Absolute>(&g.nodes, depth, o, d, &p, None);
                    let b = cast_sse::<Absolute>(&g.nodes, depth, o, d, &p);
                    assert_eq!(format!("{a:?}"), format!("{b:?}"), "{s:?} {o:?} {d:?}");
                }
            }
        }
    }
}
