//! The backward pass over a given forward state: units of rays walked in
//! parallel, then ordered reductions (module doc of `diff`).

use std::time::Instant;

use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::real::Real;

use super::super::field::{ColorField, Field};
use super::super::fused_lanes::{query_of, LaneMarch, LANES};
use super::super::integrate::Integrated;
use super::super::sample::{walk_lattice, Samples};
use super::field_grad::{param_count, param_index};
use super::lanes::{self, LaneGrad, Scratch};
use super::reduce::{
    push_rec, reduce_sorted, scatter_dense, split_packed, sum_chunks, sum_chunks_split, Dense,
    Unit, UNIT_RAYS,
};
use super::walk::{ray_grads, replay_fused, replay_fused_lanes, replay_unfused, Ctx};
use super::{DiffOptions, Grads, Ksum, Rec, Reduce};

/// The backward pass over the given forward state (module doc).
#[allow(clippy::too_many_arguments)]
/// `lane_backward`: the fused chain walks rays backward 8 at a time in
/// AVX2 lanes where [`LaneGrad`] covers the pass (else, and with `false`,
/// the scalar walk, the referee).
pub(super) fn backward<F: Real>(
    cx: &Ctx<F>,
    buffers: Option<(&Samples<F>, &Integrated<F>)>,
    opt: &DiffOptions,
    budget: &MemBudget,
    lane_backward: bool,
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
    // Density and colour on one geometry: one packed 4-channel scatter.
    let packed = cx.packed;
    let nparam = param_count(cx.field);
    let const_color = matches!(cx.color, ColorField::Constant(_));
    let per_sample = opt.per_sample && buffers.is_some();
    // Per-sample memory of the plan, checked before the walk.
    let fsz = std::mem::size_of::<F>() as u64;
    let mut bps = 0u64;
    if buffers.is_some() {
        bps += Samples::<F>::BYTES_PER_SAMPLE + Integrated::<F>::BYTES_PER_SAMPLE;
    }
    let hash = match cx.field {
        Field::HashMlp(h) => Some(h),
        _ => None,
    };
    // The hash field's parameters are reduced by fixed chunks of rays (dense
    // per-chunk gradients summed in chunk order) under either option: the
    // count does not depend on the thread count, so the sum is deterministic.
    let reduce = match (hash, opt.reduce) {
        (Some(_), Reduce::Sorted) => Reduce::Chunked {
            chunks: super::DEFAULT_CHUNKS,
        },
        (_, r) => r,
    };
    let units: Vec<(usize, usize)> = match reduce {
        Reduce::Sorted => {
            // Each record is held twice: in its unit and in the sorted array.
            bps += 2 * match packed {
                Some(_) => 4 + 7 * fsz,
                None => sig_grid.map_or(0, |_| 4 + 4 * fsz) + col_grid.map_or(0, |_| 4 + 6 * fsz),
            };
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
            let grids = match packed {
                Some(p) => p.data.len() as u64,
                None => {
                    sig_grid.map_or(0, |g| g.data.len() as u64)
                        + col_grid.map_or(0, |g| g.data.len() as u64)
                }
            };
            let dense = grids + hash.map_or(0, |h| h.param_count() as u64);
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
    let sorted = reduce == Reduce::Sorted;
    // The fused chain replays rays 8 at a time in the forward's lanes where
    // they cover the medium (bit-identical records).
    let lanes = LaneMarch::new(cx.medium, cx.m, cx.occ).filter(|_| buffers.is_none());
    let query = query_of(cx.medium);
    // ... and walk them backward in the same lanes (bit-identical gradients).
    let lane_grad = match (lane_backward, &packed) {
        (true, Some(p)) if !per_sample => LaneGrad::new(cx, lanes).map(|lg| (lg, *p)),
        _ => None,
    };
    let out_units: Vec<Unit<F>> = par_collect("f_diff", units.len(), |ui| {
        let (a, b) = units[ui];
        let mut u = Unit {
            cam: Vec::with_capacity(b - a),
            param: vec![Ksum::default(); nparam],
            color_const: [Ksum::default(); 3],
            sig_recs: vec![],
            col_recs: vec![],
            pk_recs: vec![],
            sig_dense: match (sorted, packed, sig_grid) {
                (false, None, Some(g)) => Dense::grid::<1>(g),
                _ => Dense::new(0, 1),
            },
            col_dense: match (sorted, packed, col_grid) {
                (false, None, Some(g)) => Dense::grid::<3>(g),
                _ => Dense::new(0, 1),
            },
            pk_dense: match (sorted, packed) {
                (false, Some(p)) => Dense::grid::<4>(p),
                _ => Dense::new(0, 1),
            },
            hash_dense: {
                let n = hash.map_or(0, |h| h.param_count());
                let mut d = Dense::new(n, n);
                d.touch_all();
                d
            },
            per_sample: vec![],
            samples: 0,
        };
        if let Some((lg, p)) = &lane_grad {
            let mut sc = Scratch::default();
            for first in (a..b).step_by(LANES) {
                let len = LANES.min(b - first);
                let cams = lanes::group(cx, lg, &query, first, len, &mut sc);
                for (l, cam) in cams.into_iter().take(len).enumerate() {
                    u.samples += sc.samples(l) as u64;
                    if sorted {
                        sc.cells(l, lg.ds(), |c, v| push_rec(p, Some(c), v, &mut u.pk_recs));
                    } else {
                        sc.scatter(l, p, &mut u.pk_dense);
                    }
                    u.cam.push(cam);
                }
            }
            return u;
        }
        let mut recs = Vec::new();
        let mut lane_recs: [Vec<Rec<F>>; LANES] = Default::default();
        let mut lane_log_t = [F::zero(); LANES];
        let mut ps: Vec<(F, [F; 3])> = Vec::new();
        for r in a..b {
            let log_tn = match (buffers, &lanes) {
                (Some((s, it)), _) => replay_unfused(cx, s, it, r, &mut recs),
                (None, Some(lm)) => {
                    let j = (r - a) % LANES;
                    if j == 0 {
                        let len = LANES.min(b - r);
                        lane_log_t = replay_fused_lanes(cx, lm, &query, r, len, &mut lane_recs);
                    }
                    std::mem::swap(&mut recs, &mut lane_recs[j]);
                    lane_log_t[j]
                }
                (None, None) => replay_fused(cx, r, &mut recs),
            };
            u.samples += recs.len() as u64;
            if per_sample {
                ps.clear();
                ps.resize(recs.len(), (F::zero(), [F::zero(); 3]));
            }
            // Records go out back to front; the sorted path wants (ray,
            // sample) order, so a ray's records are reversed after its walk.
            let (s0, c0, p0) = (u.sig_recs.len(), u.col_recs.len(), u.pk_recs.len());
            let sink = hash.is_some().then_some(&mut u.hash_dense.data[..]);
            let cam = ray_grads(cx, r, &recs, log_tn, sink, |i, e| {
                if let Some(p) = param_index(cx.field, e.x) {
                    u.param[p].add(e.dsigma);
                }
                if const_color {
                    for ch in 0..3 {
                        u.color_const[ch].add(e.dcolor[ch]);
                    }
                }
                if let Some(p) = packed {
                    let v = [e.dsigma, e.dcolor[0], e.dcolor[1], e.dcolor[2]];
                    if sorted {
                        push_rec(p, e.cs, v, &mut u.pk_recs);
                    } else {
                        scatter_dense(p, e.cs, v, &mut u.pk_dense);
                    }
                } else if let Some(g) = sig_grid {
                    if sorted {
                        push_rec(g, e.cs, [e.dsigma], &mut u.sig_recs);
                    } else {
                        scatter_dense(g, e.cs, [e.dsigma], &mut u.sig_dense);
                    }
                }
                if let (None, Some(g)) = (packed, col_grid) {
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
            u.pk_recs[p0..].reverse();
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
    let (dsigma, dcolor) = match (packed, sorted) {
        (Some(p), _) => {
            let (sig, col) = if sorted {
                let parts = out_units.iter_mut().map(|u| std::mem::take(&mut u.pk_recs));
                split_packed(&reduce_sorted(p, parts.collect()))
            } else {
                let parts: Vec<&Dense<F>> = out_units.iter().map(|u| &u.pk_dense).collect();
                sum_chunks_split(&parts, p.data.len() / 4)
            };
            (Some(sig), Some(col))
        }
        (None, true) => (
            sig_grid.map(|g| {
                let parts = out_units
                    .iter_mut()
                    .map(|u| std::mem::take(&mut u.sig_recs));
                reduce_sorted(g, parts.collect())
            }),
            col_grid.map(|g| {
                let parts = out_units
                    .iter_mut()
                    .map(|u| std::mem::take(&mut u.col_recs));
                reduce_sorted(g, parts.collect())
            }),
        ),
        (None, false) => (
            sig_grid.map(|g| {
                let parts: Vec<&Dense<F>> = out_units.iter().map(|u| &u.sig_dense).collect();
                sum_chunks(&parts, g.data.len())
            }),
            col_grid.map(|g| {
                let parts: Vec<&Dense<F>> = out_units.iter().map(|u| &u.col_dense).collect();
                sum_chunks(&parts, g.data.len())
            }),
        ),
    };
    let dhash = hash.map(|h| {
        let parts: Vec<&Dense<F>> = out_units.iter().map(|u| &u.hash_dense).collect();
        sum_chunks(&parts, h.param_count())
    });
    let (ps_s, ps_c) = split_per_sample(per_sample, &out_units);
    Ok(Grads {
        dsigma,
        dsigma_param: (nparam > 0).then_some(param),
        dcolor,
        dcolor_const: const_color.then_some(color_const),
        dhash,
        dsigma_samples: ps_s,
        dcolor_samples: ps_c,
        dcam: dcam.map(F::of),
        samples,
        bytes_per_sample: bps,
        time_s: t_start.elapsed().as_secs_f64(),
    })
}

#[allow(clippy::type_complexity)]
pub(super) fn split_per_sample<F: Real>(
    on: bool,
    units: &[Unit<F>],
) -> (Option<Vec<F>>, Option<Vec<[F; 3]>>) {
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
pub(super) fn lattice_bound<F: Real>(cx: &Ctx<F>) -> u64 {
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
