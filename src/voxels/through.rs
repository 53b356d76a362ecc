//! What a scene's rays are cast through ([`Through`]: the octree, the DAG,
//! or the octree with contours) and by which CPU path ([`CastPath`]: per
//! ray, the referee, by packets, SSE, from beam starts, or in AVX2 lanes), on the CPU or uploaded to the GPU.

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::gpu::voxels::{GpuAddressing, GpuContours, GpuOctree};
use crate::gpu::GpuContext;

use super::beam::cast_all_beam;
use super::cast::{Absolute, CastParams, CastReal, Relative};
use super::dag::Dag;
use super::gpu::contour_lut;
use super::octree::Octree;
use super::packet::{cast_all_packet, cast_all_packet_dag};
use super::render::{
    cast_all, cast_all_contours, cast_all_dag, cast_all_lanes, cast_all_sse, VoxelHits,
};

/// The CPU cast path (`voxels.render` param `cast`).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum CastPath {
    /// One ray at a time ([`super::cast`]): the referee of the packets.
    #[default]
    PerRay,
    /// [`super::packet`]: lanes in lockstep, identical results.
    Packet,
    /// [`super::cast_sse`]: one ray at a time, its three axes in one SSE
    /// register, identical results (f32 only).
    Sse,
    /// [`super::beam`]: each tile of a camera image starts at its
    /// conservative beam bound (tiles that meet nothing answered as misses),
    /// then the lane cast (f32; the per-ray loop otherwise): identical hit,
    /// t, leaf, normal, fewer iterations.
    Beam,
    /// [`super::cast_lanes`]: two groups of 8 (AVX2) or 16 (AVX-512) lanes,
    /// one ray per lane, lanes refilled from the stream, identical results
    /// (f32 only).
    Lanes,
}

impl CastPath {
    /// Every path, the referee first.
    pub const ALL: [CastPath; 5] = [
        CastPath::PerRay,
        CastPath::Packet,
        CastPath::Sse,
        CastPath::Beam,
        CastPath::Lanes,
    ];

    /// The path's name in scene and metric keys.
    pub fn name(self) -> &'static str {
        match self {
            CastPath::PerRay => "per_ray",
            CastPath::Packet => "packet",
            CastPath::Sse => "sse",
            CastPath::Beam => "beam",
            CastPath::Lanes => "lanes",
        }
    }
}

fn f32_only(path: CastPath) -> Error {
    Error::NotSupported(format!(
        "the {} cast is f32 only: use cast: per_ray or packet",
        path.name()
    ))
}

/// What a scene's rays are cast through, on either backend.
#[derive(Clone, Copy, Debug)]
pub enum Through<'a> {
    /// The ESVO octree ([`super::cast::cast`]).
    Octree(&'a Octree),
    /// The DAG ([`super::cast::cast_dag`]).
    Dag(&'a Dag),
    /// The octree with contours per attribute index ([`super::cast::cast_contours`]).
    Contours(&'a Octree, &'a [u32]),
}

impl<'a> Through<'a> {
    /// What a scene with these parts is cast through: the DAG when there is
    /// one (it has no contours), else the octree with or without contours.
    pub fn pick(tree: &'a Octree, dag: Option<&'a Dag>, contours: Option<&'a [u32]>) -> Self {
        match (dag, contours) {
            (Some(g), _) => Through::Dag(g),
            (None, Some(cs)) => Through::Contours(tree, cs),
            (None, None) => Through::Octree(tree),
        }
    }

    /// The CPU cast of every ray (the GPU kernel's twin for `F = f32`).
    pub fn cast_all<F: CastReal>(
        &self,
        o: &[[F; 3]],
        d: &[[F; 3]],
        p: &CastParams,
    ) -> VoxelHits<F> {
        match *self {
            Through::Octree(t) => cast_all(t, o, d, p),
            Through::Dag(g) => cast_all_dag(g, o, d, p),
            Through::Contours(t, cs) => cast_all_contours(t, cs, o, d, p).0,
        }
    }

    /// [`Through::cast_all`] by `path` (the packet and SSE paths have no
    /// contours; the SSE path is f32 only) of rays shaped `shape` (the beam
    /// path tiles an (H, W) image).
    pub fn cast_by<F: CastReal>(
        &self,
        path: CastPath,
        shape: &[usize],
        o: &[[F; 3]],
        d: &[[F; 3]],
        p: &CastParams,
    ) -> Result<VoxelHits<F>> {
        match (path, *self) {
            (CastPath::PerRay, _) => Ok(self.cast_all(o, d, p)),
            (CastPath::Packet, Through::Octree(t)) => Ok(cast_all_packet(t, o, d, p)),
            (CastPath::Packet, Through::Dag(g)) => Ok(cast_all_packet_dag(g, o, d, p)),
            (CastPath::Sse, Through::Octree(t)) => {
                cast_all_sse::<F, Relative>(&t.nodes, t.depth, o, d, p)
                    .ok_or_else(|| f32_only(path))
            }
            (CastPath::Sse, Through::Dag(g)) => {
                cast_all_sse::<F, Absolute>(&g.nodes, g.depth, o, d, p)
                    .ok_or_else(|| f32_only(path))
            }
            (CastPath::Beam, Through::Octree(t)) => Ok(cast_all_beam::<F, Relative>(
                &t.nodes, t.depth, shape, o, d, p,
            )),
            (CastPath::Beam, Through::Dag(g)) => Ok(cast_all_beam::<F, Absolute>(
                &g.nodes, g.depth, shape, o, d, p,
            )),
            (CastPath::Lanes, Through::Octree(t)) => {
                cast_all_lanes::<F, Relative>(&t.nodes, t.depth, o, d, p)
                    .ok_or_else(|| f32_only(path))
            }
            (CastPath::Lanes, Through::Dag(g)) => {
                cast_all_lanes::<F, Absolute>(&g.nodes, g.depth, o, d, p)
                    .ok_or_else(|| f32_only(path))
            }
            (_, Through::Contours(..)) => Err(Error::NotSupported(format!(
                "the {path:?} cast has no contours: use cast: per_ray"
            ))),
        }
    }

    /// The attribute index of voxel `v`'s leaf (the octree's leaf
    /// numbering; the DAG finds the same index).
    pub fn attr_index(&self, v: [u32; 3]) -> Option<u32> {
        match *self {
            Through::Octree(t) | Through::Contours(t, _) => t.attr_index(v),
            Through::Dag(g) => g.attr_index(v),
        }
    }

    /// Uploads the structure (and the contour table) to the GPU, with the
    /// kernel specialised for its addressing.
    pub fn upload<'c>(&self, ctx: &'c GpuContext) -> Result<GpuOctree<'c>> {
        match *self {
            Through::Octree(t) => {
                GpuOctree::with(ctx, &t.nodes, t.depth, GpuAddressing::Relative, None)
            }
            Through::Dag(g) => {
                GpuOctree::with(ctx, &g.nodes, g.depth, GpuAddressing::Absolute, None)
            }
            Through::Contours(t, cs) => {
                let lut = contour_lut();
                let c = GpuContours {
                    codes: cs,
                    lut: &lut,
                };
                GpuOctree::with(ctx, &t.nodes, t.depth, GpuAddressing::Relative, Some(c))
            }
        }
    }
}
