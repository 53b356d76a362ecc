//! Referee for the DAG's node counts: the number of distinct non-uniform
//! aligned cubes per level, from the scene predicate alone (no octree, no
//! DAG code). An octree node at level `l` is exactly an aligned cube of
//! `2^(depth - l)` voxels per axis that is neither all empty nor all solid
//! (uniform cubes collapse into leaves or vanish), and two nodes of one level
//! have equal subtrees exactly when their cubes hold the same voxels, so a
//! DAG that merges equal subtrees level by level has, at each level, as many
//! nodes as there are distinct voxel contents among those cubes.
//!
//! Brute force over the dense grid: `depth * 8^depth` bit reads, for small
//! depths only (at most [`MAX_REFEREE_DEPTH`]).

use std::collections::HashSet;

use crate::error::{Error, Result};

use super::shape::Shape;

/// Deepest grid the referee accepts (2^21 voxels, 256 KiB of bits).
pub const MAX_REFEREE_DEPTH: u32 = 7;

/// Distinct non-uniform cube contents at levels `0 .. depth` (level 0 is
/// the whole grid). A level with none ends the list (no deeper nodes exist).
pub fn distinct_nodes_per_level(shape: &Shape, depth: u32) -> Result<Vec<u64>> {
    if depth > MAX_REFEREE_DEPTH {
        return Err(Error::invalid(
            "depth",
            format!("the DAG referee runs up to depth {MAX_REFEREE_DEPTH}, not {depth}"),
        ));
    }
    shape.validate(depth)?;
    let n = 1usize << depth;
    let solid: Vec<bool> = (0..n * n * n)
        .map(|i| {
            shape.solid(
                depth,
                [(i % n) as u32, (i / n % n) as u32, (i / (n * n)) as u32],
            )
        })
        .collect();
    let mut out = Vec::new();
    for level in 0..depth {
        let s = n >> level;
        let mut seen: HashSet<Vec<u64>> = HashSet::new();
        for cz in (0..n).step_by(s) {
            for cy in (0..n).step_by(s) {
                for cx in (0..n).step_by(s) {
                    let mut bits = vec![0u64; (s * s * s).div_ceil(64)];
                    let mut count = 0usize;
                    for z in 0..s {
                        for y in 0..s {
                            for x in 0..s {
                                if solid[(cx + x) + n * ((cy + y) + n * (cz + z))] {
                                    let b = x + s * (y + s * z);
                                    bits[b / 64] |= 1 << (b % 64);
                                    count += 1;
                                }
                            }
                        }
                    }
                    if count != 0 && count != s * s * s {
                        seen.insert(bits);
                    }
                }
            }
        }
        if seen.is_empty() {
            break;
        }
        out.push(seen.len() as u64);
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn menger_level_one_at_depth_two_has_the_counts_worked_by_hand() {
        // 4^3 grid, sponge in the low 3^3 (cells with at most one index equal
        // to 1). The root is mixed; its octants hold 4 (low corner), 3, 3, 3
        // (one index 2 or 3), 2, 2, 2 and 1 solid cells, the equal counts in
        // different orientations: eight distinct level-1 nodes.
        let c = distinct_nodes_per_level(&Shape::Menger { level: 1 }, 2).unwrap();
        assert_eq!(c, vec![1, 8]);
        // A full grid has no nodes; an empty one neither.
        assert!(distinct_nodes_per_level(&Shape::Sphere { radius: 5.0 }, 3)
            .unwrap()
            .is_empty());
        assert!(distinct_nodes_per_level(&Shape::Boxes { boxes: vec![] }, 3)
            .unwrap()
            .is_empty());
    }

    #[test]
    fn deep_grids_are_refused() {
        assert!(distinct_nodes_per_level(&Shape::Sphere { radius: 0.8 }, 8).is_err());
    }
}
