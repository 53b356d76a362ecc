//! `cast`: the Laine–Karras ESVO ray cast (seed 003, after `Raycast.inl`),
//! generic over f32 (the GPU's precision, the seed's algorithm bit for bit)
//! and f64 (same loop, 52-bit mantissa, comparable with the exact referee).
//!
//! The world box [-1, 1]^3 maps to the octree's [1, 2]^3 by
//! `p' = p / 2 + 3 / 2`, `d' = d / 2`, so t is unchanged. Direction
//! components below `2^-23` (f32; `2^-52` for f64) are replaced by that
//! epsilon with their sign. The coordinate system is mirrored so the ray
//! travels towards -x', -y', -z' (`octant_mask`), and voxel positions and
//! sizes are floats in [1, 2) whose bit patterns give the traversal its
//! integer structure: PUSH writes (parent slot, t_max) at index `scale` of
//! a 23-entry stack, ADVANCE steps `pos` by the voxel size, POP finds the new
//! scale as the highest bit in which old and new positions differ
//! (`leading_zeros` here where ESVO converts the bits to float; WGSL's
//! `firstLeadingBit` for the GPU twin of a later issue) and rounds `pos` by
//! shifting its bits.
//! Voxel size at scale s is `2^(s - 23)`, so depth `l` is scale `23 - l`;
//! positions are exact only while voxels are at least `2^-22` wide: depth
//! at most [`super::shape::MAX_DEPTH`] = 22.
//!
//! Outputs (SCENES.md): `t` is the entry distance of the hit voxel's box
//! (or `near` when the ray starts inside it), the leaf voxel is the
//! finest-level voxel that contains the hit point, and the normal is the
//! outward normal of the face the ray entered through, zero when it started
//! inside. The loop allocates nothing.
//!
//! GPU twin: `kernels/voxels.wgsl` `esvo_cast` (entries `cast_camera`,
//! `cast_rays`), operation for operation in f32; parity cases
//! `voxel_gpu_*` in `TESTS/voxels/manifest_gpu.yaml`.

use crate::real::Real;

pub use super::cast_real::CastReal;

use super::contour::slab_interval;

/// Scale of the root's children + 1: f32's mantissa bits.
pub const S_MAX: i32 = 23;

/// Default iteration cap for a depth-`depth` tree: `max(2^16, 16 * 2^depth)`.
/// A ray grazing a one-voxel-thick line of `2^depth` voxels legitimately takes
/// a few iterations per voxel, so the cap grows with the grid.
pub fn default_max_iter(depth: u32) -> u32 {
    (16u64 << depth.min(24)).clamp(1 << 16, u32::MAX as u64) as u32
}

/// Level-of-detail cut by ray footprint: stop at a voxel once
/// `orig_size + t * dir_size >= voxel size` (world units, t at the voxel's exit).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lod {
    pub orig_size: f64,
    pub dir_size: f64,
}

/// The ray interval and options of a cast.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CastParams {
    pub near: f64,
    pub far: f64,
    pub lod: Option<Lod>,
    /// Loop iterations after which the ray is given up as a miss (`capped`);
    /// see [`default_max_iter`] (the `Default` uses 2^16).
    pub max_iter: u32,
}

impl Default for CastParams {
    fn default() -> Self {
        CastParams {
            near: 0.0,
            far: f64::INFINITY,
            lod: None,
            max_iter: 1 << 16,
        }
    }
}

impl CastParams {
    /// These params for ray `i` of a cast with per-ray starts `near` (the
    /// beam's, [`super::beam`]): `near[i]` in place of `self.near`.
    #[inline(always)]
    pub fn for_ray(&self, near: Option<&[f64]>, i: usize) -> CastParams {
        match near {
            Some(n) => CastParams {
                near: n[i],
                ..*self
            },
            None => *self,
        }
    }
}

/// What one cast found. On a miss `t = -1`, voxel and normal are zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CastHit<F> {
    pub hit: bool,
    pub t: F,
    /// World-space hit point `o + t d`.
    pub pos: [F; 3],
    /// Finest-level voxel containing the hit point.
    pub voxel: [u32; 3],
    /// Outward normal of the entered face (zero when the ray started inside).
    pub normal: [i8; 3],
    /// Depth of the voxel the cast stopped at (< tree depth for coarse leaves and LOD cuts).
    pub level: u32,
    /// Attribute index of the leaf, `u32::MAX` for an LOD cut at an inner node.
    pub attr: u32,
    /// The contour whose slab gave `t` ([`super::contour`]), 0 for none.
    pub contour: u32,
    pub iters: u32,
    pub capped: bool,
}

impl<F: CastReal> CastHit<F> {
    pub fn miss(iters: u32, capped: bool) -> Self {
        CastHit {
            hit: false,
            t: -F::one(),
            pos: [F::zero(); 3],
            voxel: [0; 3],
            normal: [0; 3],
            level: 0,
            attr: u32::MAX,
            contour: 0,
            iters,
            capped,
        }
    }
}

// Plain comparisons (no NaN handling: no NaN reaches the loop, directions
// are clamped away from zero), which compile to single min/max instructions.
#[inline(always)]
fn fmin<F: Real>(a: F, b: F) -> F {
    if a < b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn fmax<F: Real>(a: F, b: F) -> F {
    if a > b {
        a
    } else {
        b
    }
}

#[inline(always)]
fn min3<F: Real>(a: [F; 3]) -> F {
    fmin(fmin(a[0], a[1]), a[2])
}

#[inline(always)]
fn max3<F: Real>(a: [F; 3]) -> F {
    fmax(fmax(a[0], a[1]), a[2])
}

/// How a traversal finds a node's children: the one difference between the
/// octree ([`Relative`]) and the DAG ([`Absolute`]) casts, chosen at compile
/// time so both run the same loop with the same float operations.
pub trait Addressing {
    /// Whether children sit at `high word + c` ([`Absolute`]); the lane
    /// cast ([`super::cast_lanes`]) picks its vector child address by it.
    const ABSOLUTE: bool;
    /// Slot of child `c`'s descriptor, for the node at slot `parent` with
    /// low word `desc`; `child_masks` is `desc` shifted so that bits 0..7
    /// are the non-leaf bits of the children before `c` (in the mirrored
    /// order the loop visits).
    fn child(nodes: &[u32], parent: usize, desc: u32, child_masks: u32, c: u32) -> usize;
    /// Attribute index of leaf child `c` of the node at `parent`, or
    /// `u32::MAX` where the layout cannot tell (the DAG: see
    /// [`super::dag::Dag::attr_index`]).
    fn leaf_attr(nodes: &[u32], parent: usize, desc: u32, c: u32) -> u32;
    /// Slot where the node's children block starts (a prefetch hint only:
    /// the node itself for a far pointer).
    fn children(nodes: &[u32], parent: usize, desc: u32) -> usize;
}

/// ESVO octree addressing ([`super::octree`]): children at
/// `parent + ptr + popcount(non-leaf bits before c)`, through a far-pointer
/// slot when the far bit is set; the high word is the attribute base.
pub struct Relative;

/// DAG addressing ([`super::dag`]): the high word is the absolute slot of the
/// node's 8-slot children block and child `c` sits at `high + c`.
pub struct Absolute;

impl Addressing for Relative {
    const ABSOLUTE: bool = false;
    #[inline(always)]
    fn child(nodes: &[u32], parent: usize, desc: u32, child_masks: u32, _c: u32) -> usize {
        let mut ofs = (desc >> 17) as usize;
        if desc & 0x1_0000 != 0 {
            ofs = nodes[2 * (parent + ofs)] as usize;
        }
        parent + ofs + (child_masks & 0x7F).count_ones() as usize
    }
    #[inline(always)]
    fn leaf_attr(nodes: &[u32], parent: usize, desc: u32, c: u32) -> u32 {
        let leafmask = (desc >> 8) & !desc & 0xFF;
        nodes[2 * parent + 1] + (leafmask & ((1 << c) - 1)).count_ones()
    }
    #[inline(always)]
    fn children(_nodes: &[u32], parent: usize, desc: u32) -> usize {
        if desc & 0x1_0000 != 0 {
            parent
        } else {
            parent + (desc >> 17) as usize
        }
    }
}

impl Addressing for Absolute {
    const ABSOLUTE: bool = true;
    #[inline(always)]
    fn child(nodes: &[u32], parent: usize, _desc: u32, _child_masks: u32, c: u32) -> usize {
        nodes[2 * parent + 1] as usize + c as usize
    }
    #[inline(always)]
    fn leaf_attr(_nodes: &[u32], _parent: usize, _desc: u32, _c: u32) -> u32 {
        u32::MAX
    }
    #[inline(always)]
    fn children(nodes: &[u32], parent: usize, _desc: u32) -> usize {
        nodes[2 * parent + 1] as usize
    }
}

/// Casts the ray `o + t d`, t in `[near, far]`, through the octree `nodes`
/// (layout of [`super::octree`]) of depth `depth`.
pub fn cast<F: CastReal>(
    nodes: &[u32],
    depth: u32,
    o: [F; 3],
    d: [F; 3],
    p: &CastParams,
) -> CastHit<F> {
    cast_with::<F, Relative>(nodes, depth, o, d, p, None)
}

/// [`cast`] with contours (issue 14): `contours[attr]` is the contour of the
/// finest-level leaf with attribute index `attr` (0: none). At such a leaf
/// the ray's t interval inside the voxel is cut to the contour's slab; the
/// voxel is hit at the cut interval's start, or passed when it is empty.
/// `t` then never leaves the voxel's [entry, exit].
pub fn cast_contours<F: CastReal>(
    nodes: &[u32],
    depth: u32,
    o: [F; 3],
    d: [F; 3],
    p: &CastParams,
    contours: &[u32],
) -> CastHit<F> {
    cast_with::<F, Relative>(nodes, depth, o, d, p, Some(contours))
}

/// The same cast through a DAG's `nodes` (layout of [`super::dag`]): the same
/// loop as [`cast`], so `t`, voxel, normal, level and iterations are
/// bit-identical; `attr` is `u32::MAX` (the DAG finds it by
/// [`super::dag::Dag::attr_index`]).
pub fn cast_dag<F: CastReal>(
    nodes: &[u32],
    depth: u32,
    o: [F; 3],
    d: [F; 3],
    p: &CastParams,
) -> CastHit<F> {
    cast_with::<F, Absolute>(nodes, depth, o, d, p, None)
}

/// A ray ready for the loop: the mirrored ray (`dir`, `coef`, `bias`,
/// `octant`, t of axis a at coordinate x being `x * coef[a] - bias[a]`), its
/// interval in the root box, the LOD footprint in octree units and the
/// root's first child (`idx`, `pos`). Shared by [`cast_with`] and the
/// packet cast ([`super::packet`]).
#[derive(Clone, Copy, Debug)]
pub struct Start<F> {
    pub dir: [F; 3],
    pub coef: [F; 3],
    pub bias: [F; 3],
    pub octant: u32,
    pub t_min: F,
    pub t_max: F,
    pub h: F,
    pub idx: u32,
    pub pos: [F; 3],
    pub lod: Option<(F, F)>,
}

/// The ray's [`Start`], or `None` when it misses the root box (or its
/// interval ends before it).
#[inline(always)]
pub fn start<F: CastReal>(o: [F; 3], d: [F; 3], p: &CastParams) -> Option<Start<F>> {
    let one = F::one();
    let half = F::of(0.5);
    let eps = F::exp2i(F::EPS_LOG2);
    let mut dir = [d[0] * half, d[1] * half, d[2] * half];
    let orig = [
        o[0] * half + F::of(1.5),
        o[1] * half + F::of(1.5),
        o[2] * half + F::of(1.5),
    ];
    for v in dir.iter_mut() {
        if v.abs() < eps {
            *v = if v.is_sign_negative() { -eps } else { eps };
        }
    }
    // t_a(x) = x * coef_a - bias_a, mirrored so every coef is negative.
    let coef = dir.map(|v| -one / v.abs());
    let mut bias = [coef[0] * orig[0], coef[1] * orig[1], coef[2] * orig[2]];
    let mut octant = 7u32;
    for a in 0..3 {
        if dir[a] > F::zero() {
            octant ^= 1 << a;
            bias[a] = F::of(3.0) * coef[a] - bias[a];
        }
    }
    let two = F::of(2.0);
    let mut t_min = max3([0, 1, 2].map(|a| two * coef[a] - bias[a]));
    let mut t_max = min3([0, 1, 2].map(|a| coef[a] - bias[a]));
    let h = t_max;
    t_min = t_min.max(F::of(p.near));
    t_max = t_max.min(F::of(p.far));
    if t_min > t_max {
        // The ray misses the root box (or its interval ends before it):
        // ESVO would find this by advancing out of the root; stop now.
        return None;
    }
    let lod = p
        .lod
        .map(|l| (F::of(l.orig_size) * half, F::of(l.dir_size) * half));
    let mut idx = 0u32;
    let mut pos = [one; 3];
    let c15 = F::of(1.5);
    for a in 0..3 {
        if c15 * coef[a] - bias[a] > t_min {
            idx ^= 1 << a;
            pos[a] = c15;
        }
    }
    Some(Start {
        dir,
        coef,
        bias,
        octant,
        t_min,
        t_max,
        h,
        idx,
        pos,
        lod,
    })
}

/// Where the loop stopped at a voxel: its mirrored position and scale, the
/// node and child it is in, `t_min` there, whether it is a solid leaf (else
/// an LOD cut), the contour slab's (t, contour) when one gave the hit.
#[derive(Clone, Copy, Debug)]
pub struct Stop<F> {
    pub leaf: bool,
    pub pos: [F; 3],
    pub scale: i32,
    pub scale_exp2: F,
    pub t_min: F,
    pub parent: usize,
    pub desc: u32,
    pub idx: u32,
    pub contour_hit: Option<(F, u32)>,
    pub iters: u32,
}

/// The Laine–Karras loop, generic over the child addressing `A`. Per-axis
/// loops index arrays as a WGSL kernel would.
#[allow(clippy::needless_range_loop)]
pub fn cast_with<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: [F; 3],
    d: [F; 3],
    p: &CastParams,
    contours: Option<&[u32]>,
) -> CastHit<F> {
    let half = F::of(0.5);
    let two = F::of(2.0);
    let Some(st) = start(o, d, p) else {
        return CastHit::miss(0, false);
    };
    let Start {
        coef,
        bias,
        octant,
        mut t_min,
        mut t_max,
        mut h,
        mut idx,
        mut pos,
        lod,
        ..
    } = st;
    let mut stack_node = [0u32; S_MAX as usize + 1];
    let mut stack_tmax = [F::zero(); S_MAX as usize + 1];
    let mut parent = 0usize;
    let mut desc = 0u32;
    let mut scale = S_MAX - 1;
    let mut scale_exp2 = half;
    let mut iters = 0u32;
    let mut stop: Option<bool> = None; // Some(leaf?) when the loop stops at a voxel
    let mut contour_hit: Option<(F, u32)> = None;
    while scale < S_MAX {
        iters += 1;
        if iters > p.max_iter {
            return CastHit::miss(iters - 1, true);
        }
        if desc == 0 {
            desc = nodes[2 * parent];
        }
        let tc = [0, 1, 2].map(|a| pos[a] * coef[a] - bias[a]);
        let tc_max = min3(tc);
        let child_shift = idx ^ octant;
        let child_masks = desc << child_shift;
        if child_masks & 0x8000 != 0 && t_min <= t_max {
            if let Some((osz, dsz)) = lod {
                if tc_max * dsz + osz >= scale_exp2 {
                    stop = Some(child_masks & 0x80 == 0);
                    break;
                }
            }
            // INTERSECT
            let tv_max = fmin(t_max, tc_max);
            let halfs = scale_exp2 * half;
            let tcen = [0, 1, 2].map(|a| halfs * coef[a] + tc[a]);
            if t_min <= tv_max && child_masks & 0x80 == 0 {
                // A leaf: the hit, unless its contour's slab misses the ray.
                let slab = match contours {
                    Some(cs) if S_MAX - scale == depth as i32 => {
                        let at = A::leaf_attr(nodes, parent, desc, child_shift ^ 7) as usize;
                        let v = cs.get(at).copied().unwrap_or(0);
                        (v != 0).then(|| {
                            let cen = [0, 1, 2].map(|a| {
                                let lo = if octant >> a & 1 == 0 {
                                    F::of(3.0) - scale_exp2 - pos[a]
                                } else {
                                    pos[a]
                                };
                                two * lo + scale_exp2 - F::of(3.0)
                            });
                            let (ta, tb) = slab_interval(v, cen, two * scale_exp2, o, d);
                            (fmax(t_min, ta), fmin(tv_max, tb), v)
                        })
                    }
                    _ => None,
                };
                if !matches!(slab, Some((a, b, _)) if a > b) {
                    contour_hit = slab.map(|(a, _, v)| (a, v));
                    stop = Some(true);
                    break;
                }
            } else if t_min <= tv_max {
                // PUSH
                if tc_max < h {
                    stack_node[scale as usize] = parent as u32;
                    stack_tmax[scale as usize] = t_max;
                }
                h = tc_max;
                parent = A::child(nodes, parent, desc, child_masks, child_shift ^ 7);
                idx = 0;
                scale -= 1;
                scale_exp2 = halfs;
                for a in 0..3 {
                    if tcen[a] > t_min {
                        idx ^= 1 << a;
                        pos[a] += scale_exp2;
                    }
                }
                t_max = tv_max;
                desc = 0;
                continue;
            }
        }
        // ADVANCE
        let mut step = 0u32;
        for a in 0..3 {
            if tc[a] <= tc_max {
                step ^= 1 << a;
                pos[a] -= scale_exp2;
            }
        }
        t_min = tc_max;
        idx ^= step;
        if idx & step != 0 {
            // POP: the highest bit in which the positions before and after differ.
            let mut diff = 0u64;
            for a in 0..3 {
                if step >> a & 1 != 0 {
                    diff |= pos[a].bits() ^ (pos[a] + scale_exp2).bits();
                }
            }
            diff >>= F::EXTRA;
            scale = 63 - diff.leading_zeros() as i32;
            if scale >= S_MAX {
                break;
            }
            scale_exp2 = F::exp2i(scale - S_MAX);
            parent = stack_node[scale as usize] as usize;
            t_max = stack_tmax[scale as usize];
            let shift = scale as u32 + F::EXTRA;
            idx = 0;
            for a in 0..3 {
                let sh = pos[a].bits() >> shift;
                pos[a] = F::from_bits(sh << shift);
                idx |= ((sh & 1) as u32) << a;
            }
            h = F::zero();
            desc = 0;
        }
    }
    let Some(leaf) = stop else {
        return CastHit::miss(iters, false);
    };
    let stop = Stop {
        leaf,
        pos,
        scale,
        scale_exp2,
        t_min,
        parent,
        desc,
        idx,
        contour_hit,
        iters,
    };
    finish::<F, A>(nodes, depth, o, d, p, &st, &stop)
}

/// How far below the loop's `t_min` the recomputed entry time `te` of the
/// hit voxel may fall and still name the face the ray entered by: 16
/// epsilons (2^-19 in f32) of the face's product term `(pos + s) coef`.
/// Where `t_min` came from that same face, `te` equals it on the CPU. A GPU
/// driver may fuse the multiply-adds of `t = x coef - bias` (and of `bias`
/// itself) differently at the two sites, a rounding or two of terms of
/// that size apart: on an NVIDIA H100 the old exact test left a zero normal
/// on 11 of 2048 hard Menger rays. A ray that starts inside the voxel falls
/// short by far more, unless it starts within rounding of the face (a tie).
/// Twin: kernels/voxels.wgsl `entry_slack`.
pub fn entry_slack<F: CastReal>(product: F) -> F {
    F::of(16.0) * F::epsilon() * product.abs()
}

/// The hit at the voxel where the loop stopped (see the module doc for `t`,
/// voxel and normal).
#[inline(always)]
pub fn finish<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: [F; 3],
    d: [F; 3],
    p: &CastParams,
    st: &Start<F>,
    stop: &Stop<F>,
) -> CastHit<F> {
    let one = F::one();
    let two = F::of(2.0);
    let Start {
        dir,
        coef,
        bias,
        octant,
        ..
    } = *st;
    let Stop {
        leaf,
        pos,
        scale,
        scale_exp2,
        t_min,
        parent,
        desc,
        idx,
        contour_hit,
        iters,
    } = *stop;
    // Entry times of the voxel's faces (its mirrored high corner).
    let tent = [0, 1, 2].map(|a| (pos[a] + scale_exp2) * coef[a] - bias[a]);
    let te = max3(tent);
    let mut normal = [0i8; 3];
    let mut entered = None;
    let a = (0..3).find(|&a| tent[a] == te).unwrap_or(0);
    if te >= t_min - entry_slack((pos[a] + scale_exp2) * coef[a]) {
        normal[a] = if dir[a] > F::zero() { -1 } else { 1 };
        entered = Some(a);
    }
    let level = (S_MAX - scale) as u32;
    let attr = if leaf {
        A::leaf_attr(nodes, parent, desc, (idx ^ octant) ^ 7)
    } else {
        u32::MAX
    };
    let shift_fine = depth.saturating_sub(level);
    let grid = F::exp2i(depth as i32 - 1);
    // Undo the mirroring to get the voxel's low corner in [1, 2).
    let lo_oct = [0, 1, 2].map(|a| {
        if octant >> a & 1 == 0 {
            F::of(3.0) - scale_exp2 - pos[a]
        } else {
            pos[a]
        }
    });
    // t from the entered face in world units, `(x - o_a) / d_a`: the same
    // plane as t_min, without the rounding of the large `bias` terms.
    let t = match entered {
        Some(a) if d[a] != F::zero() => {
            let face = if dir[a] > F::zero() {
                lo_oct[a]
            } else {
                lo_oct[a] + scale_exp2
            };
            let x = two * face - F::of(3.0);
            ((x - o[a]) / d[a]).max(F::of(p.near))
        }
        _ => t_min,
    };
    let t = contour_hit.map_or(t, |(tc, _)| tc);
    let hitp = [0, 1, 2].map(|a| o[a] + t * d[a]);
    let mut voxel = [0u32; 3];
    for a in 0..3 {
        let lo_oct = lo_oct[a];
        let box_idx = ((lo_oct - one) * F::exp2i(level as i32))
            .to_u64()
            .unwrap_or(0) as u32;
        let lo = box_idx << shift_fine;
        let hi = lo + (1u32 << shift_fine) - 1;
        voxel[a] = if entered == Some(a) {
            if dir[a] > F::zero() {
                lo
            } else {
                hi
            }
        } else {
            let g = ((hitp[a] + one) * grid).floor();
            let g = g.to_i64().unwrap_or(0).clamp(lo as i64, hi as i64);
            g as u32
        };
    }
    CastHit {
        hit: true,
        t,
        pos: hitp,
        voxel,
        normal,
        level,
        attr,
        contour: contour_hit.map_or(0, |(_, v)| v),
        iters,
        capped: false,
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::octree::{build, Octree};
    use crate::voxels::shape::{Shape, VoxelBox};

    fn tree(s: &Shape, depth: u32) -> Octree {
        build(s, depth, &MemBudget::fixed(1 << 30)).unwrap()
    }

    fn norm(v: [f64; 3]) -> [f64; 3] {
        let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / n)
    }

    #[test]
    fn bit_helpers_are_exact_powers_of_two() {
        assert_eq!(f32::exp2i(-23), 2f32.powi(-23));
        assert_eq!(f64::exp2i(-52), 2f64.powi(-52));
        assert_eq!(f64::exp2i(3), 8.0);
        assert_eq!(<f32 as CastReal>::from_bits(CastReal::bits(1.5f32)), 1.5);
    }

    #[test]
    fn axis_rays_hit_a_full_root_on_its_face_in_all_six_directions() {
        let t = tree(&Shape::Sphere { radius: 10.0 }, 4);
        let p = CastParams::default();
        for a in 0..3 {
            for s in [-1.0, 1.0] {
                let mut o = [0.1, -0.3, 0.55];
                o[a] = -3.0 * s;
                let mut d = [0.0; 3];
                d[a] = s;
                let h = cast::<f64>(&t.nodes, 4, o, d, &p);
                assert!(h.hit);
                assert_eq!(h.t, 2.0);
                let mut n = [0i8; 3];
                n[a] = -s as i8;
                assert_eq!(h.normal, n);
                assert_eq!(h.level, 1);
                assert_eq!(
                    h.voxel[a],
                    if s > 0.0 { 0 } else { 15 },
                    "{a} {s} {:?}",
                    h.voxel
                );
                let h32 = cast::<f32>(&t.nodes, 4, o.map(|x| x as f32), d.map(|x| x as f32), &p);
                assert_eq!(
                    (h32.hit, h32.t, h32.voxel, h32.normal),
                    (true, 2.0, h.voxel, h.normal)
                );
            }
        }
    }

    /// The one-leaf stop of an axis ray entering a full root (its children
    /// are leaves, so the loop stops at its first iteration), as the loop
    /// builds it.
    fn first_leaf_stop(nodes: &[u32], st: &Start<f32>) -> Stop<f32> {
        Stop {
            leaf: true,
            pos: st.pos,
            scale: S_MAX - 1,
            scale_exp2: 0.5,
            t_min: st.t_min,
            parent: 0,
            desc: nodes[0],
            idx: st.idx,
            contour_hit: None,
            iters: 1,
        }
    }

    #[test]
    fn finish_names_the_entered_face_when_t_min_is_a_rounding_above_it() {
        let t = tree(&Shape::Sphere { radius: 10.0 }, 4);
        let p = CastParams::default();
        let (o, d) = ([0.1f32, -0.3, -3.0], [0.0f32, 0.0, 1.0]);
        let st = start(o, d, &p).unwrap();
        let stop = first_leaf_stop(&t.nodes, &st);
        let whole = cast::<f32>(&t.nodes, 4, o, d, &p);
        let h = finish::<f32, Relative>(&t.nodes, 4, o, d, &p, &st, &stop);
        assert_eq!((h.hit, h.t, h.normal), (whole.hit, whole.t, whole.normal));
        assert_eq!(h.normal, [0, 0, -1]);
        // A driver that fuses the loop's multiply-add and not finish's puts
        // t_min a rounding above the recomputed entry time: same face.
        for ulps in 1..=4u32 {
            let up = f32::from_bits(stop.t_min.to_bits() + ulps);
            let h =
                finish::<f32, Relative>(&t.nodes, 4, o, d, &p, &st, &Stop { t_min: up, ..stop });
            assert_eq!(h.normal, [0, 0, -1], "t_min {ulps} ulps above");
        }
        // A ray that starts inside the voxel: no entered face.
        let inside = Stop {
            t_min: stop.t_min + 1e-3,
            ..stop
        };
        let h = finish::<f32, Relative>(&t.nodes, 4, o, d, &p, &st, &inside);
        assert_eq!(h.normal, [0, 0, 0]);
    }

    #[test]
    fn empty_trees_and_rays_beside_the_box_miss() {
        let e = tree(&Shape::Boxes { boxes: vec![] }, 3);
        let h = cast::<f32>(
            &e.nodes,
            3,
            [0.0, 0.0, 3.0],
            [0.0, 0.0, -1.0],
            &CastParams::default(),
        );
        assert!(!h.hit && h.t == -1.0);
        let f = tree(&Shape::Sphere { radius: 10.0 }, 3);
        let h = cast::<f64>(
            &f.nodes,
            3,
            [1.5, 0.0, 3.0],
            [0.0, 0.0, -1.0],
            &CastParams::default(),
        );
        assert!(!h.hit);
        let h = cast::<f64>(
            &f.nodes,
            3,
            [0.0, 0.0, 3.0],
            [0.0, 0.0, 1.0],
            &CastParams::default(),
        );
        assert!(!h.hit, "the box is behind the ray");
    }

    #[test]
    fn ray_starting_inside_a_solid_voxel_hits_at_near_with_no_normal() {
        let t = tree(&Shape::Sphere { radius: 0.8 }, 6);
        let d = norm([0.3, -0.2, 0.9]);
        let h = cast::<f64>(&t.nodes, 6, [0.01, 0.02, 0.03], d, &CastParams::default());
        assert!(h.hit);
        assert_eq!(h.t, 0.0);
        assert_eq!(h.normal, [0, 0, 0]);
        // (x + 1) * 32: 32.32, 32.64, 32.96.
        assert_eq!(h.voxel, [32, 32, 32]);
    }

    #[test]
    fn sphere_pole_ray_hits_the_top_voxel_layer() {
        let depth = 6;
        let t = tree(&Shape::Sphere { radius: 0.8 }, depth);
        let o = [0.5 / 32.0 - 1.0 + 32.0 / 32.0, 3.0, 0.5 / 32.0];
        let h = cast::<f64>(&t.nodes, depth, o, [0.0, -1.0, 0.0], &CastParams::default());
        assert!(h.hit);
        // Centre y of the top solid voxel: largest j with (2j+1-64)^2 + 1 + 1 <= (0.8*64)^2.
        let j = (0..64u32)
            .rev()
            .find(|&j| (2 * j as i64 + 1 - 64).pow(2) + 2 <= 2621)
            .unwrap();
        assert_eq!(h.voxel, [32, j, 32]);
        assert_eq!(h.normal, [0, 1, 0]);
        assert_eq!(h.t, 3.0 - (-1.0 + 2.0 * (j + 1) as f64 / 64.0));
    }

    #[test]
    fn lod_cut_stops_at_coarser_voxels_no_later_than_the_leaf() {
        let t = tree(&Shape::Sphere { radius: 0.8 }, 7);
        let o = [2.0, 1.5, 2.5];
        let d = norm([-2.0, -1.4, -2.6]);
        let fine = cast::<f32>(
            &t.nodes,
            7,
            o.map(|x| x as f32),
            d.map(|x| x as f32),
            &CastParams::default(),
        );
        let p = CastParams {
            lod: Some(Lod {
                orig_size: 0.0,
                dir_size: 0.1,
            }),
            ..CastParams::default()
        };
        let coarse = cast::<f32>(&t.nodes, 7, o.map(|x| x as f32), d.map(|x| x as f32), &p);
        assert!(fine.hit && coarse.hit);
        assert!(coarse.level < fine.level, "{} {}", coarse.level, fine.level);
        assert!(coarse.t <= fine.t);
        assert!(coarse.iters <= fine.iters);
    }

    #[test]
    fn iteration_cap_gives_up_as_a_flagged_miss() {
        let t = tree(&Shape::Sphere { radius: 0.8 }, 7);
        let p = CastParams {
            max_iter: 3,
            ..CastParams::default()
        };
        let h = cast::<f32>(&t.nodes, 7, [2.0, 1.5, 2.5], [-0.6, -0.45, -0.66], &p);
        assert!(!h.hit && h.capped && h.iters == 3);
    }

    #[test]
    fn far_pointer_trees_and_depth_17_points_are_found() {
        let depth = 17;
        let n = 1u32 << depth;
        let pts = [
            [5u32, 70_000, 3],
            [n - 1, n - 1, n - 1],
            [65_536, 65_535, 65_536],
        ];
        let mut boxes: Vec<VoxelBox> = pts.iter().map(|&p| VoxelBox { min: p, max: p }).collect();
        boxes.push(VoxelBox {
            min: [1000, 2000, 0],
            max: [1000, 2000, n - 1],
        });
        let t = tree(&Shape::Boxes { boxes }, depth);
        let w = 2.0 / n as f64;
        for p in pts {
            let c = p.map(|i| -1.0 + (i as f64 + 0.5) * w);
            let o = [c[0] + 0.3, c[1] + 0.2, 2.0];
            let d = norm([c[0] - o[0], c[1] - o[1], c[2] - o[2]]);
            let h = cast::<f64>(&t.nodes, depth, o, d, &CastParams::default());
            assert!(h.hit && h.voxel == p, "{p:?} {h:?}");
            assert!(h.attr < t.stats.leaves as u32);
        }
        // Along the line: a ray down the z axis of the line's voxel column.
        let c = [-1.0 + 1000.5 * w, -1.0 + 2000.5 * w];
        let h = cast::<f64>(
            &t.nodes,
            depth,
            [c[0], c[1], -2.0],
            [0.0, 0.0, 1.0],
            &CastParams::default(),
        );
        assert!(
            h.hit && h.voxel == [1000, 2000, 0] && h.t == 1.0 && h.normal == [0, 0, -1],
            "{h:?}"
        );
    }
}
