//! The lane loop on AVX-512 (F, VL, BW): sixteen lanes, masks in mask
//! registers, masked moves and masked arithmetic in place of blends. Every
//! float operation is the AVX2 loop's on the same operands (a masked
//! `pos + halfs` where the AVX2 loop adds `halfs` or `+0.0`, the same
//! value since `pos >= 1`), so the outputs are bit-identical.

use std::arch::x86_64::*;

use super::stream::{
    answer, prefetch, stream, write_stack, Consts, Ended, Group, Isa, State, SPARE,
};
use crate::voxels::cast::{Addressing, CastHit, CastParams, S_MAX};

/// The AVX-512 lane loop.
pub(super) struct Avx512;

/// [`stream`] compiled for AVX-512.
///
/// # Safety
/// The CPU must have AVX2 and AVX-512F/VL/BW, and `2 * nodes.len()` must
/// fit an i32.
#[target_feature(enable = "avx2,avx512f,avx512vl,avx512bw")]
pub(super) unsafe fn stream_avx512<A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
    near: Option<&[f64]>,
    out: &mut [CastHit<f32>],
) {
    stream::<Avx512, A>(nodes, depth, o, d, p, near, out)
}

impl Isa for Avx512 {
    const W: usize = 16;
    type F = __m512;
    type I = __m512i;
    type M = __mmask16;

    #[inline(always)]
    unsafe fn splat_f(x: f32) -> __m512 {
        _mm512_set1_ps(x)
    }

    #[inline(always)]
    unsafe fn splat_i(x: i32) -> __m512i {
        _mm512_set1_epi32(x)
    }

    #[inline(always)]
    unsafe fn none() -> __mmask16 {
        0
    }

    #[inline(always)]
    unsafe fn bits(m: __mmask16) -> u32 {
        m as u32
    }

    #[inline(always)]
    fn set(m: &mut __mmask16, l: usize, on: bool) {
        if on {
            *m |= 1 << l;
        } else {
            *m &= !(1 << l);
        }
    }

    #[inline(always)]
    fn f_lanes(v: &mut __m512) -> &mut [f32] {
        // SAFETY: __m512 is 16 f32 with at least their alignment.
        unsafe { &mut *(v as *mut __m512 as *mut [f32; 16]) }
    }

    #[inline(always)]
    fn i_lanes(v: &mut __m512i) -> &mut [i32] {
        // SAFETY: __m512i is 16 i32 with at least their alignment.
        unsafe { &mut *(v as *mut __m512i as *mut [i32; 16]) }
    }

    #[inline(always)]
    unsafe fn step<A: Addressing, const N: usize>(
        g: [&mut Group<Avx512>; N],
        k: &Consts<Avx512>,
        out: &mut [CastHit<f32>],
    ) {
        step::<A, N>(g, k, out)
    }
}

/// POP's new `idx`: bit `a` is bit `scale` of axis `a`'s position.
#[inline(always)]
unsafe fn pop_idx(pos: &[__m512; 3], scale: __m512i) -> __m512i {
    let mut idx = _mm512_setzero_si512();
    for (a, p) in pos.iter().enumerate() {
        let sh = _mm512_srlv_epi32(_mm512_castps_si512(*p), scale);
        let b = _mm512_and_si512(sh, _mm512_set1_epi32(1));
        idx = _mm512_or_si512(idx, _mm512_sllv_epi32(b, _mm512_set1_epi32(a as i32)));
    }
    idx
}

/// The octree's child slot on the `push` lanes (`Relative::child`):
/// `parent + ofs` (through the far-pointer slot where the far bit is set)
/// plus the non-leaf children before `c` (`cm & 0x7F`, counted by nibbles
/// in a byte shuffle).
#[inline(always)]
unsafe fn child_relative(
    base: *const i32,
    s: &State<Avx512>,
    cm: __m512i,
    push: __mmask16,
) -> __m512i {
    let mut ofs = _mm512_srli_epi32::<17>(s.desc);
    let far = _mm512_mask_test_epi32_mask(push, s.desc, _mm512_set1_epi32(0x1_0000));
    if far != 0 {
        let far_slot = _mm512_slli_epi32::<1>(_mm512_add_epi32(s.parent, ofs));
        ofs = _mm512_mask_i32gather_epi32::<4>(ofs, far, far_slot, base);
    }
    let pop_lut = _mm512_broadcast_i32x4(_mm_setr_epi8(
        0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4,
    ));
    let before = _mm512_and_si512(cm, _mm512_set1_epi32(0x7F));
    let lo = _mm512_and_si512(before, _mm512_set1_epi32(0xF));
    let hi = _mm512_srli_epi32::<4>(before);
    let cnt = _mm512_add_epi32(
        _mm512_shuffle_epi8(pop_lut, lo),
        _mm512_shuffle_epi8(pop_lut, hi),
    );
    _mm512_add_epi32(_mm512_add_epi32(s.parent, ofs), cnt)
}

/// One loop iteration of every live lane of the `N` groups `gs` (PUSH,
/// ADVANCE, POP as masked moves), then the answers of the lanes whose ray
/// ended and their refill. The groups' operations are interleaved phase by
/// phase (each phase a loop over the groups), so one group's gathers and
/// compares overlap the other's in the CPU's window.
#[inline(always)]
#[allow(clippy::needless_range_loop)] // per-axis and per-group loops over lane vectors
unsafe fn step<A: Addressing, const N: usize>(
    gs: [&mut Group<Avx512>; N],
    k: &Consts<Avx512>,
    out: &mut [CastHit<f32>],
) {
    let base = k.nodes.as_ptr() as *const i32;
    let zf = _mm512_setzero_ps();
    let zi = _mm512_setzero_si512();
    let one = _mm512_set1_epi32(1);
    let half = _mm512_set1_ps(0.5);
    let (max_iter, lane_base) = (k.max_iter, k.lane_base);
    let m0: __mmask16 = 0;
    let (mut capped, mut live, mut slot) = ([m0; N], [m0; N], [zi; N]);
    for j in 0..N {
        let s = &mut gs[j].s;
        let act = s.act;
        s.iters = _mm512_mask_add_epi32(s.iters, act, s.iters, one);
        capped[j] = _mm512_mask_cmpgt_epi32_mask(act, s.iters, max_iter);
        live[j] = act & !capped[j];
        let need = _mm512_mask_cmpeq_epi32_mask(live[j], s.desc, zi);
        slot[j] = _mm512_slli_epi32::<1>(s.parent);
        s.desc = _mm512_mask_i32gather_epi32::<4>(s.desc, need, slot[j], base);
    }
    let (mut tc, mut tc_max, mut tv_max) = ([[zf; 3]; N], [zf; N], [zf; N]);
    let (mut shift, mut cm) = ([zi; N], [zi; N]);
    let (mut leaf, mut stop, mut push, mut adv, mut exit) =
        ([m0; N], [m0; N], [m0; N], [m0; N], [m0; N]);
    for j in 0..N {
        let s = &mut gs[j].s;
        for a in 0..3 {
            tc[j][a] = _mm512_sub_ps(_mm512_mul_ps(s.pos[a], s.coef[a]), s.bias[a]);
        }
        tc_max[j] = _mm512_min_ps(_mm512_min_ps(tc[j][0], tc[j][1]), tc[j][2]);
        shift[j] = _mm512_xor_si512(s.idx, s.octant);
        cm[j] = _mm512_sllv_epi32(s.desc, shift[j]);
        let valid = _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(
            _mm512_test_epi32_mask(cm[j], _mm512_set1_epi32(0x8000)),
            s.t_min,
            s.t_max,
        );
        let lod_stop = if let Some((osz, dsz)) = k.lod {
            let fp = _mm512_add_ps(_mm512_mul_ps(tc_max[j], dsz), osz);
            _mm512_mask_cmp_ps_mask::<_CMP_GE_OQ>(valid, fp, s.se)
        } else {
            0
        };
        tv_max[j] = _mm512_min_ps(s.t_max, tc_max[j]);
        let inter = !lod_stop & _mm512_mask_cmp_ps_mask::<_CMP_LE_OQ>(valid, s.t_min, tv_max[j]);
        leaf[j] = _mm512_testn_epi32_mask(cm[j], _mm512_set1_epi32(0x80));
        stop[j] = live[j] & (lod_stop | (inter & leaf[j]));
        push[j] = live[j] & inter & !leaf[j];
        adv[j] = live[j] & !(stop[j] | push[j]);
    }
    if push.iter().any(|&m| m != 0) {
        for j in 0..N {
            let g = &mut *gs[j];
            let (s, push) = (&mut g.s, push[j]);
            let keep = _mm512_mask_cmp_ps_mask::<_CMP_LT_OQ>(push, tc_max[j], s.h);
            let entry = _mm512_add_epi32(lane_base, s.scale);
            let at = _mm512_mask_blend_epi32(keep, _mm512_set1_epi32(SPARE as i32), entry);
            write_stack::<Avx512>(at, s.parent, &mut g.stack);
            let child = if A::ABSOLUTE {
                let hi_slot = _mm512_add_epi32(slot[j], one);
                let hi = _mm512_mask_i32gather_epi32::<4>(zi, push, hi_slot, base);
                _mm512_add_epi32(hi, _mm512_xor_si512(shift[j], _mm512_set1_epi32(7)))
            } else {
                child_relative(base, s, cm[j], push)
            };
            prefetch::<Avx512>(base, _mm512_mask_blend_epi32(push, s.parent, child));
            let halfs = _mm512_mul_ps(s.se, half);
            let mut idx_push = zi;
            for a in 0..3 {
                let tcen = _mm512_add_ps(_mm512_mul_ps(halfs, s.coef[a]), tc[j][a]);
                let up = _mm512_mask_cmp_ps_mask::<_CMP_GT_OQ>(push, tcen, s.t_min);
                idx_push = _mm512_mask_or_epi32(idx_push, up, idx_push, _mm512_set1_epi32(1 << a));
                s.pos[a] = _mm512_mask_add_ps(s.pos[a], up, s.pos[a], halfs);
            }
            s.idx = _mm512_mask_mov_epi32(s.idx, push, idx_push);
            s.h = _mm512_mask_mov_ps(s.h, push, tc_max[j]);
            s.scale = _mm512_mask_sub_epi32(s.scale, push, s.scale, one);
            s.se = _mm512_mask_mov_ps(s.se, push, halfs);
            s.t_max = _mm512_mask_mov_ps(s.t_max, push, tv_max[j]);
            s.parent = _mm512_mask_mov_epi32(s.parent, push, child);
            s.desc = _mm512_maskz_mov_epi32(!push, s.desc);
        }
    }
    if adv.iter().any(|&m| m != 0) {
        let (mut pop, mut diff) = ([m0; N], [zi; N]);
        for j in 0..N {
            let (s, adv) = (&mut gs[j].s, adv[j]);
            let mut step = zi;
            for a in 0..3 {
                let st = _mm512_cmp_ps_mask::<_CMP_LE_OQ>(tc[j][a], tc_max[j]);
                step = _mm512_mask_or_epi32(step, st, step, _mm512_set1_epi32(1 << a));
                s.pos[a] = _mm512_mask_sub_ps(s.pos[a], adv & st, s.pos[a], s.se);
                let back = _mm512_add_ps(s.pos[a], s.se);
                let x = _mm512_xor_si512(_mm512_castps_si512(s.pos[a]), _mm512_castps_si512(back));
                diff[j] = _mm512_mask_or_epi32(diff[j], st, diff[j], x);
            }
            s.t_min = _mm512_mask_mov_ps(s.t_min, adv, tc_max[j]);
            let idx_adv = _mm512_xor_si512(s.idx, step);
            s.idx = _mm512_mask_mov_epi32(s.idx, adv, idx_adv);
            pop[j] = _mm512_mask_test_epi32_mask(adv, idx_adv, step);
        }
        if pop.iter().any(|&m| m != 0) {
            for j in 0..N {
                let g = &mut *gs[j];
                let (s, pop) = (&mut g.s, pop[j]);
                let e = _mm512_castps_si512(_mm512_cvtepi32_ps(diff[j]));
                let scale = _mm512_sub_epi32(_mm512_srli_epi32::<23>(e), _mm512_set1_epi32(127));
                exit[j] = _mm512_mask_cmpgt_epi32_mask(pop, scale, _mm512_set1_epi32(S_MAX - 1));
                let ok = pop & !exit[j];
                let sidx = _mm512_add_epi32(lane_base, scale);
                s.parent = _mm512_mask_i32gather_epi32::<4>(s.parent, ok, sidx, g.stack.as_ptr());
                // `t_max`: the exit of the parent's cube, `pos` rounded at
                // `scale + 1` ([`Group::stack`]).
                let up = _mm512_add_epi32(scale, one);
                let mut exit_t = [zf; 3];
                for a in 0..3 {
                    let sh = _mm512_srlv_epi32(_mm512_castps_si512(s.pos[a]), up);
                    let corner = _mm512_castsi512_ps(_mm512_sllv_epi32(sh, up));
                    exit_t[a] = _mm512_sub_ps(_mm512_mul_ps(corner, s.coef[a]), s.bias[a]);
                }
                let exit_max = _mm512_min_ps(_mm512_min_ps(exit_t[0], exit_t[1]), exit_t[2]);
                s.t_max = _mm512_mask_min_ps(s.t_max, ok, s.t_max0, exit_max);
                for a in 0..3 {
                    let sh = _mm512_srlv_epi32(_mm512_castps_si512(s.pos[a]), scale);
                    let rounded = _mm512_castsi512_ps(_mm512_sllv_epi32(sh, scale));
                    s.pos[a] = _mm512_mask_mov_ps(s.pos[a], ok, rounded);
                }
                let se = _mm512_slli_epi32::<23>(_mm512_add_epi32(
                    scale,
                    _mm512_set1_epi32(127 - S_MAX),
                ));
                s.scale = _mm512_mask_mov_epi32(s.scale, ok, scale);
                s.se = _mm512_mask_mov_ps(s.se, ok, _mm512_castsi512_ps(se));
                s.idx = _mm512_mask_mov_epi32(s.idx, ok, pop_idx(&s.pos, scale));
                s.h = _mm512_maskz_mov_ps(!ok, s.h);
                s.desc = _mm512_maskz_mov_epi32(!ok, s.desc);
            }
        }
    }
    // Lanes whose ray ended this iteration: the answer, then the next ray.
    for j in 0..N {
        let done = (capped[j] | stop[j] | exit[j]) as u32;
        if done != 0 {
            let (capped, stop, leaf) = (capped[j] as u32, stop[j] as u32, leaf[j] as u32);
            answer::<Avx512, A>(
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
