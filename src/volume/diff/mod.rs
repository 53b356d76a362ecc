//! `f_diff`: the backward pass of emission–absorption rendering (seed 000,
//! module 6; issue 4). Gradients of a loss `L` given `dL/d rgb` per pixel
//! (and optionally `dL/d depth`, `dL/d opacity`) with respect to
//! - every sample's density and colour, scattered to dense-grid nodes
//!   through the trilinear weights (`dsigma`, `dcolor`), or summed per
//!   parameter for the constant and slab fields, per channel for a constant
//!   colour;
//! - the camera pose `delta = (rho, w)` of SCENES.md
//!   (`C2W <- C2W exp([[hat(w), rho], [0, 0]])` at delta = 0), including the
//!   dependence of `t0`, `t1` on the pose through the AABB clip.
//!
//! ## The per-ray walk (back to front, log domain)
//!
//! With `tau_k = sigma_k dt_k`, `T_k = exp(log T_k)`, `w_k = T_k alpha_k` and
//! the per-ray scalar emission `e_k = g . c_k + g_D t_k` (`g = dL/dC`,
//! `g_D = dL/d depth`), the suffix `s_k = sum_{j>k} w_j e_j + T_N (g . bg)`
//! is carried from the back (compensated sum), and
//!
//! `dL/dtau_k = T_{k+1} e_k - s_k + g_O T_N`,
//! `dL/dsigma_k = dL/dtau_k dt_k`, `dL/dc_k = g w_k`.
//!
//! `T_{k+1}` is `exp(log T_{k+1})` of the forward's own log-transmittance,
//! so nothing divides by `1 - alpha` and nothing subtracts a prefix from a
//! total: `sigma = 1e4` gives `T_{k+1} = 0` and finite gradients.
//! Early stop is a constant of the walk (its samples' gradients only).
//!
//! ## Camera
//!
//! `dL/dx_k = dL/dsigma_k grad sigma(x_k) + J_c(x_k)^T dL/dc_k`, summed into
//! `dL/do` and (times `t_k`) `dL/dd`. The sample position
//! `t_k = a_k + u_k (b_k - a_k)` and length `dt_k = b_k - a_k` move with `t0`
//! (`a_k = t0 + k dt`) and, for the last interval clipped at `t1`, with `t1`;
//! `t0`/`t1` move with `o`, `d` through the active slab plane
//! (`dt/do_a = -1/d_a`, `dt/dd_a = -t/d_a`; 0 where `near`/`far` is active).
//! Per ray `dL/drho = R^T dL/do`, `dL/dw = R^T ((o - c) x dL/do + d x dL/dd)`
//! (`R`, `c` rotation and centre of C2W), summed over rays in ray order.
//!
//! ## Chains and reductions
//!
//! - [`Chain::Unfused`] replays the persisted `f_samp` / `f_int` buffers;
//!   [`Chain::Fused`] re-walks each ray with the forward's own lattice,
//!   field queries and [`RayAcc`], keeping only one ray's samples at a time.
//!   Both feed the same per-ray walk, so they agree bit for bit.
//! - [`Reduce::Sorted`] (canonical): per-sample records in (ray, sample)
//!   order, stable-sorted by grid cell, then every node sums its eight
//!   neighbouring cells' records in a fixed order. Bit-identical across runs
//!   and thread counts. Memory: one record per sample.
//! - [`Reduce::Chunked`]: rays cut into a fixed number of contiguous chunks
//!   (not the thread count), each scattered into its own dense grid in ray
//!   order, chunks summed in order. Also deterministic; no per-sample memory
//!   in the fused chain; agrees with `Sorted` to rounding (judged).
//!
//! Rays and pixels: one ray per pixel of the generator's region, in region
//! order (as `f_ray` makes them); upstream gradients are indexed the same way.

mod camera;
mod field_grad;
pub mod gpu;
mod lanes;
mod pass;
mod reduce;
mod walk;

use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;

use super::field::{ColorField, Field, FieldDesc, Medium};
use super::integrate::{f_int, Integrated};
use super::sample::{f_samp, Samples};
use super::{prepare, Chain, Prepared, VolumeParams};

pub use camera::clip_planes;
use camera::Pose;
pub use field_grad::{cell_of, sigma_grad, Cell};
use pass::backward;
use walk::Ctx;

/// How grid gradients are reduced into nodes (see the module doc).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Reduce {
    Sorted,
    Chunked { chunks: u32 },
}

/// Default number of chunks of [`Reduce::Chunked`].
pub const DEFAULT_CHUNKS: u32 = 8;

/// Upstream gradients, one entry per ray (region order).
#[derive(Clone, Debug, PartialEq)]
pub struct Upstream<F> {
    pub rgb: Vec<[F; 3]>,
    pub depth: Option<Vec<F>>,
    pub opacity: Option<Vec<F>>,
}

/// Options of one backward pass.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct DiffOptions {
    pub chain: Chain,
    pub reduce: Reduce,
    /// Keep per-sample `dL/dsigma_k`, `dL/dc_k` (unfused chain only).
    pub per_sample: bool,
}

/// Gradients of a backward pass. Grid-shaped outputs are flat C order.
#[derive(Clone, Debug, PartialEq)]
pub struct Grads<F> {
    /// (nz, ny, nx) for a grid density.
    pub dsigma: Option<Vec<F>>,
    /// Per parameter for `constant` (1) and `slabs` (one per slab).
    pub dsigma_param: Option<Vec<F>>,
    /// (nz, ny, nx, 3) for a colour grid.
    pub dcolor: Option<Vec<F>>,
    /// For a constant colour.
    pub dcolor_const: Option<[F; 3]>,
    /// For a `hash_mlp` field: every parameter, the flat order of
    /// `HashMlpDesc::flat` (tables, then per layer weights and biases).
    pub dhash: Option<Vec<F>>,
    /// Per sample (unfused with `per_sample`), packed like `Samples`.
    pub dsigma_samples: Option<Vec<F>>,
    pub dcolor_samples: Option<Vec<[F; 3]>>,
    /// `dL/d delta`, SCENES.md order (rho_x, rho_y, rho_z, w_x, w_y, w_z).
    pub dcam: [F; 6],
    /// Samples walked backward.
    pub samples: u64,
    /// Bytes held per sample by this plan (buffers + reduction records).
    pub bytes_per_sample: u64,
    /// Seconds of the backward itself (for the unfused chain: without the
    /// forward that made its buffers).
    pub time_s: f64,
}

/// One integrated sample as the backward walk needs it.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rec<F> {
    /// Lattice index (for the t0/t1 dependence).
    pub k: u32,
    pub t: F,
    pub dt: F,
    pub sigma: F,
    pub c: [F; 3],
    /// log T_k, before the sample.
    pub log_t: F,
    pub alpha: F,
}

/// A compensated (Kahan) sum: long rays (10^5 samples) keep f32 accuracy.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct Ksum<F> {
    pub(super) s: F,
    c: F,
}

impl<F: Real> Ksum<F> {
    #[inline]
    pub(super) fn add(&mut self, x: F) {
        super::integrate::kahan_add(&mut self.s, &mut self.c, x);
    }
}

/// Per-sample results of [`backward_ray`], back to front.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct SampleGrad<F> {
    pub dtau: F,
    pub dsigma: F,
    pub dcolor: [F; 3],
    /// The sample's weight `w_k`.
    pub w: F,
}

/// The back-to-front walk of one ray (module doc): calls `each(i, grad)`
/// for `i = n-1 .. 0`. `log_tn` is the ray's final log T, `g`, `gd`, `go`
/// the upstream gradients of rgb, depth and opacity.
#[inline]
pub fn backward_ray<F: Real>(
    recs: &[Rec<F>],
    log_tn: F,
    bg: [F; 3],
    g: [F; 3],
    gd: F,
    go: F,
    mut each: impl FnMut(usize, SampleGrad<F>),
) {
    let tn = log_tn.exp();
    let mut s = tn * (g[0] * bg[0] + g[1] * bg[1] + g[2] * bg[2]);
    let mut sc = F::zero();
    let got = go * tn;
    // T_{k+1} of sample k is T_k of sample k + 1: one exp per sample.
    let mut t_next = tn;
    for i in (0..recs.len()).rev() {
        let r = &recs[i];
        let t_k = r.log_t.exp();
        let w = t_k * r.alpha;
        let e = g[0] * r.c[0] + g[1] * r.c[1] + g[2] * r.c[2] + gd * r.t;
        let dtau = t_next * e - s + got;
        each(
            i,
            SampleGrad {
                dtau,
                dsigma: dtau * r.dt,
                dcolor: [g[0] * w, g[1] * w, g[2] * w],
                w,
            },
        );
        super::integrate::kahan_add(&mut s, &mut sc, w * e);
        t_next = t_k;
    }
}

/// The forward state an unfused backward reads (what a training loop keeps
/// from its forward pass).
pub struct Forward<F> {
    pub rays: Rays<F>,
    pub samples: Samples<F>,
    pub integrated: Integrated<F>,
}

/// Runs the unfused forward chain, keeping its buffers.
pub fn forward_buffers<F: Real>(
    gen: &RayGen,
    cam: &Camera,
    params: &VolumeParams,
    budget: &MemBudget,
) -> Result<Forward<F>> {
    let prep = prepare::<F>(params, &gen.aabb, budget)?;
    let rays = f_ray::<F>(cam, gen, budget)?;
    let samples = f_samp(&rays, &prep.medium, &prep.march, prep.occ.as_ref(), budget)?;
    budget.check(
        "f_int buffers",
        bytes_for(samples.len() as u64, Integrated::<F>::BYTES_PER_SAMPLE),
    )?;
    let integrated = f_int(&samples, &prep.march);
    Ok(Forward {
        rays,
        samples,
        integrated,
    })
}

/// `f_diff`: the backward pass of `params` rendered through `cam` / `gen`
/// for upstream gradients `up` (one per ray of the region). With
/// [`Chain::Unfused`], `fwd` supplies the forward buffers (or they are made
/// here, outside the timed backward); [`Chain::Fused`] re-walks every ray.
/// Builds its own [`Prepared`] plan (the f32 medium the forward builds):
/// a caller that renders the same frame shares one with
/// [`f_diff_prepared`].
pub fn f_diff<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    up: &Upstream<F>,
    opt: &DiffOptions,
    fwd: Option<&Forward<F>>,
    budget: &MemBudget,
) -> Result<Grads<F>> {
    let prep = prepare::<F>(params, &gen.aabb, budget)?;
    f_diff_prepared(cam, gen, params, &prep, up, opt, fwd, budget, Kernel::Lanes)
}

/// How the fused chain walks its rays backward.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// 8 rays at a time in AVX2 lanes where they cover the pass
    /// (`diff/lanes.rs`), else the scalar walk.
    Lanes,
    /// Ray by ray (the referee of the lanes; for measuring them).
    Scalar,
}

/// [`f_diff`] over `prep`, the [`Prepared`] plan of `params` (built once
/// per frame and shared with the forward: the medium, occupancy and
/// march), with the walk chosen by `kernel` (same bits either way). Where
/// the medium is the packed `[sigma, r, g, b]` grid, the density and
/// colour grids are not converted again: the backward reads their cells'
/// geometry ([`Grid::geometry`](super::field::Grid::geometry)) and the
/// packed values.
#[allow(clippy::too_many_arguments)]
pub fn f_diff_prepared<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    prep: &Prepared<F>,
    up: &Upstream<F>,
    opt: &DiffOptions,
    fwd: Option<&Forward<F>>,
    budget: &MemBudget,
    kernel: Kernel,
) -> Result<Grads<F>> {
    let m = prep.march;
    m.validate()?;
    gen.validate()?;
    cam.validate()?;
    let (field, color) = match &prep.medium {
        Medium::Packed(p) => (Field::Grid(p.geometry(1)), ColorField::Grid(p.geometry(3))),
        _ => (params.field.to_real::<F>(), params.color.to_real::<F>()),
    };
    let made;
    let (rays, buffers) = match (opt.chain, fwd) {
        (Chain::Unfused, Some(f)) => (&f.rays, Some((&f.samples, &f.integrated))),
        (Chain::Unfused, None) => {
            made = forward_buffers::<F>(gen, cam, params, budget)?;
            (&made.rays, Some((&made.samples, &made.integrated)))
        }
        (Chain::Fused, _) => {
            made = Forward {
                rays: f_ray::<F>(cam, gen, budget)?,
                samples: Samples {
                    off: vec![0],
                    ray_id: vec![],
                    t: vec![],
                    dt: vec![],
                    sigma: vec![],
                    color: vec![],
                    flags: vec![],
                    skipped: 0,
                },
                integrated: Integrated {
                    rays: vec![],
                    alpha: vec![],
                    log_t: vec![],
                },
            };
            (&made.rays, None)
        }
    };
    if let Some((s, it)) = buffers {
        if s.off.len() != rays.len() + 1 || it.rays.len() != rays.len() {
            return Err(Error::invalid(
                "f_diff",
                "forward buffers do not belong to these rays",
            ));
        }
    }
    let medium = &prep.medium;
    let shared_cell = match (&field, &color) {
        (Field::Grid(a), ColorField::Grid(b)) => {
            (a.nx, a.ny, a.nz, a.oob) == (b.nx, b.ny, b.nz, b.oob)
                && a.bmin == b.bmin
                && a.scale == b.scale
        }
        _ => false,
    };
    let cx = Ctx {
        medium,
        field: &field,
        color: &color,
        m: &m,
        occ: prep.occ.as_ref(),
        rays,
        up,
        pose: Pose::of(cam),
        shared_cell,
        packed: match medium {
            Medium::Packed(p) if shared_cell => Some(p),
            _ => None,
        },
        bmin: gen.aabb.min.map(F::of),
        bmax: gen.aabb.max.map(F::of),
        near: F::of(gen.near),
        far: F::of(gen.far),
    };
    backward(&cx, buffers, opt, budget, kernel == Kernel::Lanes)
}

/// Whether the field has grid-shaped density gradients (else per sample or
/// per parameter only).
pub fn has_grid_density(f: &FieldDesc) -> bool {
    matches!(f, FieldDesc::Grid(_))
}

#[cfg(test)]
mod tests;
