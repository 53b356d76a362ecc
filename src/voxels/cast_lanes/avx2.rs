//! The lane loop on AVX2: eight lanes, masks as all-ones lanes of an
//! integer vector, blends by those masks.

use std::arch::x86_64::*;

use super::stream::{
    answer, prefetch, stream, write_stack, Consts, Ended, Group, Isa, State, SPARE,
};
use crate::voxels::cast::{Addressing, CastHit, CastParams, S_MAX};

/// The AVX2 lane loop.
pub(super) struct Avx2;

/// [`stream`] compiled for AVX2.
///
/// # Safety
/// The CPU must have AVX2 and `2 * nodes.len()` must fit an i32.
#[target_feature(enable = "avx2")]
pub(super) unsafe fn stream_avx2<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
    near: Option<&[f64]>,
    out: &mut [CastHit<f32>],
) {
    stream::<Avx2, A>(nodes, depth, o, d, p, near, out)
}

impl Isa for Avx2 {
    const W: usize = 8;
    type F = __m256;
    type I = __m256i;
    type M = __m256i;

    #[inline(always)]
    unsafe fn splat_f(x: f32) -> __m256 {
        _mm256_set1_ps(x)
    }

    #[inline(always)]
    unsafe fn splat_i(x: i32) -> __m256i {
        _mm256_set1_epi32(x)
    }

    #[inline(always)]
    unsafe fn none() -> __m256i {
        _mm256_setzero_si256()
    }

    #[inline(always)]
    unsafe fn bits(m: __m256i) -> u32 {
        mask_i(m)
    }

    #[inline(always)]
    fn set(m: &mut __m256i, l: usize, on: bool) {
        Self::i_lanes(m)[l] = if on { -1 } else { 0 };
    }

    #[inline(always)]
    fn f_lanes(v: &mut __m256) -> &mut [f32] {
        // SAFETY: __m256 is 8 f32 with at least their alignment.
        unsafe { &mut *(v as *mut __m256 as *mut [f32; 8]) }
    }

    #[inline(always)]
    fn i_lanes(v: &mut __m256i) -> &mut [i32] {
        // SAFETY: __m256i is 8 i32 with at least their alignment.
        unsafe { &mut *(v as *mut __m256i as *mut [i32; 8]) }
    }

    #[inline(always)]
    unsafe fn step<A: Addressing, const N: usize>(
        g: [&mut Group<Avx2>; N],
        k: &Consts<Avx2>,
        out: &mut [CastHit<f32>],
    ) {
        step::<A, N>(g, k, out)
    }
}

/// The lane mask of `m` as bits.
#[inline(always)]
unsafe fn mask_i(m: __m256i) -> u32 {
    _mm256_movemask_ps(_mm256_castsi256_ps(m)) as u32
}

/// All ones on lanes where `v & m == 0`.
#[inline(always)]
unsafe fn clear(v: __m256i, m: i32) -> __m256i {
    let z = _mm256_setzero_si256();
    _mm256_cmpeq_epi32(_mm256_and_si256(v, _mm256_set1_epi32(m)), z)
}

/// All ones on lanes where `a <= b` (ordered, as the scalar `<=`).
#[inline(always)]
unsafe fn le(a: __m256, b: __m256) -> __m256i {
    _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LE_OQ>(a, b))
}

/// POP's new `idx`: bit `a` is bit `scale` of axis `a`'s position.
#[inline(always)]
unsafe fn pop_idx(pos: &[__m256; 3], scale: __m256i) -> __m256i {
    let mut idx = _mm256_setzero_si256();
    for (a, p) in pos.iter().enumerate() {
        let sh = _mm256_srlv_epi32(_mm256_castps_si256(*p), scale);
        let b = _mm256_and_si256(sh, _mm256_set1_epi32(1));
        idx = _mm256_or_si256(idx, _mm256_sllv_epi32(b, _mm256_set1_epi32(a as i32)));
    }
    idx
}

/// The octree's child slot on lanes (`Relative::child`): `parent + ofs`
/// (through the far-pointer slot where the far bit is set) plus the
/// non-leaf children before `c` (`cm & 0x7F`, counted by nibbles).
#[inline(always)]
unsafe fn child_relative(base: *const i32, s: &State<Avx2>, cm: __m256i, push: __m256i) -> __m256i {
    let mut ofs = _mm256_srli_epi32::<17>(s.desc);
    let far = _mm256_andnot_si256(clear(s.desc, 0x1_0000), push);
    if mask_i(far) != 0 {
        let far_slot = _mm256_slli_epi32::<1>(_mm256_add_epi32(s.parent, ofs));
        ofs = _mm256_mask_i32gather_epi32::<4>(ofs, base, far_slot, far);
    }
    let pop_lut = _mm256_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3,
        3, 4,
    );
    let before = _mm256_and_si256(cm, _mm256_set1_epi32(0x7F));
    let lo = _mm256_and_si256(before, _mm256_set1_epi32(0xF));
    let hi = _mm256_srli_epi32::<4>(before);
    let cnt = _mm256_add_epi32(
        _mm256_shuffle_epi8(pop_lut, lo),
        _mm256_shuffle_epi8(pop_lut, hi),
    );
    _mm256_add_epi32(_mm256_add_epi32(s.parent, ofs), cnt)
}

/// One loop iteration of every live lane of the `N` groups `gs` (PUSH,
/// ADVANCE, POP by masks), then the answers of the lanes whose ray ended
/// and their refill; the groups interleaved phase by phase, as in
/// `cast_lanes/avx512.rs`.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // per-axis and per-group loops over lane vectors
unsafe fn step<A: Addressing, const N: usize>(
    gs: [&mut Group<Avx2>; N],
    k: &Consts<Avx2>,
    out: &mut [CastHit<f32>],
) {
    let base = k.nodes.as_ptr() as *const i32;
    let zf = _mm256_setzero_ps();
    let zi = _mm256_setzero_si256();
    let one = _mm256_set1_epi32(1);
    let half = _mm256_set1_ps(0.5);
    let (max_iter, lane_base) = (k.max_iter, k.lane_base);
    let (mut capped, mut live, mut slot) = ([zi; N], [zi; N], [zi; N]);
    for j in 0..N {
        let s = &mut gs[j].s;
        let act = s.act;
        s.iters = _mm256_add_epi32(s.iters, _mm256_and_si256(act, one));
        capped[j] = _mm256_and_si256(act, _mm256_cmpgt_epi32(s.iters, max_iter));
        live[j] = _mm256_andnot_si256(capped[j], act);
        // Every live lane's descriptor in one gather.
        let need = _mm256_and_si256(live[j], _mm256_cmpeq_epi32(s.desc, zi));
        slot[j] = _mm256_slli_epi32::<1>(s.parent);
        s.desc = _mm256_mask_i32gather_epi32::<4>(s.desc, base, slot[j], need);
    }
    let (mut tc, mut tc_max, mut tv_max) = ([[zf; 3]; N], [zf; N], [zf; N]);
    let (mut shift, mut cm) = ([zi; N], [zi; N]);
    let (mut leaf, mut stop, mut push, mut adv, mut exit) =
        ([zi; N], [zi; N], [zi; N], [zi; N], [zi; N]);
    for j in 0..N {
        let s = &mut gs[j].s;
        for a in 0..3 {
            tc[j][a] = _mm256_sub_ps(_mm256_mul_ps(s.pos[a], s.coef[a]), s.bias[a]);
        }
        tc_max[j] = _mm256_min_ps(_mm256_min_ps(tc[j][0], tc[j][1]), tc[j][2]);
        shift[j] = _mm256_xor_si256(s.idx, s.octant);
        cm[j] = _mm256_sllv_epi32(s.desc, shift[j]);
        let valid = _mm256_andnot_si256(clear(cm[j], 0x8000), le(s.t_min, s.t_max));
        let lod_stop = if let Some((osz, dsz)) = k.lod {
            let fp = _mm256_add_ps(_mm256_mul_ps(tc_max[j], dsz), osz);
            let cut = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(fp, s.se));
            _mm256_and_si256(valid, cut)
        } else {
            zi
        };
        tv_max[j] = _mm256_min_ps(s.t_max, tc_max[j]);
        let inter = _mm256_andnot_si256(lod_stop, _mm256_and_si256(valid, le(s.t_min, tv_max[j])));
        leaf[j] = clear(cm[j], 0x80);
        stop[j] = _mm256_and_si256(
            live[j],
            _mm256_or_si256(lod_stop, _mm256_and_si256(inter, leaf[j])),
        );
        push[j] = _mm256_and_si256(live[j], _mm256_andnot_si256(leaf[j], inter));
        adv[j] = _mm256_andnot_si256(_mm256_or_si256(stop[j], push[j]), live[j]);
    }
    if push.iter().any(|&m| mask_i(m) != 0) {
        for j in 0..N {
            let g = &mut *gs[j];
            let (s, push) = (&mut g.s, push[j]);
            // PUSH: the stack write where `tc_max < h`, per lane.
            let keep = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(tc_max[j], s.h));
            let entry = _mm256_add_epi32(lane_base, s.scale);
            let write = _mm256_and_si256(push, keep);
            let at = _mm256_blendv_epi8(_mm256_set1_epi32(SPARE as i32), entry, write);
            write_stack::<Avx2>(at, s.parent, &mut g.stack);
            let child = if A::ABSOLUTE {
                let hi_slot = _mm256_add_epi32(slot[j], one);
                let hi = _mm256_mask_i32gather_epi32::<4>(zi, base, hi_slot, push);
                _mm256_add_epi32(hi, _mm256_xor_si256(shift[j], _mm256_set1_epi32(7)))
            } else {
                child_relative(base, s, cm[j], push)
            };
            prefetch::<Avx2>(base, _mm256_blendv_epi8(s.parent, child, push));
            let halfs = _mm256_mul_ps(s.se, half);
            let mut idx_push = zi;
            let pf = _mm256_castsi256_ps(push);
            for a in 0..3 {
                let tcen = _mm256_add_ps(_mm256_mul_ps(halfs, s.coef[a]), tc[j][a]);
                let up = _mm256_cmp_ps::<_CMP_GT_OQ>(tcen, s.t_min);
                let b = _mm256_and_si256(_mm256_castps_si256(up), _mm256_set1_epi32(1 << a));
                idx_push = _mm256_or_si256(idx_push, b);
                let pushed = _mm256_add_ps(s.pos[a], _mm256_and_ps(up, halfs));
                s.pos[a] = _mm256_blendv_ps(s.pos[a], pushed, pf);
            }
            s.idx = _mm256_blendv_epi8(s.idx, idx_push, push);
            s.h = _mm256_blendv_ps(s.h, tc_max[j], pf);
            s.scale = _mm256_add_epi32(s.scale, push);
            s.se = _mm256_blendv_ps(s.se, halfs, pf);
            s.t_max = _mm256_blendv_ps(s.t_max, tv_max[j], pf);
            s.parent = _mm256_blendv_epi8(s.parent, child, push);
            s.desc = _mm256_andnot_si256(push, s.desc);
        }
    }
    if adv.iter().any(|&m| mask_i(m) != 0) {
        // ADVANCE, and the bits that changed (for POP).
        let (mut pop, mut diff) = ([zi; N], [zi; N]);
        for j in 0..N {
            let (s, adv) = (&mut gs[j].s, adv[j]);
            let af = _mm256_castsi256_ps(adv);
            let mut step = zi;
            for a in 0..3 {
                let st = _mm256_cmp_ps::<_CMP_LE_OQ>(tc[j][a], tc_max[j]);
                let b = _mm256_and_si256(_mm256_castps_si256(st), _mm256_set1_epi32(1 << a));
                step = _mm256_or_si256(step, b);
                let moved = _mm256_sub_ps(s.pos[a], _mm256_and_ps(st, s.se));
                s.pos[a] = _mm256_blendv_ps(s.pos[a], moved, af);
                let back = _mm256_add_ps(s.pos[a], s.se);
                let x = _mm256_xor_si256(_mm256_castps_si256(s.pos[a]), _mm256_castps_si256(back));
                diff[j] = _mm256_or_si256(diff[j], _mm256_and_si256(x, _mm256_castps_si256(st)));
            }
            s.t_min = _mm256_blendv_ps(s.t_min, tc_max[j], af);
            let idx_adv = _mm256_xor_si256(s.idx, step);
            s.idx = _mm256_blendv_epi8(s.idx, idx_adv, adv);
            pop[j] =
                _mm256_andnot_si256(_mm256_cmpeq_epi32(_mm256_and_si256(idx_adv, step), zi), adv);
        }
        if pop.iter().any(|&m| mask_i(m) != 0) {
            for j in 0..N {
                let g = &mut *gs[j];
                let (s, pop) = (&mut g.s, pop[j]);
                // POP: the highest differing bit is the exponent of `diff`
                // as a float (exact below 2^24; from there on the scale is
                // past S_MAX either way).
                let e = _mm256_castps_si256(_mm256_cvtepi32_ps(diff[j]));
                let scale = _mm256_sub_epi32(_mm256_srli_epi32::<23>(e), _mm256_set1_epi32(127));
                exit[j] =
                    _mm256_and_si256(pop, _mm256_cmpgt_epi32(scale, _mm256_set1_epi32(S_MAX - 1)));
                let ok = _mm256_andnot_si256(exit[j], pop);
                let okf = _mm256_castsi256_ps(ok);
                let sidx = _mm256_add_epi32(lane_base, scale);
                s.parent = _mm256_mask_i32gather_epi32::<4>(s.parent, g.stack.as_ptr(), sidx, ok);
                // `t_max`: the exit of the parent's cube, `pos` rounded at
                // `scale + 1` ([`Group::stack`]).
                let up = _mm256_add_epi32(scale, one);
                let mut exit_t = [zf; 3];
                for a in 0..3 {
                    let sh = _mm256_srlv_epi32(_mm256_castps_si256(s.pos[a]), up);
                    let corner = _mm256_castsi256_ps(_mm256_sllv_epi32(sh, up));
                    exit_t[a] = _mm256_sub_ps(_mm256_mul_ps(corner, s.coef[a]), s.bias[a]);
                }
                let exit_max = _mm256_min_ps(_mm256_min_ps(exit_t[0], exit_t[1]), exit_t[2]);
                s.t_max = _mm256_blendv_ps(s.t_max, _mm256_min_ps(s.t_max0, exit_max), okf);
                for a in 0..3 {
                    let sh = _mm256_srlv_epi32(_mm256_castps_si256(s.pos[a]), scale);
                    let rounded = _mm256_castsi256_ps(_mm256_sllv_epi32(sh, scale));
                    s.pos[a] = _mm256_blendv_ps(s.pos[a], rounded, okf);
                }
                let se = _mm256_slli_epi32::<23>(_mm256_add_epi32(
                    scale,
                    _mm256_set1_epi32(127 - S_MAX),
                ));
                s.scale = _mm256_blendv_epi8(s.scale, scale, ok);
                s.se = _mm256_blendv_ps(s.se, _mm256_castsi256_ps(se), okf);
                s.idx = _mm256_blendv_epi8(s.idx, pop_idx(&s.pos, scale), ok);
                s.h = _mm256_andnot_ps(okf, s.h);
                s.desc = _mm256_andnot_si256(ok, s.desc);
            }
        }
    }
    // Lanes whose ray ended this iteration: the answer, then the next ray.
    for j in 0..N {
        let done = mask_i(_mm256_or_si256(
            _mm256_or_si256(capped[j], stop[j]),
            exit[j],
        ));
        if done != 0 {
            let (capped, stop, leaf) = (mask_i(capped[j]), mask_i(stop[j]), mask_i(leaf[j]));
            answer::<Avx2, A>(
                &mut *gs[j],
                k,
                Ended {
                    done,
                    capped,
                    stop,
                    leaf,
                },
                out,
            );
        }
    }
}
