//! One Kerr ray with its certificate: the integrator's loop
//! ([`super::integrate::trace`]) plus, at every accepted state, the
//! constants of motion `E`, `L_z`, Carter `Q` and `H`, and the azimuth
//! swept in the Kerr–Schild `x, y` plane. Optionally the ray stops on a
//! thin equatorial disk `r_in <= r <= r_out`: every crossing of `z = 0` is
//! a located event, and a crossing outside the disk continues the ray.
//!
//! Events of every Kerr ray: 0 = escape (`r` rises through `r_end`),
//! 1 = capture (`r` falls through the outer horizon `r_+`, located: the
//! chart is regular there).

use super::hamiltonian::Hamiltonian;
use super::integrate::{trace, End, Event, EventKind, Options};
use super::kerr::Kerr;
use crate::real::Real;

/// A Kerr ray's result and certificate.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct KerrRay<F> {
    /// Final state (at the located event).
    pub y: [F; 8],
    pub end: End,
    pub steps: u64,
    /// `max |H|` along the ray.
    pub h_drift: F,
    /// Sum of the embedded local error estimates (DP45 tiers; else 0).
    pub err_est: F,
    /// `max |X - X0| / max(|X0|, 1)` for `X = E, L_z, Q` (units of M).
    pub drift: [F; 3],
    /// Azimuth swept in the `x, y` plane (radians, signed, unwrapped).
    pub sweep: F,
    /// Where the ray met the disk: the radius there.
    pub disk_r: Option<F>,
}

/// The escape and capture events of a ray in `k`, out to `r_end`.
pub fn kerr_events<F: Real>(k: &Kerr<F>, r_end: F) -> Vec<Event<F>> {
    vec![
        Event {
            kind: EventKind::KsRadius {
                a: k.a,
                value: r_end,
            },
            rising: true,
        },
        Event {
            kind: EventKind::KsRadius {
                a: k.a,
                value: k.horizon(),
            },
            rising: false,
        },
    ]
}

/// Most equatorial crossings a disk ray may make outside the disk.
const MAX_CROSSINGS: usize = 64;

/// Traces `y0` in `k` until escape at `r_end` or capture (events of
/// [`kerr_events`]), or until it meets the disk `[r_in, r_out]` when given.
pub fn trace_kerr<F: Real>(
    k: &Kerr<F>,
    y0: [F; 8],
    opt: &Options<F>,
    r_end: F,
    disk: Option<(F, F)>,
) -> KerrRay<F> {
    trace_kerr_with(k, k, y0, opt, r_end, disk)
}

/// [`trace_kerr`] with the right-hand side of `sys` (`k` itself, or the
/// per-stage referee kernel of [`super::referee_kernel`]).
pub fn trace_kerr_with<F: Real, H: Hamiltonian<F, 8>>(
    sys: &H,
    k: &Kerr<F>,
    y0: [F; 8],
    opt: &Options<F>,
    r_end: F,
    disk: Option<(F, F)>,
) -> KerrRay<F> {
    let mut ev = kerr_events(k, r_end);
    if disk.is_some() {
        for rising in [false, true] {
            ev.push(Event {
                kind: EventKind::Coord {
                    index: 3,
                    value: F::zero(),
                },
                rising,
            });
        }
    }
    let c0 = k.constants(&y0);
    let mut out = KerrRay {
        y: y0,
        end: End::MaxSteps,
        steps: 0,
        h_drift: F::zero(),
        err_est: F::zero(),
        drift: [F::zero(); 3],
        sweep: F::zero(),
        disk_r: None,
    };
    let (mut px, mut py) = (y0[1], y0[2]);
    let mut y = y0;
    for _ in 0..=MAX_CROSSINGS {
        let left = Options {
            max_steps: opt.max_steps.saturating_sub(out.steps),
            ..*opt
        };
        let drift = &mut out.drift;
        let sweep = &mut out.sweep;
        let t = trace(sys, y, &left, &ev, |_, s| {
            let c = k.constants(s);
            for i in 0..3 {
                let d = (c[i] - c0[i]).abs() / c0[i].abs().max(F::one());
                drift[i] = drift[i].max(d);
            }
            let (x1, y1) = (s[1], s[2]);
            *sweep += (px * y1 - py * x1).atan2(px * x1 + py * y1);
            px = x1;
            py = y1;
        });
        out.steps += t.steps;
        out.err_est += t.err_est;
        out.h_drift = out.h_drift.max(t.h_drift);
        out.y = t.y;
        out.end = t.end;
        match (t.end, disk) {
            (End::Event(2 | 3), Some((r_in, r_out))) => {
                let r = k.radius(&t.y);
                if r >= r_in && r <= r_out {
                    out.disk_r = Some(r);
                    return out;
                }
                // Continue from the plane itself, so the next crossing is
                // a fresh sign change.
                y = t.y;
                y[3] = F::zero();
            }
            _ => return out,
        }
    }
    out
}

/// SCENES.md deflection list in Kerr: equatorial photons (`E = 1`,
/// `L_z = b`) from `r_start` inward until back at `r_end` or captured.
#[derive(Clone, Debug, PartialEq)]
pub struct KerrDeflection {
    pub kerr: Kerr<f64>,
    pub impact: Vec<f64>,
    pub r_start: f64,
    pub r_end: f64,
}

/// Per-ray results of a Kerr deflection list, in input order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct KerrDeflectionOut<F> {
    /// Boyer–Lindquist `delta_phi - pi` (the `x, y` azimuth swept between
    /// two crossings of the same `r` equals it); 0 for captured rays.
    pub deflection: Vec<F>,
    pub captured: Vec<u8>,
    pub steps: Vec<i32>,
    pub h_drift: Vec<F>,
    pub err_est: Vec<F>,
    /// `[E, L_z, Q]` relative drift per ray.
    pub drift: Vec<[F; 3]>,
    pub reason: Vec<i32>,
}

/// Traces a Kerr deflection list.
pub fn kerr_deflection<F: Real>(
    task: &KerrDeflection,
    opt: &Options<F>,
) -> crate::error::Result<KerrDeflectionOut<F>> {
    kerr_deflection_by(task, opt, |k| k)
}

/// [`kerr_deflection`] with the right-hand side `sys(k)` (`k` itself, or
/// the per-stage referee kernel of [`super::referee_kernel`]).
pub fn kerr_deflection_by<F: Real, H: Hamiltonian<F, 8>>(
    task: &KerrDeflection,
    opt: &Options<F>,
    sys: fn(Kerr<F>) -> H,
) -> crate::error::Result<KerrDeflectionOut<F>> {
    use crate::error::Error;
    let k = task.kerr;
    if !(k.mass > 0.0 && k.a.abs() <= k.mass) {
        return Err(Error::invalid(
            "task.spacetime",
            "kerr needs M > 0 and |a| <= M",
        ));
    }
    let rh = k.horizon();
    if !(task.r_start > rh && task.r_end >= task.r_start && task.r_end.is_finite()) {
        return Err(Error::invalid(
            "r_start/r_end",
            format!("need r_+ = {rh} < r_start <= r_end"),
        ));
    }
    let kf = Kerr {
        mass: F::of(k.mass),
        a: F::of(k.a),
    };
    super::integrate::check::<F, 8, Kerr<F>>(opt, &kerr_events(&kf, F::of(task.r_end)))?;
    let starts: Vec<[F; 8]> = task
        .impact
        .iter()
        .map(|&b| {
            let pr = super::kerr::bl_pr(k.mass, k.a, task.r_start, 1.0, b, 0.0, true)
                .filter(|_| b.is_finite())
                .ok_or_else(|| {
                    Error::invalid(
                        "impact_parameters",
                        format!("b = {b} cannot start at r = {}", task.r_start),
                    )
                })?;
            let p = [-1.0, pr, 0.0, b];
            let y = super::kerr::bl_to_ks(
                k.mass,
                k.a,
                [task.r_start, std::f64::consts::FRAC_PI_2, 0.0],
                p,
            );
            Ok(y.map(F::of))
        })
        .collect::<crate::error::Result<_>>()?;
    let h = sys(kf);
    let rays = crate::parallel::par_collect("transport.kerr_deflection", starts.len(), |i| {
        trace_kerr_with(&h, &kf, starts[i], opt, F::of(task.r_end), None)
    });
    let mut out = KerrDeflectionOut::default();
    for r in &rays {
        let captured = r.end == End::Event(1);
        out.deflection.push(if captured {
            F::zero()
        } else {
            r.sweep - F::PI()
        });
        out.captured.push(captured as u8);
        out.steps.push(i32::try_from(r.steps).unwrap_or(i32::MAX));
        out.h_drift.push(r.h_drift);
        out.err_est.push(r.err_est);
        out.drift.push(r.drift);
        out.reason.push(r.end.code());
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::integrate::{Controller, Tier};
    use crate::transport::kerr::{bl_pr, bl_to_ks};

    fn dp45() -> Options<f64> {
        Options {
            tier: Tier::Dopri5(Controller {
                rtol: 1e-12,
                eta: 0.5,
                atol: 1e-12,
                h0: 1.0,
                h_min: 1e-12,
                h_max: 1e30,
            }),
            project: false,
            max_steps: 1_000_000,
        }
    }

    fn far(k: &Kerr<f64>, b: f64) -> [f64; 8] {
        let pr = bl_pr(k.mass, k.a, 1000.0, 1.0, b, 0.0, true).unwrap();
        bl_to_ks(
            k.mass,
            k.a,
            [1000.0, std::f64::consts::FRAC_PI_2, 0.0],
            [-1.0, pr, 0.0, b],
        )
    }

    #[test]
    fn rays_inside_the_critical_impact_parameter_cross_the_located_horizon() {
        let k = Kerr { mass: 1.0, a: 0.9 };
        // Equatorial critical b = xi of the circular photon orbits.
        let (rp, rr) = crate::transport::referee_kerr::photon_orbits(1.0, 0.9);
        let bp = crate::transport::referee_kerr::spherical_orbit(1.0, 0.9, rp).0;
        let br = crate::transport::referee_kerr::spherical_orbit(1.0, 0.9, rr).0;
        for (b, captured) in [
            (bp - 0.01, true),
            (bp + 0.01, false),
            (br + 0.01, true),
            (br - 0.01, false),
        ] {
            let t = trace_kerr(&k, far(&k, b), &dp45(), 1000.0, None);
            assert_eq!(t.end, End::Event(captured as usize), "b = {b}");
            if captured {
                assert!((k.radius(&t.y) - k.horizon()).abs() < 1e-12);
            }
            assert!(t.drift.iter().all(|d| *d < 1e-8), "b = {b}: {:?}", t.drift);
        }
    }

    #[test]
    fn disk_rays_stop_on_the_annulus_only() {
        let k = Kerr { mass: 1.0, a: 0.0 };
        // A ray through the pole region crossing z = 0 at r ~ b.
        let th = 1.2f64;
        let q = 36.0f64;
        let pth = q.sqrt();
        let pr = bl_pr(1.0, 0.0, 100.0, 1.0, 0.0, q, true).unwrap();
        let y0 = bl_to_ks(1.0, 0.0, [100.0, th, 0.0], [-1.0, pr, pth, 0.0]);
        let hit = trace_kerr(&k, y0, &dp45(), 1000.0, Some((3.0, 20.0)));
        let r = hit.disk_r.expect("meets the disk");
        assert!(r > 6.0 && r < 20.0 && hit.y[3].abs() < 1e-9, "{r}");
        let miss = trace_kerr(&k, y0, &dp45(), 1000.0, Some((30.0, 40.0)));
        assert!(miss.disk_r.is_none());
        assert_eq!(miss.end, End::Event(0));
    }
}
