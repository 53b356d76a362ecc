//! Node order (issue 15, point 3: "cache-friendly node order, measured"):
//! a breadth-first copy of a [`Dag`]. The build places children blocks
//! bottom-up and packs them into shared slots ([`super::dag`]), so a node's
//! children can sit far from the node and from its siblings' children.
//! Here the blocks are laid out in the order a breadth-first walk from the
//! root discovers their nodes: the root's block first, then the blocks of
//! its children, and so on, each block taking the slots from its lowest to
//! its highest non-leaf child (no sharing), so the blocks of one level are
//! contiguous and in the order of their parents. Descriptors and
//! `leaves_below` are copied, child pointers remapped; nothing else changes,
//! so every cast through the copy gives the same outputs as through the
//! original (unit test below; `voxels.gpu_bench` measures the lane cast
//! through both in one run: `dag_bfs_*`).

use std::collections::{HashMap, VecDeque};

use super::dag::{Dag, DagStats};

/// The first slot a block may start at (a block's pointer is its first
/// slot minus its lowest child octant, so never below 0).
const FIRST_BLOCK: usize = 8;

/// The non-leaf child octants of the node at `slot` (bits 0..8 of its low word).
fn nonleaf(nodes: &[u32], slot: usize) -> u32 {
    nodes[2 * slot] & 0xFF
}

/// The copy being laid out: slots so far, old node slot -> new children
/// pointer, and the nodes whose block is placed but not yet filled (old
/// slot, new pointer).
struct Layout {
    nodes: Vec<u32>,
    leaves: Vec<u32>,
    placed: HashMap<usize, u32>,
    queue: VecDeque<(usize, u32)>,
}

impl Layout {
    /// The new children pointer of the old node at `slot`: its block is
    /// placed at the end on first sight (0 when it has no non-leaf child).
    fn place(&mut self, old: &[u32], slot: usize) -> u32 {
        let m = nonleaf(old, slot);
        if m == 0 {
            return 0;
        }
        if let Some(&ptr) = self.placed.get(&slot) {
            return ptr;
        }
        let (lo, hi) = (m.trailing_zeros() as usize, 31 - m.leading_zeros() as usize);
        let first = self.leaves.len();
        let ptr = (first - lo) as u32;
        self.nodes.resize(2 * (first + hi - lo + 1), 0);
        self.leaves.resize(first + hi - lo + 1, 0);
        self.placed.insert(slot, ptr);
        self.queue.push_back((slot, ptr));
        ptr
    }
}

/// The breadth-first copy of `dag` (see the module doc).
pub fn breadth_first(dag: &Dag) -> Dag {
    let old = &dag.nodes;
    let mut l = Layout {
        nodes: vec![0u32; 2 * FIRST_BLOCK],
        leaves: vec![0u32; FIRST_BLOCK],
        placed: HashMap::new(),
        queue: VecDeque::new(),
    };
    l.nodes[0] = old[0];
    l.nodes[1] = l.place(old, 0);
    l.leaves[0] = dag.leaves_below[0];
    while let Some((slot, ptr)) = l.queue.pop_front() {
        let (m, old_ptr) = (nonleaf(old, slot), old[2 * slot + 1] as usize);
        for c in (0..8).filter(|c| m >> c & 1 == 1) {
            let (from, to) = (old_ptr + c, ptr as usize + c);
            let kid_ptr = l.place(old, from);
            l.nodes[2 * to] = old[2 * from];
            l.nodes[2 * to + 1] = kid_ptr;
            l.leaves[to] = dag.leaves_below[from];
        }
    }
    let Layout { nodes, leaves, .. } = l;
    let slots = leaves.len() as u64;
    Dag {
        depth: dag.depth,
        nodes,
        leaves_below: leaves,
        stats: DagStats {
            slots,
            bytes: 8 * slots,
            ..dag.stats.clone()
        },
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::voxels::cast::{cast_dag, Absolute, CastHit, CastParams};
    use crate::voxels::cast_lanes::cast_lanes;
    use crate::voxels::dag::build_dag;
    use crate::voxels::fixtures::{incoherent_in, scenes};
    use crate::voxels::octree::build;
    use crate::voxels::shape::Shape;

    #[test]
    fn breadth_first_copy_casts_and_indexes_exactly_like_the_dag() {
        let budget = MemBudget::fixed(1 << 30);
        // The sphere and the sponge of the shared fixture list.
        for (s, depth) in scenes().into_iter().take(2) {
            let t = build(&s, depth, &budget).unwrap();
            let g = build_dag(&t, &budget).unwrap();
            let b = breadth_first(&g);
            assert_ne!(b.nodes, g.nodes, "{s:?}: the order changed");
            let (o, d) = incoherent_in::<f32>(4000, depth);
            let p = CastParams::default();
            let mut lanes = vec![CastHit::miss(0, false); o.len()];
            cast_lanes::<Absolute>(&b.nodes, depth, &o, &d, &p, None, &mut lanes);
            for i in 0..o.len() {
                let a = cast_dag::<f32>(&g.nodes, depth, o[i], d[i], &p);
                let c = cast_dag::<f32>(&b.nodes, depth, o[i], d[i], &p);
                assert_eq!(format!("{a:?}"), format!("{c:?}"), "{s:?} ray {i}");
                assert_eq!(format!("{a:?}"), format!("{:?}", lanes[i]), "{s:?} ray {i}");
            }
            let n = 1u32 << depth;
            for v in (0..n).step_by(3).map(|i| [i, (i * 7) % n, (i * 13) % n]) {
                assert_eq!(g.attr_index(v), b.attr_index(v), "{s:?} {v:?}");
                assert_eq!(g.solid_at(v), b.solid_at(v), "{s:?} {v:?}");
            }
        }
    }

    #[test]
    fn breadth_first_blocks_follow_their_parents_level_by_level() {
        let t = build(
            &Shape::Sphere { radius: 0.8 },
            6,
            &MemBudget::fixed(1 << 30),
        )
        .unwrap();
        let b = breadth_first(&build_dag(&t, &MemBudget::fixed(1 << 30)).unwrap());
        // Walk levels breadth-first: every block met starts after the one
        // before it (blocks are placed in discovery order).
        let mut level = vec![0usize];
        let mut last = 0u32;
        let mut seen = std::collections::HashSet::new();
        while !level.is_empty() {
            let mut next = vec![];
            for &s in &level {
                let ptr = b.nodes[2 * s + 1];
                let m = nonleaf(&b.nodes, s);
                if m == 0 || !seen.insert(ptr) {
                    continue;
                }
                let first = ptr + m.trailing_zeros();
                assert!(first > last, "slot {s}: block at {first} after {last}");
                last = first;
                next.extend((0..8).filter(|c| m >> c & 1 == 1).map(|c| ptr as usize + c));
            }
            level = next;
        }
    }
}
