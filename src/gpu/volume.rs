//! The volume forward kernels on the GPU (`kernels/volume.wgsl`): `f_fused`
//! and the unfused `f_samp` (count, fill) -> `f_int` chain, batched so the
//! per-sample buffers fit the adapter's binding limit and the memory budget.
//!
//! Inputs are the kernels' own typed parameters ([`VolumeInput`]), already
//! rounded to f32 by the renderer (`src/volume/gpu.rs` builds them from the
//! volume renderer's f32 fields), so this module never imports a renderer.
//! CPU twins: `src/volume/fused.rs` `march_ray`, `src/volume/sample.rs`
//! `f_samp`, `src/volume/integrate.rs` `integrate_ray`; parity cases
//! `gpu_vol_*` in `TESTS/gpu/manifest.yaml`.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use super::rays::RayParams;
use super::volume_hash::{GpuHash, HashParams};
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;

use super::codes::FieldKind;
pub use super::codes::FLAG_UNSTABLE;

/// A node-aligned grid in f32: `n = (nx, ny, nz)`, `data` C order with
/// `ch` channels innermost, `scale = (n - 1) / (max - min)` per axis.
#[derive(Clone, Copy, Debug)]
pub struct GpuGrid<'a> {
    pub n: [u32; 3],
    pub data: &'a [f32],
    pub clamp: bool,
    pub bmin: [f32; 3],
    pub scale: [f32; 3],
}

/// The density field: a `FieldKind` code and its parameters.
#[derive(Clone, Copy, Debug)]
pub enum GpuField<'a> {
    Constant {
        s: f32,
    },
    Slabs {
        axis: u32,
        breaks: &'a [f32],
        sigma: &'a [f32],
    },
    Gaussian {
        amplitude: f32,
        mean: [f32; 3],
        inv_two_var: f32,
    },
    Shell {
        centre: [f32; 3],
        r0: f32,
        r1: f32,
        s: f32,
    },
    Linear {
        a: f32,
        g: [f32; 3],
    },
    Grid(GpuGrid<'a>),
    /// Hash grid + MLP: density and colour from one network (its colour
    /// replaces `color` / `color_grid`).
    Hash(GpuHash<'a>),
}

/// The occupancy bitfield (x fastest, `res^3` bits).
#[derive(Clone, Copy, Debug)]
pub struct GpuOccupancy<'a> {
    pub res: u32,
    pub bits: &'a [u32],
    pub bmin: [f32; 3],
    pub inv_cell: [f32; 3],
}

/// Everything the volume kernels take besides the camera.
#[derive(Clone, Copy, Debug)]
pub struct VolumeInput<'a> {
    pub field: GpuField<'a>,
    /// Constant colour, used when `color_grid` is `None`.
    pub color: [f32; 3],
    /// A 3-channel colour grid.
    pub color_grid: Option<GpuGrid<'a>>,
    pub dt: f32,
    pub max_steps: u32,
    pub early_stop: f32,
    /// `Some(seed)`: stratified sampling.
    pub stratified: Option<u32>,
    /// Log-transmittance path (else the product path).
    pub log_path: bool,
    pub background: [f32; 3],
    pub occupancy: Option<GpuOccupancy<'a>>,
}

/// Uniform of `kernels/volume.wgsl` (keep in sync with `struct VolParams`
/// there): 10 vec4<f32>, 2 vec4<u32>, 16 scalars; 256 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct VolParams {
    pub background: [f32; 4],
    pub color_const: [f32; 4],
    pub field_a: [f32; 4],
    pub field_b: [f32; 4],
    pub sg_bmin: [f32; 4],
    pub sg_scale: [f32; 4],
    pub cg_bmin: [f32; 4],
    pub cg_scale: [f32; 4],
    pub occ_bmin: [f32; 4],
    pub occ_inv_cell: [f32; 4],
    pub sg_n: [u32; 4],
    pub cg_n: [u32; 4],
    pub dt: f32,
    pub early_stop: f32,
    pub max_steps: u32,
    pub stratified: u32,
    pub seed: u32,
    pub log_path: u32,
    pub field_kind: u32,
    pub color_grid: u32,
    pub slab_axis: u32,
    pub slab_n: u32,
    pub occ_res: u32,
    pub ray_base: u32,
    pub ray_count: u32,
    /// Always 0: the kernels' Kahan sums XOR with it so that no driver can
    /// fold their compensation away (kernels/volume.wgsl `kahan`).
    pub opaque_zero: u32,
    pub _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<VolParams>() == 256);

/// One ray's result (`struct RayOut` of the kernel; 48 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRayOut {
    pub rgb: [f32; 3],
    pub trans: f32,
    pub log_trans: f32,
    pub depth: f32,
    pub opacity: f32,
    pub n: u32,
    pub saturated: u32,
    /// `FLAG_*` bits of `src/volume/sample.rs`, plus [`FLAG_UNSTABLE`].
    pub flags: u32,
    pub skipped: u32,
    pub pixel: u32,
}
const _: () = assert!(std::mem::size_of::<GpuRayOut>() == 48);

fn v4(a: [f32; 3]) -> [f32; 4] {
    [a[0], a[1], a[2], 0.0]
}

impl VolParams {
    pub(super) fn new(v: &VolumeInput) -> VolParams {
        let mut p = VolParams::zeroed();
        p.background = v4(v.background);
        p.color_const = v4(v.color);
        p.dt = v.dt;
        p.early_stop = v.early_stop;
        p.max_steps = v.max_steps;
        (p.stratified, p.seed) = v.stratified.map_or((0, 0), |s| (1, s));
        p.log_path = v.log_path as u32;
        match v.field {
            GpuField::Constant { s } => {
                (p.field_kind, p.field_a[0]) = (FieldKind::Constant as u32, s)
            }
            GpuField::Slabs { axis, sigma, .. } => {
                (p.field_kind, p.slab_axis, p.slab_n) =
                    (FieldKind::Slabs as u32, axis, sigma.len() as u32);
            }
            GpuField::Gaussian {
                amplitude,
                mean,
                inv_two_var,
            } => {
                p.field_kind = FieldKind::Gaussian as u32;
                p.field_a = [amplitude, inv_two_var, 0.0, 0.0];
                p.field_b = v4(mean);
            }
            GpuField::Shell { centre, r0, r1, s } => {
                p.field_kind = FieldKind::Shell as u32;
                p.field_a = [r0, r1, s, 0.0];
                p.field_b = v4(centre);
            }
            GpuField::Linear { a, g } => {
                p.field_kind = FieldKind::Linear as u32;
                p.field_a[0] = a;
                p.field_b = v4(g);
            }
            GpuField::Grid(g) => {
                p.field_kind = FieldKind::Grid as u32;
                p.sg_bmin = v4(g.bmin);
                p.sg_scale = v4(g.scale);
                p.sg_n = [g.n[0], g.n[1], g.n[2], g.clamp as u32];
            }
            GpuField::Hash(_) => p.field_kind = FieldKind::HashMlp as u32,
        }
        if let Some(g) = v.color_grid {
            p.color_grid = 1;
            p.cg_bmin = v4(g.bmin);
            p.cg_scale = v4(g.scale);
            p.cg_n = [g.n[0], g.n[1], g.n[2], g.clamp as u32];
        }
        if let Some(o) = v.occupancy {
            p.occ_res = o.res;
            p.occ_bmin = v4(o.bmin);
            p.occ_inv_cell = v4(o.inv_cell);
        }
        p
    }
}

/// Checks what the kernels assume (finite, in-range, consistent sizes).
pub(super) fn validate(v: &VolumeInput) -> Result<()> {
    let at = "gpu volume input";
    let grid_ok = |g: &GpuGrid, ch: u64, what: &str| -> Result<()> {
        let n = g.n.iter().map(|&x| x as u64).product::<u64>() * ch;
        if g.n.iter().any(|&x| x < 2) || n != g.data.len() as u64 {
            return Err(Error::invalid(
                at,
                format!("{what}: {} values for shape {:?} x {ch}", g.data.len(), g.n),
            ));
        }
        if n > i32::MAX as u64 {
            return Err(Error::NotSupported(format!(
                "{what}: {n} values is over the kernel's 2^31 index range"
            )));
        }
        Ok(())
    };
    match v.field {
        GpuField::Grid(g) => grid_ok(&g, 1, "density grid")?,
        GpuField::Slabs {
            axis,
            breaks,
            sigma,
        } => {
            if axis > 2 || sigma.is_empty() || breaks.len() != sigma.len() + 1 {
                return Err(Error::invalid(
                    at,
                    "slabs: need axis <= 2 and n + 1 breaks for n > 0 sigmas",
                ));
            }
        }
        _ => {}
    }
    if let Some(g) = &v.color_grid {
        grid_ok(g, 3, "colour grid")?;
    }
    if let Some(o) = &v.occupancy {
        if o.res == 0 || (o.bits.len() as u64) * 32 < (o.res as u64).pow(3) {
            return Err(Error::invalid(
                at,
                format!("occupancy: {} words for {}^3 cells", o.bits.len(), o.res),
            ));
        }
    }
    let finite = [v.dt, v.early_stop]
        .iter()
        .chain(&v.background)
        .chain(&v.color)
        .all(|x| x.is_finite());
    if !(finite && v.dt > 0.0 && v.max_steps > 0) {
        return Err(Error::invalid(
            at,
            "dt, early_stop, background and colour must be finite, dt > 0, max_steps > 0",
        ));
    }
    Ok(())
}

/// The read-only buffers every volume kernel may bind: slabs, density
/// grid, colour grid, occupancy, the hash field's uniform and parameters
/// (16-byte placeholders where unused).
pub(super) struct FieldBuffers {
    pub slabs: wgpu::Buffer,
    pub sgrid: wgpu::Buffer,
    pub cgrid: wgpu::Buffer,
    pub occ: wgpu::Buffer,
    pub hash_u: wgpu::Buffer,
    pub hparams: wgpu::Buffer,
}

impl FieldBuffers {
    pub(super) fn new(ctx: &GpuContext, v: &VolumeInput) -> Result<FieldBuffers> {
        let none: &[f32] = &[];
        let slabs: Vec<f32> = match v.field {
            GpuField::Slabs { breaks, sigma, .. } => breaks.iter().chain(sigma).copied().collect(),
            _ => vec![],
        };
        let sg = match v.field {
            GpuField::Grid(g) => g.data,
            _ => none,
        };
        let cg = v.color_grid.map_or(none, |g| g.data);
        let occ: &[u32] = v.occupancy.map_or(&[], |o| o.bits);
        let (hu, hp) = match v.field {
            GpuField::Hash(h) => (h.uniform(), h.params),
            _ => (HashParams::zeroed(), none),
        };
        Ok(FieldBuffers {
            hash_u: uniform(ctx, "volume hash field", &hu),
            hparams: storage_in(ctx, "volume hash parameters", hp)?,
            slabs: storage_in(ctx, "volume slabs", &slabs)?,
            sgrid: storage_in(ctx, "volume density grid", sg)?,
            cgrid: storage_in(ctx, "volume colour grid", cg)?,
            occ: storage_in(ctx, "volume occupancy", occ)?,
        })
    }
}

/// Loop back-edges `kernels/volume.wgsl` may take per lattice point (the
/// lattice loop, occupancy's two axis loops, `tri_setup` for density and
/// colour, the colour channel loop): a bound, for drivers that cap loops.
const LOOP_ITERS_PER_SAMPLE: u64 = 16;

/// Refuses plans whose longest ray could exceed the driver's loop cap
/// (see [`GpuContext::max_loop_iterations`]) instead of silently cutting
/// rays short. The longest ray is bounded by the box diagonal. A hash
/// field is checked here too (it needs the context): its shapes, and one
/// network evaluation against the cap.
pub(super) fn check_loop_cap(ctx: &GpuContext, gen: &RayGen, v: &VolumeInput) -> Result<()> {
    if let GpuField::Hash(h) = v.field {
        h.validate(ctx)?;
    }
    let Some(cap) = ctx.max_loop_iterations() else {
        return Ok(());
    };
    let diag = (0..3)
        .map(|a| (gen.aabb.max[a] - gen.aabb.min[a]).powi(2))
        .sum::<f64>()
        .sqrt();
    let len = diag.min(gen.far - gen.near);
    let lattice = ((len / v.dt as f64).ceil() + 1.0).min(v.max_steps as f64) as u64;
    if lattice * LOOP_ITERS_PER_SAMPLE > cap {
        return Err(Error::NotSupported(format!(
            "rays of up to {lattice} lattice points (dt {}, max_steps {}) exceed this driver's loop cap \
             ({cap} iterations per invocation, Mesa llvmpipe); at most {} points run on it",
            v.dt,
            v.max_steps,
            cap / LOOP_ITERS_PER_SAMPLE
        )));
    }
    Ok(())
}

/// Per-stage seconds of a GPU render (submit to readback done).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct GpuTimes {
    pub fused: f64,
    pub samp: f64,
    pub int: f64,
}

/// Rays of the region of `gen` in region order, as `u32` count.
pub(super) fn ray_count(gen: &RayGen) -> Result<u32> {
    let r = gen.region();
    r.width
        .checked_mul(r.height)
        .ok_or_else(|| Error::invalid("width/height", "more than 2^32 rays"))
}

/// `f_fused` on the GPU: one result per ray of the region, in region
/// order, and the seconds the kernel and readback took.
pub fn f_fused(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    v: &VolumeInput,
    budget: &MemBudget,
) -> Result<(Vec<GpuRayOut>, f64)> {
    gen.validate()?;
    cam.validate()?;
    validate(v)?;
    check_loop_cap(ctx, gen, v)?;
    refuse_hash(v, "f_fused")?;
    let n = ray_count(gen)? as u64;
    let out_bytes = n * std::mem::size_of::<GpuRayOut>() as u64;
    budget.check(
        "gpu f_fused results",
        bytes_for(n, 2 * std::mem::size_of::<GpuRayOut>() as u64),
    )?;
    let pipe = pipeline(ctx, "volume", "f_fused")?;
    let cu = uniform(ctx, "f_fused camera", &RayParams::new(cam, gen));
    let vu = uniform(ctx, "f_fused volume", &VolParams::new(v));
    let fb = FieldBuffers::new(ctx, v)?;
    let out = storage_out(ctx, "f_fused results", out_bytes)?;
    let pass = Pass {
        label: "f_fused",
        pipeline: &pipe,
        buffers: &[
            (0, &cu),
            (1, &vu),
            (2, &fb.slabs),
            (3, &fb.sgrid),
            (4, &fb.cgrid),
            (5, &fb.occ),
            (6, &out),
        ],
        n,
        wg: 64,
    };
    let rb = run(ctx, "f_fused", &[pass], &[&out])?;
    Ok((rb.take(0, n as usize)?, rb.gpu_s))
}

/// Refuses a hash field in a one-thread-a-ray kernel: the network runs one
/// thread a sample (`kernels/hash_mlp.wgsl` header), in the unfused chain.
pub(super) fn refuse_hash(v: &VolumeInput, what: &str) -> Result<()> {
    if matches!(v.field, GpuField::Hash(_)) {
        return Err(Error::NotSupported(format!(
            "{what}: a hash_mlp field runs on the GPU in the unfused chain only (its network \
             runs one thread a sample)"
        )));
    }
    Ok(())
}

/// Bytes per sample of the unfused GPU chain: samp0 + samp1 (32) and the
/// persisted (alpha, log T) (8).
pub const UNFUSED_BYTES_PER_SAMPLE: u64 = 40;

/// The unfused chain's output: per-ray results (region order; `pixel` is
/// filled on the host), the per-sample persisted `(alpha, log T)` and
/// `off`, and the seconds of each stage.
pub struct Unfused {
    pub rays: Vec<GpuRayOut>,
    pub off: Vec<u64>,
    pub persist: Vec<[f32; 2]>,
    pub times: GpuTimes,
}

/// One batch of the unfused chain after its `f_samp_fill` and `f_int` ran:
/// what a later pass over the same rays binds (`kernels/volume.wgsl`
/// bindings), with the batch's rays `start..end` of the region.
pub(super) struct Batch<'a> {
    pub cu: &'a wgpu::Buffer,
    pub fb: &'a FieldBuffers,
    /// The batch's `VolParams` (ray_base = start, ray_count = end - start).
    pub bu: &'a wgpu::Buffer,
    pub results: &'a wgpu::Buffer,
    pub off: &'a wgpu::Buffer,
    pub samp0: &'a wgpu::Buffer,
    pub samp1: &'a wgpu::Buffer,
    pub persist: &'a wgpu::Buffer,
    pub start: u32,
    pub end: u32,
}

/// Batches of whole rays whose samples fit `max_samples`, each starting at
/// a multiple of `align` rays (the last may end anywhere).
fn plan_batches(off: &[u64], max_samples: u64, align: u32) -> Result<Vec<(u32, u32)>> {
    let n = (off.len() - 1) as u32;
    let mut out = Vec::new();
    let mut start = 0u32;
    while start < n {
        let mut end = start;
        while end < n && off[end as usize + 1] - off[start as usize] <= max_samples {
            end += 1;
        }
        if end < n {
            end -= (end - start) % align;
        }
        if end == start {
            return Err(Error::NotSupported(format!(
                "unfused chain: rays {start}..{} have {} samples, over the {max_samples} one binding holds",
                (start + align).min(n),
                off[(start + align).min(n) as usize] - off[start as usize]
            )));
        }
        out.push((start, end));
        start = end;
    }
    Ok(out)
}

/// The unfused chain on the GPU: `f_samp_count` over all rays, offsets
/// scanned on the host, then per batch (rays whose samples fit the binding
/// limit and `max_batch_bytes`) `f_samp_fill` and `f_int` in one submit.
/// `keep` keeps the persisted per-sample buffers (else only per-ray results).
pub fn unfused(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    v: &VolumeInput,
    budget: &MemBudget,
    keep: bool,
) -> Result<Unfused> {
    unfused_with(ctx, cam, gen, v, budget, keep, 1, |_| Ok(()))
}

/// [`unfused`], calling `after` on every batch once its `f_int` ran,
/// batches aligned to `align` rays.
#[allow(clippy::too_many_arguments)]
pub(super) fn unfused_with(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    v: &VolumeInput,
    budget: &MemBudget,
    keep: bool,
    align: u32,
    mut after: impl FnMut(&Batch) -> Result<()>,
) -> Result<Unfused> {
    gen.validate()?;
    cam.validate()?;
    validate(v)?;
    check_loop_cap(ctx, gen, v)?;
    let n = ray_count(gen)?;
    let ray_bytes = std::mem::size_of::<GpuRayOut>() as u64;
    budget.check(
        "gpu unfused per-ray buffers",
        bytes_for(n as u64, 2 * ray_bytes + 16),
    )?;
    let cu = uniform(ctx, "unfused camera", &RayParams::new(cam, gen));
    let fb = FieldBuffers::new(ctx, v)?;
    let base = VolParams::new(v);
    let count_p = pipeline(ctx, "volume", "f_samp_count")?;
    let fill_p = pipeline(ctx, "volume", "f_samp_fill")?;
    let int_p = pipeline(ctx, "volume", "f_int")?;
    let hash_p = match v.field {
        GpuField::Hash(_) => Some(pipeline(ctx, "hash_mlp", "f_hash_fill")?),
        _ => None,
    };
    let mut times = GpuTimes::default();

    // 1. Count samples per ray (all rays at once: 16 bytes a ray).
    let counts_all = storage_out(ctx, "f_samp counts", n as u64 * 16)?;
    let mut vp = base;
    vp.ray_count = n;
    let vu = uniform(ctx, "f_samp_count volume", &vp);
    let pass = Pass {
        label: "f_samp_count",
        pipeline: &count_p,
        buffers: &[(0, &cu), (1, &vu), (5, &fb.occ), (7, &counts_all)],
        n: n as u64,
        wg: 64,
    };
    let rb = run(ctx, "f_samp_count", &[pass], &[&counts_all])?;
    times.samp += rb.gpu_s;
    let counts: Vec<[u32; 4]> = rb.take(0, n as usize)?;
    let mut off = Vec::with_capacity(n as usize + 1);
    off.push(0u64);
    for c in &counts {
        off.push(off[off.len() - 1] + c[0] as u64);
    }
    let total = off[n as usize];
    if keep {
        budget.check("gpu unfused persisted buffers", bytes_for(total, 8 + 8))?;
    }

    // 2. Batches of whole rays whose samples fit one binding.
    let max_samples = (ctx.max_binding() / 32)
        .min(budget.bytes / UNFUSED_BYTES_PER_SAMPLE)
        .max(1);
    let results = storage_out(ctx, "unfused results", n as u64 * ray_bytes)?;
    let mut persist = Vec::with_capacity(if keep { total as usize } else { 0 });
    for (start, end) in plan_batches(&off, max_samples, align)? {
        let m = off[end as usize] - off[start as usize];
        let local_off: Vec<u32> = (start..=end)
            .map(|r| (off[r as usize] - off[start as usize]) as u32)
            .collect();
        let local_counts: Vec<[u32; 4]> = counts[start as usize..end as usize].to_vec();
        let mut bp = base;
        (bp.ray_base, bp.ray_count) = (start, end - start);
        let bu = uniform(ctx, "unfused batch volume", &bp);
        let offb = storage_in(ctx, "f_samp off", &local_off)?;
        let cnt = storage_in_rw(ctx, "f_samp batch counts", &local_counts)?;
        let s0 = storage_out(ctx, "f_samp samp0", m * 16)?;
        let s1 = storage_out(ctx, "f_samp samp1", m * 16)?;
        let pe = storage_out(ctx, "f_int persist", m * 8)?;
        let rays = (end - start) as u64;
        let fill = Pass {
            label: "f_samp_fill",
            pipeline: &fill_p,
            buffers: &[
                (0, &cu),
                (1, &bu),
                (2, &fb.slabs),
                (3, &fb.sgrid),
                (4, &fb.cgrid),
                (5, &fb.occ),
                (7, &cnt),
                (8, &offb),
                (9, &s0),
                (10, &s1),
            ],
            n: rays,
            wg: 64,
        };
        let hash_buffers = [
            (0, &cu),
            (1, &bu),
            (8, &offb),
            (9, &s0),
            (10, &s1),
            (17, &fb.hash_u),
            (18, &fb.hparams),
        ];
        let mut passes = vec![fill];
        if let Some(hp) = &hash_p {
            passes.push(Pass {
                label: "f_hash_fill",
                pipeline: hp,
                buffers: &hash_buffers,
                n: m,
                wg: 64,
            });
        }
        let rb = run(ctx, "f_samp_fill", &passes, &[])?;
        times.samp += rb.gpu_s;
        let int = Pass {
            label: "f_int",
            pipeline: &int_p,
            buffers: &[
                (1, &bu),
                (6, &results),
                (7, &cnt),
                (8, &offb),
                (9, &s0),
                (10, &s1),
                (11, &pe),
            ],
            n: rays,
            wg: 64,
        };
        let read: &[&wgpu::Buffer] = if keep { &[&pe] } else { &[] };
        let rb = run(ctx, "f_int", &[int], read)?;
        times.int += rb.gpu_s;
        if keep {
            persist.extend(rb.take::<[f32; 2]>(0, m as usize)?);
        }
        after(&Batch {
            cu: &cu,
            fb: &fb,
            bu: &bu,
            results: &results,
            off: &offb,
            samp0: &s0,
            samp1: &s1,
            persist: &pe,
            start,
            end,
        })?;
    }
    let rb = run(ctx, "unfused readback", &[], &[&results])?;
    times.int += rb.gpu_s;
    let rays: Vec<GpuRayOut> = rb.take(0, n as usize)?;
    Ok(Unfused {
        rays,
        off,
        persist,
        times,
    })
}

/// A storage buffer initialised with `data` that kernels may also write.
fn storage_in_rw<T: Pod>(ctx: &GpuContext, label: &str, data: &[T]) -> Result<wgpu::Buffer> {
    let bytes: &[u8] = bytemuck::cast_slice(data);
    let b = storage_out(ctx, label, bytes.len() as u64)?;
    ctx.queue.write_buffer(&b, 0, bytes);
    Ok(b)
}

#[cfg(test)]
mod tests {
    use super::super::kernels::source;

    /// The Kahan step XORs its sum with `opaque_zero`, which the host
    /// leaves 0: without it NVIDIA's compiler folds the compensation away
    /// (an H200's vol_tiny opacity 1.06e-6 high), which no CPU adapter
    /// shows, so the guard is on the text (`VolParams::new` starts from
    /// zeroed words).
    #[test]
    fn kahan_sums_are_hidden_from_reassociation() {
        let src = source("volume").unwrap();
        let step = &src[src.find("fn kahan(").unwrap()..];
        let step = &step[..step.find("\n}").unwrap()];
        assert!(step.contains("^ V.opaque_zero"), "{step}");
    }
}
