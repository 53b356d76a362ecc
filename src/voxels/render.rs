//! Batches: the cast and the referee over many rays (fanned out through
//! `parallel`), producing SCENES.md's per-ray outputs, and the shading of
//! `image`.
//!
//! Shading (the project's choice, judged by eye): a hit gets the albedo of
//! its face's axis (x faces (0.90, 0.55, 0.40), y faces (0.85, 0.85, 0.80),
//! z faces (0.45, 0.60, 0.90)) times `0.35 + 0.65 max(0, n . L)`,
//! L = normalize(0.4, 0.9, 0.2), n the entered face's normal; a ray that
//! starts inside solid gets grey 0.5; misses get the background
//! (0.05, 0.05, 0.08). With attributes ([`shade_attr`]) the albedo is the
//! hit leaf's decoded colour and n its decoded normal instead.

use crate::parallel::par_collect;
use crate::real::Real;

use super::attributes::{AttrForm, Attributes};
use super::cast::{cast, cast_contours, cast_dag, Addressing, CastParams, CastReal};
use super::dag::Dag;
use super::hits::{cast_chunks, collect, GRAIN};
use super::octree::Octree;
use super::referee::referee;
use super::shape::Shape;

/// Per-ray results in SCENES.md's conventions (miss: t = -1, leaf = -1, normal = 0).
#[derive(Clone, Debug, Default, PartialEq)]
pub struct VoxelHits<F> {
    pub hit: Vec<u8>,
    pub t: Vec<F>,
    pub leaf: Vec<[i32; 3]>,
    pub normal: Vec<[F; 3]>,
    pub iters: Vec<i32>,
    /// Rays that hit the iteration cap (reported as misses).
    pub capped: u64,
}

/// The referee's per-ray results plus its tie flags.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct RefereeHits {
    pub hits: VoxelHits<f64>,
    pub tie: Vec<u8>,
    pub near_tie: Vec<u8>,
}

const ALBEDO: [[f64; 3]; 3] = [[0.90, 0.55, 0.40], [0.85, 0.85, 0.80], [0.45, 0.60, 0.90]];
const BACKGROUND: [f64; 3] = [0.05, 0.05, 0.08];
const LIGHT: [f64; 3] = [0.4, 0.9, 0.2];

/// The shaded colour of one ray (see the module doc).
pub fn shade<F: Real>(hit: bool, normal: [F; 3]) -> [F; 3] {
    if !hit {
        return BACKGROUND.map(F::of);
    }
    let n = normal.map(|x| x.f64());
    let Some(axis) = (0..3).find(|&a| n[a] != 0.0) else {
        return [F::of(0.5); 3];
    };
    let l = LIGHT;
    let ln = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    let k = 0.35 + 0.65 * ((n[0] * l[0] + n[1] * l[1] + n[2] * l[2]) / ln).max(0.0);
    ALBEDO[axis].map(|a| F::of(a * k))
}

/// The shaded colour of a hit leaf with decoded `colour` and unit `normal`
/// (a zero normal gets the ambient term only).
pub fn shade_attr<F: Real>(colour: [f32; 3], normal: [f32; 3]) -> [F; 3] {
    let l = LIGHT;
    let ln = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
    let nl: f64 = (0..3).map(|k| normal[k] as f64 * l[k]).sum::<f64>() / ln;
    let k = 0.35 + 0.65 * nl.max(0.0);
    colour.map(|c| F::of(c as f64 * k))
}

/// The image of a cast with attributes: each hit's leaf (found from its
/// voxel by `attr_index`) decoded in form `form` and shaded by
/// [`shade_attr`]; misses and inside starts as [`shade`]. GPU twin of the
/// decode: [`super::gpu::attr_image_gpu`].
pub fn attr_image<F: Real>(
    h: &VoxelHits<F>,
    attrs: &Attributes,
    form: AttrForm,
    attr_index: impl Fn([u32; 3]) -> Option<u32> + Sync,
) -> Vec<[F; 3]> {
    let idx = attr_indices(h, attr_index);
    shade_decoded(h, |i| {
        (idx[i] != u32::MAX)
            .then(|| attrs.decode(form, idx[i] as usize))
            .flatten()
    })
}

/// The attribute index of each ray's hit leaf (`attr_index` of its voxel),
/// `u32::MAX` for misses, inside starts and voxels without one.
pub fn attr_indices<F: Real>(
    h: &VoxelHits<F>,
    attr_index: impl Fn([u32; 3]) -> Option<u32> + Sync,
) -> Vec<u32> {
    par_collect("voxels.attr_indices", h.hit.len(), |i| {
        let inside = h.normal[i].iter().all(|x| x.f64() == 0.0);
        if h.hit[i] == 0 || inside {
            return u32::MAX;
        }
        attr_index(h.leaf[i].map(|x| x as u32)).unwrap_or(u32::MAX)
    })
}

/// The image from each ray's decoded (colour, normal) (`None`: shaded by
/// [`shade`]).
pub fn shade_decoded<F: Real>(
    h: &VoxelHits<F>,
    decoded: impl Fn(usize) -> Option<([f32; 3], [f32; 3])> + Sync,
) -> Vec<[F; 3]> {
    par_collect("voxels.attr_image", h.hit.len(), |i| match decoded(i) {
        Some((c, n)) => shade_attr(c, n),
        None => shade(h.hit[i] == 1, h.normal[i]),
    })
}

/// Which structure a scene is cast through (scene key `structure`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Structure {
    /// The ESVO octree, relative child addressing.
    #[default]
    Octree,
    /// The DAG built from it, absolute child addressing: same outputs.
    Dag,
}

/// Casts every ray `(o[i], d[i])`, t in `[p.near, p.far]`.
pub fn cast_all<F: CastReal>(
    tree: &Octree,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    cast_chunks("voxels.cast", o.len(), GRAIN, |r, out| {
        for (i, h) in r.zip(out) {
            *h = cast::<F>(&tree.nodes, tree.depth, o[i], d[i], p);
        }
    })
}

/// [`cast_all`] through the DAG (same loop, absolute addressing).
pub fn cast_all_dag<F: CastReal>(
    dag: &Dag,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    cast_chunks("voxels.cast_dag", o.len(), GRAIN, |r, out| {
        for (i, h) in r.zip(out) {
            *h = cast_dag::<F>(&dag.nodes, dag.depth, o[i], d[i], p);
        }
    })
}

/// [`cast_all`] (addressing [`super::cast::Relative`]) or [`cast_all_dag`]
/// ([`super::cast::Absolute`]) by the SSE cast ([`super::cast_sse`]): identical results
/// in f32, `None` in other precisions.
pub fn cast_all_sse<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> Option<VoxelHits<F>> {
    F::SIMD.then(|| {
        cast_chunks("voxels.cast_sse", o.len(), GRAIN, |r, out| {
            for (i, h) in r.zip(out) {
                *h = F::cast_sse::<A>(nodes, depth, o[i], d[i], p).unwrap_or(*h);
            }
        })
    })
}

/// [`cast_all`] or [`cast_all_dag`] (addressing `A`) by the lane cast
/// ([`super::cast_lanes`]): identical results in f32, `None` in other
/// precisions.
pub fn cast_all_lanes<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> Option<VoxelHits<F>> {
    F::SIMD.then(|| {
        cast_chunks("voxels.cast_lanes", o.len(), GRAIN, |r, out| {
            F::cast_lanes::<A>(nodes, depth, &o[r.clone()], &d[r], p, None, out)
        })
    })
}

/// [`cast_all`] with contours (`contours[attr]`, 0 = none); also returns
/// each ray's contour (0 when its t did not come from a slab).
pub fn cast_all_contours<F: CastReal>(
    tree: &Octree,
    contours: &[u32],
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> (VoxelHits<F>, Vec<u32>) {
    let res = par_collect("voxels.cast_contours", o.len(), |i| {
        cast_contours::<F>(&tree.nodes, tree.depth, o[i], d[i], p, contours)
    });
    let used = res.iter().map(|h| h.contour).collect();
    (collect(res), used)
}

/// Runs the referee on every ray (f64; `margin` as in [`referee`]).
pub fn referee_all(
    shape: &Shape,
    depth: u32,
    o: &[[f64; 3]],
    d: &[[f64; 3]],
    near: f64,
    far: f64,
    margin: f64,
) -> RefereeHits {
    let res = par_collect("voxels.referee", o.len(), |i| {
        referee(shape, depth, o[i], d[i], near, far, margin)
    });
    let mut out = RefereeHits::default();
    for r in res {
        let h = &mut out.hits;
        h.hit.push(r.hit as u8);
        h.t.push(r.t);
        h.leaf.push(if r.hit {
            r.voxel.map(|v| v as i32)
        } else {
            [-1; 3]
        });
        h.normal.push(r.normal.map(|v| v as f64));
        h.iters.push(r.steps as i32);
        out.tie.push(r.tie as u8);
        out.near_tie.push(r.near_tie as u8);
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn shading_is_background_on_a_miss_and_brightest_facing_the_light() {
        assert_eq!(shade::<f64>(false, [0.0; 3]), BACKGROUND);
        let up = shade::<f64>(true, [0.0, 1.0, 0.0]);
        let down = shade::<f64>(true, [0.0, -1.0, 0.0]);
        assert!(up[0] > down[0] && (down[0] - 0.35 * 0.85).abs() < 1e-12);
        assert_eq!(shade::<f32>(true, [0.0; 3]), [0.5; 3]);
    }

    #[test]
    fn attribute_shading_scales_the_decoded_colour_by_the_decoded_normal() {
        let l = LIGHT;
        let ln = (l[0] * l[0] + l[1] * l[1] + l[2] * l[2]).sqrt();
        let lit = shade_attr::<f64>([1.0, 0.5, 0.0], l.map(|x| (x / ln) as f32));
        assert!((lit[0] - 1.0).abs() < 1e-6 && (lit[1] - 0.5).abs() < 1e-6);
        let away = shade_attr::<f64>([1.0, 0.5, 0.0], [0.0, -1.0, 0.0]);
        assert_eq!(away, [0.35, 0.175, 0.0]);
    }
}
