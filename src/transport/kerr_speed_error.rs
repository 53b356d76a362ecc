//! Speed against error for Kerr shadows per integrator tier (issue 16).
//!
//! A pixel grid resolves the shadow's edge only to its pitch (0.03 M at
//! 512 x 512 over [-8, 8]), and every tier decides every pixel right there,
//! so the boundary error is measured with probe rays instead: at `n` points
//! of Bardeen's critical curve ([`critical_curve`], upper branch, the arc
//! ends excluded) the image-plane points `p +- d nhat` (`nhat` the outward
//! normal of the polygon) for each offset `d`. The inner point must be
//! captured, the outer must escape (the distant observer's constants of
//! motion are exact, so only the integrator can misplace them). A tier's
//! **boundary error** is the largest `d` at which some probe is classified
//! wrong (0 when none is: the boundary lies within the smallest offset).
//! Beside it: CPU seconds per 1000 probe rays, `max |H|`, the maximum
//! relative `Q` drift and the mean steps per ray.

use super::image::{render, ImageTask, KerrImage, Observer, Pixels};
use super::integrate::{Options, StepLaw, Tier};
use super::referee_kerr::critical_curve;
use super::tasks::{Curved, Task};
use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::judge::measure::timed;
use crate::judge::plot::{self, Chart, Series};
use crate::tensor::{Outputs, Tensor};

/// Probe points and whether each must be captured, with its offset.
pub fn probes(img: &KerrImage, n: usize, offsets: &[f64]) -> Result<Vec<([f64; 2], bool, f64)>> {
    let Observer::Distant { obs, .. } = img.observer else {
        return Err(Error::invalid(
            "task.observer",
            "the Kerr speed-error sweep needs the distant observer",
        ));
    };
    if offsets.is_empty() || !offsets.iter().all(|d| *d > 0.0 && d.is_finite()) {
        return Err(Error::invalid(
            "offsets",
            "need at least one offset, each > 0 and finite",
        ));
    }
    if n < 2 {
        return Err(Error::invalid("points", "need at least 2 curve points"));
    }
    let (m, a) = (img.kerr.mass, img.kerr.a);
    if a < 0.0 {
        return Err(Error::invalid(
            "task.a",
            "the sweep draws Bardeen's curve for a >= 0",
        ));
    }
    // The upper branch has `k` points from end to end.
    let k = 4 * n;
    let poly = critical_curve(m, a, obs.theta_o, k);
    let mut out = Vec::new();
    for i in (2..k - 2).step_by(4) {
        let (p0, p, p1) = (poly[i - 1], poly[i], poly[i + 1]);
        // Upper branch runs left to right: the outward normal is the
        // tangent turned by +90 degrees.
        let (tx, ty) = (p1[0] - p0[0], p1[1] - p0[1]);
        let len = (tx * tx + ty * ty).sqrt();
        let (nx, ny) = (-ty / len, tx / len);
        for &d in offsets {
            out.push(([p[0] - d * nx, p[1] - d * ny], true, d));
            out.push(([p[0] + d * nx, p[1] + d * ny], false, d));
        }
    }
    Ok(out)
}

/// One tier's row.
#[derive(Clone, Debug, PartialEq)]
pub struct Row {
    pub label: String,
    pub tier: &'static str,
    pub cpu_s_per_1000: f64,
    pub boundary_err: f64,
    pub wrong: usize,
    pub max_h: f64,
    pub max_q: f64,
    pub mean_steps: f64,
}

/// A tier's label: its name and its step parameter.
pub fn label(t: &Tier<f64>) -> String {
    match *t {
        Tier::Dopri5(c) => format!("dopri5 rtol {:e}", c.rtol),
        Tier::Rk4(l)
        | Tier::Dopri5Fixed(l)
        | Tier::Verlet(l)
        | Tier::Yoshida4(l)
        | Tier::ImplicitMidpoint(l) => match l {
            StepLaw::Scaled { eta, .. } => format!("{} eta {eta}", t.name()),
            StepLaw::Fixed { h } => format!("{} h {h}", t.name()),
        },
    }
}

/// The sweep of a `kerr_image` task, as outputs ([`to_outputs`], the
/// smallest offset as the plot's floor).
pub fn run(
    task: &Task<f64>,
    base: &Options<f64>,
    tiers: &[Tier<f64>],
    n: usize,
    offsets: &[f64],
    budget: &MemBudget,
) -> Result<Outputs> {
    let Task::Curved(Curved::Image(ImageTask::Kerr(img))) = task else {
        return Err(Error::invalid(
            "task",
            "transport.kerr_speed_error needs a kerr_image scene",
        ));
    };
    let floor = offsets.iter().fold(f64::INFINITY, |m, d| m.min(*d));
    to_outputs(&sweep(img, base, tiers, n, offsets, budget)?, floor)
}

/// Traces the probes of `img` (Bardeen points `n`, `offsets`) with each
/// tier of `tiers` (the rest of `base` kept).
pub fn sweep(
    img: &KerrImage,
    base: &Options<f64>,
    tiers: &[Tier<f64>],
    n: usize,
    offsets: &[f64],
    budget: &MemBudget,
) -> Result<Vec<Row>> {
    let pr = probes(img, n, offsets)?;
    let task = ImageTask::Kerr(KerrImage {
        pixels: Pixels::List(pr.iter().map(|p| p.0).collect()),
        ..img.clone()
    });
    let mut rows = Vec::new();
    for &tier in tiers {
        let opt = Options { tier, ..*base };
        let (r, _, cpu) = timed(|| render(&task, &opt, budget));
        let r = r?;
        let wrong: Vec<f64> = pr
            .iter()
            .zip(&r.captured)
            .filter(|((_, cap, _), &c)| (c == 1) != *cap)
            .map(|(p, _)| p.2)
            .collect();
        let max = |v: &[f64]| v.iter().fold(0.0f64, |m, x| m.max(*x));
        rows.push(Row {
            label: label(&tier),
            tier: tier.name(),
            cpu_s_per_1000: cpu * 1000.0 / pr.len() as f64,
            boundary_err: max(&wrong),
            wrong: wrong.len(),
            max_h: max(&r.h_drift),
            max_q: max(&r.q_drift),
            mean_steps: r.steps.iter().map(|&s| s as f64).sum::<f64>() / pr.len() as f64,
        });
    }
    Ok(rows)
}

/// The rows as `sweep` (tiers x [cpu s / 1000 rays, boundary error, wrong
/// probes, max |H|, max rel. Q drift, mean steps]), metrics
/// `t{i}_cpu_s_per_1000` / `t{i}_boundary_err` / `t{i}_max_q`, and
/// `plot_rgb`: CPU seconds against boundary error per tier (a tier with
/// no wrong probe is drawn at the smallest offset, `floor`), with a
/// markdown table of the rows on stderr.
pub fn to_outputs(rows: &[Row], floor: f64) -> Result<Outputs> {
    let mut out = Outputs::default();
    let mut flat = Vec::new();
    let mut table = String::from(
        "| tier | CPU s / 1000 rays | boundary error | wrong probes | max abs H | max rel. Q drift | mean steps |\n| --- | --- | --- | --- | --- | --- | --- |\n",
    );
    for (i, r) in rows.iter().enumerate() {
        flat.extend([
            r.cpu_s_per_1000,
            r.boundary_err,
            r.wrong as f64,
            r.max_h,
            r.max_q,
            r.mean_steps,
        ]);
        out.metric(&format!("t{i}_cpu_s_per_1000"), r.cpu_s_per_1000)
            .metric(&format!("t{i}_boundary_err"), r.boundary_err)
            .metric(&format!("t{i}_max_q"), r.max_q);
        table += &format!(
            "| {} | {:.3} | {:.1e} | {} | {:.1e} | {:.1e} | {:.0} |\n",
            r.label, r.cpu_s_per_1000, r.boundary_err, r.wrong, r.max_h, r.max_q, r.mean_steps
        );
    }
    tracing::info!("Kerr shadow speed against error:\n{table}");
    out.tensor("sweep", Tensor::from_shape_vec(&[rows.len(), 6], flat)?);
    let mut series: Vec<Series> = Vec::new();
    for r in rows {
        let x = r.boundary_err.max(floor);
        match series.iter_mut().find(|s| s.name == r.tier) {
            Some(s) => {
                s.xs.push(x);
                s.ys.push(r.cpu_s_per_1000);
            }
            None => series.push(Series::new(r.tier, vec![x], vec![r.cpu_s_per_1000])),
        }
    }
    let chart = Chart::loglog(
        "Kerr a = 0.9 shadow edge: CPU time against boundary error per tier",
        "boundary error (M, image plane; floor = smallest probe offset)",
        "CPU s per 1000 probe rays",
        series,
    );
    out.tensor("plot_rgb", plot::render(&chart)?);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::kerr::Kerr;
    use crate::transport::observer::DistantObserver;
    use crate::transport::referee_kerr::inside;

    #[test]
    fn probes_straddle_bardeens_curve() {
        let img = KerrImage {
            kerr: Kerr { mass: 1.0, a: 0.9 },
            observer: Observer::Distant {
                obs: DistantObserver {
                    r_obs: 1000.0,
                    theta_o: 1.2,
                },
                half: 8.0,
            },
            pixels: Pixels::List(vec![]),
            r_end: 1000.0,
            disk_r_out: None,
            cell_deg: 10.0,
        };
        let pr = probes(&img, 16, &[1e-2, 1e-4]).unwrap();
        assert_eq!(pr.len(), 4 * 15);
        let poly = critical_curve(1.0, 0.9, 1.2, 20_000);
        for (p, cap, _) in &pr {
            assert_eq!(inside(&poly, p[0], p[1]), *cap, "{p:?}");
        }
    }
}
