//! The transport renderer's GPU backend (issue 17): [`deflection`],
//! [`observer_scan`] and [`grin_rays`] take what their CPU namesakes in
//! [`super::tasks`] take and return the same outputs, with the rays traced
//! by `kernels/transport.wgsl` through `crate::gpu::transport`;
//! [`render_image`] renders Kerr and Ellis images through
//! `image::render_with` with the [`GpuTracer`] (the CPU's observers, start
//! states and shading; only the rays run on the GPU).
//!
//! The start states are the CPU's own (`tasks::*_setup`: constants of
//! motion and momenta computed in f64 on the host, then rounded to f32;
//! see docs/transport_gpu.md), so a GPU ray and a CPU f32 ray start from
//! the same bits; the outputs are assembled by the CPU's `tasks::*_out`.
//! The kernel computes in f32: other precisions are refused by the caller.
//! Not on the GPU (refused by name): dense-grid media, the kick-drift and
//! implicit tiers, polyline dumps, Kerr deflection lists (their swept
//! azimuth is not accumulated by the kernel).

use super::grin::Medium;
use super::image::{render_with, ImageOut, ImageTask, Tracer};
use super::integrate::{End, Event, EventKind, Options, StepLaw, Tier, Trace};
use super::kerr::Kerr;
use super::kerr_trace::{kerr_events, KerrRay};
use super::metric::Spacetime;
use super::tasks::{
    deflection_out, deflection_setup, grin_out, grin_setup, observer_out, observer_setup,
    observer_start, Curved, Deflection, DeflectionOut, GrinOut, GrinRays, ObserverOut,
    ObserverScan, Task,
};
use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::gpu::transport::{
    GpuEvent, GpuEventKind, GpuLaw, GpuSystem, GpuTier, GpuTrace, TraceInput, TracePipeline,
};
use crate::gpu::GpuContext;
use crate::real::Real;

fn f<F: Real>(v: F) -> f32 {
    v.f64() as f32
}

fn spacetime<F: Real>(st: &Spacetime<F>) -> GpuSystem {
    match *st {
        Spacetime::Minkowski => GpuSystem::Minkowski,
        Spacetime::Schwarzschild { mass } => GpuSystem::Schwarzschild { mass: f(mass) },
        Spacetime::Ellis { b0 } => GpuSystem::Ellis { b0: f(b0) },
    }
}

fn medium<F: Real>(m: &Medium<F>) -> Result<GpuSystem> {
    Ok(match m {
        Medium::Luneburg { radius } => GpuSystem::Luneburg { radius: f(*radius) },
        Medium::LuneburgCore { radius } => GpuSystem::LuneburgCore { radius: f(*radius) },
        Medium::FishEye { n0, radius } => GpuSystem::FishEye {
            n0: f(*n0),
            radius: f(*radius),
        },
        Medium::Fibre { n0, alpha } => GpuSystem::Fibre {
            n0: f(*n0),
            alpha: f(*alpha),
        },
        Medium::Sech { n0, alpha } => GpuSystem::Sech {
            n0: f(*n0),
            alpha: f(*alpha),
        },
        Medium::Grid(_) => {
            return Err(Error::NotSupported(
                "the GPU transport kernel has no dense-grid media; use the CPU backend".into(),
            ))
        }
    })
}

fn law<F: Real>(l: &StepLaw<F>) -> GpuLaw {
    match *l {
        StepLaw::Fixed { h } => GpuLaw::Fixed { h: f(h) },
        StepLaw::Scaled { eta, h_min, h_max } => GpuLaw::Scaled {
            eta: f(eta),
            h_min: f(h_min),
            h_max: f(h_max),
        },
    }
}

fn tier<F: Real>(t: &Tier<F>) -> Result<GpuTier> {
    Ok(match t {
        Tier::Rk4(l) => GpuTier::Rk4(law(l)),
        Tier::Dopri5Fixed(l) => GpuTier::Dopri5Fixed(law(l)),
        Tier::Dopri5(c) => GpuTier::Dopri5 {
            rtol: f(c.rtol),
            eta: f(c.eta),
            atol: f(c.atol),
            h0: f(c.h0),
            h_min: f(c.h_min),
            h_max: f(c.h_max),
        },
        other => {
            return Err(Error::NotSupported(format!(
                "integrator `{}` has no GPU kernel (rk4, dopri5_fixed and dopri5 do)",
                other.name()
            )))
        }
    })
}

fn events<F: Real>(ev: &[Event<F>]) -> Result<Vec<GpuEvent>> {
    ev.iter()
        .map(|e| {
            Ok(GpuEvent {
                kind: match e.kind {
                    EventKind::Coord { index, value } => GpuEventKind::Coord {
                        index: index as u32,
                        value: f(value),
                    },
                    EventKind::Sphere { radius } => GpuEventKind::Sphere { radius: f(radius) },
                    EventKind::Approach { point } => GpuEventKind::Approach {
                        point: point.map(f),
                    },
                    EventKind::KsRadius { value, .. } => GpuEventKind::KsRadius { value: f(value) },
                },
                rising: e.rising,
            })
        })
        .collect()
}

fn max_steps(opt: &Options<impl Real>) -> Result<u32> {
    u32::try_from(opt.max_steps).map_err(|_| {
        Error::invalid(
            "max_steps",
            format!("{}: the GPU kernel counts steps in 32 bits", opt.max_steps),
        )
    })
}

fn no_dump(dump: &[usize]) -> Result<()> {
    if dump.is_empty() {
        Ok(())
    } else {
        Err(Error::NotSupported(
            "dump_rays: polylines are recorded on the CPU backend only".into(),
        ))
    }
}

/// `integrate::End` from its code (the kernel writes `End::code`).
fn end_of(code: i32) -> Result<End> {
    Ok(match code {
        c if c >= 0 => End::Event(c as usize),
        -1 => End::MaxSteps,
        -2 => End::NonFinite,
        -3 => End::StepUnderflow,
        c => return Err(Error::Gpu(format!("transport kernel wrote end code {c}"))),
    })
}

fn trace_of<F: Real, const N: usize>(g: &GpuTrace) -> Result<Trace<F, N>> {
    Ok(Trace {
        y: std::array::from_fn(|i| F::of(g.y[i] as f64)),
        lambda: F::of(g.lambda as f64),
        end: end_of(g.end)?,
        steps: g.steps as u64,
        rejected: g.rejected as u64,
        h_drift: F::of(g.h_drift as f64),
        err_est: F::of(g.err_est as f64),
    })
}

fn widen<F: Real, const N: usize>(y: &[F; N]) -> [f32; 8] {
    let mut o = [0.0f32; 8];
    for (a, b) in o.iter_mut().zip(y) {
        *a = f(*b);
    }
    o
}

/// Traces `starts` on the GPU; one [`Trace`] per start, input order.
fn run<F: Real, const N: usize>(
    ctx: &GpuContext,
    system: GpuSystem,
    opt: &Options<F>,
    ev: &[Event<F>],
    starts: &[[F; N]],
    budget: &MemBudget,
) -> Result<Vec<Trace<F, N>>> {
    let starts: Vec<[f32; 8]> = starts.iter().map(widen).collect();
    run_raw(ctx, system, opt, &events(ev)?, &starts, budget)?
        .iter()
        .map(trace_of)
        .collect()
}

/// Traces f32 `starts` on the GPU: the kernel's records, input order.
fn run_raw<F: Real>(
    ctx: &GpuContext,
    system: GpuSystem,
    opt: &Options<F>,
    ev: &[GpuEvent],
    starts: &[[f32; 8]],
    budget: &MemBudget,
) -> Result<Vec<GpuTrace>> {
    let tier = tier(&opt.tier)?;
    let input = TraceInput {
        system,
        tier,
        project: opt.project,
        max_steps: max_steps(opt)?,
        events: ev,
        starts,
    };
    Ok(TracePipeline::new(ctx, &system, &tier)?
        .run(ctx, &input, budget)?
        .0)
}

/// Builds the pipeline `task` will use (so a caller can keep its compile
/// out of a timing); refuses what the kernel cannot run.
pub fn warm<F: Real>(
    ctx: &GpuContext,
    task: &Task<F>,
    opt: &Options<F>,
    budget: &MemBudget,
) -> Result<()> {
    let (system, opt) = match task {
        Task::Curved(Curved::KerrDeflection(_)) => return Err(curved_not_supported()),
        Task::Curved(Curved::Image(ImageTask::Kerr(_))) => (
            GpuSystem::Kerr {
                mass: 1.0,
                a: 0.0,
                disk: None,
            },
            *opt,
        ),
        Task::Curved(Curved::Image(ImageTask::Ellis(e))) => {
            (GpuSystem::Ellis { b0: e.b0 as f32 }, *opt)
        }
        Task::Deflection(d) => (spacetime(&d.spacetime), *opt),
        Task::Observer(s) => (spacetime(&s.spacetime), *opt),
        Task::Grin(g) => {
            let s = grin_setup(g, opt, budget, &[])?;
            (medium(&s.medium)?, s.opt)
        }
    };
    TracePipeline::new(ctx, &system, &tier(&opt.tier)?)?;
    Ok(())
}

/// [`super::tasks::deflection`] on the GPU.
pub fn deflection<F: Real>(
    ctx: &GpuContext,
    task: &Deflection<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<DeflectionOut<F>> {
    no_dump(dump)?;
    let (ev, starts) = deflection_setup(task, opt, budget, dump)?;
    let traces = run(ctx, spacetime(&task.spacetime), opt, &ev, &starts, budget)?;
    Ok(deflection_out(
        task,
        traces.into_iter().map(|t| (t, Vec::new())).collect(),
        dump,
    ))
}

/// [`super::tasks::observer_scan`] on the GPU.
pub fn observer_scan<F: Real>(
    ctx: &GpuContext,
    scan: &ObserverScan<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<ObserverOut<F>> {
    no_dump(dump)?;
    let ev = observer_setup(scan, opt)?;
    let starts: Vec<[F; 8]> = scan
        .angles_deg
        .iter()
        .map(|&a| observer_start(scan, a))
        .collect();
    let traces = run(ctx, spacetime(&scan.spacetime), opt, &ev, &starts, budget)?;
    Ok(observer_out(
        traces.into_iter().map(|t| (t, Vec::new())).collect(),
        dump,
    ))
}

/// [`super::tasks::grin_rays`] on the GPU (rays that miss the lens are not
/// launched, as on the CPU).
pub fn grin_rays<F: Real>(
    ctx: &GpuContext,
    task: &GrinRays<F>,
    opt: &Options<F>,
    budget: &MemBudget,
    dump: &[usize],
) -> Result<GrinOut<F>> {
    no_dump(dump)?;
    let g = grin_setup(task, opt, budget, dump)?;
    let launched: Vec<[F; 6]> = g.starts.iter().flatten().copied().collect();
    let mut traces = run(
        ctx,
        medium(&g.medium)?,
        &g.opt,
        &g.events,
        &launched,
        budget,
    )?
    .into_iter();
    let all = g
        .starts
        .iter()
        .map(|s| s.and_then(|_| traces.next()).map(|t| (t, Vec::new())))
        .collect();
    Ok(grin_out(task, all, dump))
}

/// Image rays on the GPU: [`Tracer`] for `image::render_with`. Start
/// states arrive in f64 (the CPU observers') and are rounded once to f32,
/// as the CPU f32 run rounds them.
pub struct GpuTracer<'a> {
    pub ctx: &'a GpuContext,
    pub budget: &'a MemBudget,
}

fn rounded(starts: &[[f64; 8]]) -> Vec<[f32; 8]> {
    starts.iter().map(|s| s.map(|v| v as f32)).collect()
}

impl<F: Real> Tracer<F> for GpuTracer<'_> {
    /// `trace_kerr` on the GPU (events of `kerr_events`, plus `z` falling
    /// and rising for a disk); `sweep` is left 0 (images do not use it).
    fn kerr(
        &self,
        k: &Kerr<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        r_end: F,
        disk: Option<(F, F)>,
    ) -> Result<Vec<KerrRay<F>>> {
        let mut ev = events(&kerr_events(k, r_end))?;
        if disk.is_some() {
            let z = GpuEventKind::Coord {
                index: 3,
                value: 0.0,
            };
            ev.extend([false, true].map(|rising| GpuEvent { kind: z, rising }));
        }
        let system = GpuSystem::Kerr {
            mass: f(k.mass),
            a: f(k.a),
            disk: disk.map(|(a, b)| (f(a), f(b))),
        };
        let raw = run_raw(self.ctx, system, opt, &ev, &rounded(starts), self.budget)?;
        raw.iter()
            .map(|g| {
                let t: Trace<F, 8> = trace_of(g)?;
                let disk_r = match (t.end, disk) {
                    (End::Event(2 | 3), Some((r_in, r_out))) => {
                        Some(k.radius(&t.y)).filter(|r| *r >= r_in && *r <= r_out)
                    }
                    _ => None,
                };
                Ok(KerrRay {
                    y: t.y,
                    end: t.end,
                    steps: t.steps,
                    h_drift: t.h_drift,
                    err_est: t.err_est,
                    drift: g.drift.map(|d| F::of(d as f64)),
                    sweep: F::zero(),
                    disk_r,
                })
            })
            .collect()
    }

    fn spherical(
        &self,
        st: &Spacetime<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        ev: &[Event<F>],
    ) -> Result<Vec<Trace<F, 8>>> {
        run_raw(
            self.ctx,
            spacetime(st),
            opt,
            &events(ev)?,
            &rounded(starts),
            self.budget,
        )?
        .iter()
        .map(trace_of)
        .collect()
    }
}

/// [`super::image::render`] with the rays traced on the GPU.
pub fn render_image<F: Real>(
    ctx: &GpuContext,
    task: &ImageTask,
    opt: &Options<F>,
    budget: &MemBudget,
) -> Result<ImageOut<F>> {
    render_with(task, opt, budget, &GpuTracer { ctx, budget })
}

/// The refusal for Kerr deflection lists (the kernel does not accumulate
/// their swept azimuth; images run on the GPU).
pub fn curved_not_supported() -> Error {
    Error::NotSupported(
        "Kerr deflection lists have no GPU kernel (the swept azimuth is CPU-only); run them on the CPU".into(),
    )
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn end_codes_round_trip() {
        for e in [
            End::Event(0),
            End::Event(3),
            End::MaxSteps,
            End::NonFinite,
            End::StepUnderflow,
        ] {
            assert_eq!(end_of(e.code()).unwrap(), e);
        }
        assert!(end_of(-6).is_err());
    }

    #[test]
    fn tiers_without_a_kernel_are_refused_by_name() {
        let t = Tier::Verlet(StepLaw::Fixed { h: 0.1f64 });
        assert!(tier(&t).unwrap_err().to_string().contains("verlet"));
        assert!(tier(&Tier::Rk4(StepLaw::Fixed { h: 0.1f64 })).is_ok());
    }
}
