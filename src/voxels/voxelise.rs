//! Conservative surface voxelisation of a triangle mesh (SCENES.md: a voxel
//! is solid when a triangle overlaps its closed box), after Schwarz and
//! Seidel 2010: per triangle, in voxel units (`u = (x + 1) N / 2`, voxel
//! `(i, j, k)` = `[i, i + 1] x [j, j + 1] x [k, k + 1]`), walk the columns
//! of the triangle's bounding box along its dominant normal axis `w`; a
//! column whose square overlaps the triangle's projection on the other two
//! axes (three 2D edge functions with critical-corner offsets) gets the
//! `w` range the triangle's plane spans over the square, and each voxel in
//! it is kept when the triangle's projections on the two remaining
//! coordinate planes overlap the voxel's faces. Closed tests throughout.
//! Together these are the 13 separating axes (box normals by the bounding
//! box, the triangle normal by the plane range, the 9 edge-axis cross
//! products by the projections), so a voxel is kept exactly when no axis
//! separates it (up to rounding); the judge's referee
//! ([`super::referee_mesh`]) tests the axes directly instead.
//!
//! The result is the sorted list of solid voxels' Morton codes (bit `3b`
//! of the code is bit `b` of i, `3b + 1` of j, `3b + 2` of k: child octant
//! order), so an aligned cube is one contiguous code range and the octree
//! build classifies it by two binary searches. Each voxel also keeps the
//! sum of its triangles' area-weighted normals (the leaf normal for
//! attributes). Zero-area triangles have no plane: they are counted in
//! `degenerate` and voxelised as nothing.

use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::parallel::{par_collect, par_sort};

use super::mesh::Mesh;
use super::shape::MAX_DEPTH;

/// A mesh's solid voxels at one depth.
#[derive(Clone, PartialEq)]
pub struct MeshVoxels {
    pub depth: u32,
    /// Morton codes of the solid voxels, strictly increasing.
    pub codes: Vec<u64>,
    /// Per code: the sum of `(b - a) x (c - a)` (twice the area times the
    /// unit normal) of the triangles overlapping the voxel.
    pub normal_sum: Vec<[f32; 3]>,
    /// The placed mesh (world units), for referees and attributes.
    pub mesh: Mesh,
    /// Triangles with a zero cross product (voxelised as nothing).
    pub degenerate: u64,
    /// Seconds the voxelisation took.
    pub voxelise_s: f64,
}

impl std::fmt::Debug for MeshVoxels {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "MeshVoxels {{ depth: {}, triangles: {}, voxels: {} }}",
            self.depth,
            self.mesh.tris.len(),
            self.codes.len()
        )
    }
}

/// Interleaves the low 21 bits of i, j, k (i in bit 0).
pub fn morton(v: [u32; 3]) -> u64 {
    fn spread(x: u32) -> u64 {
        let mut x = x as u64 & 0x1F_FFFF;
        x = (x | x << 32) & 0x1F_0000_0000_FFFF;
        x = (x | x << 16) & 0x1F_0000_FF00_00FF;
        x = (x | x << 8) & 0x100F_00F0_0F00_F00F;
        x = (x | x << 4) & 0x10C3_0C30_C30C_30C3;
        x = (x | x << 2) & 0x1249_2492_4924_9249;
        x
    }
    spread(v[0]) | spread(v[1]) << 1 | spread(v[2]) << 2
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

/// The three edge functions of a triangle projected on axes (a, b): the
/// unit square `[x, x + 1] x [y, y + 1]` overlaps the projection iff
/// `e[0] x + e[1] y + e[2] >= 0` for all three (critical corner folded in).
fn edges_2d(p: &[[f64; 3]; 3], a: usize, b: usize, nw: f64) -> [[f64; 3]; 3] {
    let s = if nw < 0.0 { -1.0 } else { 1.0 };
    [0, 1, 2].map(|i| {
        let (v, w) = (p[i], p[(i + 1) % 3]);
        let ne = [-(w[b] - v[b]) * s, (w[a] - v[a]) * s];
        let d = -(ne[0] * v[a] + ne[1] * v[b]) + ne[0].max(0.0) + ne[1].max(0.0);
        [ne[0], ne[1], d]
    })
}

fn inside(e: &[[f64; 3]; 3], x: f64, y: f64) -> bool {
    e.iter().all(|f| f[0] * x + f[1] * y + f[2] >= 0.0)
}

/// Voxel index range `[lo, hi]` whose closed cells meet `[a, b]`, clamped to the grid.
fn cell_range(a: f64, b: f64, n: i64) -> (i64, i64) {
    (
        ((a.ceil() as i64) - 1).max(0),
        (b.floor() as i64).min(n - 1),
    )
}

/// Calls `f(voxel)` for every voxel of the depth-`depth` grid that the
/// triangle `t` (world units) overlaps; false for a zero-area triangle.
pub fn triangle_voxels(t: &[[f64; 3]; 3], depth: u32, mut f: impl FnMut([u32; 3])) -> bool {
    let n = 1i64 << depth;
    let half = n as f64 / 2.0;
    let p = t.map(|v| v.map(|x| (x + 1.0) * half));
    let nrm = cross(sub(p[1], p[0]), sub(p[2], p[0]));
    let w = (0..3)
        .max_by(|&a, &b| nrm[a].abs().total_cmp(&nrm[b].abs()))
        .unwrap_or(2);
    if nrm[w] == 0.0 {
        return false;
    }
    let (u, v) = ((w + 1) % 3, (w + 2) % 3);
    let lo = [0, 1, 2].map(|a| p.iter().map(|q| q[a]).fold(f64::INFINITY, f64::min));
    let hi = [0, 1, 2].map(|a| p.iter().map(|q| q[a]).fold(f64::NEG_INFINITY, f64::max));
    let r = [0, 1, 2].map(|a| cell_range(lo[a], hi[a], n));
    let e_uv = edges_2d(&p, u, v, nrm[w]);
    let e_vw = edges_2d(&p, v, w, nrm[u]);
    let e_wu = edges_2d(&p, w, u, nrm[v]);
    let dot0 = nrm[0] * p[0][0] + nrm[1] * p[0][1] + nrm[2] * p[0][2];
    for iu in r[u].0..=r[u].1 {
        for iv in r[v].0..=r[v].1 {
            let (x, y) = (iu as f64, iv as f64);
            if !inside(&e_uv, x, y) {
                continue;
            }
            let plane = |a: f64, b: f64| (dot0 - nrm[u] * a - nrm[v] * b) / nrm[w];
            let ws = [
                plane(x, y),
                plane(x + 1.0, y),
                plane(x, y + 1.0),
                plane(x + 1.0, y + 1.0),
            ];
            let wmin = ws.iter().copied().fold(f64::INFINITY, f64::min);
            let wmax = ws.iter().copied().fold(f64::NEG_INFINITY, f64::max);
            let (k0, k1) = cell_range(wmin, wmax, n);
            for iw in k0.max(r[w].0)..=k1.min(r[w].1) {
                let z = iw as f64;
                if inside(&e_vw, y, z) && inside(&e_wu, z, x) {
                    let mut c = [0u32; 3];
                    c[u] = iu as u32;
                    c[v] = iv as u32;
                    c[w] = iw as u32;
                    f(c);
                }
            }
        }
    }
    true
}

/// Voxelises the placed mesh at `depth` (see the module doc). The (code,
/// triangle) pairs are sorted in one `u64` each; refused when their count
/// bound (the triangles' bounding-box cells) is over `budget`.
pub fn voxelise(mesh: Mesh, depth: u32, budget: &MemBudget) -> Result<MeshVoxels> {
    if depth == 0 || depth > MAX_DEPTH {
        return Err(Error::invalid(
            "depth",
            format!("{depth} is not in 1..={MAX_DEPTH}"),
        ));
    }
    let t0 = std::time::Instant::now();
    let tri_bits = 64 - (mesh.tris.len().max(2) as u64 - 1).leading_zeros();
    if 3 * depth + tri_bits > 64 {
        return Err(Error::invalid(
            "depth",
            format!(
                "a mesh of {} triangles voxelises at depth <= {}",
                mesh.tris.len(),
                (64 - tri_bits) / 3
            ),
        ));
    }
    const CHUNK: usize = 512;
    let chunks = mesh.tris.len().div_ceil(CHUNK);
    let parts = par_collect("voxels.voxelise", chunks, |c| {
        let mut out = Vec::new();
        let mut degenerate = 0u64;
        for (k, t) in mesh.tris[c * CHUNK..((c + 1) * CHUNK).min(mesh.tris.len())]
            .iter()
            .enumerate()
        {
            let id = (c * CHUNK + k) as u64;
            if !triangle_voxels(t, depth, |v| out.push(morton(v) << tri_bits | id)) {
                degenerate += 1;
            }
        }
        (out, degenerate)
    });
    let total: u64 = parts.iter().map(|p| p.0.len() as u64).sum();
    budget.check("mesh voxelisation pairs", bytes_for(total, 8 + 8))?;
    let mut pairs = Vec::with_capacity(total as usize);
    let mut degenerate = 0;
    for (p, d) in parts {
        pairs.extend_from_slice(&p);
        degenerate += d;
    }
    par_sort("voxels.voxelise_sort", &mut pairs);
    let mut codes: Vec<u64> = Vec::new();
    let mut normal_sum: Vec<[f32; 3]> = Vec::new();
    let mask = (1u64 << tri_bits) - 1;
    let mut acc = [0.0f64; 3];
    for (i, &key) in pairs.iter().enumerate() {
        let t = &mesh.tris[(key & mask) as usize];
        let c = cross(sub(t[1], t[0]), sub(t[2], t[0]));
        acc = [0, 1, 2].map(|a| acc[a] + c[a]);
        let code = key >> tri_bits;
        if pairs
            .get(i + 1)
            .is_none_or(|&next| next >> tri_bits != code)
        {
            codes.push(code);
            normal_sum.push(acc.map(|x| x as f32));
            acc = [0.0; 3];
        }
    }
    Ok(MeshVoxels {
        depth,
        codes,
        normal_sum,
        mesh,
        degenerate,
        voxelise_s: t0.elapsed().as_secs_f64(),
    })
}

impl MeshVoxels {
    /// Index range in `codes` of the aligned cube of `size` voxels per axis
    /// (a power of two) with low corner `lo`.
    pub fn range(&self, lo: [u32; 3], size: u32) -> std::ops::Range<usize> {
        let a = morton(lo);
        let b = a + (size as u64).pow(3);
        self.codes.partition_point(|&c| c < a)..self.codes.partition_point(|&c| c < b)
    }

    /// Is voxel `v` solid?
    pub fn solid(&self, v: [u32; 3]) -> bool {
        self.codes.binary_search(&morton(v)).is_ok()
    }

    /// Normalised sum of the voxel normals in the cube (zero when none).
    pub fn normal(&self, lo: [u32; 3], size: u32) -> [f64; 3] {
        let mut s = [0.0f64; 3];
        for n in &self.normal_sum[self.range(lo, size)] {
            s = [0, 1, 2].map(|a| s[a] + n[a] as f64);
        }
        let l = (s[0] * s[0] + s[1] * s[1] + s[2] * s[2]).sqrt();
        if l > 0.0 {
            s.map(|x| x / l)
        } else {
            [0.0; 3]
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn morton_codes_interleave_i_j_k_from_bit_zero() {
        assert_eq!(morton([1, 0, 0]), 1);
        assert_eq!(morton([0, 1, 0]), 2);
        assert_eq!(morton([0, 0, 1]), 4);
        assert_eq!(morton([2, 0, 0]), 8);
        assert_eq!(morton([(1 << 21) - 1, 0, 0]), 0x1249_2492_4924_9249);
    }

    fn voxels_of(t: [[f64; 3]; 3], depth: u32) -> Vec<[u32; 3]> {
        let mut v = Vec::new();
        triangle_voxels(&t, depth, |c| v.push(c));
        v.sort();
        v
    }

    /// A triangle in the plane z = 0 (a voxel boundary) touches the closed
    /// voxels on both sides: k = 1 and k = 2 at depth 2 (z = 0 is u = 2).
    #[test]
    fn a_triangle_on_a_voxel_face_marks_both_sides() {
        let v = voxels_of([[-0.9, -0.9, 0.0], [0.9, -0.9, 0.0], [-0.9, 0.9, 0.0]], 2);
        assert!(v.iter().all(|c| c[2] == 1 || c[2] == 2));
        assert!(v.contains(&[0, 0, 1]) && v.contains(&[0, 0, 2]));
        // In voxel units the hypotenuse is x + y = 4: cell (2, 2) touches it
        // at its corner, cell (3, 3) (corner sum 6) is beyond it.
        assert!(!v.contains(&[3, 3, 1]) && !v.contains(&[2, 3, 1]));
        assert!(v.contains(&[2, 2, 1]) && v.contains(&[1, 2, 2]));
    }

    /// The glmark2-data bunny at depth 7 (skipped when the package is
    /// absent): the separating-axis referee finds no triangle-overlapped
    /// voxel left empty and no solid voxel that no triangle meets.
    #[test]
    fn the_bunny_voxelisation_agrees_with_the_sat_referee() {
        use crate::voxels::octree::build;
        use crate::voxels::referee_mesh::{check_triangles, check_voxels};
        use crate::voxels::shape::Shape;
        let path = std::path::Path::new("/usr/share/glmark2/models/bunny.obj");
        if !path.exists() {
            eprintln!(
                "skipped: {} absent (Debian package glmark2-data)",
                path.display()
            );
            return;
        }
        let mesh = Mesh::load(path).unwrap().placed().unwrap();
        let budget = MemBudget::fixed(1 << 30);
        let vs = std::sync::Arc::new(voxelise(mesh, 7, &budget).unwrap());
        let tree = build(&Shape::Mesh(vs.clone()), 7, &budget).unwrap();
        let t = check_triangles(&vs.mesh, &tree, 1, 1e-9);
        let v = check_voxels(&vs.mesh, &tree, 1, 1e-9);
        eprintln!("{vs:?} {t:?} {v:?} degenerate {}", vs.degenerate);
        assert_eq!((t.missing, v.untouched), (0, 0));
        assert!(t.overlapped > 1000 && v.voxels as usize >= vs.codes.len());
    }

    #[test]
    fn zero_area_triangles_are_reported() {
        assert!(!triangle_voxels(&[[0.0; 3], [0.5; 3], [1.0; 3]], 3, |_| {}));
    }

    #[test]
    fn cube_ranges_and_normals_come_from_the_sorted_codes() {
        let m = Mesh {
            tris: vec![[[-0.9, -0.9, 0.1], [0.9, -0.9, 0.1], [-0.9, 0.9, 0.1]]],
        };
        let vs = voxelise(m, 3, &MemBudget::fixed(1 << 30)).unwrap();
        assert!(vs.codes.windows(2).all(|w| w[0] < w[1]));
        assert!(vs.solid([0, 0, 4]) && !vs.solid([0, 0, 3]) && !vs.solid([7, 7, 4]));
        assert_eq!(vs.range([0, 0, 0], 8).len(), vs.codes.len());
        let low = (0..4u32)
            .flat_map(|i| (0..4u32).map(move |j| [i, j, 4]))
            .filter(|&v| vs.solid(v))
            .count();
        assert_eq!(vs.range([0, 0, 4], 4).len(), low);
        assert_eq!(vs.normal([0, 0, 4], 1), [0.0, 0.0, 1.0]);
        assert!(vs.range([0, 0, 0], 4).is_empty());
    }
}
