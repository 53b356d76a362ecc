//! The ESVO octree and DAG casts on the GPU (`kernels/voxels.wgsl`):
//! [`GpuOctree`] holds one scene's nodes (octree or DAG, with contours when
//! asked), uploaded once, and casts batches of camera rays (generated on the
//! GPU by common.wgsl `camera_ray`, entry `cast_camera`) or given rays
//! (entry `cast_rays`), camera rays from the beam starts of
//! `kernels/voxel_beam.wgsl` where the adapter has f64. CPU twins:
//! `src/voxels/cast.rs` `cast`, `cast_dag`, `cast_contours` (f32),
//! `src/voxels/beam.rs` `beam_nears`; parity cases `voxel_gpu_*` in
//! `TESTS/voxels/manifest_gpu.yaml`. Inputs are plain node words and f32
//! parameters: nothing here imports the voxel renderer.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run_timed, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline_with;
use super::rays::RayParams;
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::thread_order::{thread_count, ThreadOrder};
use crate::rays::RayGen;

/// Uniform of `kernels/voxels.wgsl` (keep in sync with `struct VoxParams`
/// there): 12 scalars, 48 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct VoxParams {
    pub near: f32,
    pub far: f32,
    pub lod_orig: f32,
    pub lod_dir: f32,
    pub lod_on: u32,
    pub depth: u32,
    pub max_iter: u32,
    pub n: u32,
    pub write_rays: u32,
    pub order: u32,
    pub beam: u32,
    pub _pad: u32,
}
const _: () = assert!(std::mem::size_of::<VoxParams>() == 48);

/// One ray's result (`struct VoxHit` of the kernel; 32 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuVoxelHit {
    pub t: f32,
    pub voxel: [u32; 3],
    pub iters: u32,
    /// Bit 0 hit, bit 1 capped, bit 2 solid leaf, bits 8..16 level, bits 16..32 node words read.
    pub flags: u32,
    /// Byte a holds `normal[a] + 1`.
    pub normal: u32,
    pub attr: u32,
}
const _: () = assert!(std::mem::size_of::<GpuVoxelHit>() == 32);

impl GpuVoxelHit {
    pub fn hit(&self) -> bool {
        self.flags & 1 != 0
    }

    pub fn capped(&self) -> bool {
        self.flags & 2 != 0
    }

    pub fn level(&self) -> u32 {
        self.flags >> 8 & 0xFF
    }

    /// Node words (4 bytes each) the cast read: descriptors, far pointers
    /// and the leaf's attribute base (saturating at 65535).
    pub fn loads(&self) -> u32 {
        self.flags >> 16
    }

    /// The entered face's outward normal (zero on a miss or an inside start).
    pub fn normal(&self) -> [i8; 3] {
        [0, 8, 16].map(|s| (self.normal >> s & 0xFF) as i8 - 1)
    }

    /// Everything but how the cast got there (its iterations and node
    /// words read): t's bits, voxel, normal, attribute, hit / capped /
    /// solid flags and level. Casts from the beam start and from `near`
    /// agree on it.
    pub fn outcome(&self) -> (u32, [u32; 3], u32, u32, u32) {
        (
            self.t.to_bits(),
            self.voxel,
            self.normal,
            self.attr,
            self.flags & 0xFFFF,
        )
    }
}

/// The cast's options, already in the kernel's f32 (the CPU cast rounds
/// its f64 parameters the same way: `F::of`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuCastParams {
    pub near: f32,
    /// Finite (WGSL may assume no infinities): `f32::MAX` for none.
    pub far: f32,
    /// `(orig_size / 2, dir_size / 2)` in f32, as the CPU cast computes them.
    pub lod: Option<(f32, f32)>,
    pub max_iter: u32,
    /// Which camera ray a thread casts (`cast_camera` only).
    pub order: ThreadOrder,
    /// Camera rays start at their tile's beam start (`cast_camera` only;
    /// run where the adapter has f64 and there is no LOD cut;
    /// [`GpuCast::beam`] says whether it ran).
    pub beam: bool,
    /// Casts run back to back in one submission (at least 1), the
    /// results the last one's and [`GpuCast`]'s times per cast: a GPU fed
    /// one short cast at a time between readbacks may never leave its idle
    /// clock (an H200 sampled at 345 of its 1980 MHz through such casts).
    pub repeat: u32,
}

/// One 8x8 pixel tile's beam start (`struct BeamTile` of the kernels):
/// `meets` 0 when no non-empty node box meets the tile's cone (its rays are
/// misses), else its rays are cast from `near`.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuBeamTile {
    pub near: f32,
    pub meets: u32,
}

/// What a batch returned: per-ray results, the camera rays when asked for
/// (`[ox, oy, oz, dx, dy, dz]` per ray), the GPU seconds (submit to
/// readback), the kernels' seconds on the GPU clock (where the adapter has
/// timestamps; the beam pre-pass included), the iteration cap the kernel
/// ran with, and whether the rays started at beam starts.
pub struct GpuCast {
    pub hits: Vec<GpuVoxelHit>,
    pub rays: Vec<[f32; 6]>,
    pub gpu_s: f64,
    pub kernel_s: Option<f64>,
    pub max_iter: u32,
    pub beam: bool,
}

/// How the kernel finds a node's children (its `ADDRESSING` override
/// constant; the CPU's `voxels::cast::Addressing` policies).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum GpuAddressing {
    /// ESVO octree: relative pointer, popcount, far pointers.
    Relative = 0,
    /// DAG: child `c` at the absolute slot `high word + c`.
    Absolute = 1,
}

/// Contours for the kernel: `codes[attr]` (0: none) and the decode table
/// (`kernels/voxels.wgsl` `contour_lut`: 3 f32 per 18-bit normal code,
/// then 128 offsets, then 128 thicknesses).
#[derive(Clone, Copy, Debug)]
pub struct GpuContours<'a> {
    pub codes: &'a [u32],
    pub lut: &'a [f32],
}

/// Length of the contour decode table.
pub const CONTOUR_LUT_LEN: usize = 3 * (1 << 18) + 2 * 128;

/// One scene's octree (or DAG) on the GPU: the node and contour buffers
/// (uploaded once), the two pipelines of `kernels/voxels.wgsl` and the beam
/// pre-pass of `kernels/voxel_beam.wgsl` (where the adapter has f64),
/// specialised for the addressing and contours.
pub struct GpuOctree<'c> {
    ctx: &'c GpuContext,
    nodes: wgpu::Buffer,
    contours: wgpu::Buffer,
    lut: wgpu::Buffer,
    depth: u32,
    camera: wgpu::ComputePipeline,
    given: wgpu::ComputePipeline,
    beam: Option<wgpu::ComputePipeline>,
}

/// Pixels per side of a beam tile (`BEAM_TILE` of kernels/voxels.wgsl; the
/// CPU's `voxels::beam::TILE`).
pub const BEAM_TILE: u32 = 8;

/// Beam tiles of a `w` x `h` region: 8x8 pixels, or runs of 64 pixels
/// in a region one row high (as the CPU's `voxels::tiles::Tiling`).
fn beam_tile_count(w: u32, h: u32) -> u64 {
    if h == 1 {
        w.div_ceil(BEAM_TILE * BEAM_TILE) as u64
    } else {
        w.div_ceil(BEAM_TILE) as u64 * h.div_ceil(BEAM_TILE) as u64
    }
}

/// The beam pre-pass's pipeline for `addressing` (it reads no contours)
/// where the adapter has f64 and its compiler takes the kernel; `None`
/// (casts from `near`, a warning) otherwise, so a backend that cannot build
/// it still casts.
fn beam_pipeline(ctx: &GpuContext, addressing: GpuAddressing) -> Option<wgpu::ComputePipeline> {
    if !ctx.has_f64() {
        return None;
    }
    let k = [("ADDRESSING", addressing as u32 as f64)];
    pipeline_with(ctx, "voxel_beam", "beam_nears", &k)
        .inspect_err(|e| tracing::warn!("voxel beam pre-pass off: {e}"))
        .ok()
}

/// The bindings of `beam_nears` (kernels/voxel_beam.wgsl): camera, params,
/// nodes, and the tiles it writes.
fn beam_bindings<'a>(
    (cu, vu, nodes): (&'a wgpu::Buffer, &'a wgpu::Buffer, &'a wgpu::Buffer),
    tiles: &'a wgpu::Buffer,
) -> [(u32, &'a wgpu::Buffer); 4] {
    [(0, cu), (1, vu), (2, nodes), (9, tiles)]
}

/// The beam pre-pass over `n_tiles` tiles, one invocation a tile.
fn beam_pass<'a>(
    pipeline: &'a wgpu::ComputePipeline,
    buffers: &'a [(u32, &'a wgpu::Buffer)],
    n_tiles: u64,
) -> Pass<'a> {
    Pass {
        label: "beam_nears",
        pipeline,
        buffers,
        n: n_tiles,
        wg: 64,
    }
}

/// Rays per dispatch: bounded so one batch's results fit a binding.
fn batch_rays(ctx: &GpuContext) -> u64 {
    (ctx.max_binding() / 32).min(1 << 24)
}

impl<'c> GpuOctree<'c> {
    /// Uploads `nodes` (the layout of `src/voxels/octree.rs`) of a depth-`depth` tree.
    pub fn new(ctx: &'c GpuContext, nodes: &[u32], depth: u32) -> Result<GpuOctree<'c>> {
        Self::with(ctx, nodes, depth, GpuAddressing::Relative, None)
    }

    /// Uploads `nodes` in the layout `addressing` reads (`src/voxels/octree.rs`
    /// or `src/voxels/dag.rs`), with `contours` (octree only).
    pub fn with(
        ctx: &'c GpuContext,
        nodes: &[u32],
        depth: u32,
        addressing: GpuAddressing,
        contours: Option<GpuContours>,
    ) -> Result<GpuOctree<'c>> {
        if let Some(c) = contours {
            if addressing != GpuAddressing::Relative || c.lut.len() != CONTOUR_LUT_LEN {
                return Err(Error::invalid(
                    "gpu voxel contours",
                    format!(
                        "contours need the octree and a {CONTOUR_LUT_LEN}-entry table (got {:?}, {})",
                        addressing,
                        c.lut.len()
                    ),
                ));
            }
        }
        if nodes.len() < 2 || !nodes.len().is_multiple_of(2) || !(1..=22).contains(&depth) {
            return Err(Error::invalid(
                "gpu voxel octree",
                format!(
                    "{} node words at depth {depth} (need an even count >= 2, depth 1..=22)",
                    nodes.len()
                ),
            ));
        }
        let k = [
            ("ADDRESSING", addressing as u32 as f64),
            ("CONTOURS", contours.is_some() as u32 as f64),
        ];
        let (codes, lut) = contours.map_or((&[0u32][..], &[0f32][..]), |c| (c.codes, c.lut));
        Ok(GpuOctree {
            ctx,
            nodes: storage_in(ctx, "voxel nodes", nodes)?,
            contours: storage_in(ctx, "voxel contours", codes)?,
            lut: storage_in(ctx, "voxel contour table", lut)?,
            depth,
            camera: pipeline_with(ctx, "voxels", "cast_camera", &k)?,
            given: pipeline_with(ctx, "voxels", "cast_rays", &k)?,
            beam: beam_pipeline(ctx, addressing),
        })
    }

    /// The beam pre-pass a camera cast with `p` runs: asked for, built (the
    /// adapter has f64), and no LOD cut (whose stop need not be solid).
    fn beam_for(&self, p: &GpuCastParams) -> Option<&wgpu::ComputePipeline> {
        self.beam.as_ref().filter(|_| p.beam && p.lod.is_none())
    }

    /// The iteration cap the kernel runs with: `max_iter`, clamped below
    /// the driver's loop cap (the cast's main loop is its only loop; 16
    /// iterations are left for `camera_ray`'s 3-axis clip loop) so the
    /// driver never cuts a ray short silently: a ray over the cap is a
    /// `capped` miss, as on the CPU.
    pub fn kernel_max_iter(&self, max_iter: u32) -> u32 {
        match self.ctx.max_loop_iterations() {
            Some(cap) => max_iter.min(cap.saturating_sub(16) as u32),
            None => max_iter,
        }
    }

    fn params(&self, p: &GpuCastParams, n: u32, write_rays: bool) -> Result<VoxParams> {
        if !(p.near.is_finite() && p.far.is_finite() && p.near <= p.far) {
            return Err(Error::invalid(
                "gpu voxel cast",
                format!(
                    "near {} and far {} must be finite, near <= far",
                    p.near, p.far
                ),
            ));
        }
        let (lod_on, (lod_orig, lod_dir)) = p.lod.map_or((0, (0.0, 0.0)), |l| (1, l));
        Ok(VoxParams {
            near: p.near,
            far: p.far,
            lod_orig,
            lod_dir,
            lod_on,
            depth: self.depth,
            max_iter: self.kernel_max_iter(p.max_iter),
            n,
            write_rays: write_rays as u32,
            order: p.order as u32,
            beam: 0,
            _pad: 0,
        })
    }

    /// Casts the camera rays of `gen`'s region, generated on the GPU, each
    /// thread the ray `p.order` gives it; results (and, with `keep_rays`,
    /// the rays read back) in region order.
    pub fn cast_camera(
        &self,
        cam: &Camera,
        gen: &RayGen,
        p: &GpuCastParams,
        keep_rays: bool,
        budget: &MemBudget,
    ) -> Result<GpuCast> {
        gen.validate()?;
        cam.validate()?;
        let roi = gen.region();
        let n = roi.width as u64 * roi.height as u64;
        if n > batch_rays(self.ctx) {
            return Err(Error::NotSupported(format!(
                "gpu voxel cast: {n} camera rays in one image, over the {} one batch holds",
                batch_rays(self.ctx)
            )));
        }
        // Hits (and rays) and their readback, plus the beam tiles' 8 bytes
        // per 64 rays (at most one byte a ray).
        budget.check(
            "gpu voxel cast results",
            bytes_for(n, 2 * (32 + if keep_rays { 24 } else { 0 }) + 1),
        )?;
        let pre_pass = self.beam_for(p);
        let beam = pre_pass.is_some();
        let vp = VoxParams {
            beam: beam as u32,
            ..self.params(p, n as u32, keep_rays)?
        };
        let cu = uniform(self.ctx, "voxel camera", &RayParams::new(cam, gen));
        let vu = uniform(self.ctx, "voxel params", &vp);
        let hits = storage_out(self.ctx, "voxel hits", n * 32)?;
        let rays = storage_out(self.ctx, "voxel rays", if keep_rays { n * 24 } else { 0 })?;
        // Without the pre-pass one tile stands bound (the kernel reads none).
        let n_tiles = if beam {
            beam_tile_count(roi.width, roi.height)
        } else {
            1
        };
        let tiles = storage_out(self.ctx, "voxel beam tiles", n_tiles * 8)?;
        let beam_buffers = beam_bindings((&cu, &vu, &self.nodes), &tiles);
        let cast_buffers = [
            (0, &cu),
            (1, &vu),
            (2, &self.nodes),
            (4, &hits),
            (5, &rays),
            (6, &self.contours),
            (7, &self.lut),
            (8, &tiles),
        ];
        let reps = p.repeat.max(1);
        let mut passes = Vec::with_capacity(2 * reps as usize);
        for _ in 0..reps {
            if let Some(bp) = pre_pass {
                passes.push(beam_pass(bp, &beam_buffers, n_tiles));
            }
            passes.push(Pass {
                label: "cast_camera",
                pipeline: &self.camera,
                buffers: &cast_buffers,
                n: thread_count(p.order, roi.width, roi.height),
                wg: 64,
            });
        }
        let read: Vec<&wgpu::Buffer> = if keep_rays {
            vec![&hits, &rays]
        } else {
            vec![&hits]
        };
        let rb = run_timed(self.ctx, "cast_camera", &passes, &read)?;
        let n = n as usize;
        let rays = if keep_rays {
            rb.take::<[f32; 6]>(1, n)?
        } else {
            Vec::new()
        };
        let per = 1.0 / reps as f64;
        Ok(GpuCast {
            hits: rb.take(0, n)?,
            rays,
            gpu_s: rb.gpu_s * per,
            kernel_s: rb.kernel_s.map(|s| s * per),
            max_iter: vp.max_iter,
            beam,
        })
    }

    /// The beam pre-pass alone (`kernels/voxel_beam.wgsl` `beam_nears`):
    /// one [`GpuBeamTile`] per tile of `gen`'s region (8x8 pixels row by
    /// row, runs of 64 in a region one row high); an error where the
    /// pre-pass was not built.
    pub fn beam_tiles(
        &self,
        cam: &Camera,
        gen: &RayGen,
        p: &GpuCastParams,
        budget: &MemBudget,
    ) -> Result<Vec<GpuBeamTile>> {
        gen.validate()?;
        cam.validate()?;
        let Some(bp) = &self.beam else {
            return Err(Error::NotSupported(
                "gpu voxel beam: not available (the adapter has no SHADER_F64, or its \
                 backend refused kernels/voxel_beam.wgsl)"
                    .into(),
            ));
        };
        let roi = gen.region();
        let n = roi.width as u64 * roi.height as u64;
        if n > u32::MAX as u64 {
            return Err(Error::NotSupported(format!(
                "gpu voxel beam: {n} camera rays in one image, over the {} the kernel counts",
                u32::MAX
            )));
        }
        let n_tiles = beam_tile_count(roi.width, roi.height);
        budget.check("gpu voxel beam tiles", bytes_for(n_tiles, 2 * 8))?;
        let vu = uniform(self.ctx, "voxel params", &self.params(p, n as u32, false)?);
        let cu = uniform(self.ctx, "voxel camera", &RayParams::new(cam, gen));
        let tiles = storage_out(self.ctx, "voxel beam tiles", n_tiles * 8)?;
        let buffers = beam_bindings((&cu, &vu, &self.nodes), &tiles);
        let pass = beam_pass(bp, &buffers, n_tiles);
        run_timed(self.ctx, "beam_nears", &[pass], &[&tiles])?.take(0, n_tiles as usize)
    }

    /// Casts given rays `[ox, oy, oz, dx, dy, dz]`, in batches that fit a binding.
    pub fn cast_rays(
        &self,
        rays: &[[f32; 6]],
        p: &GpuCastParams,
        budget: &MemBudget,
    ) -> Result<GpuCast> {
        let n = rays.len() as u64;
        budget.check("gpu voxel cast results", bytes_for(n, 2 * 32 + 24))?;
        let mut out = GpuCast {
            hits: Vec::with_capacity(rays.len()),
            rays: Vec::new(),
            gpu_s: 0.0,
            kernel_s: Some(0.0),
            max_iter: self.kernel_max_iter(p.max_iter),
            beam: false,
        };
        let reps = p.repeat.max(1);
        let per = 1.0 / reps as f64;
        for chunk in rays.chunks(batch_rays(self.ctx) as usize) {
            let m = chunk.len() as u64;
            let vu = uniform(self.ctx, "voxel params", &self.params(p, m as u32, false)?);
            let inb = storage_in(self.ctx, "voxel rays in", chunk)?;
            let hits = storage_out(self.ctx, "voxel hits", m * 32)?;
            let buffers = [
                (1, &vu),
                (2, &self.nodes),
                (3, &inb),
                (4, &hits),
                (6, &self.contours),
                (7, &self.lut),
            ];
            let pass = Pass {
                label: "cast_rays",
                pipeline: &self.given,
                buffers: &buffers,
                n: m,
                wg: 64,
            };
            let passes = vec![pass; reps as usize];
            let rb = run_timed(self.ctx, "cast_rays", &passes, &[&hits])?;
            out.hits.extend(rb.take::<GpuVoxelHit>(0, m as usize)?);
            out.gpu_s += rb.gpu_s * per;
            out.kernel_s = out.kernel_s.zip(rb.kernel_s).map(|(a, b)| a + b * per);
        }
        Ok(out)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hit_fields_unpack_flags_and_normal_bytes() {
        let h = GpuVoxelHit {
            flags: 1 | 4 | (9 << 8) | (40 << 16),
            normal: 0x01_02_00,
            ..GpuVoxelHit::default()
        };
        assert!(h.hit() && !h.capped());
        assert_eq!((h.level(), h.loads()), (9, 40));
        assert_eq!(h.normal(), [-1, 1, 0]);
    }
}
