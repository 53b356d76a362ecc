//! The lane loop's frame, shared by its instruction sets: the lanes' ESVO
//! state ([`State`]), the ray queue that refills a lane when its ray ends
//! ([`Queue`]), the lane groups and the stream that steps them together
//! ([`stream`]), and the answers of finished lanes. What an instruction set
//! brings is its vectors, its lane masks and its loop iteration
//! ([`Isa::step`]).

use crate::voxels::cast::{finish, start, Addressing, CastHit, CastParams, Start, Stop, S_MAX};
use crate::voxels::set_bits::set_bits;
use std::cell::Cell;

/// Lane groups per stream. Measured in one run (shared machine, 30
/// interleaved rounds, sphere d10 and Menger d10, octree and DAG, 2^18
/// rays, docs/PERF.md): one group 0.91-0.97x of two, four 0.96-1.02x of
/// two; with the descriptor prefetch (12 interleaved rounds, loaded shared
/// machine) three groups 0.92-1.09x of two, four 0.93-1.09x. With
/// sixteen AVX-512 lanes (whose one group's state would fit the 32
/// registers), one group read 0.94-0.98x of two, and eight AVX2 lanes
/// 0.88-0.91x (quiet Zen 5, `voxels_gpu_sphere_d10`, two interleaved runs).
/// Since the seventeenth session one step advances both groups with their
/// operations interleaved phase by phase ([`Isa::step`]); three or four
/// groups that way ran at 0.72-0.79x the speed of two (their state spills;
/// same Zen 5, single-thread harness, docs/PERF.md).
const G: usize = 2;

/// The most lanes an instruction set has.
pub(super) const W_MAX: usize = 16;

/// Stack entries per lane (scales 0..=S_MAX).
pub(super) const SD: usize = S_MAX as usize + 1;

/// The stack entry after every lane's: the target of the lanes that do
/// not write at a PUSH ([`write_stack`]); never read.
pub(super) const SPARE: usize = W_MAX * SD;

/// Entries of a group's stack: lane `l`'s entry for scale `s` at
/// `l * SD + s`, then [`SPARE`].
pub(super) const STACK: usize = SPARE + 1;

/// An instruction set of the lane loop. Its `unsafe` functions need the
/// CPU to have the set's instructions (the loop runs only inside the
/// set's `#[target_feature]` entry, after [`super::LaneIsa::detect`]).
pub(super) trait Isa: Sized {
    /// Lanes: one ray each (at most [`W_MAX`]).
    const W: usize;
    /// `W` f32.
    type F: Copy;
    /// `W` i32.
    type I: Copy;
    /// One flag per lane.
    type M: Copy;

    /// Every lane `x`.
    unsafe fn splat_f(x: f32) -> Self::F;
    /// Every lane `x`.
    unsafe fn splat_i(x: i32) -> Self::I;
    /// No lane.
    unsafe fn none() -> Self::M;
    /// The mask as bits, lane `l` at bit `l`.
    unsafe fn bits(m: Self::M) -> u32;
    /// Sets or clears lane `l` of `m` (plain stores or bit operations: safe
    /// anywhere).
    fn set(m: &mut Self::M, l: usize, on: bool);
    /// The lanes of `v`.
    fn f_lanes(v: &mut Self::F) -> &mut [f32];
    /// The lanes of `v`.
    fn i_lanes(v: &mut Self::I) -> &mut [i32];
    /// One loop iteration of every live lane of the groups `g`, then the
    /// answers of the lanes whose ray ended ([`answer`]). The groups'
    /// operations are interleaved phase by phase (descriptor gathers, then
    /// the masks, PUSH, ADVANCE, POP, each a loop over the groups), so one
    /// group's gather latency overlaps the other's arithmetic within the
    /// CPU's reorder window; a group with no live lane passes through as
    /// empty masks. Against the groups stepped in turn, one process
    /// (seventeenth session, Zen 5, 512^2 camera rays, octree): AVX-512
    /// 0.88/0.94 of the time (sphere / Menger, from the beam's starts),
    /// 0.85/0.92 from `near`; AVX2 0.91-0.93/0.95-0.98 and 0.90-0.91/0.93-0.96.
    unsafe fn step<A: Addressing, const N: usize>(
        g: [&mut Group<Self>; N],
        k: &Consts<Self>,
        out: &mut [CastHit<f32>],
    );
}

/// The lanes' ESVO state, one lane per ray (`act`: the lanes that hold a
/// ray; `t_max0`: the ray's `t_max` at the root, from which POP recomputes
/// `t_max`, see [`Group::stack`]).
pub(super) struct State<V: Isa> {
    pub pos: [V::F; 3],
    pub coef: [V::F; 3],
    pub bias: [V::F; 3],
    pub t_min: V::F,
    pub t_max: V::F,
    pub t_max0: V::F,
    pub h: V::F,
    pub se: V::F,
    pub octant: V::I,
    pub parent: V::I,
    pub desc: V::I,
    pub idx: V::I,
    pub scale: V::I,
    pub iters: V::I,
    pub act: V::M,
}

impl<V: Isa> State<V> {
    /// Every lane idle.
    #[inline(always)]
    unsafe fn idle() -> Self {
        let (zf, zi) = (V::splat_f(0.0), V::splat_i(0));
        State {
            pos: [zf; 3],
            coef: [zf; 3],
            bias: [zf; 3],
            t_min: zf,
            t_max: zf,
            t_max0: zf,
            h: zf,
            se: zf,
            octant: zi,
            parent: zi,
            desc: zi,
            idx: zi,
            scale: zi,
            iters: zi,
            act: V::none(),
        }
    }

    /// Lane `l` set up for the ray with start `s`.
    #[inline(always)]
    fn load(&mut self, l: usize, s: &Start<f32>) {
        for a in 0..3 {
            V::f_lanes(&mut self.pos[a])[l] = s.pos[a];
            V::f_lanes(&mut self.coef[a])[l] = s.coef[a];
            V::f_lanes(&mut self.bias[a])[l] = s.bias[a];
        }
        V::f_lanes(&mut self.t_min)[l] = s.t_min;
        V::f_lanes(&mut self.t_max)[l] = s.t_max;
        V::f_lanes(&mut self.t_max0)[l] = s.t_max;
        V::f_lanes(&mut self.h)[l] = s.h;
        V::f_lanes(&mut self.se)[l] = 0.5;
        V::i_lanes(&mut self.octant)[l] = s.octant as i32;
        V::i_lanes(&mut self.parent)[l] = 0;
        V::i_lanes(&mut self.desc)[l] = 0;
        V::i_lanes(&mut self.idx)[l] = s.idx as i32;
        V::i_lanes(&mut self.scale)[l] = S_MAX - 1;
        V::i_lanes(&mut self.iters)[l] = 0;
        V::set(&mut self.act, l, true);
    }

    /// Lane `l`'s [`Stop`] at its current voxel.
    #[inline(always)]
    fn stop(&mut self, l: usize, leaf: bool) -> Stop<f32> {
        Stop {
            leaf,
            pos: [0, 1, 2].map(|a| V::f_lanes(&mut self.pos[a])[l]),
            scale: V::i_lanes(&mut self.scale)[l],
            scale_exp2: V::f_lanes(&mut self.se)[l],
            t_min: V::f_lanes(&mut self.t_min)[l],
            parent: V::i_lanes(&mut self.parent)[l] as u32 as usize,
            desc: V::i_lanes(&mut self.desc)[l] as u32,
            idx: V::i_lanes(&mut self.idx)[l] as u32,
            contour_hit: None,
            iters: V::i_lanes(&mut self.iters)[l] as u32,
        }
    }
}

/// The rays waiting for a lane, and which ray each lane holds. The
/// groups of a stream hold the same rays and share `next`, so a freed lane
/// of either group takes the next ray in order: the groups work on
/// neighbouring rays and run dry together. Against each group taking its
/// own half of the rays (one process, seventeenth session, Zen 5, octree,
/// interleaved step): 0.96-0.98 of the time from the beam's starts and
/// 0.98-0.99 from `near` at 512^2, 0.97-1.01 / 0.95-0.99 at 1920x1080.
struct Queue<'r> {
    o: &'r [[f32; 3]],
    d: &'r [[f32; 3]],
    near: Option<&'r [f64]>,
    next: &'r Cell<usize>,
    ray: [usize; W_MAX],
    starts: [Option<Start<f32>>; W_MAX],
}

impl Queue<'_> {
    /// Fills lane `l` of `s` with the next ray that enters the root box
    /// (rays that miss it are answered at once); the lane goes idle when
    /// none is left. Inlined into the step: a call there clobbers every
    /// vector register the step holds (single-thread harness, Zen 5, octree,
    /// beam starts, against the call: AVX-512 sphere d10 0.89-1.00 of the
    /// time, median 0.97, Menger d10 0.89-1.04, median 0.99; AVX2 lanes
    /// 0.98-1.02; `finish` moved out of line the same way was 1.08-1.12
    /// slower; docs/PERF.md, twentieth session).
    #[inline(always)]
    fn refill<V: Isa>(
        &mut self,
        s: &mut State<V>,
        l: usize,
        p: &CastParams,
        out: &mut [CastHit<f32>],
    ) {
        while self.next.get() < self.o.len() {
            let i = self.next.get();
            self.next.set(i + 1);
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
        V::set(&mut s.act, l, false);
        V::i_lanes(&mut s.parent)[l] = 0;
    }
}

/// Loop constants of a stream.
pub(super) struct Consts<'n, V: Isa> {
    pub nodes: &'n [u32],
    depth: u32,
    p: &'n CastParams,
    pub lod: Option<(V::F, V::F)>,
    pub max_iter: V::I,
    /// Lane `l` holds `l * SD`, its first stack entry.
    pub lane_base: V::I,
}

/// One set of `V::W` lanes: their state, stacks and ray queue.
pub(super) struct Group<'r, V: Isa> {
    pub s: State<V>,
    /// Each lane's parent slot per scale: the ESVO stack without its
    /// `t_max`, which POP recomputes as `min(t_max0, exit of the parent's
    /// cube)` from `pos` rounded at `scale + 1`.
    ///
    /// Why that is the stacked value, bit for bit: exit times of nested
    /// cubes computed as the loop computes them (`corner * coef - bias`,
    /// `coef < 0`) never grow from a cube to its child (the corners grow and
    /// rounding is monotone), so the `min` that PUSH folds in level by level
    /// equals its last term. The one case the two can differ is a stale
    /// entry, read where PUSH skipped its write because the child's exit
    /// rounded onto the parent's: a ray the float planes already
    /// mis-traverse, where the lanes' stale parent slots already differed
    /// from the per-ray cast's (the lane stacks are not cleared between
    /// rays).
    ///
    /// One scalar store a lane per PUSH and one gather per POP less than
    /// with `t_max` on the stack, for sixteen vector operations: single-thread
    /// harness, Zen 5, octree, from the beam's starts, 0.88-0.92 (sphere d10),
    /// 0.92-0.96 (Menger d10) of the time; judge runs alternated with the
    /// previous binary, 2 threads, sixteen lanes and beam, coherent
    /// 0.99-1.13x, incoherent 0.99-1.07x (runs that held still), eight AVX2
    /// lanes 0.92-1.13x (docs/PERF.md, eighteenth session).
    pub stack: [i32; STACK],
    q: Queue<'r>,
}

/// Starts the load of each lane's descriptor `nodes[2 * slot]` (PUSH's
/// prefetch: the next step of this group gathers it, after the other
/// groups' steps, so the miss overlaps their work instead of stalling the
/// loop). Every lane prefetches, the sets passing their non-pushing lanes'
/// own parent (cached): no branch on the lane mask (a loop over its bits
/// mispredicts; measured at [`write_stack`]).
#[inline(always)]
pub(super) fn prefetch<V: Isa>(base: *const i32, mut slot: V::I) {
    for &a in V::i_lanes(&mut slot).iter() {
        let p = base.wrapping_add(2 * a as u32 as usize) as *const i8;
        // SAFETY: a prefetch does not fault, whatever the address.
        unsafe { std::arch::x86_64::_mm_prefetch::<{ std::arch::x86_64::_MM_HINT_T0 }>(p) };
    }
}

/// PUSH's stack write: lane `l`'s `parent` at entry `at[l]`, its own
/// `l * SD + scale` on the lanes that write and [`SPARE`] on the others,
/// so the write has no branch on the lane mask. Measured in one process
/// against a loop over the mask's bits (thread CPU time, medians of
/// 7-9 interleaved rounds, 2^18 rays, sphere d10 and Menger d10, shared
/// 2-core Zen 4, docs/PERF.md ninth session): coherent 1.07-1.30x,
/// incoherent 0.90-1.16x, 0 differing rays; AVX-512's masked scatter in
/// its place was 1.00-1.03x of these stores on the octree and 0.86-0.94x
/// on the DAG (both measured with eight lanes, not re-taken with sixteen).
#[inline(always)]
pub(super) fn write_stack<V: Isa>(mut at: V::I, mut parent: V::I, stack: &mut [i32; STACK]) {
    let (at, pv) = (V::i_lanes(&mut at), V::i_lanes(&mut parent));
    for l in 0..V::W {
        // `at` is `l * SD + scale` (scale < SD while the lane pushes) or
        // SPARE: within the stack.
        stack[at[l] as usize] = pv[l];
    }
}

/// The masks of a step's lanes whose ray ended (`done`), by how: the
/// iteration cap, a stop (at a `leaf` or at the LOD cut), else an exit.
pub(super) struct Ended {
    pub done: u32,
    pub capped: u32,
    pub stop: u32,
    pub leaf: u32,
}

/// The answers of the lanes in `e.done`, and their refill.
#[inline(always)]
pub(super) fn answer<V: Isa, A: Addressing>(
    g: &mut Group<V>,
    k: &Consts<V>,
    e: Ended,
    out: &mut [CastHit<f32>],
) {
    let Group { s, q, .. } = g;
    let (o, d) = (q.o, q.d);
    for l in set_bits(e.done) {
        let i = q.ray[l];
        let it = V::i_lanes(&mut s.iters)[l] as u32;
        out[i] = if e.capped >> l & 1 != 0 {
            CastHit::miss(it - 1, true)
        } else if e.stop >> l & 1 != 0 {
            let stop = s.stop(l, e.leaf >> l & 1 != 0);
            match &q.starts[l] {
                Some(st) => {
                    let p = k.p.for_ray(q.near, i);
                    finish::<f32, A>(k.nodes, k.depth, o[i], d[i], &p, st, &stop)
                }
                None => CastHit::miss(it, false),
            }
        } else {
            CastHit::miss(it, false)
        };
        q.refill(s, l, k.p, out);
    }
}

/// Streams the rays `(o[i], d[i])` through [`G`] groups of lanes fed from
/// one [`Queue`] position, one iteration of every group per [`Isa::step`],
/// writing `out[i]`: the groups' loads are independent, so one group's
/// gathers overlap the others' work.
///
/// # Safety
/// The CPU must have `V`'s instructions and `2 * nodes.len()` must fit an
/// i32.
#[inline(always)]
pub(super) unsafe fn stream<V: Isa, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[f32; 3]],
    d: &[[f32; 3]],
    p: &CastParams,
    near: Option<&[f64]>,
    out: &mut [CastHit<f32>],
) {
    let k = Consts::<V> {
        nodes,
        depth,
        p,
        lod: p.lod.map(|l| {
            (
                V::splat_f(l.orig_size as f32 * 0.5),
                V::splat_f(l.dir_size as f32 * 0.5),
            )
        }),
        max_iter: V::splat_i(p.max_iter.min(i32::MAX as u32) as i32),
        lane_base: {
            // Lane `l`'s first stack entry, `l * SD`.
            let mut b = V::splat_i(0);
            for (l, x) in V::i_lanes(&mut b).iter_mut().enumerate() {
                *x = (l * SD) as i32;
            }
            b
        },
    };
    let next = Cell::new(0);
    let mut g: [Group<V>; G] = std::array::from_fn(|_| Group {
        s: State::idle(),
        stack: [0; STACK],
        q: Queue {
            o,
            d,
            near,
            next: &next,
            ray: [usize::MAX; W_MAX],
            starts: [None; W_MAX],
        },
    });
    for g in g.iter_mut() {
        for l in 0..V::W {
            g.q.refill(&mut g.s, l, p, out);
        }
    }
    while g.iter().any(|g| V::bits(g.s.act) != 0) {
        V::step::<A, G>(g.each_mut(), &k, out);
    }
}
