//! A traced transport task as named tensors (SCENES.md outputs; the
//! `transport.render` table in `judge/ops/transport.rs`): deflection tasks
//! `deflection`, `captured`, `escaped`, `side`, `steps`, `h_drift`,
//! `err_est`, `reason`; observer tasks `captured`, `steps`, `h_drift`,
//! `err_est`, `reason`; GRIN tasks `end_point`, `end_dir`, ... and by stop
//! `exit_point`, `period`, `conjugate_point`; dumped rays `polylines`,
//! `polyline_len`, `polyline_ray`.

use std::time::Instant;

use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};
use crate::transport::image::{render as render_image, ImageOut};
use crate::transport::integrate::Options;
use crate::transport::kerr_trace::kerr_deflection;
use crate::transport::tasks::{
    deflection, grin_rays, observer_scan, shadow_angle, Curved, GrinStop, Polyline, Task,
};

pub fn vec1<F: Real>(v: Vec<F>) -> Result<Tensor> {
    let n = v.len();
    Tensor::real(&[n], v)
}

pub fn i32s(v: Vec<i32>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

pub fn u8s(v: Vec<u8>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

pub fn f64s(v: Vec<f64>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n], v)
}

pub fn f64x3(v: Vec<[f64; 3]>) -> Result<Tensor> {
    let n = v.len();
    Tensor::from_shape_vec(&[n, 3], v.into_iter().flatten().collect())
}

/// `polylines` (k, L, 4), each padded with its last point,
/// `polyline_len` (k), `polyline_ray` (k) and `polyline_end` (k, 3), the
/// last recorded point, for the dumped rays; nothing when none are dumped.
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
    let ends: Vec<[F; 3]> = p
        .iter()
        .map(|(_, v)| v.last().map_or([F::zero(); 3], |q| [q[0], q[1], q[2]]))
        .collect();
    out.tensor("polyline_end", Tensor::real3(&[ends.len()], &ends)?);
    Ok(())
}

/// Traces `task` and writes its outputs into `out` (tensors named as in the
/// module doc, metrics `time_s`, `s_per_1000_rays`, `ns_per_step`, counters
/// `rays`, `steps`); returns per ray the quantity convergence studies use
/// (deflection, capture flag, period, or the end point's coordinates).
pub fn run_task<F: Real>(
    task: &Task<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
    out: &mut Outputs,
    gpu: Option<&crate::gpu::GpuContext>,
) -> Result<Vec<Vec<f64>>> {
    let t = Instant::now();
    let (rays, steps, q): (usize, Vec<i32>, Vec<Vec<f64>>) = match task {
        Task::Curved(c) => run_curved(c, opt, budget, out, gpu)?,
        Task::Deflection(d) => {
            let r = match gpu {
                None => deflection(d, opt, budget, dump)?,
                Some(c) => super::gpu::deflection(c, d, opt, budget, dump)?,
            };
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
            let r = match gpu {
                None => observer_scan(s, opt, budget, dump)?,
                Some(c) => super::gpu::observer_scan(c, s, opt, budget, dump)?,
            };
            polylines(&r.polylines, out)?;
            let q = r.captured.iter().map(|&c| vec![c as f64]).collect();
            out.tensor("captured", u8s(r.captured)?);
            out.tensor("h_drift", vec1(r.h_drift)?)
                .tensor("err_est", vec1(r.err_est)?);
            out.tensor("reason", i32s(r.reason)?);
            (s.angles_deg.len(), r.steps, q)
        }
        Task::Grin(g) => {
            let r = match gpu {
                None => grin_rays(g, opt, budget, dump)?,
                Some(c) => super::gpu::grin_rays(c, g, opt, budget, dump)?,
            };
            polylines(&r.polylines, out)?;
            if !r.polylines.is_empty() {
                // The exit data of the dumped rays, for checks against
                // `polyline_end` (the callback's last point).
                let exit: Vec<[F; 3]> = r.polylines.iter().map(|(i, _)| r.end_point[*i]).collect();
                out.tensor("polyline_exit", Tensor::real3(&[exit.len()], &exit)?);
            }
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

/// A one-element tensor.
pub fn t1(v: f64) -> Tensor {
    Tensor::from_shape_vec(&[1], vec![v]).unwrap_or_else(|_| Tensor::scalar(v))
}

fn image_tensors<F: Real>(
    r: ImageOut<F>,
    out: &mut Outputs,
) -> Result<(usize, Vec<i32>, Vec<Vec<f64>>)> {
    let sh = r.shape.clone();
    let n: usize = sh.iter().product();
    let mut sh3 = sh.clone();
    sh3.push(3);
    let q = r.captured.iter().map(|&c| vec![c as f64]).collect();
    let max = |v: &[F]| v.iter().fold(0.0f64, |m, x| m.max(x.f64()));
    out.metric("max_h_drift", max(&r.h_drift));
    if !r.q_drift.is_empty() {
        out.metric("max_e_drift", max(&r.e_drift))
            .metric("max_l_drift", max(&r.l_drift))
            .metric("max_q_drift", max(&r.q_drift));
        out.tensor("e_drift", Tensor::real(&sh, r.e_drift)?);
        out.tensor("l_drift", Tensor::real(&sh, r.l_drift)?);
        out.tensor("q_drift", Tensor::real(&sh, r.q_drift)?);
    }
    out.tensor(
        "escaped",
        Tensor::from_shape_vec(&sh, r.reason.iter().map(|&c| (c == 0) as u8).collect())?,
    );
    out.tensor("captured", Tensor::from_shape_vec(&sh, r.captured)?);
    out.tensor(
        "final_dir",
        Tensor::real(&sh3, r.final_dir.into_iter().flatten().collect())?,
    );
    out.tensor("h_drift", Tensor::real(&sh, r.h_drift)?);
    out.tensor("err_est", Tensor::real(&sh, r.err_est)?);
    out.tensor("reason", Tensor::from_shape_vec(&sh, r.reason)?);
    if sh.len() == 2 {
        out.tensor(
            "image",
            Tensor::real(&sh3, r.image.into_iter().flatten().collect())?,
        );
    }
    if let Some(ri) = r.disk_r_in {
        let inner = r
            .disk_r
            .iter()
            .filter(|v| v.f64() > 0.0)
            .fold(f64::INFINITY, |m, v| m.min(v.f64()));
        out.tensor(
            "disk_inner_r",
            t1(if inner.is_finite() { inner } else { -1.0 }),
        );
        out.tensor("disk_r_in", t1(ri));
        out.tensor(
            "disk_hit",
            Tensor::from_shape_vec(
                &sh,
                r.disk_r.iter().map(|v| (v.f64() > 0.0) as u8).collect(),
            )?,
        );
        out.tensor("disk_r", Tensor::real(&sh, r.disk_r)?);
        out.tensor("redshift", Tensor::real(&sh, r.redshift)?);
    }
    if !r.side.is_empty() {
        out.tensor("side", Tensor::from_shape_vec(&sh, r.side)?);
    }
    Ok((n, r.steps, q))
}

/// `transport.render` for [`Curved`] tasks. Deflection lists: `deflection`,
/// `captured`, `escaped`, `h_drift`, `err_est`, `reason`, `e_drift`,
/// `l_drift`, `q_drift`. Images: the per-pixel tensors of
/// `transport::image` (shape (H, W) or (n) for ray lists), `image` (H, W, 3,
/// also as PNG), disk images `disk_r`, `disk_hit`, `redshift`,
/// `disk_inner_r` (smallest disk radius hit, -1 if none) and `disk_r_in`
/// (the ISCO the renderer used); metrics `max_h_drift`, `max_e_drift`,
/// `max_l_drift`, `max_q_drift`. Returns rays, steps and per-ray values.
/// With `gpu`, images are traced by `super::gpu` (same outputs).
pub fn run_curved<F: Real>(
    c: &Curved,
    opt: &Options<F>,
    budget: &MemBudget,
    out: &mut Outputs,
    gpu: Option<&crate::gpu::GpuContext>,
) -> Result<(usize, Vec<i32>, Vec<Vec<f64>>)> {
    match (c, gpu) {
        (Curved::KerrDeflection(_), Some(_)) => Err(super::gpu::curved_not_supported()),
        (Curved::Image(t), Some(g)) => {
            image_tensors(super::gpu::render_image(g, t, opt, budget)?, out)
        }
        (Curved::KerrDeflection(d), None) => {
            let r = kerr_deflection(d, opt)?;
            let n = r.deflection.len();
            let q = r.deflection.iter().map(|v| vec![v.f64()]).collect();
            let col = |i: usize| Tensor::real(&[n], r.drift.iter().map(|d| d[i]).collect());
            out.tensor("e_drift", col(0)?)
                .tensor("l_drift", col(1)?)
                .tensor("q_drift", col(2)?);
            out.tensor("deflection", Tensor::real(&[n], r.deflection)?);
            out.tensor(
                "escaped",
                Tensor::from_shape_vec(&[n], r.captured.iter().map(|c| 1 - c).collect())?,
            );
            out.tensor("captured", Tensor::from_shape_vec(&[n], r.captured)?);
            out.tensor("h_drift", Tensor::real(&[n], r.h_drift)?);
            out.tensor("err_est", Tensor::real(&[n], r.err_est)?);
            out.tensor("reason", Tensor::from_shape_vec(&[n], r.reason)?);
            Ok((n, r.steps, q))
        }
        (Curved::Image(t), None) => image_tensors(render_image(t, opt, budget)?, out),
    }
}

/// `transport.shadow_angle`: the capture angle of an observer task by
/// bisection with the integrator (`shadow_angle_deg`), timed (`time_s`).
pub fn shadow_angle_outputs<F: Real>(
    task: &Task<F>,
    opt: &Options<F>,
    iters: u32,
) -> Result<Outputs> {
    let Task::Observer(scan) = task else {
        return Err(Error::invalid(
            "task",
            "transport.shadow_angle needs a `type: observer` task",
        ));
    };
    let t = Instant::now();
    let a = shadow_angle(scan, opt, iters)?;
    let mut out = Outputs::default();
    out.tensor("shadow_angle_deg", f64s(vec![a])?);
    out.metric("time_s", t.elapsed().as_secs_f64());
    Ok(out)
}
