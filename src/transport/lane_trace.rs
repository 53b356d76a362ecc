//! The lane path: fixed-law RK4 on four rays at once ([`super::simd4`]),
//! for the static spacetimes ([`Spacetime`]: Minkowski, Schwarzschild,
//! Ellis) in f64. The scalar loop [`super::integrate::trace`] is its
//! referee and the one to learn the algorithm from; this file repeats its
//! step with the same formulas ([`Spacetime::rhs_h`]) in lane arithmetic.
//!
//! Scheduling: rays come in chunks of [`CHUNK`] (fanned out by
//! `parallel::par_chunks`); inside a chunk each of the four lanes takes the
//! next ray as soon as its own ray ends (event, non-finite state, max
//! steps), so lanes stay full until the chunk's queue is empty. A ray's
//! arithmetic never reads another lane, so results do not depend on the
//! lane, the chunk or the thread count.
//!
//! Exactly as the scalar loop: the step law, the first stage carried from
//! the end of the step before, `|H|` at every accepted state, the
//! non-finite and max-steps ends. A step that crosses an event hands that
//! ray's two states to [`super::integrate::crossed`], the scalar locator.
//!
//! Differences from the scalar path: fused multiply-adds (AVX2+FMA) and the
//! lane [`super::simd4::sin_cos`] (<= 1 ulp from `f64::sin_cos`); the
//! bound on the results is measured in the tests below.
//!
//! Applies when: f64, tier `rk4` (any step law), no projection, every event
//! a `Coord` event; otherwise [`trace_rays`] returns `None` and the caller
//! traces with the scalar loop.

use std::any::Any;

use super::hamiltonian::{all_finite, Hamiltonian};
use super::integrate::{crossed, End, Event, EventKind, Options, StepLaw, Tier, Trace, MAX_EVENTS};
use super::metric::Spacetime;
use super::simd4::{sin_cos, Lanes, Portable};
use crate::parallel::par_chunks;
use crate::real::Real;

/// Rays per scheduling chunk (per lane about `CHUNK / 4` rays in a row).
pub const CHUNK: usize = 64;

/// Which kernel traces a ray list.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Kernel {
    /// The scalar loop ([`super::integrate::trace`]), one ray at a time.
    Scalar,
    /// Four lanes of plain Rust ([`Portable`]): the fallback without AVX2.
    Portable,
    /// Four lanes in AVX2 with FMA (x86_64, detected at run time).
    Avx2,
}

impl Kernel {
    /// The fastest kernel this CPU runs: AVX2 where `avx2` and `fma` are
    /// detected, else the portable lanes.
    pub fn best() -> Kernel {
        #[cfg(target_arch = "x86_64")]
        if is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma") {
            return Kernel::Avx2;
        }
        Kernel::Portable
    }

    pub fn name(self) -> &'static str {
        match self {
            Kernel::Scalar => "scalar",
            Kernel::Portable => "portable",
            Kernel::Avx2 => "avx2",
        }
    }
}

/// `(dy/dlambda, H)` on four lanes: [`Spacetime::rhs_h`] term for term.
#[inline(always)]
fn rhs_h<V: Lanes>(st: &Spacetime<f64>, y: &[V; 8]) -> ([V; 8], V) {
    let s = V::splat;
    let r = y[1];
    let (a, da, b, db, inv_r2, dr2) = match *st {
        Spacetime::Schwarzschild { mass } => {
            let inv_r = s(1.0) / r;
            let f = s(-2.0 * mass).mul_add(inv_r, s(1.0));
            let df = s(2.0 * mass) * inv_r * inv_r;
            let inv_f = s(1.0) / f;
            (inv_f, -df * inv_f * inv_f, f, df, inv_r * inv_r, s(2.0) * r)
        }
        Spacetime::Minkowski | Spacetime::Ellis { .. } => {
            let b0 = match *st {
                Spacetime::Ellis { b0 } => b0,
                _ => 0.0,
            };
            let r2 = r.mul_add(r, s(b0 * b0));
            let (one, zero) = (s(1.0), s(0.0));
            (one, zero, one, zero, one / r2, s(2.0) * r)
        }
    };
    let (sn, co) = sin_cos(y[2]);
    let inv_s = s(1.0) / sn;
    let inv_s2 = inv_s * inv_s;
    let ang = y[6].mul_add(y[6], y[7] * y[7] * inv_s2);
    let (pt2, pr2) = (y[4] * y[4], y[5] * y[5]);
    let half = s(0.5);
    let dpr = -half * (db.mul_add(pr2, -da * pt2)) + half * dr2 * ang * inv_r2 * inv_r2;
    let dpth = y[7] * y[7] * co * inv_s2 * inv_s * inv_r2;
    let h = (-a).mul_add(pt2, b.mul_add(pr2, ang * inv_r2)) * half;
    let z = s(0.0);
    (
        [
            -a * y[4],
            b * y[5],
            y[6] * inv_r2,
            y[7] * inv_r2 * inv_s2,
            z,
            dpr,
            dpth,
            z,
        ],
        h,
    )
}

/// [`Hamiltonian::scale`] of [`Spacetime`] on four lanes.
#[inline(always)]
fn scale<V: Lanes>(st: &Spacetime<f64>, y: &[V; 8]) -> V {
    match *st {
        Spacetime::Minkowski => y[1].abs(),
        Spacetime::Schwarzschild { mass } => y[1] - V::splat(2.0 * mass),
        Spacetime::Ellis { b0 } => y[1].mul_add(y[1], V::splat(b0 * b0)).sqrt(),
    }
}

/// `y + c k` per slot.
#[inline(always)]
fn axpy<V: Lanes>(y: &[V; 8], c: V, k: &[V; 8]) -> [V; 8] {
    std::array::from_fn(|i| c.mul_add(k[i], y[i]))
}

/// One RK4 step on four lanes from `y` with first stage `k1` (the scalar
/// [`super::integrate::rk4_step_from`]: the same stages and weights).
#[inline(always)]
fn rk4<V: Lanes>(st: &Spacetime<f64>, y: &[V; 8], k1: &[V; 8], h: V) -> [V; 8] {
    let half = V::splat(0.5) * h;
    let (k2, _) = rhs_h(st, &axpy(y, half, k1));
    let (k3, _) = rhs_h(st, &axpy(y, half, &k2));
    let (k4, _) = rhs_h(st, &axpy(y, h, &k3));
    let (c6, c3) = (h * V::splat(1.0 / 6.0), h * V::splat(1.0 / 3.0));
    let o = axpy(y, c6, k1);
    let o = axpy(&o, c3, &k2);
    let o = axpy(&o, c3, &k3);
    axpy(&o, c6, &k4)
}

/// The step size `law.h(scale)` on four lanes.
#[inline(always)]
fn step_size<V: Lanes>(law: &StepLaw<f64>, scale: V) -> V {
    match *law {
        StepLaw::Fixed { h } => V::splat(h),
        StepLaw::Scaled { eta, h_min, h_max } => (V::splat(eta) * scale)
            .max(V::splat(h_min))
            .min(V::splat(h_max)),
    }
}

/// State of the four lanes, structure of arrays: `y[slot][lane]`.
struct Block {
    y: [[f64; 4]; 8],
    k1: [[f64; 4]; 8],
    ray: [Option<usize>; 4],
    lambda: [f64; 4],
    steps: [u64; 4],
    h_drift: [f64; 4],
    gs: [[f64; MAX_EVENTS]; 4],
}

fn column(a: &[[f64; 4]; 8], l: usize) -> [f64; 8] {
    std::array::from_fn(|i| a[i][l])
}

/// The scalar path's result for a ray that never takes a lane step
/// (non-finite start or `max_steps = 0`).
fn at_start(st: &Spacetime<f64>, y0: [f64; 8], end: End) -> Trace<f64, 8> {
    ended(y0, 0.0, end, 0, st.h(&y0).abs())
}

/// A fixed-step trace's result (no rejected steps, no error estimate).
fn ended(y: [f64; 8], lambda: f64, end: End, steps: u64, h_drift: f64) -> Trace<f64, 8> {
    Trace {
        y,
        lambda,
        end,
        steps,
        rejected: 0,
        h_drift,
        err_est: 0.0,
    }
}

/// Traces the rays `starts[base..base + out.len()]` into `out` on four
/// lanes of type `V`.
#[inline(always)]
fn run_chunk<V: Lanes>(
    st: &Spacetime<f64>,
    law: &StepLaw<f64>,
    starts: &[[f64; 8]],
    opt: &Options<f64>,
    events: &[Event<f64>],
    base: usize,
    out: &mut [Trace<f64, 8>],
) {
    let coord: Vec<(usize, f64)> = events
        .iter()
        .map(|e| match e.kind {
            EventKind::Coord { index, value } => (index, value),
            _ => (1, f64::NAN),
        })
        .collect();
    let mut next = 0;
    let mut bl = Block {
        y: [[0.0; 4]; 8],
        k1: [[0.0; 4]; 8],
        ray: [None; 4],
        lambda: [0.0; 4],
        steps: [0; 4],
        h_drift: [0.0; 4],
        gs: [[0.0; MAX_EVENTS]; 4],
    };
    loop {
        for l in 0..4 {
            while bl.ray[l].is_none() && next < out.len() {
                let i = next;
                next += 1;
                let y0 = starts[base + i];
                if !all_finite(&y0) || opt.max_steps == 0 {
                    let end = if all_finite(&y0) {
                        End::MaxSteps
                    } else {
                        End::NonFinite
                    };
                    out[i] = at_start(st, y0, end);
                    continue;
                }
                let (k, h0) = st.rhs_h(&y0);
                for s in 0..8 {
                    bl.y[s][l] = y0[s];
                    bl.k1[s][l] = k[s];
                }
                bl.ray[l] = Some(i);
                bl.lambda[l] = 0.0;
                bl.steps[l] = 0;
                bl.h_drift[l] = h0.abs();
                for (g, e) in bl.gs[l].iter_mut().zip(events) {
                    *g = e.g(&y0);
                }
            }
        }
        if bl.ray.iter().all(Option::is_none) {
            return;
        }
        let y: [V; 8] = std::array::from_fn(|s| V::load(&bl.y[s]));
        let k1: [V; 8] = std::array::from_fn(|s| V::load(&bl.k1[s]));
        let h = step_size(law, scale(st, &y));
        let y1 = rk4(st, &y, &k1, h);
        let (k1n, hn) = rhs_h(st, &y1);
        let mut fin = [true; 4];
        for v in &y1 {
            let f = v.finite();
            for l in 0..4 {
                fin[l] &= f[l];
            }
        }
        let y1a: [[f64; 4]; 8] = std::array::from_fn(|s| y1[s].store());
        let (ha, hna) = (h.store(), hn.store());
        for l in 0..4 {
            let Some(i) = bl.ray[l] else { continue };
            if !fin[l] {
                let y = column(&bl.y, l);
                out[i] = ended(y, bl.lambda[l], End::NonFinite, bl.steps[l], bl.h_drift[l]);
                bl.ray[l] = None;
                continue;
            }
            let fires = events
                .iter()
                .zip(&coord)
                .enumerate()
                .any(|(e, (ev, &(idx, v)))| ev.fires(bl.gs[l][e], y1a[idx][l] - v));
            if fires {
                let (y0c, y1c) = (column(&bl.y, l), column(&y1a, l));
                if let Some((e, th, yc)) = crossed(st, opt, events, &bl.gs[l], &y0c, &y1c, ha[l]) {
                    let (lambda, drift) = (bl.lambda[l] + th * ha[l], st.h(&yc).abs());
                    let drift = bl.h_drift[l].max(drift);
                    out[i] = ended(yc, lambda, End::Event(e), bl.steps[l] + 1, drift);
                    bl.ray[l] = None;
                    continue;
                }
            }
            for (e, &(idx, v)) in coord.iter().enumerate() {
                bl.gs[l][e] = y1a[idx][l] - v;
            }
            bl.steps[l] += 1;
            bl.lambda[l] += ha[l];
            bl.h_drift[l] = bl.h_drift[l].max(hna[l].abs());
            if bl.steps[l] >= opt.max_steps {
                let y = column(&y1a, l);
                out[i] = ended(y, bl.lambda[l], End::MaxSteps, bl.steps[l], bl.h_drift[l]);
                bl.ray[l] = None;
            }
        }
        bl.y = y1a;
        bl.k1 = std::array::from_fn(|s| k1n[s].store());
    }
}

#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx2,fma")]
unsafe fn run_chunk_avx2(
    st: &Spacetime<f64>,
    law: &StepLaw<f64>,
    starts: &[[f64; 8]],
    opt: &Options<f64>,
    events: &[Event<f64>],
    base: usize,
    out: &mut [Trace<f64, 8>],
) {
    run_chunk::<super::simd4::Avx2>(st, law, starts, opt, events, base, out)
}

/// The lane path for f64: `None` where it does not apply (see the module
/// comment) or `kernel` is [`Kernel::Scalar`].
fn trace_f64(
    st: &Spacetime<f64>,
    starts: &[[f64; 8]],
    opt: &Options<f64>,
    events: &[Event<f64>],
    kernel: Kernel,
) -> Option<Vec<Trace<f64, 8>>> {
    let Tier::Rk4(law) = opt.tier else {
        return None;
    };
    let coord_only = events
        .iter()
        .all(|e| matches!(e.kind, EventKind::Coord { index, .. } if index < 8));
    if kernel == Kernel::Scalar || opt.project || !coord_only || events.len() > MAX_EVENTS {
        return None;
    }
    let blank = at_start(st, [0.0; 8], End::MaxSteps);
    let mut out = vec![blank; starts.len()];
    par_chunks("transport.lanes", &mut out, CHUNK, |c, chunk| {
        let base = c * CHUNK;
        match kernel {
            #[cfg(target_arch = "x86_64")]
            Kernel::Avx2 if Kernel::best() == Kernel::Avx2 => {
                // SAFETY: `Kernel::best` detected avx2 and fma.
                unsafe { run_chunk_avx2(st, &law, starts, opt, events, base, chunk) }
            }
            _ => run_chunk::<Portable>(st, &law, starts, opt, events, base, chunk),
        }
    });
    Some(out)
}

/// Traces every start state of `starts` in `st` with `kernel` on the lane
/// path, in input order; `None` where the lane path does not apply (then
/// the caller runs the scalar loop). Generic over the precision so that
/// tasks call it unconditionally: only `F = f64` takes lanes.
pub fn trace_rays<F: Real>(
    st: &Spacetime<F>,
    starts: &[[F; 8]],
    opt: &Options<F>,
    events: &[Event<F>],
    kernel: Kernel,
) -> Option<Vec<Trace<F, 8>>> {
    let st = (st as &dyn Any).downcast_ref::<Spacetime<f64>>()?;
    let starts: Vec<[f64; 8]> = starts
        .iter()
        .map(|y| (y as &dyn Any).downcast_ref::<[f64; 8]>().copied())
        .collect::<Option<_>>()?;
    let opt = (opt as &dyn Any).downcast_ref::<Options<f64>>()?;
    let events: Vec<Event<f64>> = events
        .iter()
        .map(|e| (e as &dyn Any).downcast_ref::<Event<f64>>().copied())
        .collect::<Option<_>>()?;
    let out = trace_f64(st, &starts, opt, &events, kernel)?;
    let boxed: Box<dyn Any> = Box::new(out);
    boxed.downcast::<Vec<Trace<F, 8>>>().ok().map(|b| *b)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::parallel::with_threads;
    use crate::transport::integrate::trace;
    use crate::transport::tasks::far_photon;

    fn rk4(law: StepLaw<f64>, max_steps: u64) -> Options<f64> {
        Options {
            tier: Tier::Rk4(law),
            project: false,
            max_steps,
        }
    }

    const SCALED: StepLaw<f64> = StepLaw::Scaled {
        eta: 0.01,
        h_min: 1e-6,
        h_max: 1e3,
    };

    fn coord(value: f64, rising: bool) -> Event<f64> {
        Event {
            kind: EventKind::Coord { index: 1, value },
            rising,
        }
    }

    /// Impact parameters around the photon orbit `b_c = 3 sqrt(3)` (hard
    /// rays: up to ~3.3 windings at 1e-9), grazing capture, and far rays.
    fn schw_impacts() -> (Vec<f64>, Vec<f64>) {
        let bc = 27f64.sqrt();
        let hard = [-1e-3, -1e-6, -1e-9, 1e-9, 1e-6, 1e-3]
            .iter()
            .map(|d| bc + d)
            .collect();
        let easy = vec![
            0.5, 2.0, 4.0, 5.0, 5.3, 6.0, 8.0, 10.0, 20.0, 50.0, 100.0, 300.0,
        ];
        (hard, easy)
    }

    /// Largest `|a_i - b_i| / max(1, |b_i|)` over the state slots.
    fn rel(a: &[f64; 8], b: &[f64; 8]) -> f64 {
        (0..8).fold(0.0, |m, i| m.max((a[i] - b[i]).abs() / b[i].abs().max(1.0)))
    }

    /// Traces `starts` on the lane path with `kernel` and with the scalar
    /// loop; asserts the same end and step count for every ray and returns
    /// the largest state difference and `|H|` drift difference.
    fn against_scalar(
        st: Spacetime<f64>,
        starts: &[[f64; 8]],
        opt: &Options<f64>,
        ev: &[Event<f64>],
        kernel: Kernel,
    ) -> (f64, f64) {
        let lanes = trace_rays(&st, starts, opt, ev, kernel).expect("lane path applies");
        let (mut dy, mut dh) = (0.0f64, 0.0f64);
        for (y0, l) in starts.iter().zip(&lanes) {
            let s = trace(&st, *y0, opt, ev, |_, _| {});
            assert_eq!((l.end, l.steps), (s.end, s.steps), "{st:?} from {y0:?}");
            dy = dy.max(rel(&l.y, &s.y));
            dh = dh.max((l.h_drift - s.h_drift).abs());
        }
        (dy, dh)
    }

    fn kernels() -> Vec<Kernel> {
        let mut k = vec![Kernel::Portable];
        if Kernel::best() == Kernel::Avx2 {
            k.push(Kernel::Avx2);
        }
        k
    }

    fn schw_starts(bs: &[f64]) -> Vec<[f64; 8]> {
        let st = Spacetime::Schwarzschild { mass: 1.0 };
        bs.iter()
            .map(|&b| far_photon(&st, 1000.0, b).unwrap())
            .collect()
    }

    #[test]
    fn lanes_end_like_the_scalar_loop_within_the_measured_bound() {
        let st = Spacetime::Schwarzschild { mass: 1.0 };
        let ev = [coord(1000.0, true), coord(2.02, false)];
        let (hard, easy) = schw_impacts();
        // Measured (AVX2+FMA): easy rays 6.7e-16 in the state, 6.4e-14 in
        // |H| drift; hard rays (windings amplify rounding) 1.8e-11 and
        // 3.7e-12. Portable lanes: 8.8e-29 and 5.6e-17 (no FMA; only
        // sin_cos differs, and not on these rays). Bounds about 4x those.
        for k in kernels() {
            let (dy, dh) = against_scalar(st, &schw_starts(&easy), &rk4(SCALED, 1 << 20), &ev, k);
            eprintln!("{k:?} easy: state {dy:e}, |H| {dh:e}");
            assert!(dy <= 4e-15 && dh <= 2.5e-13, "{k:?}: {dy:e} {dh:e}");
            let (dy, dh) = against_scalar(st, &schw_starts(&hard), &rk4(SCALED, 1 << 20), &ev, k);
            eprintln!("{k:?} hard: state {dy:e}, |H| {dh:e}");
            assert!(dy <= 8e-11 && dh <= 1.5e-11, "{k:?}: {dy:e} {dh:e}");
        }
    }

    #[test]
    fn lanes_match_scalar_in_ellis_minkowski_fixed_steps_and_step_caps() {
        let ellis = Spacetime::Ellis { b0: 1.0 };
        let starts: Vec<[f64; 8]> = [0.3, 0.9, 0.999, 1.001, 1.5, 3.0]
            .iter()
            .map(|&b| far_photon(&ellis, 50.0, b).unwrap())
            .collect();
        let ev = [coord(50.0, true), coord(-50.0, false)];
        let mink = Spacetime::Minkowski;
        let ms: Vec<[f64; 8]> = [0.5, 3.0, 20.0]
            .iter()
            .map(|&b| far_photon(&mink, 50.0, b).unwrap())
            .collect();
        let mut capped = schw_starts(&[5.3, 20.0]);
        capped.push([f64::NAN; 8]);
        let schw = Spacetime::Schwarzschild { mass: 1.0 };
        let sev = [coord(1000.0, true), coord(2.02, false)];
        for k in kernels() {
            let (dy, _) = against_scalar(ellis, &starts, &rk4(SCALED, 1 << 20), &ev, k);
            eprintln!("{k:?} ellis {dy:e}");
            assert!(dy <= 1e-13, "{k:?} ellis {dy:e}");
            let fixed = rk4(StepLaw::Fixed { h: 0.05 }, 1 << 20);
            let (dy, _) = against_scalar(mink, &ms, &fixed, &ev, k);
            eprintln!("{k:?} minkowski {dy:e}");
            assert!(dy <= 1e-13, "{k:?} minkowski {dy:e}");
            for cap in [0, 1, 37] {
                let (dy, _) = against_scalar(schw, &capped, &rk4(SCALED, cap), &sev, k);
                assert!(dy <= 1e-12, "{k:?} cap {cap} {dy:e}");
            }
        }
    }

    #[test]
    fn lane_results_do_not_depend_on_the_thread_count() {
        let st = Spacetime::Schwarzschild { mass: 1.0 };
        let ev = [coord(1000.0, true), coord(2.02, false)];
        let (hard, easy) = schw_impacts();
        let bs: Vec<f64> = easy
            .iter()
            .chain(&hard)
            .cycle()
            .take(300)
            .copied()
            .collect();
        let starts = schw_starts(&bs);
        let opt = rk4(SCALED, 1 << 20);
        let run = |n| {
            with_threads(n, || {
                trace_rays(&st, &starts, &opt, &ev, Kernel::best()).unwrap()
            })
        };
        let (one, two) = (run(1), run(2));
        assert_eq!(one, two);
        // Same ray, any lane and chunk: copies of one ray agree bit for bit.
        let first: Vec<_> = one.iter().take(easy.len()).collect();
        for (i, t) in one.iter().enumerate() {
            if i % (easy.len() + hard.len()) < easy.len() {
                assert_eq!(t, first[i % (easy.len() + hard.len())]);
            }
        }
    }

    #[test]
    fn other_tiers_projection_f32_and_scalar_kernel_take_the_scalar_loop() {
        let st = Spacetime::Schwarzschild { mass: 1.0 };
        let starts = schw_starts(&[6.0]);
        let ev = [coord(1000.0, true)];
        let opt = rk4(SCALED, 100);
        assert!(trace_rays(&st, &starts, &opt, &ev, Kernel::Scalar).is_none());
        let proj = Options {
            project: true,
            ..opt
        };
        assert!(trace_rays(&st, &starts, &proj, &ev, Kernel::best()).is_none());
        let dp = Options {
            tier: Tier::Dopri5Fixed(SCALED),
            ..opt
        };
        assert!(trace_rays(&st, &starts, &dp, &ev, Kernel::best()).is_none());
        let st32 = Spacetime::Schwarzschild { mass: 1.0f32 };
        let s32 = [starts[0].map(|v| v as f32)];
        let opt32 = Options {
            tier: Tier::Rk4(StepLaw::Fixed { h: 0.1f32 }),
            project: false,
            max_steps: 10,
        };
        let ev32 = [Event {
            kind: EventKind::Coord {
                index: 1,
                value: 1000.0f32,
            },
            rising: true,
        }];
        assert!(trace_rays(&st32, &s32, &opt32, &ev32, Kernel::best()).is_none());
    }
}
