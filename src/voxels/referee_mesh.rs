//! Referee of the mesh voxelisation: the separating-axis test for a
//! triangle against a closed box (Akenine-Möller 2001), written from the
//! axes themselves (3 box normals, the triangle normal, the 9 cross
//! products of triangle edges with box axes), each interval projected
//! directly, in f64. It shares no code with [`super::voxelise`] (which
//! walks columns with 2D edge functions): only the placed triangles.
//!
//! [`gap`] is the largest separation over the axes, in voxel units along
//! unit axes: positive means disjoint, non-positive means overlapping.
//! Near zero the two methods may round differently, so the checks skip
//! voxels with `|gap| <= margin` and count them.

use crate::parallel::par_collect;

use super::mesh::Mesh;
use super::octree::Octree;

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

/// Largest separation of triangle `t` (voxel units) from the box
/// `[lo, lo + 1]` over the 13 axes (zero axes of degenerate triangles skipped).
pub fn gap(t: &[[f64; 3]; 3], lo: [f64; 3]) -> f64 {
    let c = lo.map(|x| x + 0.5);
    let e = [0, 1, 2].map(|i| [0, 1, 2].map(|a| t[(i + 1) % 3][a] - t[i][a]));
    let unit = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let mut axes = vec![unit[0], unit[1], unit[2], cross(e[0], e[1])];
    for ei in &e {
        for u in &unit {
            axes.push(cross(*ei, *u));
        }
    }
    let mut best = f64::NEG_INFINITY;
    for a in axes {
        let len = dot(a, a).sqrt();
        if len == 0.0 {
            continue;
        }
        let p = t.map(|v| dot(a, v));
        let (tmin, tmax) = (p[0].min(p[1]).min(p[2]), p[0].max(p[1]).max(p[2]));
        let r = 0.5 * (a[0].abs() + a[1].abs() + a[2].abs());
        let m = dot(a, c);
        best = best.max((tmin - (m + r)).max((m - r) - tmax) / len);
    }
    best
}

/// The triangle in voxel units of the depth-`depth` grid.
pub fn to_voxel_units(t: &[[f64; 3]; 3], depth: u32) -> [[f64; 3]; 3] {
    let half = (1u64 << depth) as f64 / 2.0;
    t.map(|v| v.map(|x| (x + 1.0) * half))
}

/// What [`check_triangles`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct TriangleCheck {
    pub triangles: u64,
    /// Voxels the referee says a checked triangle overlaps (beyond the margin).
    pub overlapped: u64,
    /// Of those, voxels the octree leaves empty.
    pub missing: u64,
    /// Voxels within the margin of touching (not judged).
    pub ties: u64,
}

/// Every `stride`-th triangle: every voxel of its bounding box that it
/// overlaps by more than `margin` must be solid in `tree`.
pub fn check_triangles(mesh: &Mesh, tree: &Octree, stride: usize, margin: f64) -> TriangleCheck {
    let n = 1i64 << tree.depth;
    let ids: Vec<usize> = (0..mesh.tris.len()).step_by(stride.max(1)).collect();
    let per = par_collect("voxels.referee_mesh_tris", ids.len(), |k| {
        let t = to_voxel_units(&mesh.tris[ids[k]], tree.depth);
        let mut r = TriangleCheck {
            triangles: 1,
            ..Default::default()
        };
        let lo = [0, 1, 2].map(|a| t.iter().map(|v| v[a]).fold(f64::INFINITY, f64::min));
        let hi = [0, 1, 2].map(|a| t.iter().map(|v| v[a]).fold(f64::NEG_INFINITY, f64::max));
        let cells = |a: usize| {
            (
                (lo[a].floor() as i64 - 1).max(0),
                (hi[a].floor() as i64 + 1).min(n - 1),
            )
        };
        let (x, y, z) = (cells(0), cells(1), cells(2));
        for i in x.0..=x.1 {
            for j in y.0..=y.1 {
                for k in z.0..=z.1 {
                    let g = gap(&t, [i as f64, j as f64, k as f64]);
                    if g.abs() <= margin {
                        r.ties += 1;
                    } else if g < 0.0 {
                        r.overlapped += 1;
                        r.missing += !tree.solid_at([i as u32, j as u32, k as u32]) as u64;
                    }
                }
            }
        }
        r
    });
    per.iter()
        .fold(TriangleCheck::default(), |a, b| TriangleCheck {
            triangles: a.triangles + b.triangles,
            overlapped: a.overlapped + b.overlapped,
            missing: a.missing + b.missing,
            ties: a.ties + b.ties,
        })
}

/// What [`check_voxels`] found.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct VoxelCheck {
    /// Finest-level solid voxels checked.
    pub voxels: u64,
    /// Solid voxels that no triangle overlaps or touches within the margin.
    pub untouched: u64,
    /// Solid voxels whose nearest triangle is within the margin (not judged).
    pub ties: u64,
}

/// Every finest-level voxel of every `stride`-th leaf of `tree` must be
/// overlapped by some triangle. Candidates come from a bucket grid of
/// `2^bucket_depth` cells per axis over the triangles' bounding boxes.
pub fn check_voxels(mesh: &Mesh, tree: &Octree, stride: usize, margin: f64) -> VoxelCheck {
    let depth = tree.depth;
    let bd = depth.min(6);
    let shift = depth - bd;
    let nb = 1usize << bd;
    let tris: Vec<[[f64; 3]; 3]> = mesh.tris.iter().map(|t| to_voxel_units(t, depth)).collect();
    let mut buckets: Vec<Vec<u32>> = vec![Vec::new(); nb * nb * nb];
    let cell = |x: f64| ((x.floor() as i64).clamp(0, (1i64 << depth) - 1) as usize) >> shift;
    for (id, t) in tris.iter().enumerate() {
        let lo =
            [0, 1, 2].map(|a| cell(t.iter().map(|v| v[a]).fold(f64::INFINITY, f64::min) - 1.0));
        let hi =
            [0, 1, 2].map(|a| cell(t.iter().map(|v| v[a]).fold(f64::NEG_INFINITY, f64::max) + 1.0));
        for i in lo[0]..=hi[0] {
            for j in lo[1]..=hi[1] {
                for k in lo[2]..=hi[2] {
                    buckets[i + nb * (j + nb * k)].push(id as u32);
                }
            }
        }
    }
    let leaves: Vec<(u32, [u32; 3])> = tree.leaves().into_iter().step_by(stride.max(1)).collect();
    let per = par_collect("voxels.referee_mesh_voxels", leaves.len(), |l| {
        let (level, lo) = leaves[l];
        let size = 1u32 << (depth - level);
        let mut r = VoxelCheck::default();
        for dx in 0..size {
            for dy in 0..size {
                for dz in 0..size {
                    let v = [lo[0] + dx, lo[1] + dy, lo[2] + dz];
                    let b = v.map(|x| (x >> shift) as usize);
                    let g = buckets[b[0] + nb * (b[1] + nb * b[2])]
                        .iter()
                        .map(|&id| gap(&tris[id as usize], v.map(|x| x as f64)))
                        .fold(f64::INFINITY, f64::min);
                    r.voxels += 1;
                    if g.abs() <= margin {
                        r.ties += 1;
                    } else if g > 0.0 {
                        r.untouched += 1;
                    }
                }
            }
        }
        r
    });
    per.iter().fold(VoxelCheck::default(), |a, b| VoxelCheck {
        voxels: a.voxels + b.voxels,
        untouched: a.untouched + b.untouched,
        ties: a.ties + b.ties,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const T: [[f64; 3]; 3] = [[0.2, 0.2, 0.5], [3.8, 0.2, 0.5], [0.2, 3.8, 0.5]];

    #[test]
    fn gap_is_the_distance_along_the_best_axis() {
        assert!(gap(&T, [0.0, 0.0, 0.0]) < 0.0);
        assert!((gap(&T, [0.0, 0.0, 1.5]) - 1.0).abs() < 1e-12);
        assert!((gap(&T, [0.0, 0.0, -1.5]) - 1.0).abs() < 1e-12);
        // Beyond the hypotenuse x + y = 4: the box (3, 3) corner is at 6.
        let g = gap(&T, [3.0, 3.0, 0.0]);
        assert!((g - 2.0 / 2f64.sqrt()).abs() < 1e-12, "{g}");
        // Touching at a corner: (2, 2) has corner sum 4.
        assert!(gap(&T, [2.0, 2.0, 0.0]).abs() < 1e-12);
    }

    #[test]
    fn a_segment_is_separated_only_by_its_cross_axes() {
        let seg = [[0.5, 0.5, 0.5], [2.5, 2.5, 0.5], [2.5, 2.5, 0.5]];
        assert!(gap(&seg, [1.0, 1.0, 0.0]) < 0.0);
        assert!(gap(&seg, [2.0, 0.0, 0.0]) > 0.0);
    }
}
