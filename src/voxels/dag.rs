//! The sparse voxel DAG (seed 001): the octree with identical subtrees
//! merged, in the same 8-byte ESVO descriptors but with *absolute* child
//! addresses, cast by the same Laine–Karras loop ([`super::cast::cast_dag`]).
//!
//! # Build
//!
//! Bottom-up from an [`Octree`], level by level (deepest first): a node's key
//! is its valid and non-leaf masks plus the ids already given to its
//! non-leaf children. Keys go into a hash map whose lookups compare the full
//! key after the hash matches, so two nodes merge only when they are equal
//! (same masks, children already merged into the same ids): equal keys at
//! one level are exactly equal subtrees. Ids are per level; a node is never
//! merged with one of another level. The build is sequential and its output
//! depends on the octree alone (node counts are reproducible).
//!
//! # Layout
//!
//! `nodes` is a flat `u32` array of 64-bit slots like the octree's (slot `s`
//! = words `2s`, `2s + 1`; a WGSL kernel reads `array<vec2<u32>>`). Slot 0
//! is the root's descriptor. Every unique node with at least one non-leaf
//! child has a *children block* address `childPtr`: child octant `c` (bit 0
//! = +x, bit 1 = +y, bit 2 = +z) has its descriptor at slot `childPtr + c`
//! when `c` is a non-leaf child. Empty and solid-leaf children need no
//! descriptor (the parent's masks say what they are), so the slots
//! `childPtr + c` of those octants are never read through this node, and
//! blocks overlap. Blocks are placed bottom-up (deepest level first, so a
//! block's descriptors, with their own children's addresses, are known):
//! at an address where every slot it needs is free or already holds the very
//! descriptor it needs (the slots are then shared), found first among the
//! addresses that reuse a slot holding one of its descriptors, else first
//! fit from the lowest free slot (but no lower than 64 slots below the end).
//! Slots no block uses are zero. So child `c` is at `childPtr + c`, with no
//! popcount, and `nodes` holds at most one slot per DAG edge. A descriptor is
//!
//! | word | bits | field |
//! | --- | --- | --- |
//! | low | 0..8 | non-leaf mask (as the octree) |
//! | low | 8..16 | valid mask (as the octree) |
//! | low | 16 | far bit: always 0 (no far pointers: the pointer is 32 bits) |
//! | low | 17..32 | always 0 |
//! | high | 0..32 | childPtr: absolute slot of the node's children block (0 when it has no non-leaf child) |
//!
//! The octree's high word (attribute base) has no meaning in a DAG, whose
//! shared nodes stand for leaves with different attributes; it carries the
//! 32-bit pointer instead. A leaf's attribute index (the octree's
//! numbering: pre-order, a node's own leaves before its children's) comes
//! from [`Dag::attr_index`], a root-to-leaf walk over `leaves_below`, one
//! `u32` per slot: the number of octree leaves in the subtree of the
//! descriptor in that slot.

use std::collections::HashMap;

use crate::budget::MemBudget;
use crate::error::{Error, Result};

use super::octree::{Descriptor, Octree};

/// A sparse voxel DAG in the layout above.
#[derive(Clone, Debug, PartialEq)]
pub struct Dag {
    pub depth: u32,
    pub nodes: Vec<u32>,
    /// Octree leaves below the descriptor in each slot (0 for empty slots).
    pub leaves_below: Vec<u32>,
    pub stats: DagStats,
}

/// What the DAG build produced.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DagStats {
    /// Unique nodes per level (level 0 is the root).
    pub nodes_per_level: Vec<u64>,
    /// Unique nodes in all.
    pub nodes: u64,
    /// Slots of `nodes` (the root's and the packed children blocks').
    pub slots: u64,
    /// Bytes of `nodes` (8 per slot); `leaves_below` adds 4 per slot.
    pub bytes: u64,
    /// Wall-clock seconds of the build (from the octree).
    pub build_s: f64,
}

/// A node's identity for merging: masks and the ids of its non-leaf
/// children (`u32::MAX` for the others).
#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash)]
struct Key {
    valid: u8,
    nonleaf: u8,
    kids: [u32; 8],
}

/// How far below the end of the slots the first-fit search starts at the
/// latest: older holes stay empty, so a placement costs O(window).
const PACK_WINDOW: usize = 64;

/// Placement of children blocks (see the module doc): `slots[s]` is the
/// descriptor (low word | high word << 32) in slot `s`, 0 when free; slot 0
/// (the root) is reserved.
struct Packer {
    slots: Vec<u64>,
    leaves: Vec<u32>,
    /// Where each descriptor value was last written.
    at: HashMap<u64, usize>,
    /// No free slot below this one.
    first_free: usize,
}

impl Default for Packer {
    fn default() -> Self {
        Packer {
            slots: vec![u64::MAX],
            leaves: vec![0],
            at: HashMap::new(),
            first_free: 1,
        }
    }
}

impl Packer {
    /// Whether a block at `a` can hold `want` (octant, descriptor): each of
    /// its slots is free or already holds that very descriptor.
    fn fits(&self, a: usize, want: &[(usize, u64, u32)]) -> bool {
        a >= 1
            && want
                .iter()
                .all(|&(c, w, _)| self.slots.get(a + c).is_none_or(|&x| x == 0 || x == w))
    }

    /// Places a block holding descriptor `w` (with `leaves` below it) at
    /// octant `c` for each `(c, w, leaves)` of `want`, sharing slots that
    /// already hold the same descriptors where it can, else first fit.
    /// Returns the block address.
    fn place(&mut self, want: &[(usize, u64, u32)]) -> Result<u32> {
        let shared = want.iter().find_map(|&(c, w, _)| {
            let s = *self.at.get(&w)?;
            let a = s.checked_sub(c)?;
            self.fits(a, want).then_some(a)
        });
        let a = match shared {
            Some(a) => a,
            None => {
                let low = want.first().map_or(0, |x| x.0);
                let mut a = self
                    .first_free
                    .saturating_sub(low)
                    .max(self.slots.len().saturating_sub(PACK_WINDOW));
                while !self.fits(a, want) {
                    a += 1;
                }
                a
            }
        };
        for &(c, w, l) in want {
            let s = a + c;
            if self.slots.len() <= s {
                self.slots.resize(s + 1, 0);
                self.leaves.resize(s + 1, 0);
            }
            self.slots[s] = w;
            self.leaves[s] = l;
            self.at.insert(w, s);
        }
        while self.first_free < self.slots.len() && self.slots[self.first_free] != 0 {
            self.first_free += 1;
        }
        u32::try_from(a).map_err(|_| Error::invalid("voxel DAG", "more than 2^32 slots"))
    }
}

/// Bytes the build needs per octree descriptor (slot lists and ids).
const BUILD_BYTES_PER_DESCRIPTOR: u64 = 12;

/// Octree descriptor slots per level, breadth-first (children in order).
fn octree_levels(t: &Octree) -> Vec<Vec<u32>> {
    let mut levels = vec![vec![0u32]];
    loop {
        let mut next = Vec::new();
        for &s in levels.last().map(|v| v.as_slice()).unwrap_or(&[]) {
            let d = t.descriptor(s as usize);
            if d.nonleaf == 0 {
                continue;
            }
            let first = t.first_child(s as usize) as u32;
            next.extend(first..first + d.nonleaf.count_ones());
        }
        if next.is_empty() {
            return levels;
        }
        levels.push(next);
    }
}

/// Builds the DAG of `tree` (see the module doc).
pub fn build_dag(tree: &Octree, budget: &MemBudget) -> Result<Dag> {
    let t0 = std::time::Instant::now();
    let slots = tree.nodes.len() / 2;
    budget.check(
        "voxel DAG build",
        (slots as u64).checked_mul(BUILD_BYTES_PER_DESCRIPTOR),
    )?;
    let levels = octree_levels(tree);
    // id of each octree descriptor slot within its level.
    let mut id = vec![u32::MAX; slots];
    // Per level: unique keys in id order, and each unique node's leaf count.
    let mut uniq: Vec<Vec<Key>> = vec![Vec::new(); levels.len()];
    let mut leaves: Vec<Vec<u64>> = vec![Vec::new(); levels.len()];
    for l in (0..levels.len()).rev() {
        let mut map: HashMap<Key, u32> = HashMap::new();
        for &s in &levels[l] {
            let d = tree.descriptor(s as usize);
            let mut key = Key {
                valid: d.valid,
                nonleaf: d.nonleaf,
                kids: [u32::MAX; 8],
            };
            let mut below = (d.valid & !d.nonleaf).count_ones() as u64;
            if d.nonleaf != 0 {
                let mut k = tree.first_child(s as usize);
                for c in 0..8 {
                    if d.nonleaf >> c & 1 == 1 {
                        let kid = id[k];
                        key.kids[c] = kid;
                        below += leaves[l + 1][kid as usize];
                        k += 1;
                    }
                }
            }
            let next = uniq[l].len() as u32;
            let got = *map.entry(key).or_insert(next);
            if got == next {
                uniq[l].push(key);
                leaves[l].push(below);
            }
            id[s as usize] = got;
        }
    }
    drop(id);
    let nodes_per_level: Vec<u64> = uniq.iter().map(|u| u.len() as u64).collect();
    let desc = |k: &Key, ptr: u32| -> u64 {
        let [lo, _] = Descriptor {
            nonleaf: k.nonleaf,
            valid: k.valid,
            far: false,
            ptr: 0,
            attr_base: 0,
        }
        .pack();
        lo as u64 | (ptr as u64) << 32
    };
    let count =
        |n: u64| u32::try_from(n).map_err(|_| Error::invalid("voxel DAG", "more than 2^32 leaves"));
    // Blocks bottom-up, so a block's descriptors (with their own children's
    // addresses) are known when it is placed.
    let mut packer = Packer::default();
    let mut block: Vec<Vec<u32>> = vec![Vec::new(); uniq.len()];
    for l in (0..uniq.len()).rev() {
        let mut b = Vec::with_capacity(uniq[l].len());
        for k in &uniq[l] {
            let mut want = Vec::with_capacity(8);
            for c in 0..8 {
                let kid = k.kids[c] as usize;
                if k.kids[c] != u32::MAX {
                    let w = desc(&uniq[l + 1][kid], block[l + 1][kid]);
                    want.push((c, w, count(leaves[l + 1][kid])?));
                }
            }
            b.push(if want.is_empty() {
                0
            } else {
                packer.place(&want)?
            });
        }
        block[l] = b;
    }
    let nslots = packer.slots.len() as u64;
    budget.check("voxel DAG nodes", nslots.checked_mul(12))?;
    if let Some(root) = uniq.first().and_then(|u| u.first()) {
        packer.slots[0] = desc(root, block[0][0]);
        packer.leaves[0] = count(leaves[0][0])?;
    }
    let nodes: Vec<u32> = packer
        .slots
        .iter()
        .flat_map(|&w| [w as u32, (w >> 32) as u32])
        .collect();
    let leaves_below = packer.leaves;
    let stats = DagStats {
        nodes: nodes_per_level.iter().sum(),
        nodes_per_level,
        slots: nslots,
        bytes: 8 * nslots,
        build_s: t0.elapsed().as_secs_f64(),
    };
    Ok(Dag {
        depth: tree.depth,
        nodes,
        leaves_below,
        stats,
    })
}

impl Dag {
    /// Masks of the descriptor at `slot`: (valid, non-leaf).
    fn masks(&self, slot: usize) -> (u8, u8) {
        let lo = self.nodes[2 * slot];
        ((lo >> 8) as u8, lo as u8)
    }

    /// The octree attribute index of the leaf containing finest voxel `v`
    /// (`None` when `v` is empty): a root-to-leaf walk summing the leaves
    /// that come before it in the octree's pre-order.
    pub fn attr_index(&self, v: [u32; 3]) -> Option<u32> {
        let mut slot = 0usize;
        let mut base = 0u32;
        for level in (0..self.depth).rev() {
            let c = (v[0] >> level & 1) | (v[1] >> level & 1) << 1 | (v[2] >> level & 1) << 2;
            let (valid, nonleaf) = self.masks(slot);
            let leaf = valid & !nonleaf;
            if valid >> c & 1 == 0 {
                return None;
            }
            let below = (1u32 << c) - 1;
            if nonleaf >> c & 1 == 0 {
                return Some(base + (leaf as u32 & below).count_ones());
            }
            let block = self.nodes[2 * slot + 1] as usize;
            base += leaf.count_ones();
            for k in 0..c as usize {
                if nonleaf >> k & 1 == 1 {
                    base += self.leaves_below[block + k];
                }
            }
            slot = block + c as usize;
        }
        None
    }

    /// Point query: is finest voxel `v` solid? (Walks the layout, for tests.)
    pub fn solid_at(&self, v: [u32; 3]) -> bool {
        let mut slot = 0usize;
        for level in (0..self.depth).rev() {
            let c = (v[0] >> level & 1) | (v[1] >> level & 1) << 1 | (v[2] >> level & 1) << 2;
            let (valid, nonleaf) = self.masks(slot);
            if valid >> c & 1 == 0 {
                return false;
            }
            if nonleaf >> c & 1 == 0 {
                return true;
            }
            slot = self.nodes[2 * slot + 1] as usize + c as usize;
        }
        true
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxels::octree::build;
    use crate::voxels::shape::{Shape, VoxelBox};

    fn big() -> MemBudget {
        MemBudget::fixed(1 << 30)
    }

    /// The octree's leaf attribute index at voxel `v`, by its own layout.
    fn octree_attr(t: &Octree, v: [u32; 3]) -> Option<u32> {
        let mut slot = 0usize;
        for level in (0..t.depth).rev() {
            let c = (v[0] >> level & 1) | (v[1] >> level & 1) << 1 | (v[2] >> level & 1) << 2;
            let d = t.descriptor(slot);
            if d.valid >> c & 1 == 0 {
                return None;
            }
            if d.nonleaf >> c & 1 == 0 {
                let leaf = (d.valid & !d.nonleaf) as u32;
                return Some(d.attr_base + (leaf & ((1 << c) - 1)).count_ones());
            }
            let below = (d.nonleaf as u32 & ((1 << c) - 1)).count_ones() as usize;
            slot = t.first_child(slot) + below;
        }
        None
    }

    #[test]
    fn dag_answers_point_queries_and_attribute_indices_like_the_octree() {
        let shapes = [
            (Shape::Sphere { radius: 0.8 }, 5),
            (Shape::Menger { level: 3 }, 5),
            (
                Shape::Boxes {
                    boxes: vec![
                        VoxelBox {
                            min: [1, 2, 3],
                            max: [1, 2, 30],
                        },
                        VoxelBox {
                            min: [17, 2, 3],
                            max: [17, 2, 30],
                        },
                    ],
                },
                5,
            ),
        ];
        for (s, depth) in &shapes {
            let t = build(s, *depth, &big()).unwrap();
            let g = build_dag(&t, &big()).unwrap();
            let n = 1u32 << depth;
            for i in 0..n {
                for j in 0..n {
                    for k in 0..n {
                        let v = [i, j, k];
                        assert_eq!(g.solid_at(v), t.solid_at(v), "{s:?} {v:?}");
                        assert_eq!(g.attr_index(v), octree_attr(&t, v), "{s:?} {v:?}");
                    }
                }
            }
            assert_eq!(g.leaves_below[0] as u64, t.stats.leaves);
        }
    }

    #[test]
    fn menger_sponge_shrinks_and_the_far_bit_is_never_set() {
        let t = build(&Shape::Menger { level: 4 }, 7, &big()).unwrap();
        let g = build_dag(&t, &big()).unwrap();
        assert!(
            g.stats.slots * 3 < t.stats.descriptors,
            "{:?} {:?}",
            g.stats,
            t.stats
        );
        assert!((0..g.nodes.len() / 2).all(|s| g.nodes[2 * s] >> 16 == 0));
        assert_eq!(g.stats.nodes_per_level[0], 1);
    }

    #[test]
    fn packed_blocks_keep_every_read_slot_and_share_equal_ones() {
        let mut p = Packer::default();
        let blocks: [&[(usize, u64, u32)]; 5] = [
            &[(0, 11, 1), (7, 12, 1)],
            &[(0, 13, 1)],
            &[
                (0, 1, 1),
                (1, 2, 1),
                (2, 3, 1),
                (3, 4, 1),
                (4, 5, 1),
                (5, 6, 1),
                (6, 7, 1),
                (7, 8, 1),
            ],
            &[(6, 14, 1)],
            &[(1, 3, 1), (2, 4, 1)],
        ];
        for b in blocks {
            let a = p.place(b).unwrap() as usize;
            assert!(a >= 1);
            for &(c, w, _) in b {
                assert_eq!(p.slots[a + c], w, "block {b:?} at {a}");
            }
        }
        // The last block reuses the slots of descriptors 3 and 4.
        assert_eq!(p.slots.iter().filter(|&&w| w == 3 || w == 4).count(), 2);
    }

    #[test]
    fn equal_subtrees_merge_and_different_ones_do_not() {
        // Two identical single voxels in different octants share every node
        // below the root; a third one at another position inside its
        // parent does not share the finest node.
        let p = |v: [u32; 3]| VoxelBox { min: v, max: v };
        let t = build(
            &Shape::Boxes {
                boxes: vec![p([1, 1, 1]), p([9, 1, 1])],
            },
            4,
            &big(),
        )
        .unwrap();
        let g = build_dag(&t, &big()).unwrap();
        assert_eq!(g.stats.nodes_per_level, vec![1, 1, 1, 1]);
        let t = build(
            &Shape::Boxes {
                boxes: vec![p([1, 1, 1]), p([8, 1, 1])],
            },
            4,
            &big(),
        )
        .unwrap();
        let g = build_dag(&t, &big()).unwrap();
        assert_eq!(g.stats.nodes_per_level, vec![1, 2, 2, 2]);
    }
}
