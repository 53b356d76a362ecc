//! The voxel scenes' defining predicates (SCENES.md "Sparse voxels") and the
//! exact or conservative classification of a cube of voxels that the octree
//! build recurses on.
//!
//! At depth `d` the grid has `N = 2^d` voxels per axis; voxel `(i, j, k)`
//! covers `[-1 + 2i/N, -1 + 2(i+1)/N]` in x (y with j, z with k). The
//! predicate [`Shape::solid`] is the scene's definition; the build and the DDA
//! referee both evaluate it, the referee per voxel, the build only at the
//! finest level of boxes that [`Shape::classify`] cannot decide.

use std::sync::Arc;

use crate::error::{Error, Result};

use super::voxelise::MeshVoxels;

/// Largest octree depth: voxel corners are exact in the cast's f32 octree
/// coordinates `[1, 2)` (23 mantissa bits) only up to depth 22.
pub const MAX_DEPTH: u32 = 22;

/// An inclusive box of voxel indices `min ..= max` on each axis.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct VoxelBox {
    pub min: [u32; 3],
    pub max: [u32; 3],
}

/// A voxel scene, as a predicate over voxel indices.
#[derive(Clone, Debug, PartialEq)]
pub enum Shape {
    /// Solid ball of `radius` about the origin, by the centre-inside test:
    /// with `a = 2i + 1 - N` (likewise b, c; the centre is `a / N`), voxel
    /// (i, j, k) is solid iff `a^2 + b^2 + c^2 <= (radius N)^2`, the left side
    /// an exact integer, the right side `radius * N` (exact) squared in f64.
    Sphere { radius: f64 },
    /// Level-`level` Menger sponge in the grid's low corner: solid iff all of
    /// i, j, k are below `3^level` and at no base-3 digit position do two or
    /// more of them have the digit 1.
    Menger { level: u32 },
    /// The union of voxel boxes (points, lines, slabs): sparse content at any depth.
    Boxes { boxes: Vec<VoxelBox> },
    /// A triangle mesh's conservative surface voxelisation at its depth
    /// ([`super::voxelise`]): solid iff some triangle meets the closed box.
    Mesh(Arc<MeshVoxels>),
}

/// What a cube of voxels holds.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Class {
    Empty,
    Full,
    /// Not known to be uniform (it may still be; the build then collapses it).
    Mixed,
}

fn pow3(l: u32) -> u64 {
    3u64.pow(l)
}

/// Whether some index in `lo ..= hi` has base-3 digit `p` equal to 1 (`all`
/// false), or every index does (`all` true). `unit = 3^p`.
fn digit_one(lo: u64, hi: u64, unit: u64, all: bool) -> bool {
    let (qa, qb) = (lo / unit, hi / unit);
    if all {
        return qa == qb && qa % 3 == 1;
    }
    qb - qa >= 3 || (qa..=qb).any(|q| q % 3 == 1)
}

impl Shape {
    /// Checks the parameters against the depth.
    pub fn validate(&self, depth: u32) -> Result<()> {
        if depth == 0 || depth > MAX_DEPTH {
            return Err(Error::invalid(
                "depth",
                format!("{depth} is not in 1..={MAX_DEPTH}"),
            ));
        }
        let n = 1u64 << depth;
        match self {
            Shape::Sphere { radius } => {
                if !(radius.is_finite() && *radius >= 0.0) {
                    return Err(Error::invalid(
                        "shape.radius",
                        format!("{radius} is not a finite non-negative number"),
                    ));
                }
            }
            Shape::Menger { level } => {
                if *level > 14 || pow3(*level) > n {
                    return Err(Error::invalid(
                        "shape.level",
                        format!("3^{level} voxels do not fit a depth-{depth} grid of {n} voxels per axis"),
                    ));
                }
            }
            Shape::Mesh(m) => {
                if m.depth != depth {
                    return Err(Error::invalid(
                        "depth",
                        format!("the mesh was voxelised at depth {}, not {depth}", m.depth),
                    ));
                }
            }
            Shape::Boxes { boxes } => {
                for (i, b) in boxes.iter().enumerate() {
                    if (0..3).any(|a| b.min[a] > b.max[a] || b.max[a] as u64 >= n) {
                        return Err(Error::invalid(
                            format!("shape.boxes[{i}]"),
                            format!("{b:?} needs min <= max < {n} on every axis"),
                        ));
                    }
                }
            }
        }
        Ok(())
    }

    /// The defining predicate: is voxel `v` of the depth-`depth` grid solid?
    /// Indices at or beyond `2^depth` are empty.
    pub fn solid(&self, depth: u32, v: [u32; 3]) -> bool {
        let n = 1u64 << depth;
        if v.iter().any(|&x| x as u64 >= n) {
            return false;
        }
        match self {
            Shape::Sphere { radius } => {
                let s: u64 = v
                    .iter()
                    .map(|&x| (2 * x as i64 + 1 - n as i64).unsigned_abs().pow(2))
                    .sum();
                let r = radius * n as f64;
                (s as f64) <= r * r
            }
            Shape::Menger { level } => {
                let m = pow3(*level);
                if v.iter().any(|&x| x as u64 >= m) {
                    return false;
                }
                let mut w = v.map(|x| x as u64);
                for _ in 0..*level {
                    if w.iter().filter(|&&x| x % 3 == 1).count() >= 2 {
                        return false;
                    }
                    w = w.map(|x| x / 3);
                }
                true
            }
            Shape::Boxes { boxes } => boxes
                .iter()
                .any(|b| (0..3).all(|a| b.min[a] <= v[a] && v[a] <= b.max[a])),
            Shape::Mesh(m) => m.solid(v),
        }
    }

    /// Classifies the cube of `size` voxels per axis whose low corner is
    /// voxel `lo`. Exact (never Mixed for a uniform cube) for the sphere and meshes;
    /// Full exact and Empty conservative for the sponge and boxes.
    pub fn classify(&self, depth: u32, lo: [u32; 3], size: u32) -> Class {
        let n = 1u64 << depth;
        let lo64 = lo.map(|x| x as u64);
        let hi64 = lo64.map(|x| x + size as u64 - 1);
        match self {
            Shape::Mesh(m) => {
                let k = m.range(lo, size).len() as u64;
                if k == 0 {
                    Class::Empty
                } else if k == (size as u64).pow(3) {
                    Class::Full
                } else {
                    Class::Mixed
                }
            }
            Shape::Sphere { radius } => {
                let (mut smin, mut smax) = (0u64, 0u64);
                for a in 0..3 {
                    let ca = 2 * lo64[a] as i64 + 1 - n as i64;
                    let cb = 2 * hi64[a] as i64 + 1 - n as i64;
                    let (qa, qb) = (ca.unsigned_abs().pow(2), cb.unsigned_abs().pow(2));
                    smax += qa.max(qb);
                    smin += if ca < 0 && cb > 0 { 1 } else { qa.min(qb) };
                }
                let r = radius * n as f64;
                if (smax as f64) <= r * r {
                    Class::Full
                } else if (smin as f64) > r * r {
                    Class::Empty
                } else {
                    Class::Mixed
                }
            }
            Shape::Menger { level } => {
                let m = pow3(*level);
                if lo64.iter().any(|&x| x >= m) {
                    return Class::Empty;
                }
                let hic = hi64.map(|x| x.min(m - 1));
                let mut unit = 1u64;
                let mut full = hi64.iter().all(|&x| x < m);
                for _ in 0..*level {
                    let all1 = (0..3)
                        .filter(|&a| digit_one(lo64[a], hic[a], unit, true))
                        .count();
                    if all1 >= 2 {
                        return Class::Empty;
                    }
                    let some1 = (0..3)
                        .filter(|&a| digit_one(lo64[a], hic[a], unit, false))
                        .count();
                    full &= some1 <= 1;
                    unit *= 3;
                }
                if full {
                    Class::Full
                } else {
                    Class::Mixed
                }
            }
            Shape::Boxes { boxes } => {
                let mut any = false;
                for b in boxes {
                    let meets =
                        (0..3).all(|a| b.min[a] as u64 <= hi64[a] && lo64[a] <= b.max[a] as u64);
                    let covers =
                        (0..3).all(|a| b.min[a] as u64 <= lo64[a] && hi64[a] <= b.max[a] as u64);
                    if covers {
                        return Class::Full;
                    }
                    any |= meets;
                }
                if any {
                    Class::Mixed
                } else {
                    Class::Empty
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn brute(shape: &Shape, depth: u32, lo: [u32; 3], size: u32) -> (bool, bool) {
        let (mut any, mut all) = (false, true);
        for i in 0..size {
            for j in 0..size {
                for k in 0..size {
                    let s = shape.solid(depth, [lo[0] + i, lo[1] + j, lo[2] + k]);
                    any |= s;
                    all &= s;
                }
            }
        }
        (any, all)
    }

    /// Every cube of every size agrees with the voxel-by-voxel truth: Full
    /// only when all voxels are solid, Empty only when none is (and for the
    /// sphere, Mixed only when neither).
    #[test]
    fn classification_never_contradicts_the_predicate() {
        let shapes = [
            (Shape::Sphere { radius: 0.8 }, 5),
            (Shape::Menger { level: 3 }, 5),
            (
                Shape::Boxes {
                    boxes: vec![VoxelBox {
                        min: [3, 4, 5],
                        max: [3, 4, 20],
                    }],
                },
                5,
            ),
        ];
        for (shape, depth) in &shapes {
            let mut size = 1u32 << depth;
            while size >= 1 {
                for i in (0..1u32 << depth).step_by(size as usize) {
                    for j in (0..1u32 << depth).step_by(size as usize) {
                        for k in (0..1u32 << depth).step_by(size as usize) {
                            let (any, all) = brute(shape, *depth, [i, j, k], size);
                            let c = shape.classify(*depth, [i, j, k], size);
                            match c {
                                Class::Full => assert!(all, "{shape:?} {i} {j} {k} {size}"),
                                Class::Empty => assert!(!any, "{shape:?} {i} {j} {k} {size}"),
                                Class::Mixed => {
                                    if matches!(shape, Shape::Sphere { .. }) {
                                        assert!(any && !all, "sphere classification is exact")
                                    }
                                }
                            }
                        }
                    }
                }
                size /= 2;
            }
        }
    }

    #[test]
    fn menger_level_one_has_twenty_cubes() {
        let s = Shape::Menger { level: 1 };
        let count = (0..27u32)
            .filter(|x| s.solid(2, [x % 3, x / 3 % 3, x / 9]))
            .count();
        assert_eq!(count, 20);
        assert!(!s.solid(2, [1, 1, 0]) && s.solid(2, [1, 0, 0]) && !s.solid(2, [3, 0, 0]));
    }

    #[test]
    fn sphere_centre_test_matches_float_distance() {
        let s = Shape::Sphere { radius: 0.8 };
        let d = 6;
        let n = 64.0;
        for i in 0..64u32 {
            for j in [0u32, 20, 31, 32, 50] {
                let c = |x: u32| -1.0 + (2.0 * x as f64 + 1.0) / n;
                let r2 = c(i) * c(i) + c(j) * c(j) + c(7) * c(7);
                assert_eq!(s.solid(d, [i, j, 7]), r2 <= 0.64, "{i} {j}");
            }
        }
    }

    #[test]
    fn bad_parameters_are_refused() {
        assert!(Shape::Menger { level: 6 }.validate(9).is_err());
        assert!(Shape::Menger { level: 6 }.validate(10).is_ok());
        assert!(Shape::Sphere { radius: f64::NAN }.validate(4).is_err());
        assert!(Shape::Sphere { radius: 0.8 }.validate(23).is_err());
        let b = VoxelBox {
            min: [0, 0, 0],
            max: [16, 0, 0],
        };
        assert!(Shape::Boxes { boxes: vec![b] }.validate(4).is_err());
    }
}
