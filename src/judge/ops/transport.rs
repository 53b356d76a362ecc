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
//! The references are `transport::referee` (closed forms and quadratures in
//! f64 that share no code with the integrators); the ops here read the typed
//! scene and wire it to them.

use std::f64::consts::PI;
use std::time::Instant;

use super::transport_gpu as backend;
use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::real::Real;
use crate::scene::transport::{
    parse, MediumSpec, SpacetimeSpec, StopSpec, TaskSpec, TransportScene,
};
use crate::tensor::{Outputs, Tensor};
use crate::transport::integrate::Options;
use crate::transport::outputs::{f64s, f64x3, i32s, run_task, u8s};
use crate::transport::referee::{
    darwin, ellis_infinite, fibre_period, finite_sweep, fisheye_conjugate, luneburg_focus,
    sech_period, synge_deg, weak_field_series, weak_field_truncation, Spacetime,
};
use crate::transport::tasks::{grin_rays, shadow_angle, GrinRays, GrinStop, Task};

pub const OPS: &[OpEntry] = &[
    OpEntry { name: "transport.render", doc: "trace a transport scene: deflection/captured/steps/h_drift, or GRIN exit points and periods", params: &[], support: Support::CpuGpuF32, run: render },
    OpEntry {
        name: "transport.deflection_finite",
        doc: "finite-distance deflection by substitution + Gauss-Legendre (Schwarzschild), elliptic F (Ellis)",
        params: &[],
        support: Support::Any,
        run: deflection_finite,
    },
    OpEntry { name: "transport.deflection_darwin", doc: "Darwin's exact infinite-distance Schwarzschild deflection", params: &[], support: Support::Any, run: deflection_darwin },
    OpEntry { name: "transport.deflection_weak_field", doc: "weak-field series 4M/b + 15 pi M^2/4b^2 + 128 M^3/3b^3 + 3465 pi M^4/64b^4", params: &[], support: Support::Any, run: weak_field },
    OpEntry { name: "transport.ellis_infinite", doc: "Ellis deflection at infinity 2 K(b0/b) - pi by the AGM", params: &[], support: Support::Any, run: ellis_infinite_op },
    OpEntry { name: "transport.shadow_synge", doc: "Synge's capture angle and expected capture flags for an observer scene", params: &[], support: Support::Any, run: shadow_synge },
    OpEntry { name: "transport.shadow_angle", doc: "capture angle by bisection with the integrator (params.iters, default 40)", params: &["iters"], support: Support::Cpu, run: shadow_angle_op },
    OpEntry { name: "transport.grin_closed_form", doc: "Luneburg focus R d, fibre period 2 pi cos(theta0)/alpha, sech 2 pi/alpha, fish-eye conjugate -R^2 o/|o|^2", params: &[], support: Support::Any, run: grin_closed_form },
    OpEntry {
        name: "transport.convergence",
        doc: "observed order under step scaling by params.factors (default [1, 0.5, 0.25])",
        params: &["factors"],
        support: Support::Cpu,
        run: convergence,
    },
    OpEntry { name: "transport.drift_growth", doc: "max |H| after params.steps = [n1, n2] steps of a GRIN scene, and the ratio", params: &["steps"], support: Support::Cpu, run: drift_growth },
];

fn scene(ctx: &OpCtx) -> Result<TransportScene> {
    parse(ctx.scene()?)
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
    run_task(
        &task,
        &opt,
        &ctx.budget,
        &s.dump_rays,
        &mut out,
        backend::gpu(ctx)?,
    )?;
    Ok(out)
}

fn render(ctx: &OpCtx) -> Result<Outputs> {
    let s = scene(ctx)?;
    backend::prepare(ctx, &s)?;
    by_precision!(ctx, render_in(ctx, &s))
}

// ---------------------------------------------------------------------------
// Independent references: `transport::referee`.

/// The referee's description of a spacetime.
fn closed_spacetime(st: &SpacetimeSpec) -> Result<Spacetime> {
    Ok(match *st {
        SpacetimeSpec::Minkowski => Spacetime::Minkowski,
        SpacetimeSpec::Schwarzschild { mass } => Spacetime::Schwarzschild { mass },
        SpacetimeSpec::Ellis { b0 } => Spacetime::Ellis { b0 },
        SpacetimeSpec::Kerr { .. } => {
            return Err(Error::NotSupported(
                "no Kerr deflection quadrature: Kerr lists are judged against Schwarzschild runs (a = 0) and their invariants".into(),
            ))
        }
    })
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
    let st = closed_spacetime(st)?;
    let (mut d, mut cap, mut side) = (vec![], vec![], vec![]);
    for &b in &bs {
        let (sweep, c, sd) = finite_sweep(&st, b, rs, re);
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
    let mut out = Outputs::default();
    out.tensor(
        "deflection",
        f64s(bs.iter().map(|b| weak_field_series(m / b)).collect())?,
    );
    out.tensor(
        "truncation",
        f64s(bs.iter().map(|b| weak_field_truncation(m / b)).collect())?,
    );
    Ok(out)
}

fn ellis_infinite_op(ctx: &OpCtx) -> Result<Outputs> {
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
        f64s(bs.iter().map(|&b| ellis_infinite(b0, b)).collect())?,
    );
    Ok(out)
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
    let s = scene(ctx)?;
    let iters: u32 = ctx.param_or("iters", 40)?;
    if iters == 0 || iters > 60 {
        return Err(Error::invalid(
            format!("{} params.iters", ctx.case_id),
            "must lie in 1..=60",
        ));
    }
    by_precision!(ctx, shadow_angle_in(&s, iters))
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
            let (pts, hit): (Vec<[f64; 3]>, Vec<u8>) = rays
                .iter()
                .map(|r| {
                    let (p, h) = luneburg_focus(*radius, r);
                    (p, h as u8)
                })
                .unzip();
            out.tensor("exit_point", f64x3(pts)?);
            out.tensor("hit", u8s(hit)?);
        }
        (StopSpec::AxisReturn, MediumSpec::Fibre { alpha, .. }) => {
            let p = rays.iter().map(|r| fibre_period(*alpha, r)).collect();
            out.tensor("period", f64s(p)?);
        }
        (StopSpec::AxisReturn, MediumSpec::Sech { alpha, .. }) => {
            out.tensor("period", f64s(vec![sech_period(*alpha); rays.len()])?);
        }
        (StopSpec::Approach { .. }, MediumSpec::FishEye { radius, .. }) => {
            let pts = rays.iter().map(|r| fisheye_conjugate(*radius, r)).collect();
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
        levels.push(run_task(&task, &o, &ctx.budget, &[], &mut tmp, None)?);
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
    by_precision!(ctx, convergence_in(ctx, &s, &factors))
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
    let s = scene(ctx)?;
    let n: [u64; 2] = ctx.param_or("steps", [10_000, 100_000])?;
    if !(n[0] > 0 && n[1] > n[0]) {
        return Err(Error::invalid(
            format!("{} params.steps", ctx.case_id),
            "need 0 < steps[0] < steps[1]",
        ));
    }
    by_precision!(ctx, drift_in(ctx, &s, n))
}
