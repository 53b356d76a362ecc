//! Attribute and mesh operations of the `voxels` renderer (issue 14): wiring only.
//!
//! | op | what |
//! | --- | --- |
//! | `voxels.attributes` | per-leaf colour and normal, plain and DXT: colour PSNR, normal angles, bytes per voxel |
//! | `voxels.mesh_referee` | SAT referee of a mesh scene's voxelisation: `missing` (voxels a checked triangle overlaps but the octree leaves empty; every `tri_stride`-th triangle), `untouched` (solid voxels of every `leaf_stride`-th leaf that no triangle meets); voxelise and build seconds, peak RSS |

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::tensor::Outputs;
use crate::voxels::attributes::{leaf_normals, Attributes};
use crate::voxels::octree::build;
use crate::voxels::outputs::{attr_metrics, build_metrics, mesh_metrics};
use crate::voxels::referee_mesh::{check_triangles, check_voxels};
use crate::voxels::shape::Shape;

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "voxels.attributes",
        doc: "plain and DXT per-leaf colour/normal: {plain,dxt}_colour_psnr_db, _normal_{mean,p99,max}_deg, _bytes_per_voxel",
        params: &[],
        support: Support::Cpu,
        run: attributes,
    },
    OpEntry {
        name: "voxels.mesh_referee",
        doc: "separating-axis referee of the mesh voxelisation: missing, untouched, ties; voxelise_s, build_s, peak_rss_bytes",
        params: &["tri_stride", "leaf_stride", "margin"],
        support: Support::Cpu,
        run: mesh_referee,
    },
];

fn attributes(ctx: &OpCtx) -> Result<Outputs> {
    let sc = super::voxels::load(ctx)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let ns = leaf_normals(&sc.shape, &tree)?;
    let mut out = Outputs::default();
    attr_metrics(&mut out, &Attributes::build(&ns), &ns, &tree);
    build_metrics(&mut out, &tree);
    Ok(out)
}

/// Peak resident set of this process (VmHWM), bytes; 0 off Linux.
fn peak_rss_bytes() -> f64 {
    let s = std::fs::read_to_string("/proc/self/status").unwrap_or_default();
    s.lines()
        .find_map(|l| l.strip_prefix("VmHWM:"))
        .and_then(|v| v.trim().trim_end_matches("kB").trim().parse::<f64>().ok())
        .map_or(0.0, |kb| kb * 1024.0)
}

fn mesh_referee(ctx: &OpCtx) -> Result<Outputs> {
    let sc = super::voxels::load(ctx)?;
    let Shape::Mesh(m) = &sc.shape else {
        return Err(Error::invalid(ctx.scene()?.at(), "voxels.mesh_referee needs a `shape: {type: mesh}` scene"));
    };
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let margin: f64 = ctx.param_or("margin", 1e-9)?;
    let tc = check_triangles(&m.mesh, &tree, ctx.param_or("tri_stride", 1usize)?, margin);
    let vc = check_voxels(&m.mesh, &tree, ctx.param_or("leaf_stride", 1usize)?, margin);
    let mut out = Outputs::default();
    mesh_metrics(&mut out, m, &tc, &vc);
    build_metrics(&mut out, &tree);
    out.metric("peak_rss_bytes", peak_rss_bytes());
    Ok(out)
}
