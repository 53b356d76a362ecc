//! The ESVO node layout (Laine & Karras 2010) and the build that voxelises a
//! [`Shape`] into it by recursive classification of node boxes (no dense
//! grid: a solid ball costs memory for its surface only).
//!
//! # Layout
//!
//! `nodes` is one flat `u32` array of 64-bit *slots*, slot `s` being words
//! `2s` (low) and `2s + 1` (high); a WGSL kernel reads it as
//! `array<vec2<u32>>`. Slot 0 is the root's child descriptor. A child
//! descriptor is
//!
//! | word | bits | field |
//! | --- | --- | --- |
//! | low | 0..8 | non-leaf mask: bit c = 1 when child c has its own descriptor |
//! | low | 8..16 | valid mask: bit c = 1 when child c is not empty (solid leaf or node) |
//! | low | 16 | far bit: the child pointer names a far-pointer slot |
//! | low | 17..32 | child pointer (15 bits), relative, in slots |
//! | high | 0..32 | attribute base: index of the first leaf child's attribute |
//!
//! Child `c` (bit 0 = +x half, bit 1 = +y, bit 2 = +z) is empty when its
//! valid bit is 0, a solid leaf (a uniform solid cube, possibly coarser than
//! the finest level) when valid = 1 and non-leaf = 0, and an inner node when
//! both are 1 (non-leaf = 1 with valid = 0 never occurs). The non-leaf
//! children of a node have consecutive descriptors in child order, starting
//! at slot `p + ptr` for the node at slot `p`; when the far bit is set, slot
//! `p + ptr` is a far pointer instead, whose low word is the (unsigned,
//! 32-bit) distance in slots from `p` to the first child descriptor and
//! whose high word is 0. Child `c`'s descriptor is then the first plus
//! `popcount(non-leaf & ((1 << c) - 1))`. Leaf child `c`'s attribute index
//! is `base + popcount(leaf & ((1 << c) - 1))`, `leaf = valid & !non-leaf`;
//! indices run over all leaves in descriptor order, so they number the
//! leaves `0 .. leaves`.
//!
//! Serialisation: a node's children block (its non-leaf children's
//! descriptors, then the far-pointer slots the block needs) is followed by
//! the children's own subtrees in child order, so every pointer is forward.

use crate::budget::MemBudget;
use crate::error::{Error, Result};

use super::shape::{Class, Shape};

/// Largest relative child pointer that fits the 15-bit field.
pub const MAX_NEAR_PTR: u64 = (1 << 15) - 1;

/// Bytes the build needs per inner node at its peak (temporary tree 8,
/// subtree sizes 4, final descriptor 8), for the memory budget.
const BUILD_BYTES_PER_NODE: u64 = 20;

/// A sparse voxel octree over [-1, 1]^3 in the layout above.
#[derive(Clone, Debug, PartialEq)]
pub struct Octree {
    pub depth: u32,
    pub nodes: Vec<u32>,
    pub stats: BuildStats,
}

/// What the build produced.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct BuildStats {
    /// Child descriptors (inner nodes, the root included).
    pub descriptors: u64,
    /// Far-pointer slots.
    pub far_slots: u64,
    /// Solid leaves stored (each a valid, non-leaf = 0 child bit).
    pub leaves: u64,
    /// Solid finest-level voxels the tree represents.
    pub solid_voxels: u128,
    /// Bytes of `nodes`.
    pub bytes: u64,
    /// Wall-clock seconds of the build.
    pub build_s: f64,
}

impl BuildStats {
    /// Bytes per represented solid finest-level voxel (0 when there are none).
    pub fn bytes_per_voxel(&self) -> f64 {
        if self.solid_voxels == 0 {
            0.0
        } else {
            self.bytes as f64 / self.solid_voxels as f64
        }
    }
}

/// Fields of a child descriptor's low word.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Descriptor {
    pub nonleaf: u8,
    pub valid: u8,
    pub far: bool,
    pub ptr: u16,
    pub attr_base: u32,
}

impl Descriptor {
    pub fn pack(&self) -> [u32; 2] {
        debug_assert!(self.ptr as u64 <= MAX_NEAR_PTR);
        let lo = self.nonleaf as u32
            | (self.valid as u32) << 8
            | (self.far as u32) << 16
            | (self.ptr as u32) << 17;
        [lo, self.attr_base]
    }

    pub fn unpack(w: [u32; 2]) -> Descriptor {
        Descriptor {
            nonleaf: w[0] as u8,
            valid: (w[0] >> 8) as u8,
            far: w[0] & 0x1_0000 != 0,
            ptr: (w[0] >> 17) as u16,
            attr_base: w[1],
        }
    }
}

/// A node of the temporary tree: masks and the index of its first non-leaf
/// child in the temporary array (children of a node are consecutive and
/// stored before it).
#[derive(Clone, Copy, Debug, Default)]
struct Tmp {
    valid: u8,
    nonleaf: u8,
    first: u32,
}

struct Builder<'a> {
    shape: &'a Shape,
    depth: u32,
    tmp: Vec<Tmp>,
    max_nodes: u64,
    leaves: u64,
    solid: u128,
}

/// Result of building one child cube.
enum Built {
    Empty,
    Full,
    Node(Tmp),
}

impl Builder<'_> {
    /// Builds the node whose cube (at `level`, `size` voxels wide) has low
    /// corner `lo` and is known to be Mixed.
    fn node(&mut self, level: u32, lo: [u32; 3], size: u32) -> Result<Built> {
        let h = size / 2;
        let mut kids = [Tmp::default(); 8];
        let (mut nk, mut valid, mut nonleaf) = (0usize, 0u8, 0u8);
        let (mut full_leaves, mut leaf_voxels) = (0u32, 0u128);
        for c in 0..8u32 {
            let clo = [
                lo[0] + (c & 1) * h,
                lo[1] + (c >> 1 & 1) * h,
                lo[2] + (c >> 2 & 1) * h,
            ];
            let class = if level + 1 == self.depth {
                if self.shape.solid(self.depth, clo) {
                    Class::Full
                } else {
                    Class::Empty
                }
            } else {
                self.shape.classify(self.depth, clo, h)
            };
            let built = match class {
                Class::Empty => Built::Empty,
                Class::Full => Built::Full,
                Class::Mixed => self.node(level + 1, clo, h)?,
            };
            match built {
                Built::Empty => {}
                Built::Full => {
                    valid |= 1 << c;
                    full_leaves += 1;
                    leaf_voxels += 1u128 << (3 * (self.depth - level - 1));
                }
                Built::Node(t) => {
                    valid |= 1 << c;
                    nonleaf |= 1 << c;
                    kids[nk] = t;
                    nk += 1;
                }
            }
        }
        if valid == 0 {
            return Ok(Built::Empty);
        }
        if full_leaves == 8 {
            // Uniform solid: the parent stores one coarser leaf instead.
            return Ok(Built::Full);
        }
        self.leaves += full_leaves as u64;
        self.solid += leaf_voxels;
        let first = self.tmp.len() as u64;
        if (first + nk as u64) > self.max_nodes {
            return Err(Error::OutOfMemory {
                what: "voxel octree build".into(),
                needed: (first + nk as u64).saturating_mul(BUILD_BYTES_PER_NODE),
                budget: self.max_nodes.saturating_mul(BUILD_BYTES_PER_NODE),
            });
        }
        self.tmp.extend_from_slice(&kids[..nk]);
        Ok(Built::Node(Tmp {
            valid,
            nonleaf,
            first: first as u32,
        }))
    }
}

/// Number of far-pointer slots a children block needs, and the distance in
/// slots from each child's descriptor to its own children block. `sizes`
/// are the children's subtree sizes (slots after their descriptors).
fn block_plan(sizes: &[u32]) -> (u32, [u64; 8]) {
    let k = sizes.len() as u64;
    let mut nfar = 0u64;
    loop {
        let mut dist = [0u64; 8];
        let mut before = 0u64;
        let mut need = 0u64;
        for (i, &s) in sizes.iter().enumerate() {
            dist[i] = k - i as u64 + nfar + before;
            before += s as u64;
            need += (dist[i] > MAX_NEAR_PTR) as u64;
        }
        if need <= nfar {
            return (nfar as u32, dist);
        }
        nfar = need;
    }
}

/// Voxelises `shape` at `depth` into an ESVO octree. Refuses builds whose
/// node count would exceed `budget` (checked while the tree grows).
pub fn build(shape: &Shape, depth: u32, budget: &MemBudget) -> Result<Octree> {
    shape.validate(depth)?;
    let t0 = std::time::Instant::now();
    let size = 1u32 << depth;
    let mut b = Builder {
        shape,
        depth,
        tmp: Vec::new(),
        max_nodes: (budget.bytes / BUILD_BYTES_PER_NODE).min(u32::MAX as u64 / 2),
        leaves: 0,
        solid: 0,
    };
    let root = match shape.classify(depth, [0; 3], size) {
        Class::Empty => Built::Empty,
        Class::Full => Built::Full,
        Class::Mixed => b.node(0, [0; 3], size)?,
    };
    let root = match root {
        Built::Empty => Tmp::default(),
        Built::Full => {
            b.leaves = 8;
            b.solid = 1u128 << (3 * depth);
            Tmp {
                valid: 0xFF,
                nonleaf: 0,
                first: 0,
            }
        }
        Built::Node(t) => t,
    };
    // Subtree sizes, bottom-up: children sit before their parent in `tmp`.
    let mut sizes = vec![0u32; b.tmp.len() + 1];
    let node_size = |t: &Tmp, sizes: &[u32]| -> Result<u32> {
        let k = t.nonleaf.count_ones() as usize;
        let kid = &sizes[t.first as usize..t.first as usize + k];
        let (nfar, _) = block_plan(kid);
        let total = k as u64 + nfar as u64 + kid.iter().map(|&s| s as u64).sum::<u64>();
        u32::try_from(total).map_err(|_| Error::invalid("voxel octree", "more than 2^32 slots"))
    };
    for i in 0..b.tmp.len() {
        sizes[i] = node_size(&b.tmp[i], &sizes)?;
    }
    let root_size = node_size(&root, &sizes)? as u64;
    let slots = 1 + root_size;
    budget.check("voxel octree nodes", slots.checked_mul(8))?;
    let mut w = Writer {
        tmp: &b.tmp,
        sizes: &sizes,
        nodes: vec![0u32; 2 * slots as usize],
        attr: 0,
        far: 0,
    };
    w.write(&root, 0, 1, false, 1)?;
    let descriptors = slots - w.far;
    let stats = BuildStats {
        descriptors,
        far_slots: w.far,
        leaves: b.leaves,
        solid_voxels: b.solid,
        bytes: 8 * slots,
        build_s: t0.elapsed().as_secs_f64(),
    };
    debug_assert_eq!(w.attr as u64, b.leaves);
    Ok(Octree {
        depth,
        nodes: w.nodes,
        stats,
    })
}

struct Writer<'a> {
    tmp: &'a [Tmp],
    sizes: &'a [u32],
    nodes: Vec<u32>,
    attr: u32,
    far: u64,
}

impl Writer<'_> {
    /// Writes node `t`'s descriptor at slot `at` (pointer fields `far`,
    /// `ptr` chosen by the parent) and its subtree from slot `body`.
    #[allow(clippy::needless_range_loop)]
    fn write(&mut self, t: &Tmp, at: u64, body: u64, far: bool, ptr: u64) -> Result<()> {
        let k = t.nonleaf.count_ones() as usize;
        let d = Descriptor {
            nonleaf: t.nonleaf,
            valid: t.valid,
            far,
            ptr: if k == 0 { 0 } else { ptr as u16 },
            attr_base: self.attr,
        };
        self.attr += (t.valid & !t.nonleaf).count_ones();
        let [lo, hi] = d.pack();
        self.nodes[2 * at as usize] = lo;
        self.nodes[2 * at as usize + 1] = hi;
        if k == 0 {
            return Ok(());
        }
        let first = t.first as usize;
        let kid_sizes = &self.sizes[first..first + k];
        let (nfar, dist) = block_plan(kid_sizes);
        let mut far_used = 0u64;
        for i in 0..k {
            let slot = body + i as u64;
            let kid_body = slot + dist[i];
            let (kfar, kptr) = if dist[i] > MAX_NEAR_PTR {
                let fslot = body + k as u64 + far_used;
                far_used += 1;
                let rel = u32::try_from(dist[i])
                    .map_err(|_| Error::invalid("voxel octree", "far pointer over 2^32"))?;
                self.nodes[2 * fslot as usize] = rel;
                self.far += 1;
                (true, fslot - slot)
            } else {
                (false, dist[i])
            };
            let kid = self.tmp[first + i];
            self.write(&kid, slot, kid_body, kfar, kptr)?;
        }
        debug_assert_eq!(far_used, nfar as u64);
        Ok(())
    }
}

impl Octree {
    /// The descriptor at `slot`.
    pub fn descriptor(&self, slot: usize) -> Descriptor {
        Descriptor::unpack([self.nodes[2 * slot], self.nodes[2 * slot + 1]])
    }

    /// Slot of the first child descriptor of the node at `slot`.
    pub fn first_child(&self, slot: usize) -> usize {
        let d = self.descriptor(slot);
        if d.far {
            slot + self.nodes[2 * (slot + d.ptr as usize)] as usize
        } else {
            slot + d.ptr as usize
        }
    }

    /// Every stored leaf as (level, low-corner finest voxel), indexed by
    /// attribute index (pre-order: a node's own leaves, then its children's
    /// subtrees in child order).
    pub fn leaves(&self) -> Vec<(u32, [u32; 3])> {
        let mut out = Vec::with_capacity(self.stats.leaves as usize);
        let mut stack = vec![(0usize, 0u32, [0u32; 3])];
        while let Some((slot, level, lo)) = stack.pop() {
            let d = self.descriptor(slot);
            let h = 1u32 << (self.depth - level - 1);
            let corner = |c: u32| {
                [
                    lo[0] + (c & 1) * h,
                    lo[1] + (c >> 1 & 1) * h,
                    lo[2] + (c >> 2 & 1) * h,
                ]
            };
            let leaf = d.valid & !d.nonleaf;
            for c in 0..8 {
                if leaf >> c & 1 == 1 {
                    out.push((level + 1, corner(c)));
                }
            }
            if d.nonleaf != 0 {
                let first = self.first_child(slot);
                let mut k = d.nonleaf.count_ones() as usize;
                for c in (0..8).rev() {
                    if d.nonleaf >> c & 1 == 1 {
                        k -= 1;
                        stack.push((first + k, level + 1, corner(c)));
                    }
                }
            }
        }
        out
    }

    /// Point query by descending the tree: is finest voxel `v` solid? Walks
    /// the layout only (no traversal), for tests of the build.
    pub fn solid_at(&self, v: [u32; 3]) -> bool {
        let mut slot = 0usize;
        for level in (0..self.depth).rev() {
            let c = (v[0] >> level & 1) | (v[1] >> level & 1) << 1 | (v[2] >> level & 1) << 2;
            let d = self.descriptor(slot);
            if d.valid >> c & 1 == 0 {
                return false;
            }
            if d.nonleaf >> c & 1 == 0 {
                return true;
            }
            let below = (d.nonleaf as u32 & ((1 << c) - 1)).count_ones() as usize;
            slot = self.first_child(slot) + below;
        }
        true
    }

    /// Attribute index of the leaf containing finest voxel `v` (`None` when
    /// `v` is empty): the walk of [`Octree::solid_at`] reading `attr_base`.
    pub fn attr_index(&self, v: [u32; 3]) -> Option<u32> {
        let mut slot = 0usize;
        for level in (0..self.depth).rev() {
            let c = (v[0] >> level & 1) | (v[1] >> level & 1) << 1 | (v[2] >> level & 1) << 2;
            let d = self.descriptor(slot);
            if d.valid >> c & 1 == 0 {
                return None;
            }
            let below = (1u32 << c) - 1;
            if d.nonleaf >> c & 1 == 0 {
                let leaf = (d.valid & !d.nonleaf) as u32;
                return Some(d.attr_base + (leaf & below).count_ones());
            }
            slot = self.first_child(slot) + (d.nonleaf as u32 & below).count_ones() as usize;
        }
        None
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxels::shape::VoxelBox;

    fn big() -> MemBudget {
        MemBudget::fixed(1 << 30)
    }

    #[test]
    fn descriptor_bits_round_trip() {
        let d = Descriptor {
            nonleaf: 0b1010_0001,
            valid: 0b1110_0011,
            far: true,
            ptr: 0x7FFF,
            attr_base: 123456,
        };
        let w = d.pack();
        assert_eq!(w[0] & 0xFF, 0b1010_0001);
        assert_eq!(w[0] >> 8 & 0xFF, 0b1110_0011);
        assert_eq!(w[0] >> 16 & 1, 1);
        assert_eq!(w[0] >> 17, 0x7FFF);
        assert_eq!(Descriptor::unpack(w), d);
    }

    #[test]
    fn built_trees_answer_point_queries_like_the_predicate() {
        let shapes = [
            (Shape::Sphere { radius: 0.8 }, 5),
            (Shape::Menger { level: 3 }, 5),
            (
                Shape::Boxes {
                    boxes: vec![VoxelBox {
                        min: [1, 2, 3],
                        max: [1, 2, 30],
                    }],
                },
                5,
            ),
        ];
        for (s, depth) in &shapes {
            let t = build(s, *depth, &big()).unwrap();
            let n = 1u32 << depth;
            let mut solid = 0u128;
            for i in 0..n {
                for j in 0..n {
                    for k in 0..n {
                        assert_eq!(
                            t.solid_at([i, j, k]),
                            s.solid(*depth, [i, j, k]),
                            "{s:?} {i} {j} {k}"
                        );
                        solid += s.solid(*depth, [i, j, k]) as u128;
                    }
                }
            }
            assert_eq!(t.stats.solid_voxels, solid);
        }
    }

    #[test]
    fn uniform_subtrees_collapse_so_a_ball_stores_its_surface_only() {
        let t = build(&Shape::Sphere { radius: 0.8 }, 9, &big()).unwrap();
        // A 512^3 grid has 1.3e8 voxels; the ball's surface about 4 pi (0.8*256)^2 = 5.3e5.
        assert!(t.stats.descriptors < 400_000, "{:?}", t.stats);
        // (4/3) pi 0.8^3 / 8 of 512^3 = 3.6e7 solid voxels.
        assert!(
            t.stats.solid_voxels > 35_000_000 && t.stats.solid_voxels < 37_000_000,
            "{:?}",
            t.stats
        );
        // Budget that only fits the surface refuses nothing; a tiny one refuses.
        assert!(matches!(
            build(
                &Shape::Sphere { radius: 0.8 },
                9,
                &MemBudget::fixed(1 << 16)
            ),
            Err(Error::OutOfMemory { .. })
        ));
    }

    #[test]
    fn leaves_come_in_attribute_order_and_cover_the_solid_voxels() {
        let s = Shape::Sphere { radius: 0.8 };
        let t = build(&s, 5, &big()).unwrap();
        let leaves = t.leaves();
        assert_eq!(leaves.len() as u64, t.stats.leaves);
        let mut solid = 0u128;
        for (i, &(level, lo)) in leaves.iter().enumerate() {
            let size = 1u32 << (5 - level);
            solid += (size as u128).pow(3);
            assert!(t.solid_at(lo) && s.solid(5, lo), "{i} {lo:?}");
            // The attribute index the point walk finds is this leaf's, at
            // both corners of the leaf's cube.
            let hi = lo.map(|x| x + size - 1);
            assert_eq!(t.attr_index(lo), Some(i as u32));
            assert_eq!(t.attr_index(hi), Some(i as u32));
        }
        assert_eq!(solid, t.stats.solid_voxels);
    }

    #[test]
    fn empty_and_full_roots_are_single_descriptors() {
        let e = build(&Shape::Boxes { boxes: vec![] }, 4, &big()).unwrap();
        assert_eq!(e.nodes, vec![0, 0]);
        assert!(!e.solid_at([3, 3, 3]));
        let f = build(&Shape::Sphere { radius: 2.0 }, 4, &big()).unwrap();
        assert_eq!(f.descriptor(0).valid, 0xFF);
        assert_eq!(f.stats.solid_voxels, 4096);
        assert!(f.solid_at([0, 15, 7]));
    }

    #[test]
    fn far_pointers_appear_when_subtrees_are_large_and_stay_correct() {
        // Two far-apart lines at depth 14 make wide subtrees under the root.
        let mut boxes = vec![];
        for i in 0..40u32 {
            boxes.push(VoxelBox {
                min: [i * 397 % 16384, i * 211 % 16384, 0],
                max: [i * 397 % 16384, i * 211 % 16384, 16383],
            });
        }
        let s = Shape::Boxes { boxes };
        let t = build(&s, 14, &big()).unwrap();
        assert!(t.stats.far_slots > 0, "{:?}", t.stats);
        for i in 0..40u32 {
            let (x, y) = (i * 397 % 16384, i * 211 % 16384);
            for z in [0u32, 5000, 16383] {
                assert!(t.solid_at([x, y, z]));
                assert!(!t.solid_at([x ^ 1, y, z]) || s.solid(14, [x ^ 1, y, z]));
            }
        }
    }

    #[test]
    fn block_plan_adds_far_slots_only_when_needed() {
        assert_eq!(block_plan(&[10, 10]).0, 0);
        let (nfar, dist) = block_plan(&[40_000, 5, 5]);
        assert_eq!(nfar, 2);
        assert_eq!(dist[0], 3 + 2);
        assert_eq!(dist[1], 2 + 2 + 40_000);
    }
}
