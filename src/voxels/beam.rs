//! The beam pre-pass (Laine & Karras 2010, "beam optimization"), made
//! conservative: each run of [`RUN`] consecutive rays that share one origin
//! (a row segment of a camera image) is bounded by the narrowest cone about
//! their mean direction ([`Cone::around`]); a walk of the tree finds the
//! smallest distance from the origin to a non-empty node box that meets the
//! cone ([`start_distance`]), and each ray's cast starts there
//! ([`beam_params`]) instead of at `near`.
//!
//! Why the start never passes a hit: a ray's hit point lies in a solid
//! leaf, so inside a non-empty node at every level above it, and inside the
//! cone (the ray is in it); so some box the walk accepts contains it, and
//! its distance from the origin, `t |d|`, is at least that box's distance.
//! The walk prunes only boxes that are empty, miss the cone (bounding-sphere
//! test) or lie farther than the best box found. The start is pulled back
//! by [`MARGIN`] (relative) and by a bound on the rounding of the cast's
//! plane times ([`plane_time_error`]), so the cast begins strictly in the
//! empty space before its first solid voxel even as its own f32 arithmetic
//! sees it, and it then makes the same decisions as the cast from `near`
//! from that voxel on: same `hit`, `t`, `leaf`, `normal` (bit for bit;
//! fewer iterations). Runs with differing origins,
//! wider cones than [`MAX_HALF_ANGLE`], or an LOD cut (whose stop voxel
//! need not hold solid at the ray) are cast from `near` unchanged.
//! Referee: the per-ray cast (`voxel_beam_*` cases, unit tests below).

use crate::parallel::par_collect;
use crate::real::Real;

use super::cast::{cast_with, Addressing, CastHit, CastParams, CastReal};
use super::hits::collect;
use super::render::VoxelHits;

/// Rays per beam.
pub const RUN: usize = 16;

/// Relative pull-back of each start distance.
pub const MARGIN: f64 = 1e-5;

/// Cones wider than this (radians) are not walked: the bound would be poor.
pub const MAX_HALF_ANGLE: f64 = 0.5;

/// A cone from `o` about the unit `axis` with half-angle `half`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    pub o: [f64; 3],
    pub axis: [f64; 3],
    pub half: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let l = dot(v, v).sqrt();
    (l > 0.0 && l.is_finite()).then(|| v.map(|x| x / l))
}

impl Cone {
    /// The cone about the rays' mean direction holding every ray `(o[i], d[i])`,
    /// or `None` when the origins differ, a direction is zero, or the
    /// half-angle passes [`MAX_HALF_ANGLE`].
    pub fn around<F: Real>(o: &[[F; 3]], d: &[[F; 3]]) -> Option<Cone> {
        let o0 = o.first()?.map(|x| x.f64());
        if o.iter().any(|x| x.map(|v| v.f64()) != o0) {
            return None;
        }
        let dn = d
            .iter()
            .map(|v| unit(v.map(|x| x.f64())))
            .collect::<Option<Vec<_>>>()?;
        let sum = dn
            .iter()
            .fold([0.0; 3], |s, v| [0, 1, 2].map(|a| s[a] + v[a]));
        let axis = unit(sum)?;
        let half = dn
            .iter()
            .map(|v| dot(*v, axis).clamp(-1.0, 1.0).acos())
            .fold(0.0, f64::max)
            + 1e-9;
        (half <= MAX_HALF_ANGLE).then_some(Cone { o: o0, axis, half })
    }

    /// Whether the box `[lo, hi]` may meet the cone (exact for its bounding
    /// sphere, so never a false `false`).
    pub fn meets(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        let v = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]) - self.o[a]);
        let e = [0, 1, 2].map(|a| hi[a] - lo[a]);
        let r = 0.5 * dot(e, e).sqrt();
        let l = dot(v, v).sqrt();
        if l <= r {
            return true;
        }
        let ang = (dot(v, self.axis) / l).clamp(-1.0, 1.0).acos();
        ang <= self.half + (r / l).asin() + 1e-9
    }
}

/// Euclidean distance from `o` to the box `[lo, hi]` (0 inside).
pub fn box_distance(o: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    let g = [0, 1, 2].map(|a| (lo[a] - o[a]).max(o[a] - hi[a]).max(0.0));
    dot(g, g).sqrt()
}

/// The smallest distance from the cone's origin to a non-empty box of the
/// tree `nodes` (addressing `A`, depth `depth`) that meets the cone, walked
/// down to boxes no wider than the cone there (or solid leaves), nearest
/// child first, pruning boxes no nearer than the best so far. `f64::INFINITY`
/// when no non-empty box meets the cone.
pub fn start_distance<A: Addressing>(nodes: &[u32], depth: u32, cone: &Cone) -> f64 {
    let n = (1u64 << depth) as f64;
    let world = |x: u64| -1.0 + 2.0 * x as f64 / n;
    let tan = cone.half.tan();
    let mut best = f64::INFINITY;
    // (distance, slot, level, low corner in finest voxels)
    let mut stack = vec![(0.0, 0usize, 0u32, [0u64; 3])];
    let mut kids = Vec::with_capacity(8);
    while let Some((dist, slot, level, lo)) = stack.pop() {
        if dist >= best {
            continue;
        }
        let desc = nodes[2 * slot];
        let (nonleaf, valid) = (desc & 0xFF, desc >> 8 & 0xFF);
        let h = 1u64 << (depth - level - 1);
        kids.clear();
        for c in 0..8u32 {
            if valid >> c & 1 == 0 {
                continue;
            }
            let clo = [0, 1, 2].map(|a| lo[a] + (c as u64 >> a & 1) * h);
            let wlo = clo.map(world);
            let whi = clo.map(|x| world(x + h));
            if !cone.meets(wlo, whi) {
                continue;
            }
            let dist = box_distance(cone.o, wlo, whi);
            if dist >= best {
                continue;
            }
            let size = 2.0 * h as f64 / n;
            let fine = size <= 2.0 * dist * tan;
            if nonleaf >> c & 1 == 0 || fine || level + 1 >= depth {
                best = dist;
            } else {
                let child = A::child(nodes, slot, desc, desc << (7 - c), c);
                kids.push((dist, child, level + 1, clo));
            }
        }
        // Nearest child on top of the stack.
        kids.sort_by(|a, b| b.0.total_cmp(&a.0));
        stack.extend_from_slice(&kids);
    }
    best
}

/// `p` with `near` raised to the start of ray `(o, d)` for a run whose start
/// distance is `dist`: pulled back by [`MARGIN`] and by [`plane_time_error`]
/// (so the cast's own rounded plane times cannot put the start past the
/// hit voxel's entry); `p` itself when that is not beyond `near`.
pub fn beam_params<F: CastReal>(p: &CastParams, o: [F; 3], d: [F; 3], dist: f64) -> CastParams {
    let len = dot(d.map(|x| x.f64()), d.map(|x| x.f64())).sqrt();
    let s = dist / len * (1.0 - MARGIN) - plane_time_error(o, d);
    if s.is_finite() && s > p.near {
        CastParams { near: s, ..*p }
    } else {
        *p
    }
}

/// A bound on the rounding error of the cast's plane times for ray `(o, d)`
/// in precision `F`: each is `x * coef_a - bias_a` with `x` in [1, 2],
/// `coef_a = 1 / |dir_a|` (`dir = d / 2`, clamped to `2^EPS_LOG2` as the cast
/// does) and `|bias_a| <= coef_a (|o_a / 2 + 1.5| + 3)`, three roundings of
/// half an ulp each: at most `2^EPS_LOG2 * 2 coef_a (|o_a / 2 + 1.5| + 5)`,
/// doubled here for margin. A grazing axis (tiny `dir_a`) makes it large and
/// the start falls back to `near`.
pub fn plane_time_error<F: CastReal>(o: [F; 3], d: [F; 3]) -> f64 {
    let eps = 2f64.powi(F::EPS_LOG2);
    (0..3)
        .map(|a| {
            let dir = (0.5 * d[a].f64().abs()).max(eps);
            4.0 * eps / dir * ((0.5 * o[a].f64() + 1.5).abs() + 5.0)
        })
        .fold(0.0, f64::max)
}

/// The start distance of each run of `RUN` rays (`None`: cast from `near`).
pub fn run_starts<F: Real, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> Vec<Option<f64>> {
    par_collect("voxels.beam_starts", o.len().div_ceil(RUN), |k| {
        let r = k * RUN..((k + 1) * RUN).min(o.len());
        if p.lod.is_some() {
            return None;
        }
        let cone = Cone::around(&o[r.clone()], &d[r])?;
        Some(start_distance::<A>(nodes, depth, &cone))
    })
}

/// Every ray cast from its run's beam start by the SSE cast (f32) or the
/// per-ray loop (other precisions): `hit`, `t`, `leaf`, `normal` identical
/// to the per-ray cast from `near`, fewer `iters`.
pub fn cast_all_beam<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    let starts = run_starts::<F, A>(nodes, depth, o, d, p);
    let res: Vec<CastHit<F>> = par_collect("voxels.cast_beam", o.len(), |i| {
        let q = match starts[i / RUN] {
            Some(dist) => beam_params(p, o[i], d[i], dist),
            None => *p,
        };
        F::cast_sse::<A>(nodes, depth, o[i], d[i], &q)
            .unwrap_or_else(|| cast_with::<F, A>(nodes, depth, o[i], d[i], &q, None))
    });
    collect(res)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::camera::Camera;
    use crate::rays::RayGen;
    use crate::voxels::batch::Batch;
    use crate::voxels::cast::{Absolute, Relative};
    use crate::voxels::dag::build_dag;
    use crate::voxels::octree::build;
    use crate::voxels::raysets::incoherent;
    use crate::voxels::render::{cast_all, cast_all_dag};
    use crate::voxels::shape::Shape;

    fn camera_rays<F: Real>(size: u32) -> Batch<F> {
        let cam =
            Camera::pinhole_look_at([2.0, 1.5, 2.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, size, size)
                .unwrap();
        let gen = RayGen::new(size, size);
        Batch::camera(&cam, &gen, &MemBudget::fixed(1 << 30)).unwrap()
    }

    fn same_but_iters<F: CastReal>(a: &VoxelHits<F>, b: &VoxelHits<F>) {
        assert_eq!(a.hit, b.hit);
        assert_eq!(a.leaf, b.leaf);
        for i in 0..a.t.len() {
            assert_eq!(a.t[i].bits(), b.t[i].bits(), "ray {i}");
            assert_eq!(a.normal[i].map(|x| x.bits()), b.normal[i].map(|x| x.bits()));
        }
    }

    fn bound_holds<F: CastReal>(s: &Shape, depth: u32) {
        let t = build(s, depth, &MemBudget::fixed(1 << 30)).unwrap();
        let b = camera_rays::<F>(96);
        let p = b.params(None, 1 << 16);
        let exact = cast_all::<F>(&t, &b.o, &b.d, &p);
        let starts = run_starts::<F, Relative>(&t.nodes, depth, &b.o, &b.d, &p);
        let (mut raised, mut hits) = (0, 0);
        for i in 0..b.o.len() {
            let dist = starts[i / RUN].expect("camera runs share an origin");
            let q = beam_params(&p, b.o[i], b.d[i], dist);
            raised += (q.near > p.near) as u32;
            if exact.hit[i] == 1 {
                hits += 1;
                let th = exact.t[i].f64();
                assert!(q.near < th, "{s:?} ray {i}: {} >= {th}", q.near);
            }
        }
        assert!(hits > 200 && raised >= hits, "{hits} {raised}");
    }

    #[test]
    fn the_beam_start_never_passes_the_exact_casts_hit() {
        for (s, depth) in [
            (Shape::Sphere { radius: 0.8 }, 8),
            (Shape::Menger { level: 4 }, 8),
        ] {
            bound_holds::<f64>(&s, depth);
            bound_holds::<f32>(&s, depth);
        }
    }

    #[test]
    fn grazing_axes_widen_the_pull_back() {
        let o = [2.0f32, 1.5, 2.5];
        let steep = plane_time_error(o, [-0.6f32, -0.4, -0.7]);
        let grazing = plane_time_error(o, [-0.6f32, 0.0, -0.7]);
        assert!(steep < 1e-4 && grazing > 1.0, "{steep} {grazing}");
        assert!(plane_time_error([2.0f64, 1.5, 2.5], [-0.6f64, -0.4, -0.7]) < 1e-13);
    }

    #[test]
    fn beam_casts_equal_the_per_ray_cast_with_fewer_iterations() {
        let budget = MemBudget::fixed(1 << 30);
        for (s, depth) in [
            (Shape::Sphere { radius: 0.8 }, 9),
            (Shape::Menger { level: 5 }, 8),
        ] {
            let t = build(&s, depth, &budget).unwrap();
            let g = build_dag(&t, &budget).unwrap();
            let b = camera_rays::<f32>(128);
            let p = b.params(None, 1 << 16);
            let per_ray = cast_all::<f32>(&t, &b.o, &b.d, &p);
            let beam = cast_all_beam::<f32, Relative>(&t.nodes, depth, &b.o, &b.d, &p);
            same_but_iters(&beam, &per_ray);
            let it = |h: &VoxelHits<f32>| h.iters.iter().map(|&x| x as i64).sum::<i64>();
            assert!(it(&beam) < it(&per_ray), "{} {}", it(&beam), it(&per_ray));
            let dag = cast_all_beam::<f32, Absolute>(&g.nodes, depth, &b.o, &b.d, &p);
            same_but_iters(&dag, &cast_all_dag::<f32>(&g, &b.o, &b.d, &p));
            let b = camera_rays::<f64>(64);
            let p = b.params(None, 1 << 16);
            let beam = cast_all_beam::<f64, Relative>(&t.nodes, depth, &b.o, &b.d, &p);
            same_but_iters(&beam, &cast_all::<f64>(&t, &b.o, &b.d, &p));
        }
    }

    #[test]
    fn runs_without_a_shared_origin_are_cast_from_near() {
        let t = build(
            &Shape::Sphere { radius: 0.8 },
            7,
            &MemBudget::fixed(1 << 30),
        )
        .unwrap();
        let (o, d): (Vec<[f32; 3]>, Vec<[f32; 3]>) = incoherent(512, 3)
            .into_iter()
            .map(|(o, d)| (o.map(|x| x as f32), d.map(|x| x as f32)))
            .unzip();
        let p = CastParams::default();
        let starts = run_starts::<f32, Relative>(&t.nodes, 7, &o, &d, &p);
        assert!(starts.iter().all(Option::is_none));
        let beam = cast_all_beam::<f32, Relative>(&t.nodes, 7, &o, &d, &p);
        assert_eq!(beam, cast_all::<f32>(&t, &o, &d, &p));
    }

    #[test]
    fn the_cone_test_keeps_every_box_a_ray_of_the_cone_passes_through() {
        let d = [[1.0f64, 0.0, 0.0], [1.0, 0.1, 0.0], [1.0, 0.0, 0.1]];
        let cone = Cone::around(&[[0.0; 3]; 3], &d).unwrap();
        // A tiny box on the ray (1, 0.1, 0) at distance ~5.
        let c = [5.0, 0.5, 0.0];
        assert!(cone.meets(c.map(|x| x - 1e-3), c.map(|x| x + 1e-3)));
        // A box well outside, behind, and one holding the origin.
        assert!(!cone.meets([5.0, 3.0, 3.0], [5.1, 3.1, 3.1]));
        assert!(!cone.meets([-5.1, 0.0, 0.0], [-5.0, 0.1, 0.1]));
        assert!(cone.meets([-1.0; 3], [1.0; 3]));
        assert_eq!(
            box_distance([0.0; 3], [3.0, -1.0, 4.0], [5.0, 1.0, 6.0]),
            5.0
        );
        assert!(Cone::around(&[[0.0; 3], [1.0, 0.0, 0.0]], &d[..2]).is_none());
    }
}
