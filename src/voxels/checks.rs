//! Harnesses that run the casts against the referees: the contour error
//! against the analytic sphere (`referee_bounds::ball_entry`) and the GPU
//! cast's differences from the CPU cast judged by the exact DDA
//! (`referee::referee`); plain and DXT attributes against the scene's
//! normals (`attributes::quality`); the mesh voxelisation against the
//! separating-axis referee (`referee_mesh`). The judge's voxels ops wire
//! scenes to these.

use crate::error::Result;
use crate::gpu::voxels::GpuCast;
use crate::gpu::GpuContext;
use crate::rays::Rays;
use crate::tensor::{Outputs, Tensor};

use super::attributes::{leaf_normals, AttrForm, Attributes};
use super::batch::Batch;
use super::cast::{CastParams, CastReal};
use super::contour::decode;
use super::gpu::{attr_image_gpu, hits_from_gpu};
use super::octree::Octree;
use super::outputs::{attr_metrics, build_metrics, mesh_metrics, put_hits};
use super::referee::referee;
use super::referee_bounds::ball_entry;
use super::referee_contour::{box_face_tie, slab_entry_t_tie, slab_tie, voxel_entry};
use super::referee_mesh::{check_triangles, check_voxels};
use super::render::{attr_image, cast_all, cast_all_contours, VoxelHits};
use super::shape::Shape;
use super::through::{CastPath, Through};
use super::voxelise::MeshVoxels;

/// Max and 99th percentile (nearest rank) of `v` (0, 0 when empty).
fn max_p99(mut v: Vec<f64>) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    v.sort_by(f64::total_cmp);
    let k = ((0.99 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    (v[v.len() - 1], v[k])
}

/// The batch cast with cubes and with contours `cs` (a sphere of `radius`
/// at `depth`): `t` error of each against the analytic sphere
/// (`cube_err_max`, `cube_err_p99`, `contour_err_max`, `contour_err_p99`,
/// world units, over rays that meet the sphere and hit in both casts); per
/// ray `box_excess` (how far the contour hit lies outside its voxel's box)
/// and `slab_excess` (outside its slab), in voxel edges, 0 without a
/// contour hit; the contour cast's `t` and `hit`.
pub fn contour_error<F: CastReal>(
    tree: &Octree,
    cs: &[u32],
    b: &Batch<F>,
    p: &CastParams,
    radius: f64,
    depth: u32,
) -> Result<Outputs> {
    let cube = cast_all::<F>(tree, &b.o, &b.d, p);
    let (con, used) = cast_all_contours::<F>(tree, cs, &b.o, &b.d, p);
    let s = 2.0 / (1u64 << depth) as f64;
    let n = b.o.len();
    let (mut e_cube, mut e_con) = (Vec::new(), Vec::new());
    let mut box_excess = vec![0.0f64; n];
    let mut slab_excess = vec![0.0f64; n];
    for i in 0..n {
        let o = b.o[i].map(|x| x.f64());
        let d = b.d[i].map(|x| x.f64());
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let exact = ball_entry(o, d.map(|x| x / l), radius, b.near).map(|t| t / l);
        if let Some(te) = exact {
            if cube.hit[i] == 1 && con.hit[i] == 1 {
                e_cube.push((cube.t[i].f64() - te).abs());
                e_con.push((con.t[i].f64() - te).abs());
            }
        }
        if con.hit[i] == 1 && used[i] != 0 {
            let t = con.t[i].f64();
            let x = [0, 1, 2].map(|a| o[a] + t * d[a]);
            let lo = con.leaf[i].map(|v| -1.0 + v as f64 * s);
            box_excess[i] = (0..3)
                .map(|a| (lo[a] - x[a]).max(x[a] - lo[a] - s).max(0.0) / s)
                .fold(0.0, f64::max);
            let (nn, pp, hh) = decode::<f64>(used[i]);
            let f = (0..3)
                .map(|a| nn[a] * (x[a] - lo[a] - 0.5 * s))
                .sum::<f64>()
                / s;
            slab_excess[i] = ((f - pp).abs() - hh).max(0.0);
        }
    }
    let (cmax, cp99) = max_p99(e_cube);
    let (kmax, kp99) = max_p99(e_con);
    let mut out = Outputs::default();
    for (name, v) in [
        ("cube_err_max", cmax),
        ("cube_err_p99", cp99),
        ("contour_err_max", kmax),
        ("contour_err_p99", kp99),
    ] {
        out.metric(name, v);
        out.tensor(name, Tensor::scalar(v));
    }
    out.metric("voxel_size", s);
    out.counter(
        "contour_hits",
        used.iter().filter(|&&v| v != 0).count() as u64,
    );
    out.counter("contours", cs.iter().filter(|&&v| v != 0).count() as u64);
    out.tensor("box_excess", Tensor::from_shape_vec(&b.shape, box_excess)?);
    out.tensor(
        "slab_excess",
        Tensor::from_shape_vec(&b.shape, slab_excess)?,
    );
    out.tensor("t", Tensor::real(&b.shape, con.t)?);
    out.tensor("hit", Tensor::from_shape_vec(&b.shape, con.hit)?);
    Ok(out)
}

/// The GPU cast `g` of batch `b` against the CPU f32 cast of the same rays
/// through the same structure `th`, from the CPU's beam starts where the
/// GPU's rays started at its own (octree and DAG; contours have no CPU beam
/// path and are cast from `near`), with the kernel's iteration cap, so a
/// ray capped on one side is capped on the other (the beam starts of the
/// two sides may differ by an f32 ulp in a few tiles, and so the iteration
/// counts of their rays): the GPU's hits, the CPU's as `cpu_*`, `excused` /
/// `not_excused` (see [`CastPair::leaf_ties`]), `normal_not_excused` (also
/// excusing normal ties, see [`CastPair::normal_ties`]), `t_not_excused`
/// (also excusing t at normal ties and at contour slab entries, see
/// [`CastPair::t_not_excused`]), `identical_frac`,
/// `beam_ran` (1 when the GPU's camera rays started at its beam starts) and
/// `shader_f64` (1 when the adapter can run the beam pre-pass; scalars and
/// metrics), counters `rays`,
/// `differ`, `excused`, `unexcused`, `normal_differ`, `normal_excused`,
/// `gpu_capped`, `cpu_capped`; with `attrs`, the images shaded from the
/// hit leaves' attributes, decoded on the GPU (`image`) and on the CPU
/// (`cpu_image`); `rays`
/// (N, 9) when `dump`.
#[allow(clippy::too_many_arguments)]
pub fn gpu_parity(
    th: Through,
    g: &GpuCast,
    b: &Batch<f32>,
    p: &CastParams,
    scene: (&Shape, u32),
    (margin, attrs): (f64, Option<(&Attributes, AttrForm)>),
    case: &str,
    dump: bool,
) -> Result<Outputs> {
    let p = CastParams {
        max_iter: g.max_iter,
        ..*p
    };
    let cpu = match th {
        Through::Octree(_) | Through::Dag(_) if g.beam => {
            th.cast_by::<f32>(CastPath::Beam, &b.shape, &b.o, &b.d, &p)?
        }
        _ => th.cast_all::<f32>(&b.o, &b.d, &p),
    };
    let gpu = hits_from_gpu(&g.hits);
    let levels: Vec<u32> = g.hits.iter().map(|h| h.level()).collect();
    let n = gpu.hit.len();
    let pair = CastPair {
        gpu: &gpu,
        cpu: &cpu,
        gpu_level: &levels,
        o: &b.o,
        d: &b.d,
        scene,
        contours: match th {
            Through::Contours(t, cs) => Some((t, cs)),
            _ => None,
        },
        p: &p,
        case,
    };
    let (excused, differ) = pair.leaf_ties(margin);
    let nex = excused.iter().map(|&x| x as u64).sum::<u64>();
    let (normal_ok, ndiffer) = pair.normal_ties(margin);
    let nnex = normal_ok.iter().map(|&x| x as u64).sum::<u64>();
    let mut out = Outputs::default();
    out.counter("rays", n as u64)
        .counter("differ", differ as u64);
    out.counter("excused", nex)
        .counter("unexcused", differ as u64 - nex);
    out.counter("normal_differ", ndiffer as u64)
        .counter("normal_excused", nnex);
    out.counter("gpu_capped", gpu.capped)
        .counter("cpu_capped", cpu.capped);
    let identical = 1.0 - differ as f64 / n.max(1) as f64;
    out.metric("identical_frac", identical);
    out.tensor("identical_frac", Tensor::scalar(identical));
    // Whether the camera rays started at the GPU's beam starts.
    let f64s = GpuContext::get()?.has_f64();
    for (k, v) in [("beam_ran", g.beam), ("shader_f64", f64s)] {
        out.metric(k, v as u8 as f64);
        out.tensor(k, Tensor::scalar(v as u8 as f64));
    }
    let not_excused: Vec<u8> = excused.iter().map(|&x| 1 - x).collect();
    let normal_not_excused: Vec<u8> = (excused.iter().zip(&normal_ok))
        .map(|(&x, &y)| 1 - (x | y))
        .collect();
    let t_not_excused = pair.t_not_excused(margin, &excused, &normal_ok);
    out.tensor(
        "normal_not_excused",
        Tensor::from_shape_vec(&b.shape, normal_not_excused)?,
    );
    out.tensor(
        "t_not_excused",
        Tensor::from_shape_vec(&b.shape, t_not_excused)?,
    );
    out.tensor("excused", Tensor::from_shape_vec(&b.shape, excused)?);
    out.tensor(
        "not_excused",
        Tensor::from_shape_vec(&b.shape, not_excused)?,
    );
    if dump {
        let rays = Rays {
            o: b.o.clone(),
            d: b.d.clone(),
            t0: vec![p.near as f32; n],
            t1: vec![(p.far as f32).min(1e30); n],
            pixel: (0..n as u32).collect(),
        };
        out.tensor("rays", rays.to_tensor()?);
    }
    if let Some((a, form)) = attrs {
        let ix = |v| th.attr_index(v);
        let gi = attr_image_gpu(GpuContext::get()?, &gpu, (a, form), ix)?;
        out.tensor("image", Tensor::real3(&b.shape, &gi)?);
        let ci = attr_image(&cpu, a, form, ix);
        out.tensor("cpu_image", Tensor::real3(&b.shape, &ci)?);
    }
    put_hits(&mut out, gpu, &b.shape, scene.1, false)?;
    let mut c = Outputs::default();
    put_hits(&mut c, cpu, &b.shape, scene.1, false)?;
    for (k, v) in c.tensors {
        out.tensor(&format!("cpu_{k}"), v);
    }
    Ok(out)
}

/// Slack of a normal or contour-slab tie relative to the ray's coordinate
/// magnitudes (`|o| + t |d|`): 2^-20, 8 f32 ulps. The cast's entry times
/// and slab offsets carry a few ulps of those magnitudes, and which face of
/// an edge is entered first, or whether a slab just touching a voxel's
/// interval is met, flips with them (H100 against the CPU: entry-face gaps
/// up to 8.7e-7 at t = 3, |o| = 3.5, which a margin of 2^-22 world units
/// would not excuse).
const TIE_REL: f64 = 1.0 / (1u64 << 20) as f64;

/// The GPU and CPU casts of one batch and what the referee needs to judge
/// their differences.
struct CastPair<'a> {
    gpu: &'a VoxelHits<f32>,
    cpu: &'a VoxelHits<f32>,
    o: &'a [[f32; 3]],
    d: &'a [[f32; 3]],
    scene: (&'a Shape, u32),
    /// Per ray, the level of the voxel the GPU cast stopped at (an LOD
    /// cut's is coarser than the leaf's); read only with an LOD cut.
    gpu_level: &'a [u32],
    /// The contour cast's tree and contours (leaf ties also excused at
    /// slab ties, [`slab_tie`]).
    contours: Option<(&'a Octree, &'a [u32])>,
    p: &'a CastParams,
    case: &'a str,
}

impl CastPair<'_> {
    /// Per ray: 1 where `differs(i)` and the referee, with margin
    /// `margin(i)` world units, flags ray `i` as a tie or near tie (an
    /// excused difference), else 0; unexcused differences are logged. Also
    /// the number of rays that differ.
    fn excuse(
        &self,
        differs: impl Fn(usize) -> bool,
        margin: impl Fn(usize) -> f64,
        slab: impl Fn(usize) -> bool,
    ) -> (Vec<u8>, usize) {
        let (g, c) = (self.gpu, self.cpu);
        let differ: Vec<usize> = (0..g.hit.len()).filter(|&i| differs(i)).collect();
        let mut excused = vec![0u8; g.hit.len()];
        for &i in &differ {
            let (o, d) = (self.o[i].map(|x| x as f64), self.d[i].map(|x| x as f64));
            let (shape, depth) = self.scene;
            let f = referee(shape, depth, o, d, self.p.near, self.p.far, margin(i));
            excused[i] = (f.tie || f.near_tie || slab(i)) as u8;
            if excused[i] == 0 {
                eprintln!(
                    "{}: ray {i} o={o:?} d={d:?}: gpu leaf {:?} normal {:?}, cpu leaf {:?} normal {:?} (referee {:?} {:?})",
                    self.case, g.leaf[i], g.normal[i], c.leaf[i], c.normal[i], f.voxel, f.normal
                );
            }
        }
        (excused, differ.len())
    }

    /// [`Self::excuse`] where the leaves differ, with the referee's margin:
    /// a tie, or within `margin` world units of a voxel boundary; in a
    /// contour cast also a slab tie at the leaf one cast stopped at and the
    /// other passed ([`Self::slab_tie`]).
    fn leaf_ties(&self, margin: f64) -> (Vec<u8>, usize) {
        let (g, c) = (self.gpu, self.cpu);
        self.excuse(
            |i| g.leaf[i] != c.leaf[i],
            |_| margin,
            |i| self.slab_tie(i, margin),
        )
    }

    /// `TIE_REL` of ray `i`'s coordinate magnitudes at `t`.
    fn rel_slack(&self, i: usize, t: f64) -> f64 {
        let norm = |v: [f32; 3]| v.map(|x| x as f64 * x as f64).iter().sum::<f64>().sqrt();
        TIE_REL * (norm(self.o[i]) + t.max(0.0) * norm(self.d[i]))
    }

    /// Whether ray `i` of a contour cast meets the slab of the leaf that
    /// one cast stopped at and the other passed (the nearer of the two
    /// leaves, or the only one when a cast missed) within `margin` plus
    /// [`TIE_REL`] of the slab test flipping ([`slab_tie`]).
    fn slab_tie(&self, i: usize, margin: f64) -> bool {
        let Some((tree, cs)) = self.contours else {
            return false;
        };
        let (o, d) = (self.o[i].map(|x| x as f64), self.d[i].map(|x| x as f64));
        let depth = self.scene.1;
        let stop = |leaf: [i32; 3]| {
            let v = leaf.map(|x| x as u32);
            (leaf[0] >= 0).then(|| (voxel_entry(depth, v, o, d), v))
        };
        let passed = match (stop(self.gpu.leaf[i]), stop(self.cpu.leaf[i])) {
            (Some(a), Some(b)) => {
                if a.0 <= b.0 {
                    a
                } else {
                    b
                }
            }
            (Some(a), None) | (None, Some(a)) => a,
            (None, None) => return false,
        };
        let code = (tree.attr_index(passed.1))
            .and_then(|k| cs.get(k as usize).copied())
            .unwrap_or(0);
        let slack = margin + self.rel_slack(i, passed.0);
        let interval = (self.p.near, self.p.far);
        slab_tie(code, depth, passed.1, o, d, interval, slack)
    }

    /// [`Self::excuse`] where the leaves agree but the normals do not, the
    /// margin widened by [`TIE_REL`] of the ray's coordinate
    /// magnitudes: the ray enters the voxel within rounding of an edge or
    /// corner, so either face is right. With an LOD cut, also where the
    /// box the GPU stopped at is entered so ([`Self::lod_tie`]).
    fn normal_ties(&self, margin: f64) -> (Vec<u8>, usize) {
        let (g, c) = (self.gpu, self.cpu);
        self.excuse(
            |i| g.leaf[i] == c.leaf[i] && g.normal[i] != c.normal[i],
            |i| margin + self.rel_slack(i, c.t[i] as f64),
            |i| self.lod_tie(i, margin),
        )
    }

    /// Whether ray `i` of a cast with an LOD cut enters the box it stopped
    /// at (the GPU's level round its leaf) through the edge between the
    /// faces the two normals name, within `margin` plus [`TIE_REL`]
    /// ([`box_face_tie`]): the cube referee judges the finest solid voxel
    /// on the ray, which may lie beyond that box.
    fn lod_tie(&self, i: usize, margin: f64) -> bool {
        let (g, c) = (self.gpu, self.cpu);
        if self.p.lod.is_none() {
            return false;
        }
        let (o, d) = (self.o[i].map(|x| x as f64), self.d[i].map(|x| x as f64));
        let slack = margin + self.rel_slack(i, c.t[i] as f64);
        let v = g.leaf[i].map(|x| x as u32);
        let normals = [g.normal[i], c.normal[i]];
        box_face_tie((self.scene.1, self.gpu_level[i]), v, o, d, normals, slack)
    }

    /// Per ray: 1 where the two t's are judged, else 0. Not where the
    /// leaves differ excused (the t's of different voxels); nor at an
    /// excused normal tie whose t's are within the two faces' rounding of
    /// each other ([`Self::face_t_tie`]: each cast's t is its own face's;
    /// an H200 against the CPU on incoherent Menger rays: 3.0e-6 and
    /// 1.9e-5 apart relative, over `voxel_t_f32`); nor at a contour slab
    /// entry within the plane's rounding ([`Self::slab_t_tie`]). `excused`
    /// and `normal_ok` are [`Self::leaf_ties`]' and [`Self::normal_ties`]'.
    fn t_not_excused(&self, margin: f64, excused: &[u8], normal_ok: &[u8]) -> Vec<u8> {
        (0..excused.len())
            .map(|i| {
                let face = normal_ok[i] == 1 && self.face_t_tie(i, margin);
                1 - (excused[i] | face as u8 | self.slab_t_tie(i, margin) as u8)
            })
            .collect()
    }

    /// Whether ray `i`'s two t's, each from the face its cast's normal
    /// names, are within those faces' rounding of each other: the slack of
    /// [`Self::normal_ties`] over the ray's rate across each face,
    /// `slack (1 / |d_a| + 1 / |d_b|)`.
    fn face_t_tie(&self, i: usize, margin: f64) -> bool {
        let (g, c) = (self.gpu, self.cpu);
        let axis = |n: [f32; 3]| n.iter().position(|&x| x != 0.0);
        let (Some(a), Some(b)) = (axis(g.normal[i]), axis(c.normal[i])) else {
            return false;
        };
        let rate = |a: usize| (self.d[i][a] as f64).abs();
        let slack = margin + self.rel_slack(i, c.t[i] as f64);
        let bound = slack / rate(a) + slack / rate(b);
        (g.t[i] as f64 - c.t[i] as f64).abs() <= bound
    }

    /// Whether ray `i` of a contour cast, both casts hitting the same leaf
    /// through the same face, has both t's at the leaf's exact slab entry
    /// within the slab plane's rounding: `margin` plus [`TIE_REL`] of
    /// `|o| + t |d|`, over `|n . d|` ([`slab_entry_t_tie`]). An H200's
    /// worst over 32,073 slab-entry rays of the 512^2 sphere, `|dt| |n . d|
    /// / (|o| + t |d|)`, was 1.13e-7, an eighth of `TIE_REL`.
    fn slab_t_tie(&self, i: usize, margin: f64) -> bool {
        let (g, c) = (self.gpu, self.cpu);
        let Some((tree, cs)) = self.contours else {
            return false;
        };
        if g.hit[i] == 0 || g.leaf[i] != c.leaf[i] || g.normal[i] != c.normal[i] {
            return false;
        }
        let (o, d) = (self.o[i].map(|x| x as f64), self.d[i].map(|x| x as f64));
        let v = g.leaf[i].map(|x| x as u32);
        let code = (tree.attr_index(v))
            .and_then(|k| cs.get(k as usize).copied())
            .unwrap_or(0);
        let slack = margin + self.rel_slack(i, c.t[i] as f64);
        let ts = [g.t[i] as f64, c.t[i] as f64];
        slab_entry_t_tie(code, self.scene.1, v, (o, d), slack, ts)
    }
}

/// Plain and DXT attributes of `tree`'s leaves built from `shape`'s normals
/// and judged against them (`outputs::attr_metrics`), with the build's
/// metrics.
pub fn attribute_quality(shape: &Shape, tree: &Octree) -> Result<Outputs> {
    let ns = leaf_normals(shape, tree)?;
    let mut out = Outputs::default();
    attr_metrics(&mut out, &Attributes::build(&ns), &ns, tree);
    build_metrics(&mut out, tree);
    Ok(out)
}

/// The separating-axis referee over every `strides.0`-th triangle and the
/// solid voxels of every `strides.1`-th leaf, skipping gaps within `margin`
/// (`outputs::mesh_metrics`), with the build's metrics.
pub fn mesh_referee(
    m: &MeshVoxels,
    tree: &Octree,
    strides: (usize, usize),
    margin: f64,
) -> Outputs {
    let tc = check_triangles(&m.mesh, tree, strides.0, margin);
    let vc = check_voxels(&m.mesh, tree, strides.1, margin);
    let mut out = Outputs::default();
    mesh_metrics(&mut out, m, &tc, &vc);
    build_metrics(&mut out, tree);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hits(normals: &[[f32; 3]], ts: &[f32]) -> VoxelHits<f32> {
        VoxelHits {
            hit: vec![1; normals.len()],
            t: ts.to_vec(),
            leaf: vec![[0, 0, 8]; normals.len()],
            normal: normals.to_vec(),
            iters: vec![1; normals.len()],
            capped: 0,
        }
    }

    /// The pair the tests judge: cube casts (no contours, no LOD levels) of
    /// the rays `o`, `d` in `scene` with `p`.
    fn cube_pair<'a>(
        (gpu, cpu): (&'a VoxelHits<f32>, &'a VoxelHits<f32>),
        (o, d): (&'a [[f32; 3]], &'a [[f32; 3]]),
        scene: (&'a Shape, u32),
        p: &'a CastParams,
    ) -> CastPair<'a> {
        CastPair {
            gpu,
            cpu,
            o,
            d,
            scene,
            gpu_level: &[],
            contours: None,
            p,
            case: "test",
        }
    }

    #[test]
    fn normal_differences_are_excused_at_edges_only() {
        // A sphere of radius 10 fills the root box, so the scene is a solid
        // box; ray 0 meets it exactly on the edge x = y = -1, ray 1
        // in the middle of the face x = -1: both casts agree on the leaf,
        // not on the normal.
        let shape = Shape::Sphere { radius: 10.0 };
        let s = std::f32::consts::FRAC_1_SQRT_2;
        let o = [[-3.0, -3.0, 0.1], [-3.0, 0.1, 0.1]];
        let d = [[s, s, 0.0], [1.0, 0.0, 0.0]];
        let ts = [2.0 * std::f32::consts::SQRT_2, 2.0];
        let gpu = hits(&[[-1.0, 0.0, 0.0], [0.0, -1.0, 0.0]], &ts);
        let cpu = hits(&[[0.0, -1.0, 0.0], [-1.0, 0.0, 0.0]], &ts);
        let p = CastParams::default();
        let pair = cube_pair((&gpu, &cpu), (&o, &d), (&shape, 4), &p);
        assert_eq!(pair.leaf_ties(2f64.powi(-22)), (vec![0, 0], 0));
        assert_eq!(pair.normal_ties(2f64.powi(-22)), (vec![1, 0], 2));
    }

    #[test]
    fn lod_normal_differences_are_excused_at_the_cut_boxs_edge() {
        // The H200's ray 8907 of voxel_gpu_sphere_lod_parity (128^2): both
        // casts cut at the level-6 box round leaf [209, 159, 187], the GPU
        // naming its z face, the CPU its y face, entered 3.2e-7 apart in t
        // (the tie's slack there 1.4e-5); the cube referee judges voxel
        // [207, 158, 184] beyond the box, entered through z alone.
        use crate::voxels::cast::Lod;
        let shape = Shape::Sphere { radius: 0.8 };
        let o = [[2.0, 1.5, 2.5]];
        let d = [[-0.496_445_12, -0.454_952_33, -0.739_297_45]];
        let mut gpu = hits(&[[0.0, 0.0, 1.0]], &[2.747_541]);
        let mut cpu = hits(&[[0.0, 1.0, 0.0]], &[2.747_540_7]);
        (gpu.leaf, cpu.leaf) = (vec![[209, 159, 187]], vec![[209, 159, 187]]);
        let lod = Lod {
            orig_size: 0.0,
            dir_size: 0.02,
        };
        let p = CastParams {
            lod: Some(lod),
            ..CastParams::default()
        };
        let pair = CastPair {
            gpu_level: &[6],
            ..cube_pair((&gpu, &cpu), (&o, &d), (&shape, 8), &p)
        };
        assert_eq!(pair.normal_ties(2f64.powi(-22)), (vec![1], 1));
        let no_lod = CastParams::default();
        let cubes = CastPair { p: &no_lod, ..pair };
        assert_eq!(cubes.normal_ties(2f64.powi(-22)), (vec![0], 1));
    }

    #[test]
    fn t_differences_are_excused_at_excused_normal_ties_only() {
        // The H200's rays 1230 and 14356 of
        // voxel_gpu_menger_incoherent_parity: same leaf, the two casts
        // naming faces that are entered within the referee's margin, each t
        // from its own face, 3.0e-6 and 1.9e-5 apart relative. With the
        // normals agreeing, the same t's are judged.
        let shape = Shape::Menger { level: 6 };
        let o = [
            [0.187_847_85, -0.102_168_44, -0.741_204_5],
            [-0.534_753_1, -0.506_554_6, 0.735_301],
        ];
        let d = [
            [0.595_506_1, 0.777_583_6, 0.201_832_3],
            [0.022_908_41, -0.268_382_52, -0.963_04],
        ];
        let mut gpu = hits(
            &[[0.0, 0.0, -1.0], [-1.0, 0.0, 0.0]],
            &[0.130_607_2, 0.323_432_92],
        );
        let mut cpu = hits(
            &[[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]],
            &[0.130_606_82, 0.323_426_75],
        );
        gpu.leaf = vec![[648, 511, 146], [242, 208, 728]];
        cpu.leaf.clone_from(&gpu.leaf);
        let p = CastParams::default();
        let pair = cube_pair((&gpu, &cpu), (&o, &d), (&shape, 10), &p);
        let margin = 2f64.powi(-22);
        let (excused, _) = pair.leaf_ties(margin);
        let (normal_ok, _) = pair.normal_ties(margin);
        assert_eq!((&excused[..], &normal_ok[..]), (&[0, 0][..], &[1, 1][..]));
        assert_eq!(pair.t_not_excused(margin, &excused, &normal_ok), [0, 0]);
        // The same ties with the GPU's t 1e-3 off: past the faces'
        // rounding, judged.
        let off = VoxelHits {
            t: gpu.t.iter().map(|t| t + 1e-3).collect(),
            ..gpu.clone()
        };
        let apart = CastPair { gpu: &off, ..pair };
        assert_eq!(apart.t_not_excused(margin, &excused, &normal_ok), [1, 1]);
        let t_apart = VoxelHits {
            t: cpu.t.clone(),
            ..gpu.clone()
        };
        let agreed = CastPair {
            cpu: &t_apart,
            ..pair
        };
        let (normal_ok, _) = agreed.normal_ties(margin);
        assert_eq!(agreed.t_not_excused(margin, &excused, &normal_ok), [1, 1]);
    }

    #[test]
    fn contour_t_differences_are_excused_at_grazing_slab_entries_only() {
        // The H200's rays 175245, 179348, 204538 and 204541 of
        // voxel_gpu_contour_sphere_parity (512^2): same leaf, same face,
        // t at the leaf's slab entry with |n . d| 0.046, 0.071, 0.012 and
        // 0.028, 1.3e-6 to 2.4e-6 apart relative. The cube cast has no
        // slab, and t 100 times as far apart is past the plane's rounding.
        use crate::budget::MemBudget;
        use crate::voxels::contour::fit_sphere;
        use crate::voxels::octree::build;
        let shape = Shape::Sphere { radius: 0.8 };
        let tree = build(&shape, 8, &MemBudget::fixed(1 << 26)).unwrap();
        let leaf = [
            [97, 85, 215],
            [105, 82, 216],
            [164, 47, 179],
            [167, 49, 180],
        ];
        let mut cs = vec![0; tree.leaves().len()];
        for v in leaf {
            cs[tree.attr_index(v).unwrap() as usize] = fit_sphere(0.8, 8, v).unwrap();
        }
        let o = [[2.0, 1.5, 2.5]; 4];
        let d = [
            [-0.655_812_1, -0.536_724_4, -0.530_883_55],
            [-0.643_940_03, -0.548_214_3, -0.533_668_64],
            [-0.497_834_6, -0.618_052_66, -0.608_417_33],
            [-0.494_157_28, -0.618_071_1, -0.611_389_16],
        ];
        let normal = [
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [0.0, 0.0, 1.0],
            [1.0, 0.0, 0.0],
        ];
        let cpu_t = [3.416_347_7, 3.381_811_9, 3.448_790_8, 3.419_73];
        let gpu_t = [3.416_343_2, 3.381_816_4, 3.448_799_1, 3.419_735_7];
        let mut gpu = hits(&normal, &gpu_t);
        gpu.leaf = leaf.map(|v| v.map(|x| x as i32)).to_vec();
        let cpu = VoxelHits {
            t: cpu_t.to_vec(),
            ..gpu.clone()
        };
        let far = VoxelHits {
            t: (0..4)
                .map(|i| cpu_t[i] + 100.0 * (gpu_t[i] - cpu_t[i]))
                .collect(),
            ..gpu.clone()
        };
        let p = CastParams::default();
        let pair = CastPair {
            contours: Some((&tree, &cs)),
            ..cube_pair((&gpu, &cpu), (&o, &d), (&shape, 8), &p)
        };
        let (margin, none) = (2f64.powi(-22), [0; 4]);
        assert_eq!(pair.t_not_excused(margin, &none, &none), [0; 4]);
        let cubes = CastPair {
            contours: None,
            ..pair
        };
        assert_eq!(cubes.t_not_excused(margin, &none, &none), [1; 4]);
        let apart = CastPair { gpu: &far, ..pair };
        assert_eq!(apart.t_not_excused(margin, &none, &none), [1; 4]);
    }

    #[test]
    fn contour_leaf_differences_are_excused_at_slab_ties_only() {
        // Every leaf of the depth-3 sphere carries the contour of
        // `grazing`, whose ray leaves voxel [3, 3, 3] just as it enters the
        // slab: one cast stopping there and the other passing it is a tie;
        // so it is moved 1e-5 into the slab (the ends 2.9e-6 apart in t,
        // within `TIE_REL` of |o| + t |d| = 4.0: 9.5e-6 over both ends); moved
        // 1/1000 of a voxel (2.5e-4), the ray meets the slab clearly.
        use crate::budget::MemBudget;
        use crate::voxels::octree::build;
        use crate::voxels::referee_contour::grazing;
        let shape = Shape::Sphere { radius: 0.8 };
        let tree = build(&shape, 3, &MemBudget::fixed(1 << 20)).unwrap();
        let (v, _, _) = grazing(0.0);
        let cs = vec![v; tree.leaves().len()];
        let rays = [grazing(0.0), grazing(1e-5), grazing(2.5e-4)];
        let o = rays.map(|(_, o, _)| o.map(|x| x as f32));
        let d = rays.map(|(_, _, d)| d.map(|x| x as f32));
        let mut stopped = hits(&[[-1.0, 0.0, 0.0]; 3], &[1.0; 3]);
        stopped.leaf = vec![[3, 3, 3]; 3];
        let mut missed = hits(&[[0.0; 3]; 3], &[-1.0; 3]);
        (missed.hit, missed.leaf) = (vec![0; 3], vec![[-1; 3]; 3]);
        // The next voxel on the ray: the nearer leaf, [3, 3, 3], is judged.
        let mut next = stopped.clone();
        next.leaf = vec![[4, 3, 3]; 3];
        let p = CastParams::default();
        for (gpu, cpu) in [(&missed, &stopped), (&stopped, &missed), (&next, &stopped)] {
            let pair = CastPair {
                contours: Some((&tree, &cs)),
                ..cube_pair((gpu, cpu), (&o, &d), (&shape, 3), &p)
            };
            assert_eq!(pair.leaf_ties(2f64.powi(-22)), (vec![1, 1, 0], 3));
            let cubes = CastPair {
                contours: None,
                ..pair
            };
            assert_eq!(cubes.leaf_ties(2f64.powi(-22)), (vec![0, 0, 0], 3));
        }
    }
}
