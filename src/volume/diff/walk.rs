//! The per-ray driver shared by both chains of `f_diff`: replaying a ray's
//! samples (fused re-walk or persisted buffers) and walking it backward.

use crate::rays::Rays;
use crate::real::Real;
use crate::rng::rand_f64;

use super::super::field::{ColorField, Field, Grid, Medium};
use super::super::fused_lanes::{LaneMarch, LaneRay, LaneSink, LaneStep, Query, LANES};
use super::super::integrate::{Integrated, RayAcc};
use super::super::occupancy::Occupancy;
use super::super::sample::{walk_lattice, March, Samples, Sampling, TransPath};
use super::camera::{clip_planes, cross, Pose};
use super::field_grad::{cell_of, color_grad, grid_grad, sigma_grad, Cell};
use super::{backward_ray, Ksum, Rec, Upstream};

// The per-ray driver shared by both chains.

/// Everything fixed for one backward pass.
pub(super) struct Ctx<'a, F> {
    /// The forward's own field query (so the re-walk repeats it bit for bit).
    pub(super) medium: &'a Medium<F>,
    pub(super) field: &'a Field<F>,
    pub(super) color: &'a ColorField<F>,
    pub(super) m: &'a March<F>,
    pub(super) occ: Option<&'a Occupancy<F>>,
    pub(super) rays: &'a Rays<F>,
    pub(super) up: &'a Upstream<F>,
    pub(super) pose: Pose<F>,
    /// Density and colour grids share shape, box and OOB policy.
    pub(super) shared_cell: bool,
    /// With `shared_cell`: the forward's packed `[sigma, r, g, b]` grid, for
    /// the one-pass gradient and the packed 4-channel scatter.
    pub(super) packed: Option<&'a Grid<F>>,
    pub(super) bmin: [F; 3],
    pub(super) bmax: [F; 3],
    pub(super) near: F,
    pub(super) far: F,
}

/// Fills `recs` with ray `r`'s integrated samples by re-walking it with the
/// forward's operations (fused chain). Returns the ray's final log T.
pub(super) fn replay_fused<F: Real>(cx: &Ctx<F>, r: usize, recs: &mut Vec<Rec<F>>) -> F {
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

/// The records of rays `first..first + len` (`len <= LANES`), replayed in
/// the forward's AVX2 lanes: the same records and final log T as
/// [`replay_fused`] ray by ray (the lanes are bit-identical to the scalar
/// march). Clears every vector of `recs` first.
pub(super) fn replay_fused_lanes<F: Real>(
    cx: &Ctx<F>,
    lm: &LaneMarch,
    query: &Query,
    first: usize,
    len: usize,
    recs: &mut [Vec<Rec<F>>; LANES],
) -> [F; LANES] {
    struct Sink<'a, F>(&'a mut [Vec<Rec<F>>; LANES]);
    impl<F: Real> LaneSink for Sink<'_, F> {
        const RECORD: bool = true;
        fn step(&mut self, s: &LaneStep) {
            let f = |v: f32| F::of(v as f64);
            for l in (0..LANES).filter(|l| s.live & (1 << l) != 0) {
                self.0[l].push(Rec {
                    k: s.k,
                    t: f(s.t[l]),
                    dt: f(s.dt[l]),
                    sigma: f(s.sigma[l]),
                    c: [f(s.c[0][l]), f(s.c[1][l]), f(s.c[2][l])],
                    log_t: f(s.log_t[l]),
                    alpha: f(s.alpha[l]),
                });
            }
        }
    }
    recs.iter_mut().for_each(Vec::clear);
    let lane_rays = lane_rays(cx.rays, first, len);
    let out = lm.march8_into(&lane_rays, query, &mut Sink(recs));
    out.map(|(acc, _)| F::of(acc.log_t as f64))
}

/// Rays `first..first + len` in f32, as the lanes take them.
pub(super) fn lane_rays<F: Real>(rays: &Rays<F>, first: usize, len: usize) -> Vec<LaneRay> {
    let f = |v: F| v.f64() as f32;
    (first..first + len)
        .map(|r| LaneRay {
            o: rays.o[r].map(f),
            d: rays.d[r].map(f),
            t0: f(rays.t0[r]),
            t1: f(rays.t1[r]),
        })
        .collect()
}

/// Fills `recs` from the persisted buffers (unfused chain); lattice indices
/// come from walking the lattice without field queries.
pub(super) fn replay_unfused<F: Real>(
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
pub(super) struct Emit<F> {
    pub(super) x: [F; 3],
    /// Trilinear cells of the density and colour grids (computed once per
    /// sample, shared when the grids have the same geometry).
    pub(super) cs: Option<Cell<F>>,
    pub(super) cc: Option<Cell<F>>,
    pub(super) dsigma: F,
    pub(super) dcolor: [F; 3],
}

/// Walks ray `r` backward over `recs`, calling `emit(i, ..)` per sample;
/// returns the ray's `dL/d delta` (f64, for the ordered sum over rays).
pub(super) fn ray_grads<F: Real>(
    cx: &Ctx<F>,
    r: usize,
    recs: &[Rec<F>],
    log_tn: F,
    mut hash_sink: Option<&mut [F]>,
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
            // One back-propagation gives dL/dx and (into the sink) dL/dparams.
            (Field::HashMlp(h), _) => {
                let g4 = [sg.dsigma, sg.dcolor[0], sg.dcolor[1], sg.dcolor[2]];
                (
                    ([F::zero(); 3], h.backward(x, g4, hash_sink.as_deref_mut())),
                    None,
                )
            }
            // One closed-form gradient of the packed [sigma, r, g, b] grid:
            // dsigma grad sigma + J_c^T dcolor in one pass over the corners.
            (Field::Grid(_), ColorField::Grid(_)) if cx.packed.is_some() => {
                let g4 = [sg.dsigma, sg.dcolor[0], sg.dcolor[1], sg.dcolor[2]];
                let gx = match (cx.packed, cs) {
                    (Some(p), Some(c)) => grid_grad::<F, 4>(p, &c, g4),
                    _ => [F::zero(); 3],
                };
                (([F::zero(); 3], gx), cs)
            }
            (Field::Grid(g), ColorField::Grid(gcol)) if cx.shared_cell => {
                let gs = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 1>(g, &c, [F::one()]));
                let gc = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 3>(gcol, &c, sg.dcolor));
                ((gs, gc), cs)
            }
            (Field::Grid(g), _) => {
                let gs = cs.map_or([F::zero(); 3], |c| grid_grad::<F, 1>(g, &c, [F::one()]));
                let cc = match cx.color {
                    ColorField::Grid(gcol) => cell_of(gcol, x),
                    ColorField::Constant(_) | ColorField::Mlp => None,
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
                    ColorField::Constant(_) | ColorField::Mlp => None,
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
    let sums = CamSums {
        go: go_k.map(|k| k.s),
        gd: gd_k.map(|k| k.s),
        dl_t0: dl_t0.s,
        dl_t1: dl_t1.s,
    };
    cam_grads(cx, r, !recs.is_empty(), sums)
}

/// A ray's compensated sums over its samples: `dL/do`, `dL/dd` through the
/// sample positions, and `dL/dt0`, `dL/dt1`.
#[derive(Clone, Copy, Debug, Default)]
pub(super) struct CamSums<F> {
    pub(super) go: [F; 3],
    pub(super) gd: [F; 3],
    pub(super) dl_t0: F,
    pub(super) dl_t1: F,
}

/// Ray `r`'s `dL/d delta` from its sums (`any`: the ray has samples, so
/// `t0`, `t1` move with the active clip planes).
pub(super) fn cam_grads<F: Real>(cx: &Ctx<F>, r: usize, any: bool, s: CamSums<F>) -> [f64; 6] {
    let (o, d) = (cx.rays.o[r], cx.rays.d[r]);
    let (mut go_sum, mut gd_sum) = (s.go, s.gd);
    if any {
        let (p0, p1) = clip_planes(o, d, cx.bmin, cx.bmax, cx.near, cx.far);
        for ((t, mask), dl) in [(p0, s.dl_t0), (p1, s.dl_t1)] {
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
