//! Images of curved spacetimes (SCENES.md `kerr_shadow`, `kerr_disk`,
//! `ellis_wormhole`), one backward ray per pixel, each traced
//! independently (`parallel::par_collect`: results never depend on the
//! thread count), each with its accuracy certificate.
//!
//! Per pixel (row 0 at the top): `captured` (1 where the ray crossed the
//! horizon), `final_dir` (unit Cartesian direction of motion where an
//! escaping ray reached `r_end`, (0, 0, 0) otherwise), `h_drift`
//! (`max |H|`), `e_drift`, `l_drift`, `q_drift` (`max |X - X0| / max(|X0|, 1)`
//! for `E`, `L_z`, Carter `Q`; Kerr only: Ellis rays keep `E` and `L`
//! exactly, they are cyclic momenta the integrator never changes),
//! `err_est` (sum of the embedded DP45 local error estimates; 0 for tiers
//! without one), `steps`, `reason` ([`End::code`]), and the shaded
//! `image` (linear RGB). Disk images add `disk_r` (Boyer–Lindquist radius
//! where the ray met the disk, 0 elsewhere) and `redshift` (`g`, 0 off
//! the disk); Ellis images add `side` (+1 the camera's side, -1 the other
//! universe, 0 undecided).

use super::disk::{checker, disk_colour, isco_numeric, redshift};
use super::integrate::{check, trace, End, Event, EventKind, Options, Trace};
use super::kerr::{kerr_rhs, Kerr};
use super::kerr_trace::{kerr_events, trace_kerr, KerrRay};
use super::metric::Spacetime;
use super::observer::{image_plane, planar_split, reversed, DistantObserver, LocalObserver};
use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::parallel::par_collect;
use crate::real::Real;

/// Where a Kerr image's rays start.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Observer {
    /// Bardeen's image plane over `[-half, half]^2` (units of M).
    Distant { obs: DistantObserver, half: f64 },
    /// A pinhole camera at finite distance.
    Local(LocalObserver),
}

/// Which pixels a Kerr image traces.
#[derive(Clone, Debug, PartialEq)]
pub enum Pixels {
    Grid {
        width: usize,
        height: usize,
    },
    /// Explicit image-plane points `(alpha, beta)` (distant observer only):
    /// hard-ray lists.
    List(Vec<[f64; 2]>),
}

/// A Kerr image (`kerr_shadow`, `kerr_disk`, hard-ray lists).
#[derive(Clone, Debug, PartialEq)]
pub struct KerrImage {
    /// The physical spacetime (spin as in the scene).
    pub kerr: Kerr<f64>,
    pub observer: Observer,
    pub pixels: Pixels,
    pub r_end: f64,
    /// Outer disk radius; the disk runs from the prograde ISCO.
    pub disk_r_out: Option<f64>,
    pub cell_deg: f64,
}

/// The Ellis wormhole seen by a static camera at `l_cam` on the +x axis
/// looking at the throat, up +z.
#[derive(Clone, Debug, PartialEq)]
pub struct EllisImage {
    pub b0: f64,
    pub l_cam: f64,
    pub fov_deg: f64,
    pub width: usize,
    pub height: usize,
    pub r_end: f64,
    pub cell_deg: f64,
}

/// An image task (closed set).
#[derive(Clone, Debug, PartialEq)]
pub enum ImageTask {
    Kerr(KerrImage),
    Ellis(EllisImage),
}

/// Per-pixel results (see the module doc), flattened row-major.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct ImageOut<F> {
    /// `[height, width]`, or `[n]` for a ray list.
    pub shape: Vec<usize>,
    pub captured: Vec<u8>,
    pub final_dir: Vec<[F; 3]>,
    pub h_drift: Vec<F>,
    pub e_drift: Vec<F>,
    pub l_drift: Vec<F>,
    pub q_drift: Vec<F>,
    pub err_est: Vec<F>,
    pub steps: Vec<i32>,
    pub reason: Vec<i32>,
    pub image: Vec<[F; 3]>,
    pub disk_r: Vec<F>,
    pub redshift: Vec<F>,
    pub side: Vec<i32>,
    /// The disk's inner radius used (the numeric ISCO), when there is a disk.
    pub disk_r_in: Option<f64>,
}

impl ImageTask {
    /// Number of rays.
    pub fn rays(&self) -> usize {
        match self {
            ImageTask::Kerr(k) => match &k.pixels {
                Pixels::Grid { width, height } => width * height,
                Pixels::List(l) => l.len(),
            },
            ImageTask::Ellis(e) => e.width * e.height,
        }
    }
}

fn sky_colour(d: [f64; 3], cell: f64, side: i32) -> [f64; 3] {
    let c = checker(d, cell);
    match (side, c) {
        (1, 0) => [0.08, 0.2, 0.6],
        (1, _) => [0.85, 0.9, 1.0],
        (_, 0) => [0.45, 0.08, 0.02],
        (_, _) => [1.0, 0.7, 0.2],
    }
}

fn unit(v: [f64; 3]) -> [f64; 3] {
    let n = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
    if n > 0.0 {
        [v[0] / n, v[1] / n, v[2] / n]
    } else {
        [0.0; 3]
    }
}

fn grid_ok(w: usize, h: usize, budget: &MemBudget) -> Result<()> {
    if w == 0 || h == 0 || w > 1 << 14 || h > 1 << 14 {
        return Err(Error::invalid(
            "width/height",
            format!("{w} x {h}: each in 1..=16384"),
        ));
    }
    budget.check("image rays", bytes_for((w * h) as u64, 160))
}

/// Traces an image's rays from their f64 start states: the CPU fan-out
/// ([`CpuTracer`]) or the GPU kernel (`super::gpu::GpuTracer`, issue 17).
/// Kerr rays follow `trace_kerr` in `k` (the reversed spacetime);
/// spherical rays `trace` in `st` with `ev`.
pub trait Tracer<F: Real> {
    fn kerr(
        &self,
        k: &Kerr<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        r_end: F,
        disk: Option<(F, F)>,
    ) -> Result<Vec<KerrRay<F>>>;
    fn spherical(
        &self,
        st: &Spacetime<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        ev: &[Event<F>],
    ) -> Result<Vec<Trace<F, 8>>>;
}

/// The CPU fan-out (`parallel::par_collect`, one ray per item).
pub struct CpuTracer;

impl<F: Real> Tracer<F> for CpuTracer {
    fn kerr(
        &self,
        k: &Kerr<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        r_end: F,
        disk: Option<(F, F)>,
    ) -> Result<Vec<KerrRay<F>>> {
        Ok(par_collect("transport.kerr_image", starts.len(), |i| {
            trace_kerr(k, starts[i].map(F::of), opt, r_end, disk)
        }))
    }

    fn spherical(
        &self,
        st: &Spacetime<F>,
        starts: &[[f64; 8]],
        opt: &Options<F>,
        ev: &[Event<F>],
    ) -> Result<Vec<Trace<F, 8>>> {
        Ok(par_collect("transport.ellis_image", starts.len(), |i| {
            trace(st, starts[i].map(F::of), opt, ev, |_, _| {})
        }))
    }
}

/// Renders `task` in precision `F`.
pub fn render<F: Real>(
    task: &ImageTask,
    opt: &Options<F>,
    budget: &MemBudget,
) -> Result<ImageOut<F>> {
    render_with(task, opt, budget, &CpuTracer)
}

/// Renders `task` with its rays traced by `tr` (same outputs).
pub fn render_with<F: Real>(
    task: &ImageTask,
    opt: &Options<F>,
    budget: &MemBudget,
    tr: &impl Tracer<F>,
) -> Result<ImageOut<F>> {
    match task {
        ImageTask::Kerr(k) => kerr_image(k, opt, budget, tr),
        ImageTask::Ellis(e) => ellis_image(e, opt, budget, tr),
    }
}

fn kerr_image<F: Real>(
    t: &KerrImage,
    opt: &Options<F>,
    budget: &MemBudget,
    tr: &impl Tracer<F>,
) -> Result<ImageOut<F>> {
    let k = t.kerr;
    if !(k.mass > 0.0 && k.a.abs() < k.mass && k.mass.is_finite()) {
        return Err(Error::invalid(
            "task.a",
            format!("need M > 0 and |a| < M (a = {})", k.a),
        ));
    }
    let (shape, n) = match &t.pixels {
        Pixels::Grid { width, height } => {
            grid_ok(*width, *height, budget)?;
            (vec![*height, *width], width * height)
        }
        Pixels::List(l) => {
            if !matches!(t.observer, Observer::Distant { .. }) {
                return Err(Error::invalid(
                    "task.rays",
                    "ray lists need the distant observer",
                ));
            }
            (vec![l.len()], l.len())
        }
    };
    match t.observer {
        Observer::Distant { obs, half } => {
            obs.validate(&k)?;
            if !(half > 0.0 && half.is_finite()) {
                return Err(Error::invalid("task.half_width", "must be > 0"));
            }
            if !(t.r_end >= obs.r_obs) {
                return Err(Error::invalid("task.r_end", "must be >= r_obs"));
            }
        }
        Observer::Local(o) => {
            o.validate(&k)?;
            if !(t.r_end > o.r) {
                return Err(Error::invalid("task.r_end", "must exceed the camera's r"));
            }
        }
    }
    let kr = reversed(k);
    let kf = Kerr {
        mass: F::of(kr.mass),
        a: F::of(kr.a),
    };
    check::<F, 8, Kerr<F>>(opt, &kerr_events(&kf, F::of(t.r_end)))?;
    let r_in = t.disk_r_out.map(|_| isco_numeric(k.mass, k.a.abs()));
    if let (Some(ri), Some(ro)) = (r_in, t.disk_r_out) {
        if !(ro > ri) {
            return Err(Error::invalid(
                "task.disk.r_out",
                format!("{ro}: must exceed the ISCO {ri}"),
            ));
        }
    }
    let disk = r_in.zip(t.disk_r_out).map(|(a, b)| (F::of(a), F::of(b)));
    let launch = |i: usize| -> Result<[f64; 8]> {
        match (&t.observer, &t.pixels) {
            (Observer::Distant { obs, half }, Pixels::Grid { width, height }) => {
                let (al, be) = image_plane(i % width, i / width, *width, *height, *half, *half);
                obs.launch(&k, al, be)
            }
            (Observer::Distant { obs, .. }, Pixels::List(l)) => obs.launch(&k, l[i][0], l[i][1]),
            (Observer::Local(o), Pixels::Grid { width, height }) => {
                Ok(o.launch(&k, i % width, i / width, *width, *height))
            }
            (Observer::Local(_), Pixels::List(_)) => {
                Err(Error::invalid("task.rays", "unreachable"))
            }
        }
    };
    let starts: Vec<[f64; 8]> = (0..n).map(launch).collect::<Result<_>>()?;
    let rays = tr.kerr(&kf, &starts, opt, F::of(t.r_end), disk)?;
    let mut out = ImageOut {
        shape,
        disk_r_in: r_in,
        ..Default::default()
    };
    for (i, r) in rays.iter().enumerate() {
        let captured = r.end == End::Event(1);
        let escaped = r.end == End::Event(0);
        let dir = if escaped {
            let d = kerr_rhs(kf.mass, kf.a, &r.y);
            unit([d[1].f64(), d[2].f64(), d[3].f64()])
        } else {
            [0.0; 3]
        };
        let mut g = 0.0;
        let mut rgb = if escaped {
            sky_colour(dir, t.cell_deg, 1).map(|c| 0.35 * c)
        } else {
            [0.0; 3]
        };
        if let (Some(dr), Some(ri)) = (r.disk_r, r_in) {
            // The physical photon's L_z is minus the backward ray's.
            let xi = -starts[i][1] * starts[i][6] + starts[i][2] * starts[i][5];
            // Matter orbits prograde: with a < 0 that is towards -phi.
            let s = if k.a < 0.0 { -1.0 } else { 1.0 };
            g = redshift(k.mass, k.a.abs(), dr.f64(), s * xi);
            rgb = disk_colour(dr.f64(), ri, g);
        }
        out.captured.push(captured as u8);
        out.final_dir.push(dir.map(F::of));
        out.h_drift.push(r.h_drift);
        out.e_drift.push(r.drift[0]);
        out.l_drift.push(r.drift[1]);
        out.q_drift.push(r.drift[2]);
        out.err_est.push(r.err_est);
        out.steps.push(i32::try_from(r.steps).unwrap_or(i32::MAX));
        out.reason.push(r.end.code());
        out.image.push(rgb.map(F::of));
        if disk.is_some() {
            out.disk_r.push(r.disk_r.unwrap_or(F::zero()));
            out.redshift.push(F::of(g));
        }
    }
    Ok(out)
}

fn ellis_image<F: Real>(
    t: &EllisImage,
    opt: &Options<F>,
    budget: &MemBudget,
    tr: &impl Tracer<F>,
) -> Result<ImageOut<F>> {
    grid_ok(t.width, t.height, budget)?;
    if !(t.b0 > 0.0
        && t.l_cam.is_finite()
        && t.r_end > t.l_cam.abs()
        && t.fov_deg > 0.0
        && t.fov_deg < 180.0)
    {
        return Err(Error::invalid(
            "task",
            "ellis_image needs b0 > 0, |l_cam| < r_end, fov_deg in (0, 180)",
        ));
    }
    let st = Spacetime::Ellis { b0: F::of(t.b0) };
    let ev = [
        Event {
            kind: EventKind::Coord {
                index: 1,
                value: F::of(t.r_end),
            },
            rising: true,
        },
        Event {
            kind: EventKind::Coord {
                index: 1,
                value: F::of(-t.r_end),
            },
            rising: false,
        },
    ];
    check::<F, 8, Spacetime<F>>(opt, &ev)?;
    let (w, h) = (t.width, t.height);
    let f = (h as f64 / 2.0) / (t.fov_deg.to_radians() / 2.0).tan();
    let st64 = Spacetime::Ellis { b0: t.b0 };
    let setup = par_collect("transport.ellis_image", w * h, |i| {
        let (u, v) = (i % w, i / w);
        let x = (u as f64 + 0.5 - w as f64 / 2.0) / f;
        let y = -(v as f64 + 0.5 - h as f64 / 2.0) / f;
        // World: forward -x, right +y, up +z.
        let d = unit([-1.0, x, y]);
        let (psi, tv) = planar_split(d);
        let p = st64.static_observer_momentum(t.l_cam, psi);
        let y0 = [
            0.0,
            t.l_cam,
            std::f64::consts::FRAC_PI_2,
            0.0,
            p[0],
            p[1],
            p[2],
            p[3],
        ];
        (y0, tv)
    });
    let starts: Vec<[f64; 8]> = setup.iter().map(|s| s.0).collect();
    let traces = tr.spherical(&st, &starts, opt, &ev)?;
    let rays: Vec<_> = traces.into_iter().zip(setup.iter().map(|s| s.1)).collect();
    let mut out = ImageOut {
        shape: vec![h, w],
        ..Default::default()
    };
    for (tr, tv) in &rays {
        let side = match tr.end {
            End::Event(0) => 1,
            End::Event(1) => -1,
            _ => 0,
        };
        let (l, ph) = (tr.y[1].f64(), tr.y[3].f64());
        let dir = if side != 0 {
            // Direction of motion in the orbital plane, from the outward radial.
            let r2 = t.b0 * t.b0 + l * l;
            let (vl, vph) = (tr.y[5].f64() * side as f64, tr.y[7].f64() / r2.sqrt());
            let ang = ph + vph.atan2(vl);
            unit([ang.cos(), ang.sin() * tv[1], ang.sin() * tv[2]])
        } else {
            [0.0; 3]
        };
        out.captured.push(0);
        out.final_dir.push(dir.map(F::of));
        out.h_drift.push(tr.h_drift);
        out.err_est.push(tr.err_est);
        out.steps.push(i32::try_from(tr.steps).unwrap_or(i32::MAX));
        out.reason.push(tr.end.code());
        out.side.push(side);
        let rgb = if side == 0 {
            [0.0; 3]
        } else {
            sky_colour(dir, t.cell_deg, side)
        };
        out.image.push(rgb.map(F::of));
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::transport::integrate::{Controller, Tier};

    fn dp45(rtol: f64) -> Options<f64> {
        Options {
            tier: Tier::Dopri5(Controller {
                rtol,
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

    #[test]
    fn schwarzschild_shadow_is_the_disk_of_radius_3_sqrt_3() {
        let task = ImageTask::Kerr(KerrImage {
            kerr: Kerr {
                mass: 1.0,
                a: 1e-12,
            },
            observer: Observer::Distant {
                obs: DistantObserver {
                    r_obs: 1000.0,
                    theta_o: 1.0,
                },
                half: 8.0,
            },
            pixels: Pixels::Grid {
                width: 24,
                height: 24,
            },
            r_end: 1000.0,
            disk_r_out: None,
            cell_deg: 10.0,
        });
        let out = render(&task, &dp45(1e-10), &MemBudget::fixed(1 << 30)).unwrap();
        let px = 16.0 / 24.0;
        for (i, &c) in out.captured.iter().enumerate() {
            let (x, y) = image_plane(i % 24, i / 24, 24, 24, 8.0, 8.0);
            let d = (x * x + y * y).sqrt() - 27f64.sqrt();
            if d.abs() > px {
                assert_eq!(c, (d < 0.0) as u8, "pixel {i} at {d}");
            }
        }
    }

    #[test]
    fn ellis_image_is_mirror_symmetric_and_sees_both_sides() {
        let task = ImageTask::Ellis(EllisImage {
            b0: 1.0,
            l_cam: 6.0,
            fov_deg: 60.0,
            width: 16,
            height: 16,
            r_end: 1000.0,
            cell_deg: 10.0,
        });
        let out = render(&task, &dp45(1e-10), &MemBudget::fixed(1 << 30)).unwrap();
        assert!(out.side.contains(&1) && out.side.contains(&-1));
        for v in 0..16 {
            for u in 0..16 {
                let (a, b) = (out.image[v * 16 + u], out.image[v * 16 + 15 - u]);
                assert_eq!(a, b, "({u}, {v})");
            }
        }
    }
}
