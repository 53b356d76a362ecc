//! Voxel casts and octree builds as named tensors, metrics and counters.
//!
//! `voxels.gpu_parity` outputs the GPU's `hit`, `t`, `leaf`, `normal`,
//! `iters`, `leaf_key`, the CPU's as `cpu_*`, and `excused` (uint8,
//! `voxels::checks::excused`; `ulp_margin` defaults to 2^-22, one f32 ulp
//! of the octree's [1, 2) coordinates); counters `differ`, `excused`,
//! `unexcused`; `identical_frac` (scalar tensor and metric).

use crate::error::Result;
use crate::gpu::voxels::GpuCast;
use crate::gpu::GpuContext;
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};
use crate::voxels::attributes::{quality, AttrForm, Attributes};
use crate::voxels::batch::Batch;
use crate::voxels::dag::Dag;
use crate::voxels::gpu::{attr_image_gpu, hits_from_gpu};
use crate::voxels::octree::Octree;
use crate::voxels::referee_mesh::{TriangleCheck, VoxelCheck};
use crate::voxels::render::{shade, RefereeHits, VoxelHits};
use crate::voxels::through::Through;
use crate::voxels::voxelise::MeshVoxels;

fn with_3(shape: &[usize]) -> Vec<usize> {
    let mut s = shape.to_vec();
    s.push(3);
    s
}

/// `i + N (j + N k)` (N = 2^depth) as f64, -1 on a miss: one number per ray
/// for counting differing voxels; exact for depth <= 17.
pub fn leaf_key(leaf: &[[i32; 3]], depth: u32) -> Vec<f64> {
    let n = (1u64 << depth) as f64;
    leaf.iter()
        .map(|v| {
            if v[0] < 0 {
                -1.0
            } else {
                v[0] as f64 + n * (v[1] as f64 + n * v[2] as f64)
            }
        })
        .collect()
}

/// Writes a cast's hits into `out` with per-ray shape `shape`: `leaf_key`,
/// `image` (shaded, when `image`), `hit`, `t`, `leaf`, `normal`, `iters`;
/// counter `capped`.
pub fn put_hits<F: Real>(
    out: &mut Outputs,
    h: VoxelHits<F>,
    shape: &[usize],
    depth: u32,
    image: bool,
) -> Result<()> {
    out.tensor(
        "leaf_key",
        Tensor::from_shape_vec(shape, leaf_key(&h.leaf, depth))?,
    );
    if image {
        let img: Vec<[F; 3]> = h
            .hit
            .iter()
            .zip(&h.normal)
            .map(|(&x, &n)| shade(x == 1, n))
            .collect();
        out.tensor("image", Tensor::real3(shape, &img)?);
    }
    out.tensor("hit", Tensor::from_shape_vec(shape, h.hit)?);
    out.tensor("t", Tensor::real(shape, h.t)?);
    out.tensor(
        "leaf",
        Tensor::from_shape_vec(
            &with_3(shape),
            h.leaf.into_iter().flatten().collect::<Vec<i32>>(),
        )?,
    );
    out.tensor("normal", Tensor::real3(shape, &h.normal)?);
    out.tensor("iters", Tensor::from_shape_vec(shape, h.iters)?);
    out.counter("capped", h.capped);
    Ok(())
}

/// The octree's build statistics as metrics and counters.
pub fn build_metrics(out: &mut Outputs, tree: &Octree) {
    let s = &tree.stats;
    out.metric("build_s", s.build_s)
        .metric("bytes_per_voxel", s.bytes_per_voxel())
        .metric(
            "bytes_per_leaf",
            if s.leaves == 0 {
                0.0
            } else {
                s.bytes as f64 / s.leaves as f64
            },
        )
        .metric("solid_voxels", s.solid_voxels as f64);
    out.counter("bytes", s.bytes)
        .counter("descriptors", s.descriptors)
        .counter("far_slots", s.far_slots);
    out.counter("leaves", s.leaves);
}

/// Attribute storage and quality: for `plain` and `dxt`, `{form}_colour_psnr_db`,
/// `{form}_colour_max_abs`, `{form}_normal_{mean,p99,max}_deg` (metrics and
/// scalar tensors), `{form}_bytes_per_voxel` (attributes alone) and
/// `{form}_total_bytes_per_voxel` (with the octree's nodes); counters
/// `attr_leaves`, `zero_normals`.
pub fn attr_metrics(out: &mut Outputs, a: &Attributes, ns: &[[f64; 3]], tree: &Octree) {
    let voxels = tree.stats.solid_voxels.max(1) as f64;
    for (name, form) in [("plain", AttrForm::Plain), ("dxt", AttrForm::Dxt)] {
        let q = quality(a, form, ns);
        let bytes = a.bytes(form) as f64;
        for (k, v) in [
            ("colour_psnr_db", q.colour_psnr_db),
            ("colour_max_abs", q.colour_max_abs),
            ("normal_mean_deg", q.normal_mean_deg),
            ("normal_p99_deg", q.normal_p99_deg),
            ("normal_max_deg", q.normal_max_deg),
            ("bytes_per_voxel", bytes / voxels),
            (
                "total_bytes_per_voxel",
                (bytes + tree.stats.bytes as f64) / voxels,
            ),
        ] {
            let key = format!("{name}_{k}");
            out.metric(&key, v);
            out.tensor(&key, Tensor::scalar(v));
        }
        out.counter("zero_normals", q.zero_normals);
    }
    out.counter("attr_leaves", a.leaves as u64);
}

/// The mesh referee's findings and the voxelisation's size: counters
/// `triangles_checked`, `overlapped`, `missing`, `triangle_ties`,
/// `voxels_checked`, `untouched`, `voxel_ties`, `mesh_voxels`,
/// `degenerate`; `missing` and `untouched` also as scalar tensors; metrics
/// `voxelise_s`, `mesh_voxel_bytes` (codes and normal sums).
pub fn mesh_metrics(out: &mut Outputs, m: &MeshVoxels, t: &TriangleCheck, v: &VoxelCheck) {
    out.counter("triangles_checked", t.triangles)
        .counter("overlapped", t.overlapped)
        .counter("missing", t.missing)
        .counter("triangle_ties", t.ties)
        .counter("voxels_checked", v.voxels)
        .counter("untouched", v.untouched)
        .counter("voxel_ties", v.ties)
        .counter("mesh_voxels", m.codes.len() as u64)
        .counter("triangles", m.mesh.tris.len() as u64)
        .counter("degenerate", m.degenerate);
    out.tensor("missing", Tensor::scalar(t.missing as f64));
    out.tensor("untouched", Tensor::scalar(v.untouched as f64));
    out.tensor("overlapped", Tensor::scalar(t.overlapped as f64));
    out.metric("voxelise_s", m.voxelise_s)
        .metric("mesh_voxel_bytes", (m.codes.len() * (8 + 12)) as f64);
}

/// The DAG's counters and build time, beside an octree's.
pub fn dag_metrics(out: &mut Outputs, g: &Dag) {
    let s = &g.stats;
    out.counter("dag_nodes", s.nodes)
        .counter("dag_slots", s.slots)
        .counter("dag_bytes", s.bytes);
    out.metric("dag_build_s", s.build_s);
}

impl RefereeHits {
    /// The hits (as [`put_hits`], without the image) and the tie flags:
    /// `tie`, `near_tie`, their complements `untied`, `clear`; counters
    /// `ties`, `near_ties`.
    pub fn to_outputs(self, shape: &[usize], depth: u32, out: &mut Outputs) -> Result<()> {
        out.counter("ties", self.tie.iter().map(|&x| x as u64).sum());
        out.counter("near_ties", self.near_tie.iter().map(|&x| x as u64).sum());
        let untied: Vec<u8> = self.tie.iter().map(|&x| 1 - x).collect();
        let clear: Vec<u8> = self.near_tie.iter().map(|&x| 1 - x).collect();
        out.tensor("tie", Tensor::from_shape_vec(shape, self.tie)?);
        out.tensor("near_tie", Tensor::from_shape_vec(shape, self.near_tie)?);
        out.tensor("untied", Tensor::from_shape_vec(shape, untied)?);
        out.tensor("clear", Tensor::from_shape_vec(shape, clear)?);
        put_hits(out, self.hits, shape, depth, false)
    }
}

impl<F: Real> Batch<F> {
    /// A cast of this batch as SCENES.md outputs (as [`put_hits`], with the
    /// image: `image` when given (attribute shading, `render::attr_image`),
    /// else shaded from the normals; `kind` for hard rays; `rays` (N, 9) when
    /// `dump`), metrics `cast_s` (= `secs`), `mrays_per_s`, counters `rays`,
    /// `hits`.
    pub fn cast_outputs(
        self,
        (h, image): (VoxelHits<F>, Option<Vec<[F; 3]>>),
        (secs, hits): (f64, u64),
        depth: u32,
        dump: bool,
        out: &mut Outputs,
    ) -> Result<()> {
        // The cast's rays (a GPU camera cast reads its rays back only when
        // dumping: `self` may hold none).
        let n = h.hit.len() as u64;
        if dump {
            out.tensor("rays", self.to_rays().to_tensor()?);
        }
        out.metric("cast_s", secs)
            .metric("mrays_per_s", n as f64 / secs.max(1e-12) / 1e6);
        out.counter("rays", n).counter("hits", hits);
        if let Some(img) = &image {
            out.tensor("image", Tensor::real3(&self.shape, img)?);
        }
        put_hits(out, h, &self.shape, depth, image.is_none())?;
        if let Some(k) = self.kind {
            out.tensor("kind", Tensor::from_shape_vec(&self.shape, k)?);
        }
        Ok(())
    }
}

/// A GPU cast of `b` as [`Batch::cast_outputs`] (the kernel's `gpu_s` as
/// `cast_s`; with `attrs` the image shaded from the hit leaves' attributes
/// decoded on the GPU, [`attr_image_gpu`], through `th`'s leaf numbering),
/// plus metric `wall_s` (`wall`, submit to readback with the upload),
/// counter `kernel_max_iter` and, where the adapter has timestamp queries,
/// metric `kernel_s` (the cast on the GPU's clock) and scalar
/// `kernel_share` (`kernel_s` over submit to readback).
pub fn gpu_cast_outputs(
    cast: &GpuCast,
    b: Batch<f32>,
    (attrs, form, th): (Option<&Attributes>, AttrForm, Through),
    (wall, depth, dump): (f64, u32, bool),
    out: &mut Outputs,
) -> Result<()> {
    out.metric("wall_s", wall)
        .counter("kernel_max_iter", cast.max_iter as u64);
    if let Some(k) = cast.kernel_s {
        // The kernels' share of submit-to-readback: in (0, 1] when the
        // timestamps bracket the right passes.
        out.metric("kernel_s", k);
        out.tensor("kernel_share", Tensor::scalar(k / cast.gpu_s.max(1e-12)));
    }
    let hits = cast.hits.iter().filter(|h| h.hit()).count() as u64;
    let h = hits_from_gpu(&cast.hits);
    let img = match attrs {
        Some(a) => Some(attr_image_gpu(GpuContext::get()?, &h, (a, form), |v| {
            th.attr_index(v)
        })?),
        None => None,
    };
    b.cast_outputs((h, img), (cast.gpu_s, hits), depth, dump, out)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A GPU camera cast's batch holds no rays unless they were read back:
    /// the rate and the `rays` counter count the cast's results.
    #[test]
    fn cast_outputs_count_the_results_when_the_batch_holds_no_rays() {
        let b = Batch::<f32> {
            o: Vec::new(),
            d: Vec::new(),
            shape: vec![2, 3],
            near: 0.0,
            far: 1.0,
            kind: None,
        };
        let h = VoxelHits::<f32> {
            hit: vec![0; 6],
            t: vec![-1.0; 6],
            leaf: vec![[-1; 3]; 6],
            normal: vec![[0.0; 3]; 6],
            iters: vec![0; 6],
            capped: 0,
        };
        let mut out = Outputs::default();
        b.cast_outputs((h, None), (2e-6, 0), 4, false, &mut out)
            .unwrap();
        assert_eq!(out.counters["rays"], 6);
        assert!((out.metrics["mrays_per_s"] - 3.0).abs() < 1e-9);
    }
}
