//! What a transport scene asks for, as typed tasks over many rays, each ray
//! traced independently (`parallel::par_collect`, so results never depend
//! on the thread count).
//!
//! - [`deflection`]: photons from radius `r_start` with impact parameters
//!   `b` (E = 1, L = b, equatorial), until back at `r_end`, captured, or
//!   (Ellis) out at `-r_end` on the other side.
//! - [`observer_scan`], [`shadow_angle`]: photons leaving a static observer
//!   at angles from the inward radial direction: captured or escaping.
//! - [`grin_rays`]: GRIN rays from listed origins and directions until a
//!   stop condition ([`GrinStop`]).

use super::grin::Medium;
use super::integrate::{check, trace, End, Event, EventKind, Options, Trace};
use super::lane_trace::{trace_rays, Kernel};
use super::metric::Spacetime;
use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::real::Real;

/// A scene's task (closed set).
#[derive(Clone, Debug, PartialEq)]
pub enum Task<F> {
    Deflection(Deflection<F>),
    Observer(ObserverScan<F>),
    Grin(GrinRays<F>),
    /// Kerr deflection lists and images ([`Curved`]).
    Curved(Curved),
}

/// Tasks of the curved-spacetime renderers with f64 parameters (closed set).
#[derive(Clone, Debug, PartialEq)]
pub enum Curved {
    KerrDeflection(super::kerr_trace::KerrDeflection),
    Image(super::image::ImageTask),
}

/// Most points kept per dumped polyline.
pub const MAX_POLYLINE: usize = 1 << 20;

/// A dumped ray: its index and `(x, y, z, lambda)` at every accepted step
/// (Cartesian; spacetimes map `(r, theta, phi)` with `r` the radial
/// coordinate, signed `l` for Ellis).
pub type Polyline<F> = (usize, Vec<[F; 4]>);

/// A traced ray and its recorded points (empty unless dumped).
pub type Traced<F, const N: usize> = (Trace<F, N>, Vec<[F; 4]>);

/// A deflection list's stop events and start states.
pub type Starts8<F> = (Vec<Event<F>>, Vec<[F; 8]>);

fn cart6<F: Real>(y: &[F; 6]) -> [F; 3] {
    [y[0], y[1], y[2]]
}

fn cart8<F: Real>(y: &[F; 8]) -> [F; 3] {
    let (st, ct) = y[2].sin_cos();
    let (sp, cp) = y[3].sin_cos();
    [y[1] * st * cp, y[1] * st * sp, y[1] * ct]
}

/// Traces one ray, recording its polyline when `record` (the only
/// allocation, and only for dumped rays).
fn traced<F: Real, const N: usize, H: super::hamiltonian::Hamiltonian<F, N>>(
    sys: &H,
    y0: [F; N],
    opt: &Options<F>,
    ev: &[Event<F>],
    record: bool,
    cart: fn(&[F; N]) -> [F; 3],
) -> Traced<F, N> {
    if !record {
        return (trace(sys, y0, opt, ev, |_, _| {}), Vec::new());
    }
    let mut pts = Vec::new();
    let t = trace(sys, y0, opt, ev, |l, y| {
        if pts.len() < MAX_POLYLINE {
            let c = cart(y);
            pts.push([c[0], c[1], c[2], l]);
        }
    });
    (t, pts)
}

fn check_dump(dump: &[usize], n: usize, budget: &MemBudget) -> Result<()> {
    if let Some(i) = dump.iter().find(|&&i| i >= n) {
        return Err(Error::invalid(
            "dump_rays",
            format!("ray {i} does not exist ({n} rays)"),
        ));
    }
    budget.check(
        "polylines",
        bytes_for(dump.len() as u64, MAX_POLYLINE as u64 * 32),
    )
}

/// `reason` code of a GRIN ray that never meets its lens.
pub const MISSED_LENS: i32 = -5;

/// A list of photons from far away (SCENES.md deflection scenes).
#[derive(Clone, Debug, PartialEq)]
pub struct Deflection<F> {
    pub spacetime: Spacetime<F>,
    /// Impact parameters `b = L / E`, each > 0.
    pub impact: Vec<f64>,
    /// Start radius (`l` for Ellis), moving inward.
    pub r_start: f64,
    /// End radius (|l| for Ellis).
    pub r_end: f64,
    /// Capture at `r = r_h (1 + horizon_eps)` (spacetimes with a horizon).
    pub horizon_eps: f64,
}

/// Per-ray results of a deflection list, in input order.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct DeflectionOut<F> {
    /// `delta_phi - pi`; 0 for captured rays.
    pub deflection: Vec<F>,
    pub captured: Vec<u8>,
    /// Ellis: the side the ray ends on (+1 start side, -1 the other);
    /// +1 elsewhere.
    pub side: Vec<i32>,
    pub steps: Vec<i32>,
    pub h_drift: Vec<F>,
    pub err_est: Vec<F>,
    /// [`End::code`].
    pub reason: Vec<i32>,
    pub polylines: Vec<Polyline<F>>,
}

fn budget_rays(budget: &MemBudget, what: &str, n: usize, per_ray: u64) -> Result<()> {
    budget.check(what, bytes_for(n as u64, per_ray))
}

fn steps_i32(s: u64) -> i32 {
    i32::try_from(s).unwrap_or(i32::MAX)
}

/// The equatorial starting state for a photon of impact parameter `b` at
/// radius `r0`, moving inward.
pub fn far_photon<F: Real>(st: &Spacetime<F>, r0: f64, b: f64) -> Result<[F; 8]> {
    let p = st
        .to_f64()
        .equatorial_momentum(r0, 1.0, b, true)
        .ok_or_else(|| {
            Error::invalid(
                "impact_parameters",
                format!("b = {b} cannot start at r = {r0} (no real p_r there)"),
            )
        })?;
    let y = [
        0.0,
        r0,
        std::f64::consts::FRAC_PI_2,
        0.0,
        p[0],
        p[1],
        p[2],
        p[3],
    ];
    Ok(y.map(F::of))
}

impl<F: Real> Spacetime<F> {
    /// The same spacetime with f64 parameters (initial data are computed
    /// in f64, then rounded).
    pub fn to_f64(&self) -> Spacetime<f64> {
        match *self {
            Spacetime::Minkowski => Spacetime::Minkowski,
            Spacetime::Schwarzschild { mass } => Spacetime::Schwarzschild { mass: mass.f64() },
            Spacetime::Ellis { b0 } => Spacetime::Ellis { b0: b0.f64() },
        }
    }
}

/// The stop events of a ray in `st` between radii: index 0 = escape
/// (back out through `r_end`), 1 = capture (horizon) or crossing (Ellis,
/// out through `-r_end`).
fn spacetime_events<F: Real>(st: &Spacetime<F>, r_end: f64, horizon_eps: f64) -> Vec<Event<F>> {
    let mut ev = vec![Event {
        kind: EventKind::Coord {
            index: 1,
            value: F::of(r_end),
        },
        rising: true,
    }];
    match st {
        Spacetime::Schwarzschild { .. } => {
            let rh = st.horizon().map_or(0.0, |h| h.f64());
            ev.push(Event {
                kind: EventKind::Coord {
                    index: 1,
                    value: F::of(rh * (1.0 + horizon_eps)),
                },
                rising: false,
            });
        }
        Spacetime::Ellis { .. } => ev.push(Event {
            kind: EventKind::Coord {
                index: 1,
                value: F::of(-r_end),
            },
            rising: false,
        }),
        Spacetime::Minkowski => {}
    }
    ev
}

fn validate_radii<F: Real>(
    st: &Spacetime<F>,
    r_start: f64,
    r_end: f64,
    horizon_eps: f64,
) -> Result<()> {
    let rh = st.horizon().map_or(0.0, |h| h.f64());
    if !(r_start.is_finite() && r_end.is_finite() && r_start > rh && r_end > rh) {
        return Err(Error::invalid(
            "r_start/r_end",
            format!("must be finite and outside the horizon r = {rh}"),
        ));
    }
    if !(horizon_eps > 0.0 && horizon_eps < 1.0) {
        return Err(Error::invalid(
            "horizon_eps",
            format!("{horizon_eps}: must lie in (0, 1)"),
        ));
    }
    Ok(())
}

/// The validated start states and stop events of a deflection list,
/// shared by the CPU fan-out ([`deflection`]) and the GPU kernel
/// (`super::gpu`).
pub fn deflection_setup<F: Real>(
    task: &Deflection<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<Starts8<F>> {
    check_dump(dump, task.impact.len(), budget)?;
    validate_radii(&task.spacetime, task.r_start, task.r_end, task.horizon_eps)?;
    if task.r_end < task.r_start {
        return Err(Error::invalid(
            "r_end",
            "must be >= r_start (the ray ends on its way out)",
        ));
    }
    budget_rays(budget, "deflection rays", task.impact.len(), 64)?;
    let ev = spacetime_events(&task.spacetime, task.r_end, task.horizon_eps);
    check::<F, 8, Spacetime<F>>(opt, &ev)?;
    let starts: Vec<[F; 8]> = task
        .impact
        .iter()
        .map(|&b| {
            if !(b > 0.0 && b.is_finite()) {
                return Err(Error::invalid(
                    "impact_parameters",
                    format!("{b}: must be > 0 and finite"),
                ));
            }
            far_photon(&task.spacetime, task.r_start, b)
        })
        .collect::<Result<_>>()?;
    Ok((ev, starts))
}

/// Traces every photon of `task` with the fastest kernel of this CPU
/// ([`Kernel::best`]).
pub fn deflection<F: Real>(
    task: &Deflection<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<DeflectionOut<F>> {
    deflection_with(task, opt, budget, dump, Kernel::best())
}

/// [`deflection`] with a chosen kernel: the lane path where it applies
/// ([`super::lane_trace`]), the scalar loop elsewhere and for the dumped
/// rays (their polylines are the scalar loop's steps).
pub fn deflection_with<F: Real>(
    task: &Deflection<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
    kernel: Kernel,
) -> Result<DeflectionOut<F>> {
    let (ev, starts) = deflection_setup(task, opt, budget, dump)?;
    let scalar = |i: usize| {
        traced(
            &task.spacetime,
            starts[i],
            opt,
            &ev,
            dump.contains(&i),
            cart8,
        )
    };
    let traces = match trace_rays(&task.spacetime, &starts, opt, &ev, kernel) {
        Some(ts) => ts
            .into_iter()
            .enumerate()
            .map(|(i, t)| {
                if dump.contains(&i) {
                    scalar(i)
                } else {
                    (t, Vec::new())
                }
            })
            .collect(),
        None => par_collect("transport.deflection", starts.len(), scalar),
    };
    Ok(deflection_out(task, traces, dump))
}

/// A deflection list's outputs from its traces (input order) and the
/// polylines of the dumped rays.
pub fn deflection_out<F: Real>(
    task: &Deflection<F>,
    traces: Vec<Traced<F, 8>>,
    dump: &[usize],
) -> DeflectionOut<F> {
    let mut out = DeflectionOut::default();
    let pi = F::PI();
    let is_schw = matches!(task.spacetime, Spacetime::Schwarzschild { .. });
    for (i, (t, poly)) in traces.into_iter().enumerate() {
        if dump.contains(&i) {
            out.polylines.push((i, poly));
        }
        let t = &t;
        let captured = is_schw && t.end == End::Event(1);
        out.deflection
            .push(if captured { F::zero() } else { t.y[3] - pi });
        out.captured.push(captured as u8);
        out.side.push(if t.y[1] < F::zero() { -1 } else { 1 });
        push_common(
            &mut out.steps,
            &mut out.h_drift,
            &mut out.err_est,
            &mut out.reason,
            t,
        );
    }
    out
}

fn push_common<F: Real, const N: usize>(
    steps: &mut Vec<i32>,
    h: &mut Vec<F>,
    e: &mut Vec<F>,
    reason: &mut Vec<i32>,
    t: &Trace<F, N>,
) {
    steps.push(steps_i32(t.steps));
    h.push(t.h_drift);
    e.push(t.err_est);
    reason.push(t.end.code());
}

/// Photons leaving a static observer (Synge's shadow).
#[derive(Clone, Debug, PartialEq)]
pub struct ObserverScan<F> {
    pub spacetime: Spacetime<F>,
    pub r_obs: f64,
    /// Angles from the inward radial direction, degrees in [0, 180].
    pub angles_deg: Vec<f64>,
    pub r_end: f64,
    pub horizon_eps: f64,
}

/// Per-angle results of an observer scan.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ObserverOut<F> {
    pub captured: Vec<u8>,
    pub steps: Vec<i32>,
    pub h_drift: Vec<F>,
    pub err_est: Vec<F>,
    pub reason: Vec<i32>,
    pub polylines: Vec<Polyline<F>>,
}

/// The start state of the photon leaving the observer at `psi_deg` from
/// the inward radial direction (computed in f64, then rounded).
pub fn observer_start<F: Real>(scan: &ObserverScan<F>, psi_deg: f64) -> [F; 8] {
    let st64 = scan.spacetime.to_f64();
    let p = st64.static_observer_momentum(scan.r_obs, psi_deg.to_radians());
    [
        0.0,
        scan.r_obs,
        std::f64::consts::FRAC_PI_2,
        0.0,
        p[0],
        p[1],
        p[2],
        p[3],
    ]
    .map(F::of)
}

fn observer_trace<F: Real>(
    scan: &ObserverScan<F>,
    ev: &[Event<F>],
    opt: &Options<F>,
    psi_deg: f64,
    record: bool,
) -> Traced<F, 8> {
    let y = observer_start(scan, psi_deg);
    traced(&scan.spacetime, y, opt, ev, record, cart8)
}

/// The validated stop events of an observer scan (shared with the GPU).
pub fn observer_setup<F: Real>(scan: &ObserverScan<F>, opt: &Options<F>) -> Result<Vec<Event<F>>> {
    if scan.spacetime.horizon().is_none() {
        return Err(Error::NotSupported(
            "observer scans need a spacetime with a horizon (schwarzschild)".into(),
        ));
    }
    validate_radii(&scan.spacetime, scan.r_obs, scan.r_end, scan.horizon_eps)?;
    if scan.r_end <= scan.r_obs {
        return Err(Error::invalid("r_end", "must exceed r_obs"));
    }
    if let Some(a) = scan
        .angles_deg
        .iter()
        .find(|a| !(**a >= 0.0 && **a <= 180.0))
    {
        return Err(Error::invalid(
            "angles_deg",
            format!("{a}: must lie in [0, 180]"),
        ));
    }
    let ev = spacetime_events(&scan.spacetime, scan.r_end, scan.horizon_eps);
    check::<F, 8, Spacetime<F>>(opt, &ev)?;
    Ok(ev)
}

/// Traces one photon per angle of `scan`.
pub fn observer_scan<F: Real>(
    scan: &ObserverScan<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<ObserverOut<F>> {
    let ev = observer_setup(scan, opt)?;
    check_dump(dump, scan.angles_deg.len(), budget)?;
    budget_rays(budget, "observer rays", scan.angles_deg.len(), 64)?;
    let traces = par_collect("transport.observer", scan.angles_deg.len(), |i| {
        observer_trace(scan, &ev, opt, scan.angles_deg[i], dump.contains(&i))
    });
    Ok(observer_out(traces, dump))
}

/// An observer scan's outputs from its traces (input order).
pub fn observer_out<F: Real>(traces: Vec<Traced<F, 8>>, dump: &[usize]) -> ObserverOut<F> {
    let mut out = ObserverOut::default();
    for (i, (t, poly)) in traces.into_iter().enumerate() {
        if dump.contains(&i) {
            out.polylines.push((i, poly));
        }
        let t = &t;
        out.captured.push((t.end == End::Event(1)) as u8);
        push_common(
            &mut out.steps,
            &mut out.h_drift,
            &mut out.err_est,
            &mut out.reason,
            t,
        );
    }
    out
}

/// The angle (degrees from the inward radial direction) separating
/// captured from escaping photons, by `iters` bisections of [0, 180]
/// (angles below it are captured). Rays that end undecided (max steps)
/// count as captured: they sit on the photon sphere.
pub fn shadow_angle<F: Real>(scan: &ObserverScan<F>, opt: &Options<F>, iters: u32) -> Result<f64> {
    let ev = observer_setup(scan, opt)?;
    let (mut lo, mut hi) = (0.0f64, 180.0f64);
    for _ in 0..iters {
        let mid = 0.5 * (lo + hi);
        let (t, _) = observer_trace(scan, &ev, opt, mid, false);
        if t.end == End::Event(0) {
            hi = mid;
        } else {
            lo = mid;
        }
    }
    Ok(0.5 * (lo + hi))
}

/// When a GRIN ray stops.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GrinStop<F> {
    /// Leaving the medium's lens sphere (located on the sphere).
    LensExit,
    /// Back on the x axis: `y` rises through 0 (one full period of a ray
    /// launched from the axis upward).
    AxisReturn,
    /// Closest approach to `point` (a local minimum of the distance).
    Approach { point: [F; 3] },
    /// A fixed number of steps (drift studies).
    Steps { n: u64 },
}

/// GRIN rays from listed origins and directions.
#[derive(Clone, Debug, PartialEq)]
pub struct GrinRays<F> {
    pub medium: Medium<F>,
    /// `[ox, oy, oz, dx, dy, dz]`, directions of any non-zero length.
    pub rays: Vec<[f64; 6]>,
    pub stop: GrinStop<F>,
}

/// Per-ray GRIN results.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct GrinOut<F> {
    /// Where the ray stopped.
    pub end_point: Vec<[F; 3]>,
    /// Unit direction there.
    pub end_dir: Vec<[F; 3]>,
    pub steps: Vec<i32>,
    pub h_drift: Vec<F>,
    pub err_est: Vec<F>,
    /// [`End::code`], or [`MISSED_LENS`].
    pub reason: Vec<i32>,
    pub polylines: Vec<Polyline<F>>,
}

/// Advances `o` along unit `d` to the sphere of radius `r` if it starts
/// outside (n = 1 there, so the path is straight); `None` if it misses.
fn to_sphere(o: [f64; 3], d: [f64; 3], r: f64) -> Option<[f64; 3]> {
    let od = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
    let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
    if c <= 0.0 {
        return Some(o);
    }
    let disc = od * od - c;
    if disc < 0.0 || od >= 0.0 {
        return None;
    }
    // Entry root written without cancellation: t = c / (-od + sqrt(disc)).
    let t = c / (-od + disc.sqrt());
    Some([o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]])
}

/// What a GRIN task traces: the medium the rays integrate (a lens-exit
/// run continues the Luneburg formula past its sphere), the options (a
/// `steps` stop sets `max_steps`), the stop events, and per ray its start
/// state (`None`: it misses the lens). Shared with the GPU (`super::gpu`).
#[derive(Clone, Debug)]
pub struct GrinSetup<F> {
    pub medium: Medium<F>,
    pub opt: Options<F>,
    pub events: Vec<Event<F>>,
    pub starts: Vec<Option<[F; 6]>>,
}

/// Validates `task` and builds its [`GrinSetup`].
pub fn grin_setup<F: Real>(
    task: &GrinRays<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<GrinSetup<F>> {
    check_dump(dump, task.rays.len(), budget)?;
    budget_rays(budget, "grin rays", task.rays.len(), 96)?;
    let lens = task.medium.boundary_radius();
    let ev: Vec<Event<F>> = match task.stop {
        GrinStop::LensExit => {
            let r = lens.ok_or_else(|| {
                Error::invalid(
                    "stop",
                    "lens_exit needs a medium with a lens sphere (luneburg)",
                )
            })?;
            vec![Event {
                kind: EventKind::Sphere { radius: r },
                rising: true,
            }]
        }
        GrinStop::AxisReturn => vec![Event {
            kind: EventKind::Coord {
                index: 1,
                value: F::zero(),
            },
            rising: true,
        }],
        GrinStop::Approach { point } => vec![Event {
            kind: EventKind::Approach { point },
            rising: true,
        }],
        GrinStop::Steps { .. } => vec![],
    };
    let opt = match task.stop {
        GrinStop::Steps { n } => Options {
            max_steps: n,
            ..*opt
        },
        _ => *opt,
    };
    check::<F, 6, Medium<F>>(&opt, &ev)?;
    // Inside a lens-exit run the field is continued smoothly past the
    // sphere, so stages of the step that straddles it keep the tier's order.
    let medium = match (task.stop, &task.medium) {
        (GrinStop::LensExit, Medium::Luneburg { radius }) => {
            Medium::LuneburgCore { radius: *radius }
        }
        (_, m) => m.clone(),
    };
    let mut starts = Vec::with_capacity(task.rays.len());
    for (i, r) in task.rays.iter().enumerate() {
        let len = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
        if !(r.iter().all(|v| v.is_finite()) && len > 0.0) {
            return Err(Error::invalid(
                format!("rays[{i}]"),
                "needs finite numbers and a non-zero direction",
            ));
        }
        let d = [r[3] / len, r[4] / len, r[5] / len];
        let o = [r[0], r[1], r[2]];
        let o = match (task.stop, lens) {
            (GrinStop::LensExit, Some(rad)) => to_sphere(o, d, rad.f64()),
            _ => Some(o),
        };
        starts.push(o.map(|o| {
            let n2 = task.medium.n2_grad(&o.map(F::of)).0.max(F::zero());
            let n = n2.sqrt();
            [
                F::of(o[0]),
                F::of(o[1]),
                F::of(o[2]),
                n * F::of(d[0]),
                n * F::of(d[1]),
                n * F::of(d[2]),
            ]
        }));
    }
    Ok(GrinSetup {
        medium,
        opt,
        events: ev,
        starts,
    })
}

/// Traces every GRIN ray of `task`.
pub fn grin_rays<F: Real>(
    task: &GrinRays<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<GrinOut<F>> {
    let g = grin_setup(task, opt, budget, dump)?;
    let traces = par_collect("transport.grin", g.starts.len(), |i| {
        g.starts[i].map(|y0| traced(&g.medium, y0, &g.opt, &g.events, dump.contains(&i), cart6))
    });
    Ok(grin_out(task, traces, dump))
}

/// A GRIN task's outputs from its traces (input order; `None`: the ray
/// missed its lens).
pub fn grin_out<F: Real>(
    task: &GrinRays<F>,
    traces: Vec<Option<Traced<F, 6>>>,
    dump: &[usize],
) -> GrinOut<F> {
    let mut out = GrinOut::default();
    for (i, t) in traces.into_iter().enumerate() {
        let t = t.map(|(t, poly)| {
            if dump.contains(&i) {
                out.polylines.push((i, poly));
            }
            t
        });
        match &t {
            Some(t) => {
                out.end_point.push([t.y[0], t.y[1], t.y[2]]);
                let p = (t.y[3] * t.y[3] + t.y[4] * t.y[4] + t.y[5] * t.y[5]).sqrt();
                let dir = if p > F::zero() {
                    [t.y[3] / p, t.y[4] / p, t.y[5] / p]
                } else {
                    [F::zero(); 3]
                };
                out.end_dir.push(dir);
                push_common(
                    &mut out.steps,
                    &mut out.h_drift,
                    &mut out.err_est,
                    &mut out.reason,
                    t,
                );
            }
            None => {
                let r = task.rays[i];
                out.end_point.push([r[0], r[1], r[2]].map(F::of));
                out.end_dir.push([F::zero(); 3]);
                out.steps.push(0);
                out.h_drift.push(F::zero());
                out.err_est.push(F::zero());
                out.reason.push(MISSED_LENS);
            }
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::integrate::{Controller, StepLaw, Tier};

    fn rk4(eta: f64) -> Options<f64> {
        Options {
            tier: Tier::Rk4(StepLaw::Scaled {
                eta,
                h_min: 1e-6,
                h_max: 100.0,
            }),
            project: false,
            max_steps: 1_000_000,
        }
    }

    fn budget() -> MemBudget {
        MemBudget::fixed(1 << 30)
    }

    #[test]
    fn minkowski_rays_sweep_the_straight_line_angle() {
        let task = Deflection {
            spacetime: Spacetime::Minkowski,
            impact: vec![1.0, 10.0, 300.0],
            r_start: 1000.0,
            r_end: 1000.0,
            horizon_eps: 0.01,
        };
        let out = deflection(&task, &rk4(0.01), &budget(), &[]).unwrap();
        for (d, b) in out.deflection.iter().zip(&task.impact) {
            let want = -2.0 * (b / 1000.0f64).asin();
            assert!((d - want).abs() < 1e-8, "b={b}: {d} vs {want}");
        }
        assert!(out.reason.iter().all(|&r| r == 0));
    }

    #[test]
    fn schwarzschild_splits_capture_at_the_critical_impact_parameter() {
        let bc = 27f64.sqrt();
        let task = Deflection {
            spacetime: Spacetime::Schwarzschild { mass: 1.0 },
            impact: vec![bc - 1e-3, bc + 1e-3, 2.0, 8.0],
            r_start: 1000.0,
            r_end: 1000.0,
            horizon_eps: 0.01,
        };
        let out = deflection(&task, &rk4(0.005), &budget(), &[]).unwrap();
        assert_eq!(out.captured, vec![1, 0, 1, 0]);
        assert!(
            out.deflection[1] > 4.0,
            "near-critical rays wind: {}",
            out.deflection[1]
        );
    }

    #[test]
    fn ellis_rays_below_the_throat_cross_to_the_other_side() {
        let task = Deflection {
            spacetime: Spacetime::Ellis { b0: 1.0 },
            impact: vec![0.5, 2.0],
            r_start: 100.0,
            r_end: 100.0,
            horizon_eps: 0.01,
        };
        let out = deflection(&task, &rk4(0.01), &budget(), &[]).unwrap();
        assert_eq!(out.side, vec![-1, 1]);
        assert_eq!(out.reason, vec![1, 0]);
    }

    #[test]
    fn synge_angle_is_45_degrees_at_r_6() {
        let scan = ObserverScan {
            spacetime: Spacetime::Schwarzschild { mass: 1.0 },
            r_obs: 6.0,
            angles_deg: vec![40.0, 50.0],
            r_end: 1000.0,
            horizon_eps: 0.01,
        };
        let opt = Options {
            tier: Tier::Dopri5(Controller {
                rtol: 1e-12,
                eta: 0.5,
                atol: 1e-12,
                h0: 0.01,
                h_min: 1e-12,
                h_max: 100.0,
            }),
            project: false,
            max_steps: 100_000,
        };
        assert_eq!(
            observer_scan(&scan, &opt, &budget(), &[]).unwrap().captured,
            vec![1, 0]
        );
        let a = shadow_angle(&scan, &opt, 30).unwrap();
        assert!((a - 45.0).abs() < 1e-6, "{a}");
    }

    #[test]
    fn luneburg_rays_focus_on_the_far_pole() {
        let task = GrinRays {
            medium: Medium::Luneburg { radius: 1.0f64 },
            rays: (1..10)
                .map(|k| [-2.0, k as f64 / 10.0, 0.0, 1.0, 0.0, 0.0])
                .chain([[-2.0, 1.5, 0.0, 1.0, 0.0, 0.0]])
                .collect(),
            stop: GrinStop::LensExit,
        };
        let out = grin_rays(
            &task,
            &Options {
                tier: Tier::Rk4(StepLaw::Fixed { h: 0.01 }),
                project: false,
                max_steps: 100_000,
            },
            &budget(),
            &[],
        )
        .unwrap();
        for p in &out.end_point[..9] {
            assert!(
                (p[0] - 1.0).abs() < 1e-9 && p[1].abs() < 1e-9 && p[2] == 0.0,
                "{p:?}"
            );
        }
        assert_eq!(out.reason[9], MISSED_LENS);
    }

    #[test]
    fn fish_eye_images_a_point_on_its_conjugate() {
        let task = GrinRays {
            medium: Medium::FishEye {
                n0: 2.0f64,
                radius: 1.0,
            },
            rays: (1..12)
                .map(|k| {
                    let a = (30.0 * k as f64).to_radians();
                    [0.5, 0.0, 0.0, a.cos(), a.sin(), 0.0]
                })
                .collect(),
            stop: GrinStop::Approach {
                point: [-2.0, 0.0, 0.0],
            },
        };
        let out = grin_rays(
            &task,
            &Options {
                tier: Tier::Rk4(StepLaw::Fixed { h: 0.005 }),
                project: false,
                max_steps: 1_000_000,
            },
            &budget(),
            &[],
        )
        .unwrap();
        for p in &out.end_point {
            assert!((p[0] + 2.0).abs() < 1e-6 && p[1].abs() < 1e-6, "{p:?}");
        }
    }
}
