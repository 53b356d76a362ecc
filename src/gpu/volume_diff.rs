//! `f_diff` on the GPU (`kernels/volume_diff.wgsl` entry `f_diff_ray`): the
//! unfused forward chain runs batch by batch ([`super::volume`]) and each
//! batch's persisted samples are walked backward on the device while they
//! are still there; gradients accumulate across batches in one buffer and
//! come back once.
//!
//! **Deterministic reduction.** Every gradient value (density grid node,
//! colour grid node and channel, constant/slab parameter, constant colour
//! channel) is a 64-bit two's-complement fixed-point number held in two
//! `atomic<u32>` words, `value = integer / scale`, `scale` a power of two.
//! The kernel adds `trunc(v scale)` with a hand-made carry ([`fx_split`] is
//! its CPU twin); integer addition is associative, so the sum is the same
//! whatever order the threads run in: two runs are bit-identical. `scale`
//! is chosen from a bound `B` of any one value's sum of magnitudes
//! ([`DiffInput::bound_sigma`], `bound_color`; derived in
//! `src/volume/diff/gpu.rs`) as the largest power of two with
//! `B scale <= 2^61`, so no sum can overflow; a per-add magnitude over 2^62
//! or a non-finite gradient sets a flag and the pass is refused. Resolution:
//! `1 / scale = B / 2^61`, i.e. 4.3e-19 of the bound.
//!
//! **Fast path.** `float_atomic` adds f32 by compare-exchange on the low
//! word instead: thread order decides the rounding, so runs may differ in
//! the last bits. It is measured against the fixed-point path.
//!
//! **Hash field.** Per batch, `f_diff_ray` runs twice around
//! `f_diff_hash` (one thread a sample): stage 0 stores each sample's
//! `dL/d(sigma, rgb)`, `f_diff_hash` back-propagates it through the network
//! (every parameter one fixed-point value, scale from `bound_hash`) and
//! leaves `dL/dx`, stage 1 walks again with it for the pose.
//!
//! **Pose.** Each workgroup reduces its 64 rays' `dL/d(rho, w)` in a fixed
//! tree in workgroup memory; batches start at multiples of 64 rays so a
//! workgroup's partial has one slot; the host sums the partials in ray
//! order in f64.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use super::volume::{ray_count, unfused_with, GpuField, GpuRayOut, VolumeInput};
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;

/// Rays per workgroup of `f_diff_ray` (and the batch alignment).
const WG: u32 = 64;

/// Storage buffers `f_diff_ray` binds in one stage.
const STORAGE_BINDINGS: u32 = 12;

/// What the backward takes besides the forward's [`VolumeInput`].
#[derive(Clone, Copy, Debug)]
pub struct DiffInput<'a> {
    /// Two per ray of the region (region order): `(dL/dr, dL/dg, dL/db,
    /// dL/d depth)` and `(dL/d opacity, 0, 0, 0)`.
    pub up: &'a [[f32; 4]],
    /// Rows of the camera-to-world rotation, and its centre.
    pub pose_r: [[f32; 3]; 3],
    pub pose_c: [f32; 3],
    /// The clip box and near/far, as `f_ray` clips.
    pub bmin: [f32; 3],
    pub bmax: [f32; 3],
    pub near: f32,
    pub far: f32,
    /// Bounds of the sum of |contributions| to any one density value
    /// (grid node or parameter) and any one colour value.
    pub bound_sigma: f64,
    pub bound_color: f64,
    /// The same for any one hash field parameter.
    pub bound_hash: f64,
    /// f32 compare-exchange atomics instead of fixed point.
    pub float_atomic: bool,
}

/// Gradients of a GPU backward pass (flat C order where grid-shaped).
#[derive(Clone, Debug, PartialEq)]
pub struct GpuGrads {
    /// Density grid nodes (empty unless the field is a grid).
    pub sigma: Vec<f32>,
    /// Colour grid nodes x 3 (empty unless the colour is a grid).
    pub color: Vec<f32>,
    /// Constant (1) or slab (one per slab) density parameters.
    pub param: Vec<f32>,
    /// Constant colour.
    pub color_const: [f32; 3],
    /// Hash field parameters (flat order; empty unless the field is one).
    pub hash: Vec<f32>,
    /// `dL/d delta` (rho, w), summed over workgroups in ray order in f64.
    pub dcam: [f64; 6],
    /// Samples walked backward.
    pub samples: u64,
    /// Seconds of the forward chain and of the backward passes with the
    /// gradient readback (submit to readback done).
    pub forward_s: f64,
    pub backward_s: f64,
}

/// Uniform of `kernels/volume_diff.wgsl` (keep in sync with `struct
/// DiffParams` there): 6 vec4<f32>, 3 f32, 9 u32; 144 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
struct DiffParams {
    pose_r0: [f32; 4],
    pose_r1: [f32; 4],
    pose_r2: [f32; 4],
    pose_c: [f32; 4],
    bmin: [f32; 4],
    bmax: [f32; 4],
    fx_sigma: f32,
    fx_color: f32,
    off_sigma: u32,
    off_color: u32,
    off_param: u32,
    off_ccol: u32,
    off_flags: u32,
    float_atomic: u32,
    part_base: u32,
    off_hash: u32,
    fx_hash: f32,
    hash_stage: u32,
}
const _: () = assert!(std::mem::size_of::<DiffParams>() == 144);

/// The largest power of two `s` with `bound s <= 2^61` (1 for a zero
/// bound), within f32's exponent range.
pub fn fx_scale(bound: f64) -> f32 {
    if bound.is_nan() || bound <= 0.0 || bound.is_infinite() {
        return 1.0;
    }
    let e = (61.0 - bound.log2()).floor().clamp(-120.0, 120.0);
    (2.0f64).powi(e as i32) as f32
}

/// The two words the kernel adds for `v` at `scale` (CPU twin of WGSL
/// `fx_add`): `trunc(|v| scale)` split into (low, high), negated in two's
/// complement for negative `v`; `None` where the kernel flags it.
pub fn fx_split(v: f32, scale: f32) -> Option<(u32, u32)> {
    let a = v * scale;
    let m = a.abs();
    if m.is_nan() || m >= 2f32.powi(62) {
        return None;
    }
    let hi_m = (m * 2f32.powi(-32)).floor();
    let (mut lo, mut hi) = ((m - hi_m * 2f32.powi(32)) as u32, hi_m as u32);
    if a < 0.0 {
        hi = (!hi).wrapping_add((lo == 0) as u32);
        lo = (!lo).wrapping_add(1);
    }
    Some((lo, hi))
}

/// The value of a fixed-point pair (low, high) at `scale`.
pub fn fx_value(lo: u32, hi: u32, scale: f32) -> f64 {
    (((hi as u64) << 32 | lo as u64) as i64) as f64 / scale as f64
}

/// Value offsets of the accumulator: density nodes, colour nodes x 3,
/// parameters, hash field parameters, constant colour x 3, the flag value;
/// and the total.
struct Layout {
    sigma: u32,
    color: u32,
    param: u32,
    hash: u32,
    ccol: u32,
    flags: u32,
    total: u64,
}

impl Layout {
    fn of(v: &VolumeInput) -> Result<Layout> {
        let nodes = |n: [u32; 3]| n.iter().map(|&x| x as u64).product::<u64>();
        let ns = match v.field {
            GpuField::Grid(g) => nodes(g.n),
            _ => 0,
        };
        let nc = v.color_grid.map_or(0, |g| 3 * nodes(g.n));
        let np = match v.field {
            GpuField::Constant { .. } => 1,
            GpuField::Slabs { sigma, .. } => sigma.len() as u64,
            _ => 0,
        };
        let nh = match v.field {
            GpuField::Hash(h) => h.params.len() as u64,
            _ => 0,
        };
        let total = ns + nc + np + nh + 3 + 1;
        let as_u32 = |x: u64| {
            u32::try_from(x).map_err(|_| {
                Error::NotSupported(format!("f_diff: {total} gradient values exceed 2^32"))
            })
        };
        Ok(Layout {
            sigma: 0,
            color: as_u32(ns)?,
            param: as_u32(ns + nc)?,
            hash: as_u32(ns + nc + np)?,
            ccol: as_u32(ns + nc + np + nh)?,
            flags: as_u32(ns + nc + np + nh + 3)?,
            total,
        })
    }
}

/// The backward pass of the scene `v` seen through `cam` / `gen` for the
/// upstream gradients of `d`, with the unfused forward it needs.
pub fn f_diff(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    v: &VolumeInput,
    d: &DiffInput,
    budget: &MemBudget,
) -> Result<GpuGrads> {
    let n = ray_count(gen)?;
    if d.up.len() as u64 != 2 * n as u64 {
        return Err(Error::invalid(
            "gpu f_diff upstream",
            format!("{} entries for {n} rays (two per ray)", d.up.len()),
        ));
    }
    if let Some(bad) = d.up.iter().flatten().find(|x| !x.is_finite()) {
        return Err(Error::invalid(
            "gpu f_diff upstream",
            format!("a non-finite upstream gradient {bad}"),
        ));
    }
    let have = ctx.limits.max_storage_buffers_per_shader_stage;
    if have < STORAGE_BINDINGS {
        return Err(Error::NotSupported(format!(
            "f_diff_ray binds {STORAGE_BINDINGS} storage buffers; this adapter allows {have}"
        )));
    }
    let lay = Layout::of(v)?;
    let groups = n.div_ceil(WG) as u64;
    budget.check(
        "gpu f_diff accumulators",
        bytes_for(lay.total, 8 * 2).and_then(|b| b.checked_add(groups * 64)),
    )?;
    let (fx_sigma, fx_color) = (fx_scale(d.bound_sigma), fx_scale(d.bound_color));
    let fx_hash = fx_scale(d.bound_hash);
    let v4 = |a: [f32; 3], w: f32| [a[0], a[1], a[2], w];
    let base = DiffParams {
        pose_r0: v4(d.pose_r[0], 0.0),
        pose_r1: v4(d.pose_r[1], 0.0),
        pose_r2: v4(d.pose_r[2], 0.0),
        pose_c: v4(d.pose_c, 0.0),
        bmin: v4(d.bmin, d.near),
        bmax: v4(d.bmax, d.far),
        fx_sigma,
        fx_color,
        off_sigma: lay.sigma,
        off_color: lay.color,
        off_param: lay.param,
        off_ccol: lay.ccol,
        off_flags: lay.flags,
        float_atomic: d.float_atomic as u32,
        part_base: 0,
        off_hash: lay.hash,
        fx_hash,
        hash_stage: 0,
    };
    let pipe = pipeline(ctx, "volume_diff", "f_diff_ray")?;
    let hash_pipe = match v.field {
        GpuField::Hash(_) => Some(pipeline(ctx, "volume_diff", "f_diff_hash")?),
        _ => None,
    };
    let upb = storage_in(ctx, "f_diff upstream", d.up)?;
    let acc = storage_out(ctx, "f_diff accumulators", lay.total * 8)?;
    let part = storage_out(ctx, "f_diff pose partials", groups * 32)?;
    let mut backward_s = 0.0;
    let fwd = unfused_with(ctx, cam, gen, v, budget, false, WG, |b| {
        let du = |hash_stage| {
            let p = DiffParams {
                part_base: b.start / WG,
                hash_stage,
                ..base
            };
            uniform(ctx, "f_diff params", &p)
        };
        let (du0, du1) = (du(0), du(1));
        let m = (b.samp0.size() / 16).max(1);
        let sgrad_bytes = if hash_pipe.is_some() { m * 16 } else { 16 };
        budget.check("gpu f_diff per-sample gradients", Some(sgrad_bytes))?;
        let sgrad = storage_out(ctx, "f_diff per-sample gradients", sgrad_bytes)?;
        let walk = |du| {
            [
                (0, b.cu),
                (1, b.bu),
                (2, &b.fb.slabs),
                (3, &b.fb.sgrid),
                (4, &b.fb.cgrid),
                (6, b.results),
                (8, b.off),
                (9, b.samp0),
                (10, b.samp1),
                (11, b.persist),
                (12, du),
                (13, &upb),
                (14, &acc),
                (15, &part),
                (19, &sgrad),
            ]
        };
        let (w0, w1) = (walk(&du0), walk(&du1));
        let rays = (b.end - b.start) as u64;
        let ray_pass = |buffers| Pass {
            label: "f_diff_ray",
            pipeline: &pipe,
            buffers,
            n: rays,
            wg: WG,
        };
        let hash_buffers = [
            (0, b.cu),
            (1, b.bu),
            (8, b.off),
            (9, b.samp0),
            (12, &du1),
            (14, &acc),
            (17, &b.fb.hash_u),
            (18, &b.fb.hparams),
            (19, &sgrad),
        ];
        let passes = match &hash_pipe {
            None => vec![ray_pass(&w0)],
            Some(hp) => vec![
                ray_pass(&w0),
                Pass {
                    label: "f_diff_hash",
                    pipeline: hp,
                    buffers: &hash_buffers,
                    n: m,
                    wg: WG,
                },
                ray_pass(&w1),
            ],
        };
        backward_s += run(ctx, "f_diff_ray", &passes, &[])?.gpu_s;
        Ok(())
    })?;
    let rb = run(ctx, "f_diff readback", &[], &[&acc, &part])?;
    backward_s += rb.gpu_s;
    let words: Vec<u32> = rb.take(0, 2 * lay.total as usize)?;
    let parts: Vec<f32> = rb.take(1, 8 * groups as usize)?;
    if words[2 * lay.flags as usize] != 0 {
        return Err(Error::Gpu(
            "f_diff: a gradient was not finite or exceeded the fixed-point range".into(),
        ));
    }
    let value = |i: u32, scale: f32| -> f32 {
        let w = 2 * i as usize;
        if d.float_atomic {
            f32::from_bits(words[w])
        } else {
            fx_value(words[w], words[w + 1], scale) as f32
        }
    };
    let mut dcam = [0.0f64; 6];
    for p in parts.chunks(8) {
        for q in 0..6 {
            dcam[q] += p[q] as f64;
        }
    }
    Ok(GpuGrads {
        sigma: (lay.sigma..lay.color).map(|i| value(i, fx_sigma)).collect(),
        color: (lay.color..lay.param).map(|i| value(i, fx_color)).collect(),
        param: (lay.param..lay.hash).map(|i| value(i, fx_sigma)).collect(),
        hash: (lay.hash..lay.ccol).map(|i| value(i, fx_hash)).collect(),
        color_const: [0, 1, 2].map(|c| value(lay.ccol + c, fx_color)),
        dcam,
        samples: fwd.rays.iter().map(|r: &GpuRayOut| r.n as u64).sum(),
        forward_s: fwd.times.samp + fwd.times.int,
        backward_s,
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rand_f64;

    fn add(acc: &mut (u32, u32), w: (u32, u32)) {
        let (lo, c) = acc.0.overflowing_add(w.0);
        acc.0 = lo;
        acc.1 = acc.1.wrapping_add(w.1).wrapping_add(c as u32);
    }

    #[test]
    fn fx_sums_equal_the_exact_sum_to_one_unit_per_add_in_any_order() {
        let vals: Vec<f32> = (0..2000)
            .map(|i| {
                ((rand_f64(7, i, 0, 0) - 0.5) * 10f64.powf(rand_f64(7, i, 0, 1) * 8.0 - 4.0)) as f32
            })
            .collect();
        let bound: f64 = vals.iter().map(|v| v.abs() as f64).sum();
        let s = fx_scale(bound);
        let exact: f64 = vals.iter().map(|&v| v as f64).sum();
        let mut fwd = (0u32, 0u32);
        let mut rev = (0u32, 0u32);
        for &v in &vals {
            add(&mut fwd, fx_split(v, s).unwrap());
        }
        for &v in vals.iter().rev() {
            add(&mut rev, fx_split(v, s).unwrap());
        }
        assert_eq!(fwd, rev, "integer sums do not depend on order");
        let got = fx_value(fwd.0, fwd.1, s);
        assert!(
            (got - exact).abs() <= vals.len() as f64 / s as f64,
            "{got} vs {exact}"
        );
    }

    #[test]
    fn fx_split_negates_in_twos_complement() {
        let s = 2f32.powi(40);
        for v in [-1.5f32, -1e-9, -3.0e5, 1.5, 7.25e5, -2.0f32.powi(-40)] {
            let (lo, hi) = fx_split(v, s).unwrap();
            let back = fx_value(lo, hi, s);
            assert!((back - v as f64).abs() <= 1.0 / s as f64, "{v}: {back}");
        }
        assert_eq!(fx_split(-1.0, 1.0), Some((u32::MAX, u32::MAX)));
    }

    #[test]
    fn fx_split_refuses_what_would_overflow() {
        assert!(fx_split(f32::NAN, 1.0).is_none());
        assert!(fx_split(1.0, 2f32.powi(62)).is_none());
        assert!(fx_split(f32::INFINITY, 1.0).is_none());
    }

    #[test]
    fn fx_scale_keeps_the_bound_under_2_pow_61() {
        for b in [1e-12, 1e-3, 1.0, 3.0, 1e6, 1e15] {
            let s = fx_scale(b) as f64;
            assert!(b * s <= 2f64.powi(61) && b * s > 2f64.powi(59), "{b}: {s}");
        }
        assert_eq!(fx_scale(0.0), 1.0);
        assert_eq!(fx_scale(f64::NAN), 1.0);
    }
}
