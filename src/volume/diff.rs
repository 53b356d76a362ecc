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

use std::time::Instant;

use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;
use crate::rng::rand_f64;

use super::field::{ColorField, Field, FieldDesc, Grid, Medium, Oob};
use super::integrate::{f_int, Integrated, RayAcc};
use super::occupancy::Occupancy;
use super::sample::{f_samp, walk_lattice, March, Samples, Sampling, TransPath};
use super::{Chain, VolumeParams};

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
struct Ksum<F> {
    s: F,
    c: F,
}

impl<F: Real> Ksum<F> {
    #[inline]
    fn add(&mut self, x: F) {
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
    let mut lt_next = log_tn;
    for i in (0..recs.len()).rev() {
        let r = &recs[i];
        let t_next = lt_next.exp();
        let w = r.log_t.exp() * r.alpha;
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
        lt_next = r.log_t;
    }
}

// ---------------------------------------------------------------------------
// Field derivatives (closed enums of `field.rs`, differentiated here).

/// The trilinear cell of a point: base corner, fractions, and d(frac)/dx
/// per axis (0 where a clamp holds the coordinate). Mirrors
/// `Grid::trilinear` operation for operation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell<F> {
    pub base: [i64; 3],
    pub f: [F; 3],
    pub ds: [F; 3],
}

/// The cell of `x`, or `None` where every corner is outside (value 0).
#[inline]
pub fn cell_of<F: Real>(g: &Grid<F>, x: [F; 3]) -> Option<Cell<F>> {
    let n = [g.nx, g.ny, g.nz];
    let mut c = Cell {
        base: [0; 3],
        f: [F::zero(); 3],
        ds: g.scale,
    };
    for a in 0..3 {
        let u = (x[a] - g.bmin[a]) * g.scale[a];
        let top = F::of((n[a] - 1) as f64);
        match g.oob {
            Oob::Clamp => {
                let cl = u.max(F::zero()).min(top);
                let fl = cl.floor().min(F::of((n[a] - 2) as f64));
                c.base[a] = fl.to_i64().unwrap_or(0);
                c.f[a] = cl - fl;
                if u < F::zero() || u > top {
                    c.ds[a] = F::zero();
                }
            }
            Oob::Zero => {
                let fl = u.floor();
                if fl < -F::one() || fl > top {
                    return None;
                }
                c.f[a] = u - fl;
                c.base[a] = fl.to_i64().unwrap_or(-1);
            }
        }
    }
    Some(c)
}

/// Trilinear weight of corner `d` (bit a = offset on axis a).
#[inline]
fn corner_weight<F: Real>(f: [F; 3], d: usize) -> F {
    let one = F::one();
    let p = |a: usize| if d >> a & 1 == 1 { f[a] } else { one - f[a] };
    p(0) * p(1) * p(2)
}

/// Flat node index of corner `d` of `base`, `None` outside the grid.
#[inline]
fn corner_node<F>(g: &Grid<F>, base: [i64; 3], d: usize) -> Option<usize> {
    let i = base[0] + (d & 1) as i64;
    let j = base[1] + (d >> 1 & 1) as i64;
    let k = base[2] + (d >> 2 & 1) as i64;
    if i < 0 || j < 0 || k < 0 || i >= g.nx as i64 || j >= g.ny as i64 || k >= g.nz as i64 {
        return None;
    }
    Some((k as usize * g.ny + j as usize) * g.nx + i as usize)
}

/// `sum_ch gout[ch] grad value_ch(x)` of a `C`-channel grid.
#[inline]
fn grid_grad<F: Real, const C: usize>(g: &Grid<F>, c: &Cell<F>, gout: [F; C]) -> [F; 3] {
    let one = F::one();
    let mut out = [F::zero(); 3];
    for d in 0..8 {
        let Some(node) = corner_node(g, c.base, d) else {
            continue;
        };
        let mut v = F::zero();
        for (ch, go) in gout.iter().enumerate() {
            v += *go * g.data[node * g.ch + ch];
        }
        for (a, o) in out.iter_mut().enumerate() {
            let mut dw = if d >> a & 1 == 1 { one } else { -one };
            for b in 0..3 {
                if b != a {
                    dw *= if d >> b & 1 == 1 {
                        c.f[b]
                    } else {
                        one - c.f[b]
                    };
                }
            }
            *o += v * dw * c.ds[a];
        }
    }
    out
}

/// grad sigma at `x` (0 where sigma is piecewise constant).
#[inline]
pub fn sigma_grad<F: Real>(field: &Field<F>, x: [F; 3]) -> [F; 3] {
    match field {
        Field::Constant { .. } | Field::Slabs { .. } | Field::Shell { .. } => [F::zero(); 3],
        Field::Gaussian {
            amplitude,
            mean,
            inv_two_var,
        } => {
            let dx = [x[0] - mean[0], x[1] - mean[1], x[2] - mean[2]];
            let s = *amplitude
                * (-(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2]) * *inv_two_var).exp();
            let k = -F::of(2.0) * *inv_two_var * s;
            [k * dx[0], k * dx[1], k * dx[2]]
        }
        Field::Linear { a, g } => {
            if *a + g[0] * x[0] + g[1] * x[1] + g[2] * x[2] > F::zero() {
                *g
            } else {
                [F::zero(); 3]
            }
        }
        Field::Grid(g) => match cell_of(g, x) {
            Some(c) => grid_grad::<F, 1>(g, &c, [F::one()]),
            None => [F::zero(); 3],
        },
    }
}

/// `J_c(x)^T gc` of the colour field.
#[inline]
fn color_grad<F: Real>(color: &ColorField<F>, x: [F; 3], gc: [F; 3]) -> [F; 3] {
    match color {
        ColorField::Constant(_) => [F::zero(); 3],
        ColorField::Grid(g) => match cell_of(g, x) {
            Some(c) => grid_grad::<F, 3>(g, &c, gc),
            None => [F::zero(); 3],
        },
    }
}

/// Parameter index of the constant / slab density at `x` (as `Field::sigma`
/// chooses the slab); `None` for other fields or outside every slab.
#[inline]
fn param_index<F: Real>(field: &Field<F>, x: [F; 3]) -> Option<usize> {
    match field {
        Field::Constant { .. } => Some(0),
        Field::Slabs {
            axis,
            breaks,
            sigma,
        } => {
            let v = x[*axis];
            let n = sigma.len();
            (0..n)
                .find(|&i| breaks[i] <= v && (v < breaks[i + 1] || (i + 1 == n && v <= breaks[n])))
        }
        _ => None,
    }
}

fn param_count<F>(field: &Field<F>) -> usize {
    match field {
        Field::Constant { .. } => 1,
        Field::Slabs { sigma, .. } => sigma.len(),
        _ => 0,
    }
}

// ---------------------------------------------------------------------------
// Camera derivatives.

/// The active planes of `clip_aabb` for t0 and for t1: the value and the
/// axes whose slab plane attains it. A ray through an edge or corner has
/// several (a kink of t0 or t1): its derivative is then the mean of the
/// one-sided ones, which is what a central difference converges to. No
/// axis where `near` / `far` holds. Same operations as `rays::clip_aabb`.
#[allow(clippy::type_complexity)]
#[inline]
pub fn clip_planes<F: Real>(
    o: [F; 3],
    d: [F; 3],
    bmin: [F; 3],
    bmax: [F; 3],
    near: F,
    far: F,
) -> ((F, [bool; 3]), (F, [bool; 3])) {
    let (mut lo, mut hi) = (near, far);
    let mut ends = [(F::zero(), F::zero()); 3];
    for a in 0..3 {
        if d[a] == F::zero() {
            continue;
        }
        let inv = F::one() / d[a];
        let ta = (bmin[a] - o[a]) * inv;
        let tb = (bmax[a] - o[a]) * inv;
        ends[a] = (ta.min(tb), ta.max(tb));
        lo = lo.max(ends[a].0);
        hi = hi.min(ends[a].1);
    }
    let mut m0 = [false; 3];
    let mut m1 = [false; 3];
    for a in 0..3 {
        if d[a] != F::zero() {
            m0[a] = lo != near && ends[a].0 == lo;
            m1[a] = hi != far && ends[a].1 == hi;
        }
    }
    ((lo, m0), (hi, m1))
}

fn cross<F: Real>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The pose in precision `F`: rotation rows and centre of C2W.
#[derive(Clone, Copy, Debug)]
struct Pose<F> {
    r: [[F; 3]; 3],
    c: [F; 3],
}

impl<F: Real> Pose<F> {
    fn of(cam: &Camera) -> Pose<F> {
        let m = cam.c2w();
        Pose {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| F::of(m[i][j]))),
            c: [0, 1, 2].map(|i| F::of(m[i][3])),
        }
    }

    /// `R^T v`.
    fn rt(&self, v: [F; 3]) -> [F; 3] {
        [0, 1, 2].map(|j| self.r[0][j] * v[0] + self.r[1][j] * v[1] + self.r[2][j] * v[2])
    }
}

// ---------------------------------------------------------------------------
// The per-ray driver shared by both chains.

/// Everything fixed for one backward pass.
struct Ctx<'a, F> {
    /// The forward's own field query (so the re-walk repeats it bit for bit).
    medium: &'a Medium<F>,
    field: &'a Field<F>,
    color: &'a ColorField<F>,
    m: &'a March<F>,
    occ: Option<&'a Occupancy<F>>,
    rays: &'a Rays<F>,
    up: &'a Upstream<F>,
    pose: Pose<F>,
    /// Density and colour grids share shape, box and OOB policy.
    shared_cell: bool,
    bmin: [F; 3],
    bmax: [F; 3],
    near: F,
    far: F,
}

/// Fills `recs` with ray `r`'s integrated samples by re-walking it with the
/// forward's operations (fused chain). Returns the ray's final log T.
fn replay_fused<F: Real>(cx: &Ctx<F>, r: usize, recs: &mut Vec<Rec<F>>) -> F {
    recs.clear();
    let rays = cx.rays;
    let mut acc = RayAcc::default();
    walk_lattice(
        rays.o[r],
        rays.d[r],
        rays.t0[r],
        rays.t1[r],
        rays.pixel[r],
        cx.m,
        cx.occ,
        |k, t, h, x| {
            let tk = match cx.m.path {
                TransPath::Product => acc.transmittance::<false>(),
                TransPath::Log => acc.transmittance::<true>(),
            };
            if tk < cx.m.early_stop {
                return false;
            }
            let (sigma, c) = cx.medium.query(x);
            let log_t = acc.log_t;
            let alpha = acc.step(tk, sigma, c, t, h);
            recs.push(Rec {
                k,
                t,
                dt: h,
                sigma,
                c,
                log_t,
                alpha,
            });
            true
        },
    );
    acc.log_t
}

/// Fills `recs` from the persisted buffers (unfused chain); lattice indices
/// come from walking the lattice without field queries.
fn replay_unfused<F: Real>(
    cx: &Ctx<F>,
    s: &Samples<F>,
    it: &Integrated<F>,
    r: usize,
    recs: &mut Vec<Rec<F>>,
) -> F {
    recs.clear();
    let rays = cx.rays;
    let lo = s.off[r] as usize;
    let n = it.rays[r].n as usize;
    let mut j = 0usize;
    walk_lattice(
        rays.o[r],
        rays.d[r],
        rays.t0[r],
        rays.t1[r],
        rays.pixel[r],
        cx.m,
        cx.occ,
        |k, _, _, _| {
            if j >= n {
                return false;
            }
            let q = lo + j;
            recs.push(Rec {
                k,
                t: s.t[q],
                dt: s.dt[q],
                sigma: s.sigma[q],
                c: s.color[q],
                log_t: it.log_t[q],
                alpha: it.alpha[q],
            });
            j += 1;
            true
        },
    );
    it.rays[r].log_trans
}

/// Gradient of one sample for the reductions.
#[derive(Clone, Copy, Debug)]
struct Emit<F> {
    x: [F; 3],
    /// Trilinear cells of the density and colour grids (computed once per
    /// sample, shared when the grids have the same geometry).
    cs: Option<Cell<F>>,
    cc: Option<Cell<F>>,
    dsigma: F,
    dcolor: [F; 3],
}

/// Walks ray `r` backward over `recs`, calling `emit(i, ..)` per sample;
/// returns the ray's `dL/d delta` (f64, for the ordered sum over rays).
fn ray_grads<F: Real>(
    cx: &Ctx<F>,
    r: usize,
    recs: &[Rec<F>],
    log_tn: F,
    mut emit: impl FnMut(usize, Emit<F>),
) -> [f64; 6] {
    let rays = cx.rays;
    let (o, d, t0, t1) = (rays.o[r], rays.d[r], rays.t0[r], rays.t1[r]);
    let g = cx.up.rgb[r];
    let gd = cx.up.depth.as_ref().map_or(F::zero(), |v| v[r]);
    let go = cx.up.opacity.as_ref().map_or(F::zero(), |v| v[r]);
    let (mut go_k, mut gd_k) = ([Ksum::<F>::default(); 3], [Ksum::<F>::default(); 3]);
    let (mut dl_t0, mut dl_t1) = (Ksum::<F>::default(), Ksum::<F>::default());
    let one = F::one();
    backward_ray(recs, log_tn, cx.m.background, g, gd, go, |i, sg| {
        let rc = &recs[i];
        let x = [o[0] + rc.t * d[0], o[1] + rc.t * d[1], o[2] + rc.t * d[2]];
        let cs = match cx.field {
            Field::Grid(g) => cell_of(g, x),
            _ => None,
        };
        let (gs, cc) = match (cx.field, cx.color) {
            (Field::Grid(g), ColorField::Grid(gcol)) if cx.shared_cell => {
                let gs = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 1>(g, &c, [F::one()]));
                let gc = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 3>(gcol, &c, sg.dcolor));
                ((gs, gc), cs)
            }
            (Field::Grid(g), _) => {
                let gs = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 1>(g, &c, [F::one()]));
                let cc = match cx.color {
                    ColorField::Grid(gcol) => cell_of(gcol, x),
                    ColorField::Constant(_) => None,
                };
                let gc = match (cx.color, cc) {
                    (ColorField::Grid(gcol), Some(c)) => grid_grad::<F, 3>(gcol, &c, sg.dcolor),
                    _ => [F::zero(); 3],
                };
                ((gs, gc), cc)
            }
            _ => {
                let cc = match cx.color {
                    ColorField::Grid(gcol) => cell_of(gcol, x),
                    ColorField::Constant(_) => None,
                };
                (
                    (sigma_grad(cx.field, x), color_grad(cx.color, x, sg.dcolor)),
                    cc,
                )
            }
        };
        let (gs, gc) = gs;
        let gx = [0, 1, 2].map(|a| sg.dsigma * gs[a] + gc[a]);
        for a in 0..3 {
            go_k[a].add(gx[a]);
            gd_k[a].add(rc.t * gx[a]);
        }
        let dl_tpos = gx[0] * d[0] + gx[1] * d[1] + gx[2] * d[2] + gd * sg.w;
        let dl_dt = sg.dtau * rc.sigma;
        let clipped = t0 + F::of((rc.k + 1) as f64) * cx.m.dt > t1;
        if clipped {
            let u = match cx.m.sampling {
                Sampling::Fixed => F::of(0.5),
                Sampling::Stratified { seed } => F::of(rand_f64(seed, rays.pixel[r], 0, rc.k)),
            };
            dl_t0.add(dl_tpos * (one - u) - dl_dt);
            dl_t1.add(dl_tpos * u + dl_dt);
        } else {
            dl_t0.add(dl_tpos);
        }
        emit(
            i,
            Emit {
                x,
                cs,
                cc,
                dsigma: sg.dsigma,
                dcolor: sg.dcolor,
            },
        );
    });
    let (mut go_sum, mut gd_sum) = (go_k.map(|k| k.s), gd_k.map(|k| k.s));
    let (dl_t0, dl_t1) = (dl_t0.s, dl_t1.s);
    if !recs.is_empty() {
        let (p0, p1) = clip_planes(o, d, cx.bmin, cx.bmax, cx.near, cx.far);
        for ((t, mask), dl) in [(p0, dl_t0), (p1, dl_t1)] {
            let n = mask.iter().filter(|&&m| m).count();
            for a in (0..3).filter(|&a| mask[a]) {
                let share = dl / F::of(n as f64);
                go_sum[a] -= share / d[a];
                gd_sum[a] -= share * t / d[a];
            }
        }
    }
    let rho = cx.pose.rt(go_sum);
    let oc = [
        o[0] - cx.pose.c[0],
        o[1] - cx.pose.c[1],
        o[2] - cx.pose.c[2],
    ];
    let a = cross(oc, go_sum);
    let b = cross(d, gd_sum);
    let w = cx.pose.rt([a[0] + b[0], a[1] + b[1], a[2] + b[2]]);
    [
        rho[0].f64(),
        rho[1].f64(),
        rho[2].f64(),
        w[0].f64(),
        w[1].f64(),
        w[2].f64(),
    ]
}

// ---------------------------------------------------------------------------
// Reductions.

/// One sample's record for the sorted reduction.
#[derive(Clone, Copy, Debug)]
struct GridRec<F, const C: usize> {
    key: u32,
    f: [F; 3],
    g: [F; C],
}

/// Cell key of a base corner: `(base + 1)` per axis in a `(n+1)^3` lattice.
fn cell_key<F>(g: &Grid<F>, base: [i64; 3]) -> u32 {
    let (i, j, k) = (
        (base[0] + 1) as usize,
        (base[1] + 1) as usize,
        (base[2] + 1) as usize,
    );
    ((k * (g.ny + 1) + j) * (g.nx + 1) + i) as u32
}

fn push_rec<F: Real, const C: usize>(
    g: &Grid<F>,
    cell: Option<Cell<F>>,
    v: [F; C],
    out: &mut Vec<GridRec<F, C>>,
) {
    if let Some(c) = cell {
        out.push(GridRec {
            key: cell_key(g, c.base),
            f: c.f,
            g: v,
        });
    }
}

fn scatter_dense<F: Real, const C: usize>(
    g: &Grid<F>,
    cell: Option<Cell<F>>,
    v: [F; C],
    out: &mut [F],
) {
    if let Some(c) = cell {
        for d in 0..8 {
            if let Some(node) = corner_node(g, c.base, d) {
                let w = corner_weight(c.f, d);
                for ch in 0..C {
                    out[node * C + ch] += w * v[ch];
                }
            }
        }
    }
}

/// Canonical reduction: stable sort by cell, then each node sums its eight
/// neighbouring cells (corner order 0..8, records in stable order).
fn reduce_sorted<F: Real, const C: usize>(g: &Grid<F>, mut recs: Vec<GridRec<F, C>>) -> Vec<F> {
    use rayon::prelude::*;
    let ncell = (g.nx + 1) * (g.ny + 1) * (g.nz + 1);
    recs.par_sort_by_key(|r| r.key);
    let mut start = vec![0u32; ncell + 1];
    for r in &recs {
        start[r.key as usize + 1] += 1;
    }
    for i in 0..ncell {
        start[i + 1] += start[i];
    }
    let nodes = g.nx * g.ny * g.nz;
    let mut out = vec![F::zero(); nodes * C];
    crate::parallel::par_chunks("f_diff_gather", &mut out, 4096 * C, |ci, chunk| {
        let first = ci * 4096;
        for (q, slot) in chunk.chunks_mut(C).enumerate() {
            let node = first + q;
            let (i, j, k) = (node % g.nx, node / g.nx % g.ny, node / (g.nx * g.ny));
            let mut acc = [Ksum::<F>::default(); C];
            for d in 0..8 {
                let base = [
                    i as i64 - (d & 1) as i64,
                    j as i64 - (d >> 1 & 1) as i64,
                    k as i64 - (d >> 2 & 1) as i64,
                ];
                let key = cell_key(g, base) as usize;
                for r in &recs[start[key] as usize..start[key + 1] as usize] {
                    let w = corner_weight(r.f, d);
                    for (a, g) in acc.iter_mut().zip(&r.g) {
                        a.add(w * *g);
                    }
                }
            }
            for (o, a) in slot.iter_mut().zip(&acc) {
                *o = a.s;
            }
        }
    });
    out
}

/// Sums per-chunk dense grids in chunk order.
fn sum_chunks<F: Real>(parts: &[&[F]], len: usize) -> Vec<F> {
    let mut out = vec![F::zero(); len];
    crate::parallel::par_chunks("f_diff_chunk_sum", &mut out, 1 << 14, |ci, chunk| {
        let first = ci << 14;
        for (q, slot) in chunk.iter_mut().enumerate() {
            let mut a = F::zero();
            for p in parts {
                a += p[first + q];
            }
            *slot = a;
        }
    });
    out
}

/// What one unit of rays (a contiguous range) produced.
struct Unit<F> {
    cam: Vec<[f64; 6]>,
    param: Vec<Ksum<F>>,
    color_const: [Ksum<F>; 3],
    sig_recs: Vec<GridRec<F, 1>>,
    col_recs: Vec<GridRec<F, 3>>,
    sig_dense: Vec<F>,
    col_dense: Vec<F>,
    per_sample: Vec<(F, [F; 3])>,
    samples: u64,
}

/// Rays per unit of the sorted reduction.
const UNIT_RAYS: usize = 256;

/// The backward pass over the given forward state (module doc).
#[allow(clippy::too_many_arguments)]
fn backward<F: Real>(
    cx: &Ctx<F>,
    buffers: Option<(&Samples<F>, &Integrated<F>)>,
    opt: &DiffOptions,
    budget: &MemBudget,
) -> Result<Grads<F>> {
    let n = cx.rays.len();
    if cx.up.rgb.len() != n
        || cx.up.depth.as_ref().is_some_and(|v| v.len() != n)
        || cx.up.opacity.as_ref().is_some_and(|v| v.len() != n)
    {
        return Err(Error::invalid(
            "f_diff upstream",
            format!("need one gradient per ray ({n})"),
        ));
    }
    if let Some(bad) = cx.up.rgb.iter().flatten().find(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "f_diff upstream",
            format!("dL/d rgb has a non-finite value {bad}"),
        ));
    }
    let sig_grid = match cx.field {
        Field::Grid(g) => Some(g),
        _ => None,
    };
    let col_grid = match cx.color {
        ColorField::Grid(g) => Some(g),
        _ => None,
    };
    let nparam = param_count(cx.field);
    let per_sample = opt.per_sample && buffers.is_some();
    // Per-sample memory of the plan, checked before the walk.
    let fsz = std::mem::size_of::<F>() as u64;
    let mut bps = 0u64;
    if buffers.is_some() {
        bps += Samples::<F>::BYTES_PER_SAMPLE + Integrated::<F>::BYTES_PER_SAMPLE;
    }
    let units: Vec<(usize, usize)> = match opt.reduce {
        Reduce::Sorted => {
            bps += sig_grid.map_or(0, |_| 4 + 4 * fsz) + col_grid.map_or(0, |_| 4 + 6 * fsz);
            (0..n)
                .step_by(UNIT_RAYS)
                .map(|a| (a, (a + UNIT_RAYS).min(n)))
                .collect()
        }
        Reduce::Chunked { chunks } => {
            if chunks == 0 || chunks > 1024 {
                return Err(Error::invalid(
                    "f_diff chunks",
                    format!("{chunks} is not in 1..=1024"),
                ));
            }
            let k = chunks as u64;
            let dense = sig_grid.map_or(0, |g| g.data.len() as u64)
                + col_grid.map_or(0, |g| g.data.len() as u64);
            budget.check(
                "f_diff chunk grids",
                bytes_for(dense, fsz).and_then(|b| b.checked_mul(k + 1)),
            )?;
            let k = chunks as usize;
            (0..k).map(|c| (c * n / k, (c + 1) * n / k)).collect()
        }
    };
    if per_sample {
        bps += 4 * fsz;
    }
    let m_bound: u64 = match buffers {
        Some((s, _)) => s.len() as u64,
        None if bps > 0 => lattice_bound(cx),
        None => 0,
    };
    budget.check("f_diff per-sample state", bytes_for(m_bound, bps))?;

    let t_start = Instant::now();
    let sorted = opt.reduce == Reduce::Sorted;
    let out_units: Vec<Unit<F>> = par_collect("f_diff", units.len(), |ui| {
        let (a, b) = units[ui];
        let mut u = Unit {
            cam: Vec::with_capacity(b - a),
            param: vec![Ksum::default(); nparam],
            color_const: [Ksum::default(); 3],
            sig_recs: vec![],
            col_recs: vec![],
            sig_dense: match (sorted, sig_grid) {
                (false, Some(g)) => vec![F::zero(); g.data.len()],
                _ => vec![],
            },
            col_dense: match (sorted, col_grid) {
                (false, Some(g)) => vec![F::zero(); g.data.len()],
                _ => vec![],
            },
            per_sample: vec![],
            samples: 0,
        };
        let mut recs = Vec::new();
        let mut ps: Vec<(F, [F; 3])> = Vec::new();
        for r in a..b {
            let log_tn = match buffers {
                Some((s, it)) => replay_unfused(cx, s, it, r, &mut recs),
                None => replay_fused(cx, r, &mut recs),
            };
            u.samples += recs.len() as u64;
            if per_sample {
                ps.clear();
                ps.resize(recs.len(), (F::zero(), [F::zero(); 3]));
            }
            // Records go out back to front; the sorted path wants (ray,
            // sample) order, so a ray's records are reversed after its walk.
            let (s0, c0) = (u.sig_recs.len(), u.col_recs.len());
            let cam = ray_grads(cx, r, &recs, log_tn, |i, e| {
                if let Some(p) = param_index(cx.field, e.x) {
                    u.param[p].add(e.dsigma);
                }
                if col_grid.is_none() {
                    for ch in 0..3 {
                        u.color_const[ch].add(e.dcolor[ch]);
                    }
                }
                if let Some(g) = sig_grid {
                    if sorted {
                        push_rec(g, e.cs, [e.dsigma], &mut u.sig_recs);
                    } else {
                        scatter_dense(g, e.cs, [e.dsigma], &mut u.sig_dense);
                    }
                }
                if let Some(g) = col_grid {
                    if sorted {
                        push_rec(g, e.cc, e.dcolor, &mut u.col_recs);
                    } else {
                        scatter_dense(g, e.cc, e.dcolor, &mut u.col_dense);
                    }
                }
                if per_sample {
                    ps[i] = (e.dsigma, e.dcolor);
                }
            });
            u.sig_recs[s0..].reverse();
            u.col_recs[c0..].reverse();
            if per_sample {
                u.per_sample.extend_from_slice(&ps);
                // Samples after an early stop keep zero gradients.
                if let Some((s, _)) = buffers {
                    let total = (s.off[r + 1] - s.off[r]) as usize;
                    u.per_sample.resize(
                        u.per_sample.len() + total - recs.len(),
                        (F::zero(), [F::zero(); 3]),
                    );
                }
            }
            u.cam.push(cam);
        }
        u
    });

    // Ordered reductions over units.
    let mut dcam = [0.0f64; 6];
    let mut param = vec![F::zero(); nparam];
    let mut color_const = [F::zero(); 3];
    let mut samples = 0u64;
    for u in &out_units {
        for c in &u.cam {
            for q in 0..6 {
                dcam[q] += c[q];
            }
        }
        for (p, v) in param.iter_mut().zip(&u.param) {
            *p += v.s;
        }
        for ch in 0..3 {
            color_const[ch] += u.color_const[ch].s;
        }
        samples += u.samples;
    }
    let mut out_units = out_units;
    let (dsigma, dcolor) = if sorted {
        let sig = sig_grid.map(|g| {
            let recs: Vec<GridRec<F, 1>> = out_units
                .iter_mut()
                .flat_map(|u| std::mem::take(&mut u.sig_recs))
                .collect();
            reduce_sorted(g, recs)
        });
        let col = col_grid.map(|g| {
            let recs: Vec<GridRec<F, 3>> = out_units
                .iter_mut()
                .flat_map(|u| std::mem::take(&mut u.col_recs))
                .collect();
            reduce_sorted(g, recs)
        });
        (sig, col)
    } else {
        let sig = sig_grid.map(|g| {
            let parts: Vec<&[F]> = out_units.iter().map(|u| &u.sig_dense[..]).collect();
            sum_chunks(&parts, g.data.len())
        });
        let col = col_grid.map(|g| {
            let parts: Vec<&[F]> = out_units.iter().map(|u| &u.col_dense[..]).collect();
            sum_chunks(&parts, g.data.len())
        });
        (sig, col)
    };
    let (ps_s, ps_c) = split_per_sample(per_sample, &out_units);
    Ok(Grads {
        dsigma,
        dsigma_param: (nparam > 0).then_some(param),
        dcolor,
        dcolor_const: col_grid.is_none().then_some(color_const),
        dsigma_samples: ps_s,
        dcolor_samples: ps_c,
        dcam: dcam.map(F::of),
        samples,
        bytes_per_sample: bps,
        time_s: t_start.elapsed().as_secs_f64(),
    })
}

#[allow(clippy::type_complexity)]
fn split_per_sample<F: Real>(on: bool, units: &[Unit<F>]) -> (Option<Vec<F>>, Option<Vec<[F; 3]>>) {
    if !on {
        return (None, None);
    }
    let s = units
        .iter()
        .flat_map(|u| u.per_sample.iter().map(|p| p.0))
        .collect();
    let c = units
        .iter()
        .flat_map(|u| u.per_sample.iter().map(|p| p.1))
        .collect();
    (Some(s), Some(c))
}

/// Lattice points of every ray (an upper bound of the samples walked).
fn lattice_bound<F: Real>(cx: &Ctx<F>) -> u64 {
    let r = cx.rays;
    par_collect("f_diff_count", r.len(), |i| {
        let mut c = 0u64;
        walk_lattice(
            r.o[i],
            r.d[i],
            r.t0[i],
            r.t1[i],
            r.pixel[i],
            cx.m,
            cx.occ,
            |_, _, _, _| {
                c += 1;
                true
            },
        );
        c
    })
    .iter()
    .sum()
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
    let m = params.march::<F>();
    let medium = Medium::<F>::new(&params.field, &params.color);
    let occ = occupancy::<F>(params, gen, budget)?;
    let rays = f_ray::<F>(cam, gen, budget)?;
    let samples = f_samp(&rays, &medium, &m, occ.as_ref(), budget)?;
    budget.check(
        "f_int buffers",
        bytes_for(samples.len() as u64, Integrated::<F>::BYTES_PER_SAMPLE),
    )?;
    let integrated = f_int(&samples, &m);
    Ok(Forward {
        rays,
        samples,
        integrated,
    })
}

fn occupancy<F: Real>(
    params: &VolumeParams,
    gen: &RayGen,
    budget: &MemBudget,
) -> Result<Option<Occupancy<F>>> {
    Ok(match params.occupancy {
        0 => None,
        r => Some(Occupancy::<F>::build(&params.field, &gen.aabb, r, budget)?),
    })
}

/// `f_diff`: the backward pass of `params` rendered through `cam` / `gen`
/// for upstream gradients `up` (one per ray of the region). With
/// [`Chain::Unfused`], `fwd` supplies the forward buffers (or they are made
/// here, outside the timed backward); [`Chain::Fused`] re-walks every ray.
pub fn f_diff<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    up: &Upstream<F>,
    opt: &DiffOptions,
    fwd: Option<&Forward<F>>,
    budget: &MemBudget,
) -> Result<Grads<F>> {
    let m = params.march::<F>();
    m.validate()?;
    gen.validate()?;
    cam.validate()?;
    let field = params.field.to_real::<F>();
    let color = params.color.to_real::<F>();
    let occ = occupancy::<F>(params, gen, budget)?;
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
    let medium = Medium::<F>::new(&params.field, &params.color);
    let cx = Ctx {
        medium: &medium,
        field: &field,
        color: &color,
        m: &m,
        occ: occ.as_ref(),
        rays,
        up,
        pose: Pose::of(cam),
        shared_cell: match (&field, &color) {
            (Field::Grid(a), ColorField::Grid(b)) => {
                (a.nx, a.ny, a.nz, a.oob) == (b.nx, b.ny, b.nz, b.oob)
                    && a.bmin == b.bmin
                    && a.scale == b.scale
            }
            _ => false,
        },
        bmin: gen.aabb.min.map(F::of),
        bmax: gen.aabb.max.map(F::of),
        near: F::of(gen.near),
        far: F::of(gen.far),
    };
    backward(&cx, buffers, opt, budget)
}

/// Whether the field has grid-shaped density gradients (else per sample or
/// per parameter only).
pub fn has_grid_density(f: &FieldDesc) -> bool {
    matches!(f, FieldDesc::Grid(_))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::field::{Analytic, ColorDesc, GridDesc};

    fn params(field: FieldDesc, color: ColorDesc, es: f64) -> VolumeParams {
        VolumeParams {
            field,
            color,
            dt: 0.05,
            max_steps: 1024,
            early_stop: es,
            sampling: Sampling::Fixed,
            path: TransPath::Product,
            background: [0.1, 0.2, 0.3],
            occupancy: 0,
        }
    }

    fn cam() -> Camera {
        Camera::pinhole_look_at([0.3, 0.2, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6).unwrap()
    }

    fn up<F: Real>(n: usize) -> Upstream<F> {
        Upstream {
            rgb: (0..n)
                .map(|i| [0, 1, 2].map(|c| F::of(rand_f64(7, i as u32, 0, c) - 0.3)))
                .collect(),
            depth: None,
            opacity: None,
        }
    }

    fn grid_params() -> VolumeParams {
        let sig = GridDesc::sample([5, 6, 7], [-1.0; 3], [1.0; 3], Oob::Zero, |x| {
            3.0 + 2.0 * x[0] - x[1] * x[2]
        });
        let mut col =
            GridDesc::filled([4, 4, 4], &[0.5, 0.5, 0.5], [-1.0; 3], [1.0; 3], Oob::Clamp);
        for (i, v) in col.data.iter_mut().enumerate() {
            *v = 0.2 + 0.6 * rand_f64(3, i as u32, 0, 0);
        }
        params(FieldDesc::Grid(sig), ColorDesc::Grid(col), 0.0)
    }

    fn run<F: Real>(p: &VolumeParams, chain: Chain, reduce: Reduce) -> Grads<F> {
        let gen = RayGen::new(8, 6);
        let opt = DiffOptions {
            chain,
            reduce,
            per_sample: true,
        };
        f_diff::<F>(
            &cam(),
            &gen,
            p,
            &up(48),
            &opt,
            None,
            &MemBudget::fixed(1 << 28),
        )
        .unwrap()
    }

    /// L = sum W . rgb of a plain f64 render with the node perturbed.
    fn loss(p: &VolumeParams, c: &Camera) -> f64 {
        let gen = RayGen::new(8, 6);
        let r = crate::volume::render::<f64>(
            c,
            &gen,
            p,
            Chain::Fused,
            crate::volume::compose::Compose::Sorted,
            &MemBudget::fixed(1 << 28),
        )
        .unwrap();
        let w = up::<f64>(48).rgb;
        r.image
            .rgb
            .iter()
            .zip(&w)
            .map(|(a, b)| a[0] * b[0] + a[1] * b[1] + a[2] * b[2])
            .sum()
    }

    #[test]
    fn constant_medium_gradient_is_l_exp_minus_tau_times_c_minus_b() {
        // One ortho ray along -z through [-1, 1]: L = 2.
        let c =
            Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
        let mut p = params(
            FieldDesc::Analytic(Analytic::Constant { s: 2.0 }),
            ColorDesc::Constant([1.0, 0.5, 0.25]),
            0.0,
        );
        p.dt = 0.01;
        let gen = RayGen::new(2, 2);
        let u = Upstream {
            rgb: vec![[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.0; 3]],
            depth: None,
            opacity: None,
        };
        for chain in [Chain::Fused, Chain::Unfused] {
            let opt = DiffOptions {
                chain,
                reduce: Reduce::Sorted,
                per_sample: false,
            };
            let g =
                f_diff::<f64>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
            let expect: f64 = (0..3)
                .map(|ch| 2.0 * (-4.0f64).exp() * ([1.0, 0.5, 0.25][ch] - [0.1, 0.2, 0.3][ch]))
                .sum();
            let got = g.dsigma_param.unwrap()[0];
            assert!(
                (got - expect).abs() < 1e-12 * expect.abs(),
                "{got} {expect}"
            );
            let op = -(-4.0f64).exp_m1();
            let dc = g.dcolor_const.unwrap();
            assert!(
                (dc[0] - op).abs() < 1e-13 && (dc[2] - op).abs() < 1e-13,
                "{dc:?}"
            );
        }
    }

    #[test]
    fn grid_node_gradients_match_central_differences_f64() {
        let p = grid_params();
        let g = run::<f64>(&p, Chain::Fused, Reduce::Sorted);
        let ds = g.dsigma.unwrap();
        let dc = g.dcolor.unwrap();
        let FieldDesc::Grid(sg) = &p.field else {
            unreachable!()
        };
        let ColorDesc::Grid(cg) = &p.color else {
            unreachable!()
        };
        let h = 1e-6;
        let big = ds.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for node in [100, 117, 130, 155, 170] {
            let mut q = p.clone();
            let mut s2 = sg.clone();
            s2.data[node] += h;
            q.field = FieldDesc::Grid(s2.clone());
            let lp = loss(&q, &cam());
            s2.data[node] -= 2.0 * h;
            q.field = FieldDesc::Grid(s2);
            let lm = loss(&q, &cam());
            let fd = (lp - lm) / (2.0 * h);
            assert!(
                (fd - ds[node]).abs() <= 1e-6 * big.max(1e-3),
                "node {node}: {fd} vs {}",
                ds[node]
            );
        }
        let bigc = dc.iter().fold(0.0f64, |a, v| a.max(v.abs()));
        for idx in [63, 64, 100, 121, 130] {
            let mut q = p.clone();
            let mut c2 = cg.clone();
            c2.data[idx] += h;
            q.color = ColorDesc::Grid(c2.clone());
            let lp = loss(&q, &cam());
            c2.data[idx] -= 2.0 * h;
            q.color = ColorDesc::Grid(c2);
            let lm = loss(&q, &cam());
            let fd = (lp - lm) / (2.0 * h);
            assert!(
                (fd - dc[idx]).abs() <= 1e-6 * bigc.max(1e-3),
                "colour {idx}: {fd} vs {}",
                dc[idx]
            );
        }
    }

    #[test]
    fn a_ray_leaving_through_an_edge_gets_the_mean_of_its_one_sided_derivatives() {
        // Pixel (1, 0) of the centred 8 x 6 view leaves the box exactly
        // through the edge x = -1, y = 1 (|d_x| = |d_y|): t1 has a kink.
        let c = Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 8, 6)
            .unwrap();
        let mut p = params(
            FieldDesc::Analytic(Analytic::Gaussian {
                amplitude: 8.0,
                mean: [0.0; 3],
                std: 0.4,
            }),
            ColorDesc::Constant([1.0, 0.5, 0.25]),
            0.0,
        );
        p.dt = 0.01;
        let mut gen = RayGen::new(8, 6);
        gen.roi = Some(crate::rays::Roi {
            x: 1,
            y: 0,
            width: 1,
            height: 1,
        });
        let opt = DiffOptions {
            chain: Chain::Fused,
            reduce: Reduce::Sorted,
            per_sample: false,
        };
        let upr = Upstream {
            rgb: vec![[1.0, 0.3, -0.2]],
            depth: None,
            opacity: None,
        };
        let b = MemBudget::fixed(1 << 24);
        let g = f_diff::<f64>(&c, &gen, &p, &upr, &opt, None, &b).unwrap();
        let lossg = |cc: &Camera| {
            let r = crate::volume::render::<f64>(
                cc,
                &gen,
                &p,
                Chain::Fused,
                crate::volume::compose::Compose::Sorted,
                &b,
            )
            .unwrap();
            r.image.rgb[0][0] + 0.3 * r.image.rgb[0][1] - 0.2 * r.image.rgb[0][2]
        };
        let h = 1e-6;
        for q in 0..6 {
            let mut xi = [0.0; 6];
            xi[q] = h;
            let lp = lossg(&perturb(&c, xi));
            xi[q] = -h;
            let lm = lossg(&perturb(&c, xi));
            let fd = (lp - lm) / (2.0 * h);
            assert!((fd - g.dcam[q]).abs() < 1e-5, "{q}: {fd} {:?}", g.dcam);
        }
    }

    #[test]
    fn pose_gradient_matches_central_differences_f64() {
        for p in [
            grid_params(),
            params(
                FieldDesc::Analytic(Analytic::Gaussian {
                    amplitude: 8.0,
                    mean: [0.1, 0.0, -0.1],
                    std: 0.4,
                }),
                ColorDesc::Constant([1.0, 0.5, 0.25]),
                0.0,
            ),
        ] {
            let g = run::<f64>(&p, Chain::Fused, Reduce::Sorted);
            let h = 1e-6;
            for q in 0..6 {
                let mut xi = [0.0; 6];
                xi[q] = h;
                let lp = loss(&p, &perturb(&cam(), xi));
                xi[q] = -h;
                let lm = loss(&p, &perturb(&cam(), xi));
                let fd = (lp - lm) / (2.0 * h);
                let scale = g.dcam.iter().fold(0.0f64, |a, v| a.max(v.abs()));
                assert!(
                    (fd - g.dcam[q]).abs() <= 2e-4 * scale,
                    "component {q}: fd {fd} vs {:?}",
                    g.dcam
                );
            }
        }
    }

    /// C2W exp(xi) for a single-component xi (pure translation or rotation).
    fn perturb(c: &Camera, xi: [f64; 6]) -> Camera {
        let m = *c.c2w();
        let w = [xi[3], xi[4], xi[5]];
        let th = (w[0] * w[0] + w[1] * w[1] + w[2] * w[2]).sqrt();
        let mut e = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        if th > 0.0 {
            let k = w.map(|v| v / th);
            let kx = [[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]];
            for i in 0..3 {
                for j in 0..3 {
                    let kk: f64 = (0..3).map(|l| kx[i][l] * kx[l][j]).sum();
                    e[i][j] += th.sin() * kx[i][j] + (1.0 - th.cos()) * kk;
                }
            }
        }
        let mut out = m;
        for i in 0..3 {
            for j in 0..3 {
                out[i][j] = (0..3).map(|l| m[i][l] * e[l][j]).sum();
            }
            out[i][3] = m[i][3] + (0..3).map(|l| m[i][l] * xi[l]).sum::<f64>();
        }
        c.with_c2w(out)
    }

    #[test]
    fn fused_equals_unfused_bit_for_bit_and_chunked_agrees_with_sorted() {
        let p = grid_params();
        for es in [0.0, 1e-2] {
            let q = VolumeParams {
                early_stop: es,
                ..p.clone()
            };
            let a = run::<f32>(&q, Chain::Fused, Reduce::Sorted);
            let b = run::<f32>(&q, Chain::Unfused, Reduce::Sorted);
            assert_eq!(a.dsigma, b.dsigma);
            assert_eq!(a.dcolor, b.dcolor);
            assert_eq!(a.dcam, b.dcam);
            let c = run::<f32>(&q, Chain::Fused, Reduce::Chunked { chunks: 3 });
            let d = run::<f32>(&q, Chain::Unfused, Reduce::Chunked { chunks: 3 });
            assert_eq!(c.dsigma, d.dsigma);
            let (x, y) = (a.dsigma.unwrap(), c.dsigma.unwrap());
            let big = x.iter().fold(0.0f32, |m, v| m.max(v.abs()));
            for (u, v) in x.iter().zip(&y) {
                assert!((u - v).abs() <= 1e-5 * big, "{u} {v}");
            }
        }
    }

    #[test]
    fn sorted_reduction_is_bit_identical_across_thread_counts() {
        let p = grid_params();
        let one = crate::parallel::with_threads(1, || run::<f32>(&p, Chain::Fused, Reduce::Sorted));
        let two = crate::parallel::with_threads(2, || run::<f32>(&p, Chain::Fused, Reduce::Sorted));
        let again = crate::parallel::with_threads(3, || {
            run::<f32>(&p, Chain::Unfused, Reduce::Chunked { chunks: 4 })
        });
        let again2 = crate::parallel::with_threads(1, || {
            run::<f32>(&p, Chain::Unfused, Reduce::Chunked { chunks: 4 })
        });
        assert_eq!(
            one,
            Grads {
                time_s: one.time_s,
                ..two
            }
        );
        assert_eq!(again.dsigma, again2.dsigma);
        assert_eq!(again.dcolor, again2.dcolor);
    }

    #[test]
    fn huge_density_gives_finite_gradients_of_the_right_sign() {
        let c =
            Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
        let p = VolumeParams {
            dt: 0.01,
            ..params(
                FieldDesc::Analytic(Analytic::Constant { s: 1e4 }),
                ColorDesc::Constant([1.0, 0.5, 0.25]),
                1e-4,
            )
        };
        let gen = RayGen::new(2, 2);
        let u = Upstream {
            rgb: vec![[1.0, 0.0, 0.0]; 4],
            depth: Some(vec![1.0; 4]),
            opacity: Some(vec![1.0; 4]),
        };
        let opt = DiffOptions {
            chain: Chain::Unfused,
            reduce: Reduce::Sorted,
            per_sample: true,
        };
        let g = f_diff::<f32>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
        let s = g.dsigma_samples.unwrap();
        assert!(s.iter().all(|v| v.is_finite()));
        // The first sample: more density there brings the (nearer) colour
        // forward: d rgb_r / d sigma_0 = T_1 c_r dt >= 0, and depth shrinks.
        assert!(g.dcam.iter().all(|v| v.is_finite()));
        assert!(g.dsigma_param.unwrap()[0].is_finite());
        assert!(s[0] >= 0.0);
    }

    #[test]
    fn tiny_optical_depth_keeps_relative_accuracy_in_f32() {
        // sigma dt = 1e-9: dC/dsigma = L e^{-tau} (c - b), tau ~ 2e-7.
        let c =
            Camera::ortho_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
        let p = VolumeParams {
            dt: 0.01,
            ..params(
                FieldDesc::Analytic(Analytic::Constant { s: 1e-7 }),
                ColorDesc::Constant([1.0, 0.5, 0.25]),
                0.0,
            )
        };
        let gen = RayGen::new(1, 1);
        let u = Upstream {
            rgb: vec![[1.0, 0.0, 0.0]],
            depth: None,
            opacity: None,
        };
        let opt = DiffOptions {
            chain: Chain::Fused,
            reduce: Reduce::Sorted,
            per_sample: false,
        };
        let g = f_diff::<f32>(&c, &gen, &p, &u, &opt, None, &MemBudget::fixed(1 << 24)).unwrap();
        let got = g.dsigma_param.unwrap()[0] as f64;
        let expect = 2.0 * (-2e-7f64).exp() * 0.9;
        assert!(((got - expect) / expect).abs() < 1e-5, "{got} {expect}");
    }
}
