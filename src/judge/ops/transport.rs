//! Operations of the `transport` renderer (curved rays) and their
//! independent references.
//!
//! | op | what |
//! | --- | --- |
//! | `transport.render` | trace a transport scene: SCENES.md outputs per task (below) |
//! | `transport.deflection_finite` | deflection between the scene's start and end radii by quadrature (Schwarzschild), elliptic integrals (Ellis), arcsines (Minkowski) |
//! | `transport.deflection_darwin` | Darwin's exact infinite-distance Schwarzschild deflection (Carlson R_F) |
//! | `transport.deflection_weak_field` | the weak-field series in M/b to 4th order, and its 5th-order term as `truncation` |
//! | `transport.ellis_infinite` | Ellis infinite-distance deflection `2 K(b0/b) - pi` (AGM) |
//! | `transport.shadow_synge` | Synge's capture angle at the scene's observer, and the expected capture flags |
//! | `transport.shadow_angle` | the capture angle found by bisection with the integrator |
//! | `transport.grin_closed_form` | GRIN focus points and periods in closed form |
//! | `transport.convergence` | observed order `log2(|q1 - q2| / |q2 - q3|)` under step scaling |
//! | `transport.drift_growth` | `max |H|` after `steps[0]` and `steps[1]` steps of a GRIN scene, and their ratio |
//!
//! `transport.render` outputs: deflection tasks `deflection`, `captured`,
//! `escaped` (uint8 masks), `side` (int32, Ellis), `steps` (int32),
//! `h_drift`, `err_est`, `reason` (int32, `integrate::End::code`); observer tasks
//! `captured`, `steps`, `h_drift`, `err_est`, `reason`; GRIN tasks
//! `end_point` (n, 3), `end_dir`, `steps`, `h_drift`, `err_est`, `reason`,
//! and by stop: `exit_point` (lens exit), `period` (axis return: axial
//! distance travelled), `conjugate_point` (approach). Metrics `time_s`,
//! `s_per_1000_rays`, `ns_per_step`; counters `rays`, `steps`.
//!
//! The references share no code with the integrators: they read the typed
//! scene and evaluate closed forms in f64 here.

use std::f64::consts::PI;
use std::time::Instant;

use super::transport_gpu as backend;
use super::{OpCtx, OpEntry};
use crate::error::{Error, Result};
use crate::real::{Precision, Real};
use crate::scene::transport::{
    parse, MediumSpec, SpacetimeSpec, StopSpec, TaskSpec, TransportScene,
};
use crate::tensor::{Outputs, Tensor};
use crate::transport::integrate::Options;
use crate::transport::tasks::{grin_rays, shadow_angle, GrinRays, GrinStop, Polyline, Task};

pub const OPS: &[OpEntry] = &[
    OpEntry { name: "transport.render", doc: "trace a transport scene: deflection/captured/steps/h_drift, or GRIN exit points and periods", params: &[], run: render },
    OpEntry {
        name: "transport.deflection_finite",
        doc: "finite-distance deflection by substitution + Gauss-Legendre (Schwarzschild), elliptic F (Ellis)",
        params: &[],
        run: deflection_finite,
    },
    OpEntry { name: "transport.deflection_darwin", doc: "Darwin's exact infinite-distance Schwarzschild deflection", params: &[], run: deflection_darwin },
    OpEntry { name: "transport.deflection_weak_field", doc: "weak-field series 4M/b + 15 pi M^2/4b^2 + 128 M^3/3b^3 + 3465 pi M^4/64b^4", params: &[], run: weak_field },
    OpEntry { name: "transport.ellis_infinite", doc: "Ellis deflection at infinity 2 K(b0/b) - pi by the AGM", params: &[], run: ellis_infinite },
    OpEntry { name: "transport.shadow_synge", doc: "Synge's capture angle and expected capture flags for an observer scene", params: &[], run: shadow_synge },
    OpEntry { name: "transport.shadow_angle", doc: "capture angle by bisection with the integrator (params.iters, default 40)", params: &["iters"], run: shadow_angle_op },
    OpEntry { name: "transport.grin_closed_form", doc: "Luneburg focus R d, fibre period 2 pi cos(theta0)/alpha, sech 2 pi/alpha, fish-eye conjugate -R^2 o/|o|^2", params: &[], run: grin_closed_form },
    OpEntry {
        name: "transport.convergence",
        doc: "observed order under step scaling by params.factors (default [1, 0.5, 0.25])",
        params: &["factors"],
        run: convergence,
    },
    OpEntry { name: "transport.drift_growth", doc: "max |H| after params.steps = [n1, n2] steps of a GRIN scene, and the ratio", params: &["steps"], run: drift_growth },
];

fn scene(ctx: &OpCtx) -> Result<TransportScene> {
    parse(ctx.scene()?)
}

fn vec1<F: Real>(v: Vec<F>) -> Result<Tensor> {
    let n = v.len();
    Tensor::real(&[n], v)
}

fn i32s(v: Vec<i32>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

fn u8s(v: Vec<u8>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

fn f64s(v: Vec<f64>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

fn f64x3(v: Vec<[f64; 3]>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n, 3], v.into_iter().flatten().collect())
}

/// `polylines` (k, L, 4), each padded with its last point, and
/// `polyline_len` (k) for the dumped rays; nothing when none are dumped.
fn polylines<F: Real>(p: &[Polyline<F>], out: &mut Outputs) -> Result<()> {
    if p.is_empty() {
        return Ok(());
    }
    let l = p.iter().map(|(_, v)| v.len()).max().unwrap_or(0).max(1);
    let mut flat = Vec::with_capacity(p.len() * l * 4);
    for (_, v) in p {
        let last = v.last().copied().unwrap_or([F::zero(); 4]);
        flat.extend(
            v.iter()
                .chain(std::iter::repeat(&last))
                .take(l)
                .flatten()
                .copied(),
        );
    }
    out.tensor("polylines", Tensor::real(&[p.len(), l, 4], flat)?);
    out.tensor(
        "polyline_len",
        i32s(p.iter().map(|(_, v)| v.len() as i32).collect())?,
    );
    out.tensor(
        "polyline_ray",
        i32s(p.iter().map(|(i, _)| *i as i32).collect())?,
    );
    Ok(())
}

/// One traced task's outputs, and per ray the quantity convergence studies
/// use (deflection, capture flag, period, or the end point's coordinates).
fn run_task<F: Real>(
    task: &Task<F>,
    opt: &Options<F>,
    ctx: &OpCtx,
    dump: &[usize],
    out: &mut Outputs,
) -> Result<Vec<Vec<f64>>> {
    let t = Instant::now();
    let (rays, steps, q): (usize, Vec<i32>, Vec<Vec<f64>>) = match task {
        Task::Deflection(d) => {
            let r = backend::deflection(ctx, d, opt, dump)?;
            polylines(&r.polylines, out)?;
            let q = r.deflection.iter().map(|v| vec![v.f64()]).collect();
            out.tensor("deflection", vec1(r.deflection)?);
            out.tensor("escaped", u8s(r.captured.iter().map(|c| 1 - c).collect())?);
            out.tensor("captured", u8s(r.captured)?);
            out.tensor("side", i32s(r.side)?);
            out.tensor("h_drift", vec1(r.h_drift)?)
                .tensor("err_est", vec1(r.err_est)?);
            out.tensor("reason", i32s(r.reason)?);
            (d.impact.len(), r.steps, q)
        }
        Task::Observer(s) => {
            let r = backend::observer_scan(ctx, s, opt, dump)?;
            polylines(&r.polylines, out)?;
            let q = r.captured.iter().map(|&c| vec![c as f64]).collect();
            out.tensor("captured", u8s(r.captured)?);
            out.tensor("h_drift", vec1(r.h_drift)?)
                .tensor("err_est", vec1(r.err_est)?);
            out.tensor("reason", i32s(r.reason)?);
            (s.angles_deg.len(), r.steps, q)
        }
        Task::Grin(g) => {
            let r = backend::grin_rays(ctx, g, opt, dump)?;
            polylines(&r.polylines, out)?;
            let ends: Vec<Vec<f64>> = r
                .end_point
                .iter()
                .map(|p| p.iter().map(|v| v.f64()).collect())
                .collect();
            let q: Vec<Vec<f64>> = match g.stop {
                GrinStop::AxisReturn => {
                    let period: Vec<F> = r
                        .end_point
                        .iter()
                        .zip(&g.rays)
                        .map(|(p, o)| p[0] - F::of(o[0]))
                        .collect();
                    let q = period.iter().map(|v| vec![v.f64()]).collect();
                    out.tensor("period", vec1(period)?);
                    q
                }
                GrinStop::LensExit => {
                    out.tensor(
                        "exit_point",
                        Tensor::real3(&[r.end_point.len()], &r.end_point)?,
                    );
                    out.tensor("exit_dir", Tensor::real3(&[r.end_dir.len()], &r.end_dir)?);
                    ends
                }
                GrinStop::Approach { .. } => {
                    out.tensor(
                        "conjugate_point",
                        Tensor::real3(&[r.end_point.len()], &r.end_point)?,
                    );
                    ends
                }
                GrinStop::Steps { .. } => ends,
            };
            out.tensor(
                "end_point",
                Tensor::real3(&[r.end_point.len()], &r.end_point)?,
            );
            out.tensor("end_dir", Tensor::real3(&[r.end_dir.len()], &r.end_dir)?);
            out.tensor("h_drift", vec1(r.h_drift)?)
                .tensor("err_est", vec1(r.err_est)?);
            out.tensor("reason", i32s(r.reason)?);
            (g.rays.len(), r.steps, q)
        }
    };
    let secs = t.elapsed().as_secs_f64();
    let total: u64 = steps.iter().map(|&s| s.max(0) as u64).sum();
    out.metric("time_s", secs);
    out.metric("s_per_1000_rays", secs * 1000.0 / rays.max(1) as f64);
    out.metric("ns_per_step", secs * 1e9 / total.max(1) as f64);
    out.counter("rays", rays as u64).counter("steps", total);
    out.tensor("steps", i32s(steps)?);
    Ok(q)
}

fn render_in<F: Real>(ctx: &OpCtx, s: &TransportScene) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    let mut out = Outputs::default();
    if let Some(b) = s.research_banner() {
        // warn, not info: the preset overrides the scene's integrator, and the
        // banner must show at the default log level.
        tracing::warn!("{}", b.line);
        out.counter("research_settings_hash", b.hash);
    }
    run_task(&task, &opt, ctx, &s.dump_rays, &mut out)?;
    Ok(out)
}

fn render(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    backend::prepare(ctx, &s)?;
    match ctx.precision {
        Precision::F32 => render_in::<f32>(ctx, &s),
        Precision::F64 => render_in::<f64>(ctx, &s),
    }
}

// ---------------------------------------------------------------------------
// Independent references (f64, closed forms and quadrature).

/// Gauss–Legendre nodes and weights on [-1, 1] (Newton on P_n).
fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (1..=n)
        .map(|i| {
            let mut x = (PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// `int_a^b f` by composite 20-point Gauss–Legendre on `panels` panels.
fn integrate(f: impl Fn(f64) -> f64, a: f64, b: f64, panels: usize) -> f64 {
    let gl = gauss_legendre(20);
    let w = (b - a) / panels as f64;
    (0..panels)
        .map(|p| {
            let (lo, hi) = (a + p as f64 * w, a + (p + 1) as f64 * w);
            let (c, r) = (0.5 * (lo + hi), 0.5 * (hi - lo));
            gl.iter().map(|(x, wt)| wt * f(c + r * x)).sum::<f64>() * r
        })
        .sum()
}

/// Real roots of `2 M u^3 - u^2 + 1/b^2` in increasing order, when three
/// (b above 3 sqrt(3) M), by the trigonometric formula and Newton polish.
fn orbit_roots(m: f64, b: f64) -> Option<[f64; 3]> {
    // u^3 + a u^2 + c = 0, a = -1/(2M), c = 1/(2 M b^2); u = v - a/3.
    let a = -1.0 / (2.0 * m);
    let c = 1.0 / (2.0 * m * b * b);
    let p = -a * a / 3.0;
    let q = 2.0 * a * a * a / 27.0 + c;
    if 4.0 * p * p * p + 27.0 * q * q >= 0.0 {
        return None;
    }
    let k = 2.0 * (-p / 3.0).sqrt();
    let th = ((3.0 * q / (2.0 * p)) * (-3.0 / p).sqrt())
        .clamp(-1.0, 1.0)
        .acos()
        / 3.0;
    let mut r: [f64; 3] =
        std::array::from_fn(|j| k * (th - 2.0 * PI * j as f64 / 3.0).cos() - a / 3.0);
    let f = |u: f64| 2.0 * m * u * u * u - u * u + 1.0 / (b * b);
    let df = |u: f64| 6.0 * m * u * u - 2.0 * u;
    for u in &mut r {
        for _ in 0..3 {
            let d = df(*u);
            if d != 0.0 {
                *u -= f(*u) / d;
            }
        }
    }
    r.sort_by(f64::total_cmp);
    Some(r)
}

/// `int_{u0}^{u_t} du / sqrt(1/b^2 - u^2 (1 - 2 M u))` (half the sweep from
/// radius 1/u0 to the turning point), with `u = u_t - s^2` removing the
/// turning-point singularity and `s = sqrt(u3 - u_t) sinh(w)` the
/// near-double-root peak: the integrand becomes
/// `2 / sqrt(2 M (u_t - u1 - s^2))`, smooth on [0, w0].
fn schwarzschild_half_sweep(m: f64, b: f64, u0: f64) -> Option<f64> {
    let [u1, ut, u3] = orbit_roots(m, b)?;
    if !(ut > u0) {
        return None;
    }
    let d = u3 - ut;
    let w0 = ((ut - u0).sqrt() / d.sqrt()).asinh();
    Some(integrate(
        |w| {
            let s = d.sqrt() * w.sinh();
            2.0 / (2.0 * m * (ut - u1 - s * s)).sqrt()
        },
        0.0,
        w0,
        40,
    ))
}

/// Carlson's symmetric elliptic integral R_F(x, y, z) (duplication).
fn carlson_rf(mut x: f64, mut y: f64, mut z: f64) -> f64 {
    for _ in 0..200 {
        let a = (x + y + z) / 3.0;
        let dev = ((a - x).abs()).max((a - y).abs()).max((a - z).abs());
        if dev < 1e-4 * a {
            let (dx, dy) = ((a - x) / a, (a - y) / a);
            let dz = -dx - dy;
            let e2 = dx * dy - dz * dz;
            let e3 = dx * dy * dz;
            return (1.0 - e2 / 10.0 + e3 / 14.0 + e2 * e2 / 24.0 - 3.0 * e2 * e3 / 44.0)
                / a.sqrt();
        }
        let (sx, sy, sz) = (x.sqrt(), y.sqrt(), z.sqrt());
        let l = sx * sy + sy * sz + sz * sx;
        x = 0.25 * (x + l);
        y = 0.25 * (y + l);
        z = 0.25 * (z + l);
    }
    f64::NAN
}

/// Incomplete elliptic integral of the first kind F(phi, k), |phi| <= pi/2.
fn ellip_f(phi: f64, k: f64) -> f64 {
    let (s, c) = phi.sin_cos();
    s * carlson_rf(c * c, 1.0 - k * k * s * s, 1.0)
}

/// Complete K(k) by the arithmetic-geometric mean.
fn ellip_k_agm(k: f64) -> f64 {
    let (mut a, mut g) = (1.0f64, (1.0 - k * k).sqrt());
    for _ in 0..60 {
        let (an, gn) = (0.5 * (a + g), (a * g).sqrt());
        a = an;
        g = gn;
        if (a - g).abs() <= 1e-16 * a {
            break;
        }
    }
    PI / (2.0 * a)
}

/// Sweep `delta_phi` between radii `rs` and `re` (Ellis: `l`) for impact
/// parameter `b`; `(sweep, captured, side)`.
fn finite_sweep(st: &SpacetimeSpec, b: f64, rs: f64, re: f64) -> (f64, bool, i32) {
    match *st {
        SpacetimeSpec::Minkowski => (PI - (b / rs).asin() - (b / re).asin(), false, 1),
        SpacetimeSpec::Schwarzschild { mass } => match (
            schwarzschild_half_sweep(mass, b, 1.0 / rs),
            schwarzschild_half_sweep(mass, b, 1.0 / re),
        ) {
            (Some(a), Some(c)) => (a + c, false, 1),
            _ => (0.0, true, 1),
        },
        SpacetimeSpec::Ellis { b0 } => {
            let (us, ue) = (
                1.0 / (b0 * b0 + rs * rs).sqrt(),
                1.0 / (b0 * b0 + re * re).sqrt(),
            );
            if b > b0 {
                // dphi = d psi / sqrt(1 - k^2 sin^2 psi), b u = sin psi, k = b0 / b.
                let k = b0 / b;
                let kk = ellip_f(PI / 2.0, k);
                (
                    2.0 * kk - ellip_f((b * us).asin(), k) - ellip_f((b * ue).asin(), k),
                    false,
                    1,
                )
            } else {
                // dphi = (b/b0) d chi / sqrt(1 - (b/b0)^2 sin^2 chi), b0 u = sin chi.
                let k = b / b0;
                let kk = ellip_f(PI / 2.0, k);
                (
                    (b / b0)
                        * (2.0 * kk - ellip_f((b0 * us).asin(), k) - ellip_f((b0 * ue).asin(), k)),
                    false,
                    -1,
                )
            }
        }
    }
}

fn deflection_list(s: &TransportScene) -> Result<(&SpacetimeSpec, Vec<f64>, f64, f64)> {
    match &s.task {
        TaskSpec::Deflection {
            spacetime,
            impact_parameters,
            r_start,
            r_end,
            repeat,
            ..
        } => {
            let n = impact_parameters.len() * *repeat as usize;
            Ok((
                spacetime,
                impact_parameters.iter().copied().cycle().take(n).collect(),
                *r_start,
                r_end.unwrap_or(*r_start),
            ))
        }
        _ => Err(Error::invalid(
            "task",
            "this reference needs a `type: deflection` task",
        )),
    }
}

fn deflection_finite(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let (st, bs, rs, re) = deflection_list(&s)?;
    let (mut d, mut cap, mut side) = (vec![], vec![], vec![]);
    for &b in &bs {
        let (sweep, c, sd) = finite_sweep(st, b, rs, re);
        d.push(if c { 0.0 } else { sweep - PI });
        cap.push(c as u8);
        side.push(sd);
    }
    let mut out = Outputs::default();
    out.tensor("deflection", f64s(d)?);
    out.tensor("escaped", u8s(cap.iter().map(|c| 1 - c).collect())?);
    out.tensor("captured", u8s(cap)?);
    out.tensor("side", i32s(side)?);
    Ok(out)
}

/// Darwin (1959): with periapsis P (largest root of P^3 - b^2 P + 2 M b^2),
/// `Q^2 = (P - 2M)(P + 6M)`, `k^2 = (Q - P + 6M) / 2Q`,
/// `sin^2 zeta = (Q - P + 2M) / (Q - P + 6M)`:
/// `alpha = -pi + 4 sqrt(P/Q) (K(k) - F(zeta, k))`.
fn darwin(m: f64, b: f64) -> Option<f64> {
    if b <= 27f64.sqrt() * m {
        return None;
    }
    let p = 2.0 * b / 3f64.sqrt() * ((-(27f64.sqrt()) * m / b).acos() / 3.0).cos();
    let q = ((p - 2.0 * m) * (p + 6.0 * m)).sqrt();
    let k = ((q - p + 6.0 * m) / (2.0 * q)).sqrt();
    let zeta = ((q - p + 2.0 * m) / (q - p + 6.0 * m)).sqrt().asin();
    Some(-PI + 4.0 * (p / q).sqrt() * (ellip_f(PI / 2.0, k) - ellip_f(zeta, k)))
}

fn schwarzschild_mass(st: &SpacetimeSpec) -> Result<f64> {
    match *st {
        SpacetimeSpec::Schwarzschild { mass } => Ok(mass),
        _ => Err(Error::invalid(
            "task.spacetime",
            "this reference is for schwarzschild",
        )),
    }
}

fn deflection_darwin(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let (st, bs, _, _) = deflection_list(&s)?;
    let m = schwarzschild_mass(st)?;
    let d: Vec<Option<f64>> = bs.iter().map(|&b| darwin(m, b)).collect();
    let mut out = Outputs::default();
    out.tensor(
        "escaped",
        u8s(d.iter().map(|v| v.is_some() as u8).collect())?,
    );
    out.tensor(
        "deflection",
        f64s(d.into_iter().map(|v| v.unwrap_or(0.0)).collect())?,
    );
    Ok(out)
}

fn weak_field(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let (st, bs, _, _) = deflection_list(&s)?;
    let m = schwarzschild_mass(st)?;
    let series = |x: f64| {
        4.0 * x + 15.0 * PI / 4.0 * x * x + 128.0 / 3.0 * x.powi(3) + 3465.0 * PI / 64.0 * x.powi(4)
    };
    let mut out = Outputs::default();
    out.tensor(
        "deflection",
        f64s(bs.iter().map(|b| series(m / b)).collect())?,
    );
    out.tensor(
        "truncation",
        f64s(bs.iter().map(|b| 3584.0 / 5.0 * (m / b).powi(5)).collect())?,
    );
    Ok(out)
}

fn ellis_infinite(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let (st, bs, _, _) = deflection_list(&s)?;
    let b0 = match *st {
        SpacetimeSpec::Ellis { b0 } => b0,
        _ => {
            return Err(Error::invalid(
                "task.spacetime",
                "this reference is for ellis",
            ))
        }
    };
    if let Some(b) = bs.iter().find(|&&b| b <= b0) {
        return Err(Error::invalid(
            "task.impact_parameters",
            format!("{b}: 2 K(b0/b) - pi needs b > b0"),
        ));
    }
    let mut out = Outputs::default();
    out.tensor(
        "deflection",
        f64s(bs.iter().map(|b| 2.0 * ellip_k_agm(b0 / b) - PI).collect())?,
    );
    Ok(out)
}

/// Synge (1966): `sin psi = 3 sqrt(3) M sqrt(1 - 2M/r) / r`, with psi past
/// 90 degrees inside the photon sphere (r < 3M).
fn synge_deg(m: f64, r: f64) -> f64 {
    let s = (27f64.sqrt() * m * (1.0 - 2.0 * m / r).sqrt() / r).min(1.0);
    let psi = s.asin().to_degrees();
    if r < 3.0 * m {
        180.0 - psi
    } else {
        psi
    }
}

fn observer_setup(s: &TransportScene) -> Result<(f64, f64, &Vec<f64>)> {
    match &s.task {
        TaskSpec::Observer {
            spacetime,
            r_obs,
            angles_deg,
            ..
        } => Ok((schwarzschild_mass(spacetime)?, *r_obs, angles_deg)),
        _ => Err(Error::invalid(
            "task",
            "this operation needs a `type: observer` task",
        )),
    }
}

fn shadow_synge(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let (m, r, angles) = observer_setup(&s)?;
    let psi = synge_deg(m, r);
    let mut out = Outputs::default();
    out.tensor("shadow_angle_deg", f64s(vec![psi])?);
    out.tensor(
        "captured",
        u8s(angles.iter().map(|&a| (a < psi) as u8).collect())?,
    );
    Ok(out)
}

fn shadow_angle_in<F: Real>(s: &TransportScene, iters: u32) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    let Task::Observer(scan) = task else {
        return Err(Error::invalid(
            "task",
            "transport.shadow_angle needs a `type: observer` task",
        ));
    };
    let t = Instant::now();
    let a = shadow_angle(&scan, &opt, iters)?;
    let mut out = Outputs::default();
    out.tensor("shadow_angle_deg", f64s(vec![a])?);
    out.metric("time_s", t.elapsed().as_secs_f64());
    Ok(out)
}

fn shadow_angle_op(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = scene(ctx)?;
    let iters: u32 = ctx.param_or("iters", 40)?;
    if iters == 0 || iters > 60 {
        return Err(Error::invalid(
            format!("{} params.iters", ctx.case_id),
            "must lie in 1..=60",
        ));
    }
    match ctx.precision {
        Precision::F32 => shadow_angle_in::<f32>(&s, iters),
        Precision::F64 => shadow_angle_in::<f64>(&s, iters),
    }
}

fn unit(r: &[f64; 6]) -> [f64; 3] {
    let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
    [r[3] / n, r[4] / n, r[5] / n]
}

fn grin_closed_form(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    let TaskSpec::Grin { medium, rays, stop } = &s.task else {
        return Err(Error::invalid(
            "task",
            "transport.grin_closed_form needs a `type: grin` task",
        ));
    };
    let medium = match medium {
        MediumSpec::Grid { sample, .. } => sample.as_ref(),
        m => m,
    };
    let mut out = Outputs::default();
    match (stop, medium) {
        (StopSpec::LensExit, MediumSpec::Luneburg { radius }) => {
            // A parallel beam along d focuses at R d on the far side.
            let pts: Vec<[f64; 3]> = rays.iter().map(|r| unit(r).map(|c| radius * c)).collect();
            let hit: Vec<u8> = rays
                .iter()
                .map(|r| {
                    let d = unit(r);
                    let od = r[0] * d[0] + r[1] * d[1] + r[2] * d[2];
                    let perp2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2] - od * od;
                    (perp2 < radius * radius) as u8
                })
                .collect();
            out.tensor("exit_point", f64x3(pts)?);
            out.tensor("hit", u8s(hit)?);
        }
        (StopSpec::AxisReturn, MediumSpec::Fibre { alpha, .. }) => {
            let p = rays.iter().map(|r| 2.0 * PI * unit(r)[0] / alpha).collect();
            out.tensor("period", f64s(p)?);
        }
        (StopSpec::AxisReturn, MediumSpec::Sech { alpha, .. }) => {
            out.tensor("period", f64s(vec![2.0 * PI / alpha; rays.len()])?);
        }
        (StopSpec::Approach { .. }, MediumSpec::FishEye { radius, .. }) => {
            let pts = rays
                .iter()
                .map(|r| {
                    let o2 = r[0] * r[0] + r[1] * r[1] + r[2] * r[2];
                    [0, 1, 2].map(|k| -radius * radius * r[k] / o2)
                })
                .collect();
            out.tensor("conjugate_point", f64x3(pts)?);
        }
        (st, m) => {
            return Err(Error::NotSupported(format!(
                "no closed form for stop {st:?} in medium {m:?}"
            )))
        }
    }
    if let (StopSpec::AxisReturn, Some(r)) =
        (stop, rays.iter().find(|r| r[1] != 0.0 || r[2] != 0.0))
    {
        return Err(Error::invalid(
            "task.rays",
            format!("{r:?}: the period closed form needs rays launched from the axis (y = z = 0)"),
        ));
    }
    Ok(out)
}

fn convergence_in<F: Real>(ctx: &OpCtx, s: &TransportScene, factors: &[f64]) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    let mut levels: Vec<Vec<Vec<f64>>> = vec![];
    let mut steps = vec![];
    for &k in factors {
        let o = Options {
            tier: opt.tier.scaled_by(F::of(k)),
            ..opt
        };
        let mut tmp = Outputs::default();
        levels.push(run_task(&task, &o, ctx, &[], &mut tmp)?);
        steps.push(tmp.counters.get("steps").copied().unwrap_or(0) as f64);
    }
    let n = levels[0].len();
    // Differences are Euclidean norms over a ray's quantity (a point's three
    // coordinates). Exact agreement leaves no order to measure: 0, so an
    // order gate fails.
    let dist = |a: &[f64], b: &[f64]| {
        a.iter()
            .zip(b)
            .map(|(x, y)| (x - y) * (x - y))
            .sum::<f64>()
            .sqrt()
    };
    let order: Vec<f64> = (0..n)
        .map(|i| {
            let d1 = dist(&levels[0][i], &levels[1][i]);
            let d2 = dist(&levels[1][i], &levels[2][i]);
            if d1 > 0.0 && d2 > 0.0 {
                (d1 / d2).log2() / (factors[0] / factors[1]).log2()
            } else {
                0.0
            }
        })
        .collect();
    let mut out = Outputs::default();
    out.tensor("order", f64s(order)?);
    let k = levels[0].first().map_or(0, Vec::len);
    let flat: Vec<f64> = levels.into_iter().flatten().flatten().collect();
    out.tensor(
        "levels",
        Tensor::from_shape_vec(&[factors.len(), n, k], flat)?,
    );
    out.tensor("level_steps", f64s(steps)?);
    Ok(out)
}

fn convergence(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = scene(ctx)?;
    let factors: Vec<f64> = ctx.param_or("factors", vec![1.0, 0.5, 0.25])?;
    let ok = factors.len() == 3
        && factors.iter().all(|f| *f > 0.0 && f.is_finite())
        && factors[0] / factors[1] == factors[1] / factors[2]
        && factors[0] != factors[1];
    if !ok {
        return Err(Error::invalid(
            format!("{} params.factors", ctx.case_id),
            "three positive factors in one geometric ratio, e.g. [1, 0.5, 0.25]",
        ));
    }
    match ctx.precision {
        Precision::F32 => convergence_in::<f32>(ctx, &s, &factors),
        Precision::F64 => convergence_in::<f64>(ctx, &s, &factors),
    }
}

fn drift_in<F: Real>(ctx: &OpCtx, s: &TransportScene, n: [u64; 2]) -> Result<Outputs> {
    let (task, opt) = s.build::<F>()?;
    let Task::Grin(g) = task else {
        return Err(Error::invalid(
            "task",
            "transport.drift_growth needs a `type: grin` task",
        ));
    };
    let run = |k: u64| -> Result<Vec<f64>> {
        let t = GrinRays {
            stop: GrinStop::Steps { n: k },
            ..g.clone()
        };
        let r = grin_rays(&t, &opt, &ctx.budget, &[])?;
        Ok(r.h_drift.iter().map(|v| v.f64()).collect())
    };
    let (a, b) = (run(n[0])?, run(n[1])?);
    let growth = a
        .iter()
        .zip(&b)
        .map(|(x, y)| if *x > 0.0 { y / x } else { f64::MAX })
        .collect();
    let mut out = Outputs::default();
    out.tensor("h_drift_short", f64s(a)?)
        .tensor("h_drift_long", f64s(b)?)
        .tensor("growth", f64s(growth)?);
    Ok(out)
}

fn drift_growth(ctx: &OpCtx) -> Result<Outputs> {
    ctx.cpu_only()?;
    let s = scene(ctx)?;
    let n: [u64; 2] = ctx.param_or("steps", [10_000, 100_000])?;
    if !(n[0] > 0 && n[1] > n[0]) {
        return Err(Error::invalid(
            format!("{} params.steps", ctx.case_id),
            "need 0 < steps[0] < steps[1]",
        ));
    }
    match ctx.precision {
        Precision::F32 => drift_in::<f32>(ctx, &s, n),
        Precision::F64 => drift_in::<f64>(ctx, &s, n),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn elliptic_integrals_agree_with_each_other_and_known_values() {
        for k in [0.0, 0.3, 0.9, 0.999] {
            assert!(
                (ellip_f(PI / 2.0, k) - ellip_k_agm(k)).abs() < 1e-14,
                "k={k}"
            );
        }
        // K(1/sqrt 2) = Gamma(1/4)^2 / (4 sqrt(pi)) = 1.854074677301372.
        assert!((ellip_k_agm(0.5f64.sqrt()) - 1.854_074_677_301_372).abs() < 1e-14);
        assert!((ellip_f(0.7, 0.0) - 0.7).abs() < 1e-15);
    }

    #[test]
    fn quadrature_sweep_matches_darwin_far_out() {
        for b in [5.3, 6.0, 10.0, 100.0] {
            let q = 2.0 * schwarzschild_half_sweep(1.0, b, 0.0).unwrap() - PI;
            let d = darwin(1.0, b).unwrap();
            assert!((q - d).abs() < 1e-10, "b={b}: {q} vs {d}");
        }
        // Near-critical: the sinh substitution keeps the quadrature accurate.
        let b = 27f64.sqrt() + 1e-6;
        let (q, d) = (
            2.0 * schwarzschild_half_sweep(1.0, b, 0.0).unwrap() - PI,
            darwin(1.0, b).unwrap(),
        );
        assert!((q - d).abs() < 1e-8, "{q} vs {d}");
        assert!(schwarzschild_half_sweep(1.0, 5.0, 1e-3).is_none());
    }

    #[test]
    fn darwin_matches_the_weak_field_series_for_large_b() {
        let b = 1000.0;
        let x: f64 = 1.0 / b;
        let series = 4.0 * x
            + 15.0 * PI / 4.0 * x * x
            + 128.0 / 3.0 * x.powi(3)
            + 3465.0 * PI / 64.0 * x.powi(4);
        // The difference is the 5th-order term 3584/5 (M/b)^5 = 7.2e-13.
        let d = darwin(1.0, b).unwrap() - series;
        assert!((d / (3584.0 / 5.0 * x.powi(5)) - 1.0).abs() < 0.05, "{d:e}");
    }

    #[test]
    fn ellis_finite_sweep_tends_to_2k_minus_pi() {
        let st = SpacetimeSpec::Ellis { b0: 1.0 };
        let (s, _, side) = finite_sweep(&st, 2.0, 1e12, 1e12);
        assert!((s - PI - (2.0 * ellip_k_agm(0.5) - PI)).abs() < 1e-11);
        assert_eq!(side, 1);
        assert_eq!(finite_sweep(&st, 0.5, 100.0, 100.0).2, -1);
    }

    #[test]
    fn synge_angle_is_45_at_6m_and_90_at_3m() {
        assert!((synge_deg(1.0, 6.0) - 45.0).abs() < 1e-12);
        assert!((synge_deg(1.0, 3.0) - 90.0).abs() < 1e-6);
        assert!(synge_deg(1.0, 2.5) > 90.0);
    }
}
