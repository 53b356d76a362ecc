//! `cast_lanes`: the f32 Laine–Karras loop of [`super::cast::cast_with`]
//! for [`W`] independent rays at once, one ray per AVX2 lane (issue 15,
//! point 3: many rays in flight). The per-ray SSE cast ([`super::cast_sse`])
//! is bound by the latency of the descriptor load `nodes[2 * parent]`: each
//! iteration waits for it, and the branch on it mispredicts. Here each lane
//! carries its own ESVO state (position, scale, `t_min`/`t_max`, `h`,
//! parent, descriptor, its own 23-entry stack), and one loop iteration
//! advances every live lane: the descriptors of all lanes are one gather
//! (eight loads in flight), PUSH, ADVANCE and POP are computed on every lane
//! and blended by masks (no data-dependent branch in the step), child
//! addresses and POP's stack reads are gathers, a PUSH prefetches each
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
//! AVX2 is detected at run time ([`LaneIsa`]), and the same loop is also
//! compiled with AVX-512F/VL (32 vector registers, mask blends; still eight
//! lanes) where the CPU has it; without AVX2, or when the node array is too
//! large for 32-bit gather indices, the SSE per-ray cast runs. No contours
//! (the per-ray cast does them).

use super::cast::{Addressing, CastHit, CastParams};
use super::cast_sse::cast_sse;
use super::hits::{cast_chunks, GRAIN};
use super::render::VoxelHits;

/// Lanes: one ray each.
pub const W: usize = 8;

/// What the lane loop is compiled for, picked at run time.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord)]
pub enum LaneIsa {
    /// No lane loop: the SSE per-ray cast (no AVX2, or a node array too
    /// large for 32-bit gather indices).
    Sse,
    /// The AVX2 lane loop.
    Avx2,
    /// The same loop with AVX-512F/VL enabled: still eight lanes and the
    /// same IEEE operations, but 32 vector registers (the lane state
    /// spills less) and mask-register blends.
    Avx512,
}

impl LaneIsa {
    /// The widest set this CPU runs for a node array of `len` words.
    pub fn detect(len: usize) -> LaneIsa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && len < (1 << 30) {
                let avx512 = has!("avx512f") && has!("avx512vl");
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
            return unsafe { avx2::stream_avx512::<A>(nodes, depth, o, d, p, near, out) }
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
mod avx2 {
    use std::arch::x86_64::*;

    use super::W;
    use crate::voxels::cast::{finish, start, Addressing, CastHit, CastParams, Start, Stop, S_MAX};

    /// Lane groups per stream. Measured in one run (shared machine, 30
    /// interleaved rounds, sphere d10 and Menger d10, octree and DAG,
    /// 2^18 rays, docs/PERF.md): one group 0.91-0.97x of two, four
    /// 0.96-1.02x of two; with the descriptor prefetch (12 interleaved
    /// rounds, loaded shared machine) three groups 0.92-1.09x of two, four
    /// 0.93-1.09x.
    const G: usize = 2;

    /// Stack entries per lane (scales 0..=S_MAX).
    const SD: usize = S_MAX as usize + 1;

    /// The stack entry after every lane's: the target of the lanes that do
    /// not write at a PUSH ([`push_stack`]); never read.
    const SPARE: usize = W * SD;

    /// The lanes' ESVO state, one lane per ray (`act`: all ones on lanes
    /// that hold a ray).
    #[derive(Clone, Copy)]
    struct State {
        pos: [__m256; 3],
        coef: [__m256; 3],
        bias: [__m256; 3],
        t_min: __m256,
        t_max: __m256,
        h: __m256,
        se: __m256,
        octant: __m256i,
        parent: __m256i,
        desc: __m256i,
        idx: __m256i,
        scale: __m256i,
        iters: __m256i,
        act: __m256i,
    }

    /// Lane `l` of a float vector.
    #[inline(always)]
    fn lf(v: &mut __m256) -> &mut [f32; W] {
        // SAFETY: __m256 is 8 f32 with at least their alignment.
        unsafe { &mut *(v as *mut __m256 as *mut [f32; W]) }
    }

    /// Lane `l` of an integer vector.
    #[inline(always)]
    fn li(v: &mut __m256i) -> &mut [i32; W] {
        // SAFETY: __m256i is 8 i32 with at least their alignment.
        unsafe { &mut *(v as *mut __m256i as *mut [i32; W]) }
    }

    impl State {
        /// Lane `l` set up for the ray with start `s`.
        #[inline(always)]
        fn load(&mut self, l: usize, s: &Start<f32>) {
            for a in 0..3 {
                lf(&mut self.pos[a])[l] = s.pos[a];
                lf(&mut self.coef[a])[l] = s.coef[a];
                lf(&mut self.bias[a])[l] = s.bias[a];
            }
            lf(&mut self.t_min)[l] = s.t_min;
            lf(&mut self.t_max)[l] = s.t_max;
            lf(&mut self.h)[l] = s.h;
            lf(&mut self.se)[l] = 0.5;
            li(&mut self.octant)[l] = s.octant as i32;
            li(&mut self.parent)[l] = 0;
            li(&mut self.desc)[l] = 0;
            li(&mut self.idx)[l] = s.idx as i32;
            li(&mut self.scale)[l] = S_MAX - 1;
            li(&mut self.iters)[l] = 0;
            li(&mut self.act)[l] = -1;
        }

        /// Lane `l`'s [`Stop`] at its current voxel.
        #[inline(always)]
        fn stop(&mut self, l: usize, leaf: bool) -> Stop<f32> {
            Stop {
                leaf,
                pos: [0, 1, 2].map(|a| lf(&mut self.pos[a])[l]),
                scale: li(&mut self.scale)[l],
                scale_exp2: lf(&mut self.se)[l],
                t_min: lf(&mut self.t_min)[l],
                parent: li(&mut self.parent)[l] as u32 as usize,
                desc: li(&mut self.desc)[l] as u32,
                idx: li(&mut self.idx)[l] as u32,
                contour_hit: None,
                iters: li(&mut self.iters)[l] as u32,
            }
        }
    }

    /// Bits of a lane mask, lowest first.
    #[inline(always)]
    fn bits(mut m: u32) -> impl Iterator<Item = usize> {
        std::iter::from_fn(move || {
            (m != 0).then(|| {
                let l = m.trailing_zeros() as usize;
                m &= m - 1;
                l
            })
        })
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

    /// The rays waiting for a lane, and which ray each lane holds.
    struct Queue<'r> {
        o: &'r [[f32; 3]],
        d: &'r [[f32; 3]],
        near: Option<&'r [f64]>,
        next: usize,
        end: usize,
        ray: [usize; W],
        starts: [Option<Start<f32>>; W],
    }

    impl Queue<'_> {
        /// Fills lane `l` of `s` with the next ray that enters the root box
        /// (rays that miss it are answered at once); the lane goes idle when
        /// none is left.
        fn refill(&mut self, s: &mut State, l: usize, p: &CastParams, out: &mut [CastHit<f32>]) {
            while self.next < self.end {
                let i = self.next;
                self.next += 1;
                let st = match self.near {
                    None => start(self.o[i], self.d[i], p),
                    // A beam tile that meets nothing ([`crate::voxels::beam`]).
                    Some(n) if n[i] == f64::INFINITY => None,
                    Some(n) => start(self.o[i], self.d[i], &CastParams { near: n[i], ..*p }),
                };
                match st {
                    Some(st) => {
                        s.load(l, &st);
                        self.ray[l] = i;
                        self.starts[l] = Some(st);
                        return;
                    }
                    None => out[i] = CastHit::miss(0, false),
                }
            }
            self.ray[l] = usize::MAX;
            li(&mut s.act)[l] = 0;
            li(&mut s.parent)[l] = 0;
        }
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
    unsafe fn child_relative(base: *const i32, s: &State, cm: __m256i, push: __m256i) -> __m256i {
        let mut ofs = _mm256_srli_epi32::<17>(s.desc);
        let far = _mm256_andnot_si256(clear(s.desc, 0x1_0000), push);
        if mask_i(far) != 0 {
            let far_slot = _mm256_slli_epi32::<1>(_mm256_add_epi32(s.parent, ofs));
            ofs = _mm256_mask_i32gather_epi32::<4>(ofs, base, far_slot, far);
        }
        let pop_lut = _mm256_setr_epi8(
            0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2, 3, 3, 4, 0, 1, 1, 2, 1, 2, 2, 3, 1, 2, 2, 3, 2,
            3, 3, 4,
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

    /// Starts the load of each `push` lane's descriptor `nodes[2 * slot]`:
    /// the next step of this group gathers it, after the other groups'
    /// steps, so the miss overlaps their work instead of stalling the loop.
    /// Every lane prefetches, the others their own parent's (cached)
    /// descriptor: no branch on the lane mask (a loop over its bits
    /// mispredicts; measured below at [`push_stack`]).
    #[inline(always)]
    unsafe fn prefetch(base: *const i32, parent: __m256i, slot: __m256i, push: __m256i) {
        let mut at = [0i32; W];
        let slot = _mm256_blendv_epi8(parent, slot, push);
        _mm256_storeu_si256(at.as_mut_ptr() as *mut __m256i, slot);
        for a in at {
            let p = base.wrapping_add(2 * a as u32 as usize) as *const i8;
            _mm_prefetch::<_MM_HINT_T0>(p);
        }
    }

    /// PUSH's stack write on the `write` lanes: lane `l`'s parent and
    /// `t_max` at its entry for its scale, `l * SD + scale`. Every lane
    /// stores, the others into the spare entry [`SPARE`], so the write has
    /// no branch on the lane mask. Measured in one process against a loop
    /// over the mask's bits (thread CPU time, medians of 7-9 interleaved
    /// rounds, 2^18 rays, sphere d10 and Menger d10, shared 2-core Zen 4,
    /// docs/PERF.md ninth session): coherent 1.07-1.30x, incoherent
    /// 0.90-1.16x, 0 differing rays; AVX-512's masked scatter in its place
    /// was 1.00-1.03x of these stores on the octree and 0.86-0.94x on the DAG.
    #[inline(always)]
    unsafe fn push_stack(
        s: &State,
        write: __m256i,
        lane_base: __m256i,
        stack_node: &mut [i32; W * SD + 1],
        stack_tmax: &mut [f32; W * SD + 1],
    ) {
        let entry = _mm256_add_epi32(lane_base, s.scale);
        let at = _mm256_blendv_epi8(_mm256_set1_epi32(SPARE as i32), entry, write);
        let (mut ai, mut pv, mut tv) = ([0i32; W], [0i32; W], [0f32; W]);
        _mm256_storeu_si256(ai.as_mut_ptr() as *mut __m256i, at);
        _mm256_storeu_si256(pv.as_mut_ptr() as *mut __m256i, s.parent);
        _mm256_storeu_ps(tv.as_mut_ptr(), s.t_max);
        for l in 0..W {
            // `at` is `l * SD + scale` (scale < SD while the lane pushes)
            // or SPARE: within both stacks.
            let k = ai[l] as usize;
            stack_node[k] = pv[l];
            stack_tmax[k] = tv[l];
        }
    }

    /// Loop constants of a stream.
    struct Consts<'n> {
        nodes: &'n [u32],
        depth: u32,
        p: &'n CastParams,
        lod: Option<(__m256, __m256)>,
        max_iter: __m256i,
        lane_base: __m256i,
    }

    /// One set of [`W`] lanes: their state, stacks (lane `l`'s entry for
    /// scale `s` at `l * SD + s`, then [`SPARE`]) and ray queue.
    struct Group<'r> {
        s: State,
        stack_node: [i32; W * SD + 1],
        stack_tmax: [f32; W * SD + 1],
        q: Queue<'r>,
    }

    /// [`stream`] compiled for AVX2.
    ///
    /// # Safety
    /// The CPU must have AVX2 and `2 * nodes.len()` must fit an i32.
    #[target_feature(enable = "avx2")]
    pub unsafe fn stream_avx2<A: Addressing>(
        nodes: &[u32],
        depth: u32,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        p: &CastParams,
        near: Option<&[f64]>,
        out: &mut [CastHit<f32>],
    ) {
        stream::<A>(nodes, depth, o, d, p, near, out)
    }

    /// [`stream`] compiled with AVX-512F/VL as well (32 vector registers,
    /// mask blends; the same eight lanes and IEEE operations).
    ///
    /// # Safety
    /// The CPU must have AVX2 and AVX-512F/VL, and `2 * nodes.len()` must
    /// fit an i32.
    #[target_feature(enable = "avx2,avx512f,avx512vl")]
    pub unsafe fn stream_avx512<A: Addressing>(
        nodes: &[u32],
        depth: u32,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        p: &CastParams,
        near: Option<&[f64]>,
        out: &mut [CastHit<f32>],
    ) {
        stream::<A>(nodes, depth, o, d, p, near, out)
    }

    /// Streams the rays `(o[i], d[i])` through [`G`] groups of lanes (the
    /// rays split into `G` consecutive runs, one per group), one iteration
    /// of each live group in turn, writing `out[i]`: the groups' loads are
    /// independent, so one group's gathers overlap the others' work.
    ///
    /// # Safety
    /// The CPU must have AVX2 and `2 * nodes.len()` must fit an i32.
    #[inline(always)]
    unsafe fn stream<A: Addressing>(
        nodes: &[u32],
        depth: u32,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        p: &CastParams,
        near: Option<&[f64]>,
        out: &mut [CastHit<f32>],
    ) {
        let k = Consts {
            nodes,
            depth,
            p,
            lod: p.lod.map(|l| {
                (
                    _mm256_set1_ps(l.orig_size as f32 * 0.5),
                    _mm256_set1_ps(l.dir_size as f32 * 0.5),
                )
            }),
            max_iter: _mm256_set1_epi32(p.max_iter.min(i32::MAX as u32) as i32),
            lane_base: _mm256_mullo_epi32(
                _mm256_setr_epi32(0, 1, 2, 3, 4, 5, 6, 7),
                _mm256_set1_epi32(SD as i32),
            ),
        };
        let n = o.len();
        let mut g: [Group; G] =
            std::array::from_fn(|j| group(o, d, near, j * n / G, (j + 1) * n / G));
        for g in g.iter_mut() {
            for l in 0..W {
                g.q.refill(&mut g.s, l, p, out);
            }
        }
        loop {
            let mut live = false;
            for g in g.iter_mut() {
                if mask_i(g.s.act) != 0 {
                    live = true;
                    step::<A>(g, &k, out);
                }
            }
            if !live {
                return;
            }
        }
    }

    /// A group with idle lanes over rays `start..end`.
    #[inline(always)]
    unsafe fn group<'r>(
        o: &'r [[f32; 3]],
        d: &'r [[f32; 3]],
        near: Option<&'r [f64]>,
        start: usize,
        end: usize,
    ) -> Group<'r> {
        let zf = _mm256_setzero_ps();
        let zi = _mm256_setzero_si256();
        Group {
            s: State {
                pos: [zf; 3],
                coef: [zf; 3],
                bias: [zf; 3],
                t_min: zf,
                t_max: zf,
                h: zf,
                se: zf,
                octant: zi,
                parent: zi,
                desc: zi,
                idx: zi,
                scale: zi,
                iters: zi,
                act: zi,
            },
            stack_node: [0; W * SD + 1],
            stack_tmax: [0.0; W * SD + 1],
            q: Queue {
                o,
                d,
                near,
                next: start,
                end,
                ray: [usize::MAX; W],
                starts: [None; W],
            },
        }
    }

    /// One loop iteration of every live lane of `g` (PUSH, ADVANCE, POP by
    /// masks), then the answers of the lanes whose ray ended and their refill.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // per-axis loops over lane vectors, as the scalar cast
    unsafe fn step<A: Addressing>(g: &mut Group, k: &Consts, out: &mut [CastHit<f32>]) {
        let (nodes, depth, p) = (k.nodes, k.depth, k.p);
        let base = nodes.as_ptr() as *const i32;
        let zf = _mm256_setzero_ps();
        let zi = _mm256_setzero_si256();
        let one = _mm256_set1_epi32(1);
        let half = _mm256_set1_ps(0.5);
        let (max_iter, lane_base) = (k.max_iter, k.lane_base);
        let (o, d) = (g.q.o, g.q.d);
        let Group {
            s,
            stack_node,
            stack_tmax,
            q,
        } = g;
        let act = s.act;
        s.iters = _mm256_add_epi32(s.iters, _mm256_and_si256(act, one));
        let capped = _mm256_and_si256(act, _mm256_cmpgt_epi32(s.iters, max_iter));
        let live = _mm256_andnot_si256(capped, act);
        // Every live lane's descriptor in one gather.
        let need = _mm256_and_si256(live, _mm256_cmpeq_epi32(s.desc, zi));
        let slot = _mm256_slli_epi32::<1>(s.parent);
        s.desc = _mm256_mask_i32gather_epi32::<4>(s.desc, base, slot, need);
        let mut tc = [zf; 3];
        for a in 0..3 {
            tc[a] = _mm256_sub_ps(_mm256_mul_ps(s.pos[a], s.coef[a]), s.bias[a]);
        }
        let tc_max = _mm256_min_ps(_mm256_min_ps(tc[0], tc[1]), tc[2]);
        let shift = _mm256_xor_si256(s.idx, s.octant);
        let cm = _mm256_sllv_epi32(s.desc, shift);
        let valid = _mm256_andnot_si256(clear(cm, 0x8000), le(s.t_min, s.t_max));
        let lod_stop = if let Some((osz, dsz)) = k.lod {
            let fp = _mm256_add_ps(_mm256_mul_ps(tc_max, dsz), osz);
            let cut = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_GE_OQ>(fp, s.se));
            _mm256_and_si256(valid, cut)
        } else {
            zi
        };
        let tv_max = _mm256_min_ps(s.t_max, tc_max);
        let inter = _mm256_andnot_si256(lod_stop, _mm256_and_si256(valid, le(s.t_min, tv_max)));
        let leaf = clear(cm, 0x80);
        let stop = _mm256_and_si256(
            live,
            _mm256_or_si256(lod_stop, _mm256_and_si256(inter, leaf)),
        );
        let push = _mm256_and_si256(live, _mm256_andnot_si256(leaf, inter));
        let adv = _mm256_andnot_si256(_mm256_or_si256(stop, push), live);
        let mut exit = zi;
        if mask_i(push) != 0 {
            // PUSH: the stack write where `tc_max < h`, per lane.
            let keep = _mm256_castps_si256(_mm256_cmp_ps::<_CMP_LT_OQ>(tc_max, s.h));
            push_stack(
                s,
                _mm256_and_si256(push, keep),
                lane_base,
                stack_node,
                stack_tmax,
            );
            let child = if A::ABSOLUTE {
                let hi_slot = _mm256_add_epi32(slot, one);
                let hi = _mm256_mask_i32gather_epi32::<4>(zi, base, hi_slot, push);
                _mm256_add_epi32(hi, _mm256_xor_si256(shift, _mm256_set1_epi32(7)))
            } else {
                child_relative(base, s, cm, push)
            };
            prefetch(base, s.parent, child, push);
            let halfs = _mm256_mul_ps(s.se, half);
            let mut idx_push = zi;
            let pf = _mm256_castsi256_ps(push);
            for a in 0..3 {
                let tcen = _mm256_add_ps(_mm256_mul_ps(halfs, s.coef[a]), tc[a]);
                let up = _mm256_cmp_ps::<_CMP_GT_OQ>(tcen, s.t_min);
                let b = _mm256_and_si256(_mm256_castps_si256(up), _mm256_set1_epi32(1 << a));
                idx_push = _mm256_or_si256(idx_push, b);
                let pushed = _mm256_add_ps(s.pos[a], _mm256_and_ps(up, halfs));
                s.pos[a] = _mm256_blendv_ps(s.pos[a], pushed, pf);
            }
            s.idx = _mm256_blendv_epi8(s.idx, idx_push, push);
            s.h = _mm256_blendv_ps(s.h, tc_max, pf);
            s.scale = _mm256_add_epi32(s.scale, push);
            s.se = _mm256_blendv_ps(s.se, halfs, pf);
            s.t_max = _mm256_blendv_ps(s.t_max, tv_max, pf);
            s.parent = _mm256_blendv_epi8(s.parent, child, push);
            s.desc = _mm256_andnot_si256(push, s.desc);
        }
        if mask_i(adv) != 0 {
            // ADVANCE, and the bits that changed (for POP).
            let af = _mm256_castsi256_ps(adv);
            let mut step = zi;
            let mut diff = zi;
            for a in 0..3 {
                let st = _mm256_cmp_ps::<_CMP_LE_OQ>(tc[a], tc_max);
                let b = _mm256_and_si256(_mm256_castps_si256(st), _mm256_set1_epi32(1 << a));
                step = _mm256_or_si256(step, b);
                let moved = _mm256_sub_ps(s.pos[a], _mm256_and_ps(st, s.se));
                s.pos[a] = _mm256_blendv_ps(s.pos[a], moved, af);
                let back = _mm256_add_ps(s.pos[a], s.se);
                let x = _mm256_xor_si256(_mm256_castps_si256(s.pos[a]), _mm256_castps_si256(back));
                diff = _mm256_or_si256(diff, _mm256_and_si256(x, _mm256_castps_si256(st)));
            }
            s.t_min = _mm256_blendv_ps(s.t_min, tc_max, af);
            let idx_adv = _mm256_xor_si256(s.idx, step);
            s.idx = _mm256_blendv_epi8(s.idx, idx_adv, adv);
            let pop =
                _mm256_andnot_si256(_mm256_cmpeq_epi32(_mm256_and_si256(idx_adv, step), zi), adv);
            if mask_i(pop) != 0 {
                // POP: the highest differing bit is the exponent of `diff`
                // as a float (exact below 2^24; from there on the scale is
                // past S_MAX either way).
                let e = _mm256_castps_si256(_mm256_cvtepi32_ps(diff));
                let scale = _mm256_sub_epi32(_mm256_srli_epi32::<23>(e), _mm256_set1_epi32(127));
                exit =
                    _mm256_and_si256(pop, _mm256_cmpgt_epi32(scale, _mm256_set1_epi32(S_MAX - 1)));
                let ok = _mm256_andnot_si256(exit, pop);
                let okf = _mm256_castsi256_ps(ok);
                let sidx = _mm256_add_epi32(lane_base, scale);
                s.parent =
                    _mm256_mask_i32gather_epi32::<4>(s.parent, stack_node.as_ptr(), sidx, ok);
                s.t_max = _mm256_mask_i32gather_ps::<4>(s.t_max, stack_tmax.as_ptr(), sidx, okf);
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
        // Lanes whose ray ended this iteration: the answer, then the next ray.
        let done = mask_i(_mm256_or_si256(_mm256_or_si256(capped, stop), exit));
        if done != 0 {
            let (capped_m, stop_m, leaf_m) = (mask_i(capped), mask_i(stop), mask_i(leaf));
            for l in bits(done) {
                let i = q.ray[l];
                let it = li(&mut s.iters)[l] as u32;
                out[i] = if capped_m >> l & 1 != 0 {
                    CastHit::miss(it - 1, true)
                } else if stop_m >> l & 1 != 0 {
                    let stop = s.stop(l, leaf_m >> l & 1 != 0);
                    match &q.starts[l] {
                        Some(st) => {
                            let p = p.for_ray(q.near, i);
                            finish::<f32, A>(nodes, depth, o[i], d[i], &p, st, &stop)
                        }
                        None => CastHit::miss(it, false),
                    }
                } else {
                    CastHit::miss(it, false)
                };
                q.refill(s, l, p, out);
            }
        }
    }
}

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
