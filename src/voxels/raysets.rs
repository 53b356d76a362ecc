//! Test and benchmark ray sets besides camera rays, drawn with the SCENES.md
//! counter-based RNG (`rand(seed, ray, 0, dim)`), so every run and every
//! backend sees the same rays.
//!
//! - [`incoherent`]: origins uniform in [-1, 1]^3, directions uniform on the sphere.
//! - [`hard`]: the judge's hard rays, in kinds (see [`HardKind`]).

use crate::rng::rand_f64;

use super::shape::Shape;

/// A ray as (origin, unit direction) in f64.
pub type Ray64 = ([f64; 3], [f64; 3]);

fn unit_dir(seed: u32, i: u32, dim: u32) -> [f64; 3] {
    let z = 1.0 - 2.0 * rand_f64(seed, i, 0, dim);
    let r = (1.0 - z * z).max(0.0).sqrt();
    let ph = 2.0 * std::f64::consts::PI * rand_f64(seed, i, 0, dim + 1);
    [r * ph.cos(), r * ph.sin(), z]
}

/// `n` rays with origins uniform in the box and uniform directions.
pub fn incoherent(n: u32, seed: u32) -> Vec<Ray64> {
    (0..n)
        .map(|i| {
            (
                [0, 1, 2].map(|k| -1.0 + 2.0 * rand_f64(seed, i, 0, k)),
                unit_dir(seed, i, 3),
            )
        })
        .collect()
}

/// The kinds of hard rays, in the order [`hard`] emits them.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum HardKind {
    /// Axis-parallel, from outside the root, through voxel centres.
    AxisCentres,
    /// Axis-parallel exactly along voxel edges (both other coordinates on grid planes).
    AxisEdges,
    /// Axis-parallel in a voxel face plane (one other coordinate on a plane).
    AxisFaces,
    /// Diagonals through grid corners (all three crossings at one instant).
    Corners,
    /// Two-axis diagonals through grid edges.
    Edges,
    /// Starting inside a solid (or interesting) voxel, random direction.
    Inside,
    /// Starting outside the root, aimed at an interesting voxel's centre.
    Aimed,
    /// Axis-parallel, passing 1e-3 voxel widths outside the face of the last
    /// solid voxel found walking sideways from an interesting one.
    JustMissing,
}

pub const HARD_KINDS: [HardKind; 8] = [
    HardKind::AxisCentres,
    HardKind::AxisEdges,
    HardKind::AxisFaces,
    HardKind::Corners,
    HardKind::Edges,
    HardKind::Inside,
    HardKind::Aimed,
    HardKind::JustMissing,
];

/// Voxels worth aiming at: the boxes' corners for box scenes, else solid
/// voxels found by sampling the predicate (random voxels when none is found).
fn interesting(shape: &Shape, depth: u32, n: u32, seed: u32) -> Vec<[u32; 3]> {
    let g = 1u64 << depth;
    let pick =
        |i: u32, k: u32| ((rand_f64(seed ^ 0x5eed, i, 1, k) * g as f64) as u64).min(g - 1) as u32;
    if let Shape::Boxes { boxes } = shape {
        if !boxes.is_empty() {
            return (0..n as usize)
                .map(|i| {
                    let b = boxes[i % boxes.len()];
                    if (i / boxes.len()) % 2 == 0 {
                        b.min
                    } else {
                        b.max
                    }
                })
                .collect();
        }
    }
    (0..n)
        .map(|i| {
            let mut v = [pick(i, 0), pick(i, 1), pick(i, 2)];
            for tr in 0..64u32 {
                if shape.solid(depth, v) {
                    break;
                }
                v = [0, 1, 2].map(|k| pick(i, 3 + 3 * tr + k));
            }
            v
        })
        .collect()
}

/// `per_kind` rays of each [`HardKind`] for the depth-`depth` grid of `shape`.
pub fn hard(shape: &Shape, depth: u32, per_kind: u32, seed: u32) -> Vec<(Ray64, HardKind)> {
    let n = 1i64 << depth;
    let w = 2.0 / n as f64;
    let plane = |k: i64| -1.0 + k as f64 * w;
    let centre = |k: i64| -1.0 + (k as f64 + 0.5) * w;
    let u = |i: u32, k: u32| rand_f64(seed, i, 0, k);
    let cell = |i: u32, k: u32| ((u(i, k) * n as f64) as i64).min(n - 1);
    let spots = interesting(shape, depth, per_kind, seed);
    let mut out = Vec::new();
    for kind in HARD_KINDS {
        for i in 0..per_kind {
            let a = (i % 3) as usize;
            let s = if (i / 3) % 2 == 0 { 1.0 } else { -1.0 };
            let (b, c) = ((a + 1) % 3, (a + 2) % 3);
            let v = spots[i as usize].map(|x| x as i64);
            let ray = match kind {
                HardKind::AxisCentres | HardKind::AxisEdges | HardKind::AxisFaces => {
                    let mut o = [0.0; 3];
                    o[a] = -1.5 * s;
                    let on_b = kind != HardKind::AxisCentres;
                    let on_c = kind == HardKind::AxisEdges;
                    // Half the rays go through interesting voxels, half anywhere.
                    let (vb, vc) = if i % 2 == 0 {
                        (v[b], v[c])
                    } else {
                        (cell(i, 0), cell(i, 1))
                    };
                    o[b] = if on_b { plane(vb) } else { centre(vb) };
                    o[c] = if on_c { plane(vc) } else { centre(vc) };
                    let mut d = [0.0; 3];
                    d[a] = s;
                    (o, d)
                }
                HardKind::Corners => {
                    let g = if i % 2 == 0 {
                        v
                    } else {
                        [cell(i, 0), cell(i, 1), cell(i, 2)]
                    };
                    let sg = [0, 1, 2].map(|k| if u(i, 3 + k) < 0.5 { -1.0 } else { 1.0 });
                    let q = 1.0 / 3f64.sqrt();
                    (
                        [0, 1, 2].map(|k| plane(g[k]) - 1.5 * sg[k]),
                        sg.map(|x| x * q),
                    )
                }
                HardKind::Edges => {
                    let g = if i % 2 == 0 {
                        v
                    } else {
                        [cell(i, 0), cell(i, 1), cell(i, 2)]
                    };
                    let (sb, sc) = (
                        if u(i, 3) < 0.5 { -1.0 } else { 1.0 },
                        if u(i, 4) < 0.5 { -1.0 } else { 1.0 },
                    );
                    let q = 1.0 / 2f64.sqrt();
                    let mut o = [0.0; 3];
                    let mut d = [0.0; 3];
                    o[a] = centre(g[a]);
                    o[b] = plane(g[b]) - 1.5 * sb;
                    o[c] = plane(g[c]) - 1.5 * sc;
                    d[b] = sb * q;
                    d[c] = sc * q;
                    (o, d)
                }
                HardKind::Inside => {
                    let o = [0, 1, 2].map(|k| plane(v[k]) + w * u(i, k as u32));
                    (o, unit_dir(seed, i, 3))
                }
                HardKind::Aimed => {
                    let from = unit_dir(seed, i, 0).map(|x| 2.5 * x);
                    let t = v.map(centre);
                    let d = [0, 1, 2].map(|k| t[k] - from[k]);
                    let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                    (from, d.map(|x| x / l))
                }
                HardKind::JustMissing => {
                    let mut o = [0.0; 3];
                    o[a] = -1.5 * s;
                    let side = if u(i, 0) < 0.5 { -1i64 } else { 1 };
                    // Walk from the voxel towards `side` along b to the last
                    // solid one, so the ray grazes a face with empty space beyond.
                    let mut e = v;
                    for _ in 0..n {
                        let mut next = e;
                        next[b] += side;
                        let inside = (0..n).contains(&next[b]);
                        if !inside || !shape.solid(depth, next.map(|x| x as u32)) {
                            break;
                        }
                        e = next;
                    }
                    o[b] = centre(e[b]) + side as f64 * (0.5 + 1e-3) * w;
                    o[c] = centre(e[c]);
                    let mut d = [0.0; 3];
                    d[a] = s;
                    (o, d)
                }
            };
            out.push((ray, kind));
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ray_sets_are_unit_deterministic_and_in_range() {
        let a = incoherent(100, 7);
        assert_eq!(a, incoherent(100, 7));
        for (o, d) in &a {
            assert!(o.iter().all(|x| (-1.0..1.0).contains(x)));
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12);
        }
        let h = hard(&Shape::Sphere { radius: 0.8 }, 6, 10, 1);
        assert_eq!(h.len(), 80);
        for ((_, d), _) in &h {
            assert!(((d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt() - 1.0).abs() < 1e-12);
        }
    }
}
