//! A transport scene's task handed to the referees (`transport::referee`:
//! closed forms and quadratures in f64 that share no code with the
//! integrators), their values as named tensors. The judge's
//! `transport.*` reference rows call these.

use std::f64::consts::PI;

use crate::error::{Error, Result};
use crate::scene::transport::{MediumSpec, SpacetimeSpec, StopSpec, TaskSpec, TransportScene};
use crate::tensor::Outputs;
use crate::transport::outputs::{f64s, f64x3, i32s, u8s};
use crate::transport::referee::{
    darwin, ellis_infinite, fibre_period, finite_sweep, fisheye_conjugate, luneburg_focus,
    sech_period, synge_deg, weak_field_series, weak_field_truncation, Spacetime,
};

/// The spacetime, impact parameters (each repeated), start and end radii
/// of a deflection task.
fn deflection_list(s: &TransportScene) -> Result<(&SpacetimeSpec, Vec<f64>, f64, f64)> {
    let TaskSpec::Deflection {
        spacetime,
        impact_parameters: b,
        r_start,
        r_end,
        repeat,
        ..
    } = &s.task
    else {
        return Err(Error::invalid(
            "task",
            "this reference needs a `type: deflection` task",
        ));
    };
    let bs = b
        .iter()
        .copied()
        .cycle()
        .take(b.len() * *repeat as usize)
        .collect();
    Ok((spacetime, bs, *r_start, r_end.unwrap_or(*r_start)))
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

pub fn deflection_finite(s: &TransportScene) -> Result<Outputs> {
    let (st, bs, rs, re) = deflection_list(s)?;
    let st = match *st {
        SpacetimeSpec::Minkowski => Spacetime::Minkowski,
        SpacetimeSpec::Schwarzschild { mass } => Spacetime::Schwarzschild { mass },
        SpacetimeSpec::Ellis { b0 } => Spacetime::Ellis { b0 },
        SpacetimeSpec::Kerr { .. } => return Err(Error::NotSupported(
            "no Kerr deflection quadrature: Kerr lists are judged against Schwarzschild runs (a = 0) and their invariants".into(),
        )),
    };
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
    out.tensor("captured", u8s(cap)?)
        .tensor("side", i32s(side)?);
    Ok(out)
}

pub fn deflection_darwin(s: &TransportScene) -> Result<Outputs> {
    let (st, bs, _, _) = deflection_list(s)?;
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

pub fn weak_field(s: &TransportScene) -> Result<Outputs> {
    let (st, bs, _, _) = deflection_list(s)?;
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

pub fn ellis_infinite_deflection(s: &TransportScene) -> Result<Outputs> {
    let (st, bs, _, _) = deflection_list(s)?;
    let SpacetimeSpec::Ellis { b0 } = *st else {
        return Err(Error::invalid(
            "task.spacetime",
            "this reference is for ellis",
        ));
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

pub fn shadow_synge(s: &TransportScene) -> Result<Outputs> {
    let TaskSpec::Observer {
        spacetime,
        r_obs,
        angles_deg,
        ..
    } = &s.task
    else {
        return Err(Error::invalid(
            "task",
            "this operation needs a `type: observer` task",
        ));
    };
    let psi = synge_deg(schwarzschild_mass(spacetime)?, *r_obs);
    let mut out = Outputs::default();
    out.tensor("shadow_angle_deg", f64s(vec![psi])?);
    out.tensor(
        "captured",
        u8s(angles_deg.iter().map(|&a| (a < psi) as u8).collect())?,
    );
    Ok(out)
}

pub fn grin_closed_form(s: &TransportScene) -> Result<Outputs> {
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
            out.tensor("exit_point", f64x3(pts)?)
                .tensor("hit", u8s(hit)?);
        }
        (StopSpec::AxisReturn, MediumSpec::Fibre { alpha, .. }) => {
            out.tensor(
                "period",
                f64s(rays.iter().map(|r| fibre_period(*alpha, r)).collect())?,
            );
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
        let why =
            format!("{r:?}: the period closed form needs rays launched from the axis (y = z = 0)");
        return Err(Error::invalid("task.rays", why));
    }
    Ok(out)
}
