//! The packet (stream) cast: the Laine–Karras loop of [`super::cast`] run
//! for [`W`] rays in lockstep, one lane per ray, with per-lane masks
//! choosing PUSH, ADVANCE, POP or stop, and a lane refilled with the next
//! ray of the stream as soon as its ray finishes (so lanes stay busy when
//! iteration counts differ). Each lane performs exactly the float and bit
//! operations of [`super::cast::cast_with`] on its ray (the same
//! [`start`] and [`finish`], the loop body lane by lane), so every output
//! is bit-identical to the per-ray cast, which stays the referee (case
//! `voxel_packet_*_identical` in `TESTS/voxels/manifest_packet.yaml`).
//!
//! The arithmetic of an iteration (ray-plane times, masks, blends of the
//! lane state) is written as loops over lane arrays that the compiler turns
//! into SIMD; the AVX2 instance is chosen at run time
//! (`is_x86_feature_detected!`), otherwise the same code runs at the
//! baseline instruction set. Descriptor loads, stack writes and POP's bit
//! search stay per lane. Contours are not cast here (the per-ray cast does).

use crate::parallel::par_chunks;

use super::cast::{
    finish, start, Absolute, Addressing, CastHit, CastParams, CastReal, Relative, Start, Stop,
    S_MAX,
};
use super::dag::Dag;
use super::hits::collect;
use super::octree::Octree;
use super::render::VoxelHits;
use super::set_bits::set_bits;

/// Lanes per packet.
pub const W: usize = 8;

/// Rays per parallel chunk (one lane set streams through a chunk).
const CHUNK: usize = 512;

const IDLE: usize = usize::MAX;

/// Which instance of the lane loop runs on this CPU.
pub fn simd_level() -> &'static str {
    #[cfg(target_arch = "x86_64")]
    {
        if std::is_x86_feature_detected!("avx2") {
            return "avx2";
        }
    }
    "baseline"
}

/// [`super::render::cast_all`] by packets: identical results.
pub fn cast_all_packet<F: CastReal>(
    tree: &Octree,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    collect(stream_all::<F, Relative>(&tree.nodes, tree.depth, o, d, p))
}

/// [`super::render::cast_all_dag`] by packets: identical results.
pub fn cast_all_packet_dag<F: CastReal>(
    dag: &Dag,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    collect(stream_all::<F, Absolute>(&dag.nodes, dag.depth, o, d, p))
}

fn stream_all<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> Vec<CastHit<F>> {
    let mut out = vec![CastHit::miss(0, false); o.len()];
    let avx2 = simd_level() == "avx2";
    par_chunks("voxels.cast_packet", &mut out, CHUNK, |c, chunk| {
        let r = c * CHUNK..c * CHUNK + chunk.len();
        let (o, d) = (&o[r.clone()], &d[r]);
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: the CPU has AVX2 (checked at run time just above).
            unsafe { stream_avx2::<F, A>(nodes, depth, o, d, p, chunk) };
            return;
        }
        let _ = avx2;
        stream::<F, A>(nodes, depth, o, d, p, chunk);
    });
    out
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2")]
unsafe fn stream_avx2<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
    out: &mut [CastHit<F>],
) {
    stream::<F, A>(nodes, depth, o, d, p, out)
}

/// The state of [`W`] casts, one per lane, as lane arrays (axis-major).
struct Lanes<F> {
    ray: [usize; W],
    st: [Start<F>; W],
    coef: [[F; W]; 3],
    bias: [[F; W]; 3],
    pos: [[F; W]; 3],
    octant: [u32; W],
    t_min: [F; W],
    t_max: [F; W],
    h: [F; W],
    parent: [u32; W],
    desc: [u32; W],
    idx: [u32; W],
    scale: [i32; W],
    scale_exp2: [F; W],
    iters: [u32; W],
    stack_node: [[u32; S_MAX as usize + 1]; W],
    stack_tmax: [[F; S_MAX as usize + 1]; W],
}

impl<F: CastReal> Lanes<F> {
    fn new() -> Self {
        let z = F::zero();
        let st = Start {
            dir: [z; 3],
            coef: [z; 3],
            bias: [z; 3],
            octant: 0,
            t_min: z,
            t_max: z,
            h: z,
            idx: 0,
            pos: [z; 3],
            lod: None,
        };
        Lanes {
            ray: [IDLE; W],
            st: [st; W],
            coef: [[z; W]; 3],
            bias: [[z; W]; 3],
            pos: [[z; W]; 3],
            octant: [0; W],
            t_min: [z; W],
            t_max: [z; W],
            h: [z; W],
            parent: [0; W],
            desc: [0; W],
            idx: [0; W],
            scale: [S_MAX - 1; W],
            scale_exp2: [z; W],
            iters: [0; W],
            stack_node: [[0; S_MAX as usize + 1]; W],
            stack_tmax: [[z; S_MAX as usize + 1]; W],
        }
    }

    #[inline(always)]
    fn load(&mut self, l: usize, ray: usize, s: Start<F>) {
        self.ray[l] = ray;
        self.st[l] = s;
        for a in 0..3 {
            self.coef[a][l] = s.coef[a];
            self.bias[a][l] = s.bias[a];
            self.pos[a][l] = s.pos[a];
        }
        self.octant[l] = s.octant;
        self.t_min[l] = s.t_min;
        self.t_max[l] = s.t_max;
        self.h[l] = s.h;
        self.parent[l] = 0;
        self.desc[l] = 0;
        self.idx[l] = s.idx;
        self.scale[l] = S_MAX - 1;
        self.scale_exp2[l] = F::of(0.5);
        self.iters[l] = 0;
    }

    /// The lane's [`Stop`] at its current voxel.
    #[inline(always)]
    fn stop(&self, l: usize, leaf: bool) -> Stop<F> {
        Stop {
            leaf,
            pos: [self.pos[0][l], self.pos[1][l], self.pos[2][l]],
            scale: self.scale[l],
            scale_exp2: self.scale_exp2[l],
            t_min: self.t_min[l],
            parent: self.parent[l] as usize,
            desc: self.desc[l],
            idx: self.idx[l],
            contour_hit: None,
            iters: self.iters[l],
        }
    }
}

#[inline(always)]
fn sel<T: Copy>(m: bool, a: T, b: T) -> T {
    if m {
        a
    } else {
        b
    }
}

/// Streams the rays `(o[i], d[i])` through [`W`] lanes, writing `out[i]`.
#[inline(always)]
#[allow(clippy::needless_range_loop)]
fn stream<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
    out: &mut [CastHit<F>],
) {
    let half = F::of(0.5);
    let (lod_on, osz, dsz) = match p.lod {
        Some(l) => (true, F::of(l.orig_size) * half, F::of(l.dir_size) * half),
        None => (false, F::zero(), F::zero()),
    };
    let mut ln = Lanes::<F>::new();
    let mut next = 0usize;
    loop {
        // Refill idle lanes with the next rays (a ray missing the root box
        // is answered at once).
        let mut any = false;
        for l in 0..W {
            while ln.ray[l] == IDLE && next < o.len() {
                let i = next;
                next += 1;
                match start(o[i], d[i], p) {
                    Some(s) => ln.load(l, i, s),
                    None => out[i] = CastHit::miss(0, false),
                }
            }
            any |= ln.ray[l] != IDLE;
        }
        if !any {
            return;
        }
        // Iteration count and descriptor fetch, branch-free on every lane
        // (an idle lane's `parent` is a valid slot); the capped lanes.
        let mut active = 0u32;
        let mut capped = 0u32;
        for l in 0..W {
            let on = ln.ray[l] != IDLE;
            active |= (on as u32) << l;
            ln.iters[l] += 1;
            capped |= ((on && ln.iters[l] > p.max_iter) as u32) << l;
            let w = nodes[2 * ln.parent[l] as usize];
            ln.desc[l] = sel(ln.desc[l] == 0, w, ln.desc[l]);
        }
        for l in set_bits(capped) {
            out[ln.ray[l]] = CastHit::miss(ln.iters[l] - 1, true);
            ln.ray[l] = IDLE;
        }
        active &= !capped;
        // Lane arithmetic: ray-plane times and the masks of each branch.
        let mut tc = [[F::zero(); W]; 3];
        let mut tc_max = [F::zero(); W];
        let mut tv_max = [F::zero(); W];
        let mut cmask = [0u32; W];
        let mut stop_m = [false; W];
        let mut stop_leaf = [false; W];
        let mut push = [false; W];
        for l in 0..W {
            for a in 0..3 {
                tc[a][l] = ln.pos[a][l] * ln.coef[a][l] - ln.bias[a][l];
            }
            let m01 = sel(tc[0][l] < tc[1][l], tc[0][l], tc[1][l]);
            tc_max[l] = sel(m01 < tc[2][l], m01, tc[2][l]);
            let cm = ln.desc[l] << (ln.idx[l] ^ ln.octant[l]);
            cmask[l] = cm;
            let valid = (cm & 0x8000 != 0) & (ln.t_min[l] <= ln.t_max[l]);
            let lod_stop = lod_on & valid & (tc_max[l] * dsz + osz >= ln.scale_exp2[l]);
            tv_max[l] = sel(ln.t_max[l] < tc_max[l], ln.t_max[l], tc_max[l]);
            let inter = valid & !lod_stop & (ln.t_min[l] <= tv_max[l]);
            let leaf = cm & 0x80 == 0;
            stop_m[l] = lod_stop | (inter & leaf);
            stop_leaf[l] = leaf;
            push[l] = inter & !leaf;
        }
        let (mut stops, mut pushes) = (0u32, 0u32);
        for l in 0..W {
            stops |= (stop_m[l] as u32) << l;
            pushes |= (push[l] as u32) << l;
        }
        stops &= active;
        // Stops: the hit, and the lane is free.
        for l in set_bits(stops) {
            let i = ln.ray[l];
            let stop = ln.stop(l, stop_leaf[l]);
            out[i] = finish::<F, A>(nodes, depth, o[i], d[i], p, &ln.st[l], &stop);
            ln.ray[l] = IDLE;
        }
        // PUSH: stack write and child address per lane, the rest blended.
        for l in set_bits(pushes & active) {
            let s = ln.scale[l] as usize;
            let keep = tc_max[l] < ln.h[l];
            ln.stack_node[l][s] = sel(keep, ln.parent[l], ln.stack_node[l][s]);
            ln.stack_tmax[l][s] = sel(keep, ln.t_max[l], ln.stack_tmax[l][s]);
            let shift = ln.idx[l] ^ ln.octant[l];
            ln.parent[l] = A::child(
                nodes,
                ln.parent[l] as usize,
                ln.desc[l],
                cmask[l],
                shift ^ 7,
            ) as u32;
        }
        let mut pop = [false; W];
        let mut step = [0u32; W];
        for l in 0..W {
            let pu = push[l];
            let halfs = ln.scale_exp2[l] * half;
            let mut idx_push = 0u32;
            let mut idx_step = 0u32;
            for a in 0..3 {
                let tcen = halfs * ln.coef[a][l] + tc[a][l];
                let up = tcen > ln.t_min[l];
                idx_push |= (up as u32) << a;
                let st = tc[a][l] <= tc_max[l];
                idx_step |= (st as u32) << a;
                let pushed = sel(up, ln.pos[a][l] + halfs, ln.pos[a][l]);
                let stepped = sel(st, ln.pos[a][l] - ln.scale_exp2[l], ln.pos[a][l]);
                ln.pos[a][l] = sel(pu, pushed, stepped);
            }
            ln.h[l] = sel(pu, tc_max[l], ln.h[l]);
            ln.scale[l] -= pu as i32;
            ln.scale_exp2[l] = sel(pu, halfs, ln.scale_exp2[l]);
            ln.t_max[l] = sel(pu, tv_max[l], ln.t_max[l]);
            ln.desc[l] = sel(pu, 0, ln.desc[l]);
            // ADVANCE on the other lanes.
            ln.t_min[l] = sel(pu, ln.t_min[l], tc_max[l]);
            let idx_adv = ln.idx[l] ^ idx_step;
            ln.idx[l] = sel(pu, idx_push, idx_adv);
            step[l] = idx_step;
            pop[l] = !pu & (idx_adv & idx_step != 0);
        }
        let mut pops = 0u32;
        for l in 0..W {
            pops |= (pop[l] as u32) << l;
        }
        // POP (per lane): the highest differing bit, the stack, rounding.
        for l in set_bits(pops & active & !stops) {
            let se = ln.scale_exp2[l];
            let mut diff = 0u64;
            for a in 0..3 {
                let x = ln.pos[a][l].bits() ^ (ln.pos[a][l] + se).bits();
                diff |= sel(step[l] >> a & 1 != 0, x, 0);
            }
            diff >>= F::EXTRA;
            let scale = 63 - diff.leading_zeros() as i32;
            if scale >= S_MAX {
                out[ln.ray[l]] = CastHit::miss(ln.iters[l], false);
                ln.ray[l] = IDLE;
                continue;
            }
            ln.scale[l] = scale;
            ln.scale_exp2[l] = F::exp2i(scale - S_MAX);
            ln.parent[l] = ln.stack_node[l][scale as usize];
            ln.t_max[l] = ln.stack_tmax[l][scale as usize];
            let shift = scale as u32 + F::EXTRA;
            let mut idx = 0;
            for a in 0..3 {
                let sh = ln.pos[a][l].bits() >> shift;
                ln.pos[a][l] = F::from_bits(sh << shift);
                idx |= ((sh & 1) as u32) << a;
            }
            ln.idx[l] = idx;
            ln.h[l] = F::zero();
            ln.desc[l] = 0;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::dag::build_dag;
    use crate::voxels::fixtures::{incoherent_in as rays, lod, scenes};
    use crate::voxels::octree::build;
    use crate::voxels::render::{cast_all, cast_all_dag};
    use crate::voxels::shape::Shape;

    fn same<F: CastReal>(a: &VoxelHits<F>, b: &VoxelHits<F>) {
        assert_eq!(a.hit, b.hit);
        assert_eq!(a.leaf, b.leaf);
        assert_eq!(a.iters, b.iters);
        assert_eq!(a.capped, b.capped);
        for i in 0..a.t.len() {
            assert_eq!(a.t[i].bits(), b.t[i].bits(), "ray {i}");
            assert_eq!(a.normal[i].map(|x| x.bits()), b.normal[i].map(|x| x.bits()));
        }
    }

    #[test]
    fn packets_equal_the_per_ray_cast_bit_for_bit_in_f32_and_f64() {
        let budget = MemBudget::fixed(1 << 30);
        // The sphere and the sponge of the shared fixture list.
        for (s, depth) in scenes().into_iter().take(2) {
            let t = build(&s, depth, &budget).unwrap();
            let g = build_dag(&t, &budget).unwrap();
            let (o, d) = rays::<f32>(3000, depth);
            let p = CastParams::default();
            same(&cast_all_packet(&t, &o, &d, &p), &cast_all(&t, &o, &d, &p));
            same(
                &cast_all_packet_dag(&g, &o, &d, &p),
                &cast_all_dag(&g, &o, &d, &p),
            );
            let (o, d) = rays::<f64>(1000, depth + 1);
            same(&cast_all_packet(&t, &o, &d, &p), &cast_all(&t, &o, &d, &p));
        }
    }

    #[test]
    fn packets_keep_the_lod_cut_the_interval_and_the_iteration_cap() {
        let budget = MemBudget::fixed(1 << 30);
        let t = build(&Shape::Sphere { radius: 0.8 }, 8, &budget).unwrap();
        let (o, d) = rays::<f32>(2000, 4);
        for p in [
            lod(0.02),
            CastParams {
                near: 0.5,
                far: 2.0,
                ..CastParams::default()
            },
            CastParams {
                max_iter: 9,
                ..CastParams::default()
            },
        ] {
            let a = cast_all_packet(&t, &o, &d, &p);
            same(&a, &cast_all(&t, &o, &d, &p));
            if p.max_iter == 9 {
                assert!(a.capped > 100, "{}", a.capped);
            }
        }
    }
}
