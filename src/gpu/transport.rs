//! Curved rays on the GPU: `kernels/transport.wgsl` entry `trace`, one
//! thread per ray, for GRIN media, static spherical spacetimes
//! (Minkowski, Schwarzschild, Ellis) and Kerr (Kerr–Schild, with the thin
//! equatorial disk and the `E`, `L_z`, `Q` certificate) with the RK4, fixed-step
//! Dormand–Prince 5 and adaptive Dormand–Prince 5(4) tiers, events located
//! as on the CPU.
//!
//! CPU twin: `src/transport/integrate.rs` `trace`; the inputs are the
//! kernel's own typed parameters ([`TraceInput`]), built by
//! `src/transport/gpu.rs` from the same start states the CPU traces (so
//! nothing here imports the renderer). Parity cases `trgpu_*` in
//! `TESTS/transport/manifest_gpu.yaml`; contract in `docs/transport_gpu.md`.
//! Float32 only.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline_with;
use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};

/// The Hamiltonian system a ray follows (kernel `SYS_*` codes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuSystem {
    Minkowski,
    Schwarzschild {
        mass: f32,
    },
    Ellis {
        b0: f32,
    },
    /// Kerr–Schild Kerr with spin `a`; `disk` = `(r_in, r_out)` makes
    /// crossings of `z = 0` inside the annulus end the ray (events 2, 3
    /// must then watch `z` falling and rising), others continue it.
    Kerr {
        mass: f32,
        a: f32,
        disk: Option<(f32, f32)>,
    },
    Luneburg {
        radius: f32,
    },
    LuneburgCore {
        radius: f32,
    },
    FishEye {
        n0: f32,
        radius: f32,
    },
    Fibre {
        n0: f32,
        alpha: f32,
    },
    Sech {
        n0: f32,
        alpha: f32,
    },
}

impl GpuSystem {
    /// Kernel code, parameters, and the phase-space dimension (6 GRIN, 8
    /// spacetimes).
    fn code(&self) -> (u32, [f32; 4], u32) {
        let two = |a, b| [a, b, 0.0, 0.0];
        match *self {
            GpuSystem::Minkowski => (0, [0.0; 4], 8),
            GpuSystem::Schwarzschild { mass } => (1, two(mass, 0.0), 8),
            GpuSystem::Ellis { b0 } => (2, two(b0, 0.0), 8),
            GpuSystem::Kerr { mass, a, disk } => {
                let (r_in, r_out) = disk.unwrap_or((0.0, 0.0));
                (3, [mass, a, r_in, r_out], 8)
            }
            GpuSystem::Luneburg { radius } => (10, two(radius, 0.0), 6),
            GpuSystem::LuneburgCore { radius } => (11, two(radius, 0.0), 6),
            GpuSystem::FishEye { n0, radius } => (12, two(n0, radius), 6),
            GpuSystem::Fibre { n0, alpha } => (13, two(n0, alpha), 6),
            GpuSystem::Sech { n0, alpha } => (14, two(n0, alpha), 6),
        }
    }
}

/// A fixed-step law: constant `h`, or `h = clamp(eta * scale, h_min, h_max)`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuLaw {
    Fixed { h: f32 },
    Scaled { eta: f32, h_min: f32, h_max: f32 },
}

/// The tiers the kernel runs.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuTier {
    Rk4(GpuLaw),
    Dopri5Fixed(GpuLaw),
    /// The CPU's controller (`integrate::Controller`), same fields.
    Dopri5 {
        rtol: f32,
        eta: f32,
        atol: f32,
        h0: f32,
        h_min: f32,
        h_max: f32,
    },
}

/// What `g` an event watches (`integrate::EventKind`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuEventKind {
    Coord {
        index: u32,
        value: f32,
    },
    Sphere {
        radius: f32,
    },
    Approach {
        point: [f32; 3],
    },
    /// The Boyer–Lindquist radius of a Kerr–Schild state (Kerr only).
    KsRadius {
        value: f32,
    },
}

#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuEvent {
    pub kind: GpuEventKind,
    pub rising: bool,
}

/// Everything one launch traces: every ray follows the same system, tier
/// and events from its own start state (8 floats; GRIN rays leave slots 6
/// and 7 at zero).
#[derive(Clone, Copy, Debug)]
pub struct TraceInput<'a> {
    pub system: GpuSystem,
    pub tier: GpuTier,
    pub project: bool,
    pub max_steps: u32,
    pub events: &'a [GpuEvent],
    pub starts: &'a [[f32; 8]],
}

/// Uniform of `kernels/transport.wgsl` (keep in sync with `struct Params`
/// there): 9 vec4<f32>, 12 u32, 3 vec4<u32>; 240 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct TraceParams {
    pub sys: [f32; 4],
    pub law: [f32; 4],
    pub ctl: [f32; 4],
    pub ctl2: [f32; 4],
    pub ev_val: [f32; 4],
    pub ev_pt: [[f32; 4]; 4],
    /// The system and tier codes (the kernel reads them as its pipeline's
    /// override constants `SYSTEM`, `TIER`; kept here for dumps).
    pub system: u32,
    pub tier: u32,
    pub law_kind: u32,
    pub project: u32,
    pub max_steps: u32,
    /// Step attempts (accepted + rejected) per ray and dispatch.
    pub chunk: u32,
    pub n: u32,
    pub n_dim: u32,
    pub n_events: u32,
    pub _pad: [u32; 3],
    pub ev_kind: [u32; 4],
    pub ev_index: [u32; 4],
    pub ev_rising: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<TraceParams>() == 240);

/// One ray's result (`struct TraceOut` of the kernel; 80 bytes): the CPU's
/// `integrate::Trace` in f32, and for Kerr the certificate of
/// `kerr_trace::KerrRay` (`drift` of `E`, `L_z`, `Q`).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuTrace {
    pub y: [f32; 8],
    pub lambda: f32,
    /// `integrate::End::code` (never the kernel's internal `END_RUNNING`).
    pub end: i32,
    pub steps: u32,
    pub rejected: u32,
    pub h_drift: f32,
    pub err_est: f32,
    pub drift: [f32; 3],
    pub _pad: [u32; 3],
}
const _: () = assert!(std::mem::size_of::<GpuTrace>() == 80);

/// A ray between dispatches (`struct RayState` of the kernel; 160 bytes).
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuRayState {
    pub trace: GpuTrace,
    pub k1: [f32; 8],
    pub gs: [f32; 4],
    /// Kerr: `(E, L_z, Q, 0)` of the start.
    pub c0: [f32; 4],
    pub h_ctl: f32,
    pub just_rejected: u32,
    /// 0 fresh, 1 running, 2 done.
    pub phase: u32,
    /// Kerr disk: crossings of `z = 0` outside the disk so far.
    pub crossings: u32,
}
const _: () = assert!(std::mem::size_of::<GpuRayState>() == 160);

const PHASE_DONE: u32 = 2;

/// Step attempts per ray and dispatch. Under a driver loop cap (llvmpipe:
/// 65535 back-edges per invocation, after which loops are cut and results
/// silently wrong) 1024: measured 3 back-edges per RK4 step, plus at most
/// 4 x 100 Illinois iterations at the end, so 20x margin. Elsewhere 8192,
/// which keeps one dispatch short of display watchdogs.
fn chunk(cap: Option<u64>) -> u32 {
    if cap.is_some() {
        1024
    } else {
        8192
    }
}

fn law(l: GpuLaw) -> (u32, [f32; 4]) {
    match l {
        GpuLaw::Fixed { h } => (0, [h, 0.0, 0.0, 0.0]),
        GpuLaw::Scaled { eta, h_min, h_max } => (1, [eta, h_min, h_max, 0.0]),
    }
}

impl TraceParams {
    /// The kernel's parameters for `v` (validated by [`validate`]), with
    /// `loop_cap` the driver's back-edge cap per invocation, if any.
    pub fn new(v: &TraceInput, loop_cap: Option<u64>) -> TraceParams {
        let mut p = TraceParams::zeroed();
        let (system, sys, n_dim) = v.system.code();
        (p.system, p.n_dim) = (system, n_dim);
        p.sys = sys;
        match v.tier {
            GpuTier::Rk4(l) | GpuTier::Dopri5Fixed(l) => (p.law_kind, p.law) = law(l),
            GpuTier::Dopri5 {
                rtol,
                eta,
                atol,
                h0,
                h_min,
                h_max,
            } => {
                p.ctl = [rtol, eta, atol, h0];
                p.ctl2 = [h_min, h_max, 0.0, 0.0];
            }
        }
        p.tier = tier_code(&v.tier);
        p.project = v.project as u32;
        p.max_steps = v.max_steps;
        p.chunk = chunk(loop_cap);
        p.n = v.starts.len() as u32;
        p.n_events = v.events.len() as u32;
        for (i, e) in v.events.iter().enumerate() {
            p.ev_rising[i] = e.rising as u32;
            match e.kind {
                GpuEventKind::Coord { index, value } => {
                    (p.ev_kind[i], p.ev_index[i], p.ev_val[i]) = (0, index, value)
                }
                GpuEventKind::Sphere { radius } => (p.ev_kind[i], p.ev_val[i]) = (1, radius),
                GpuEventKind::Approach { point } => {
                    p.ev_kind[i] = 2;
                    p.ev_pt[i] = [point[0], point[1], point[2], 0.0];
                }
                GpuEventKind::KsRadius { value } => (p.ev_kind[i], p.ev_val[i]) = (3, value),
            }
        }
        p
    }
}

/// Checks what the kernel assumes: at most 4 events, coordinate events on
/// a slot of the state, finite positive steps, fewer than 2^32 rays.
fn validate(v: &TraceInput) -> Result<()> {
    let at = "gpu transport input";
    let (_, _, n_dim) = v.system.code();
    if v.events.len() > 4 {
        return Err(Error::invalid(
            at,
            format!("{} events, at most 4", v.events.len()),
        ));
    }
    if v.events
        .iter()
        .any(|e| matches!(e.kind, GpuEventKind::Coord { index, .. } if index >= n_dim))
    {
        return Err(Error::invalid(
            at,
            "a coordinate event watches a slot past the state",
        ));
    }
    let kerr = matches!(v.system, GpuSystem::Kerr { .. });
    if v.events
        .iter()
        .any(|e| matches!(e.kind, GpuEventKind::KsRadius { .. }) && !kerr)
    {
        return Err(Error::invalid(
            at,
            "a Kerr-Schild radius event outside Kerr",
        ));
    }
    if let GpuSystem::Kerr {
        disk: Some((r_in, r_out)),
        ..
    } = v.system
    {
        let z_events = v.events.len() == 4
            && v.events[2..].iter().zip([false, true]).all(|(e, rising)| {
                e.rising == rising
                    && e.kind
                        == GpuEventKind::Coord {
                            index: 3,
                            value: 0.0,
                        }
            });
        if !(r_in > 0.0 && r_out > r_in && z_events) {
            return Err(Error::invalid(
                at,
                "a Kerr disk needs 0 < r_in < r_out and events 2, 3 on z = 0 falling, rising",
            ));
        }
    }
    let law_ok = |l: GpuLaw| match l {
        GpuLaw::Fixed { h } => h > 0.0 && h.is_finite(),
        GpuLaw::Scaled { eta, h_min, h_max } => {
            eta > 0.0 && h_min > 0.0 && h_max >= h_min && h_max.is_finite()
        }
    };
    let ok = match v.tier {
        GpuTier::Rk4(l) | GpuTier::Dopri5Fixed(l) => law_ok(l),
        GpuTier::Dopri5 {
            rtol,
            eta,
            atol,
            h0,
            h_min,
            h_max,
        } => {
            rtol >= 0.0
                && atol >= 0.0
                && rtol + atol > 0.0
                && eta > 0.0
                && h0 > 0.0
                && h_min > 0.0
                && h_max >= h_min
                && h_max.is_finite()
        }
    };
    if !ok {
        return Err(Error::invalid(
            at,
            format!(
                "{:?}: steps and tolerances must be positive and finite in f32",
                v.tier
            ),
        ));
    }
    if u32::try_from(v.starts.len()).is_err() {
        return Err(Error::invalid(at, "more than 2^32 rays"));
    }
    Ok(())
}

fn tier_code(t: &GpuTier) -> u32 {
    match t {
        GpuTier::Rk4(_) => 0,
        GpuTier::Dopri5Fixed(_) => 1,
        GpuTier::Dopri5 { .. } => 2,
    }
}

/// The `trace` pipeline specialised for one system and tier (override
/// constants `SYSTEM`, `TIER`; built once per process by the registry).
pub struct TracePipeline {
    pipe: wgpu::ComputePipeline,
    system: u32,
    tier: u32,
}

impl TracePipeline {
    pub fn new(ctx: &GpuContext, system: &GpuSystem, tier: &GpuTier) -> Result<TracePipeline> {
        let (system, tier) = (system.code().0, tier_code(tier));
        let constants = [("SYSTEM", system as f64), ("TIER", tier as f64)];
        Ok(TracePipeline {
            pipe: pipeline_with(ctx, "transport", "trace", &constants)?,
            system,
            tier,
        })
    }

    /// Traces every start of `v`: one [`GpuTrace`] per ray in input order,
    /// and the seconds the dispatches and readbacks took. Rays advance
    /// `chunk` step attempts per dispatch (see [`chunk`]), dispatched
    /// until every ray is done.
    pub fn run(
        &self,
        ctx: &GpuContext,
        v: &TraceInput,
        budget: &MemBudget,
    ) -> Result<(Vec<GpuTrace>, f64)> {
        validate(v)?;
        let p = TraceParams::new(v, ctx.max_loop_iterations());
        if (p.system, p.tier) != (self.system, self.tier) {
            return Err(Error::invalid(
                "gpu transport input",
                format!(
                    "system {} / tier {} given to the pipeline built for {} / {}",
                    p.system, p.tier, self.system, self.tier
                ),
            ));
        }
        let n = v.starts.len() as u64;
        let bytes = n * std::mem::size_of::<GpuRayState>() as u64;
        // The state buffer, its upload copy and one readback.
        let per = std::mem::size_of::<GpuRayState>() as u64;
        budget.check("gpu transport rays", bytes_for(n, 3 * per))?;
        let u = uniform(ctx, "trace params", &p);
        let init: Vec<GpuRayState> = v
            .starts
            .iter()
            .map(|y| GpuRayState {
                trace: GpuTrace {
                    y: *y,
                    ..GpuTrace::default()
                },
                ..GpuRayState::default()
            })
            .collect();
        let rays = storage_out(ctx, "trace rays", bytes)?;
        ctx.queue
            .write_buffer(&rays, 0, bytemuck::cast_slice(&init));
        let pass = Pass {
            label: "trace",
            pipeline: &self.pipe,
            buffers: &[(0, &u), (1, &rays)],
            n,
            wg: 64,
        };
        // Every dispatch advances each undecided ray by `chunk` attempts and
        // rejections shrink the step until it underflows, so this ends; the
        // bound only guards against a kernel that stops making progress.
        let rounds = (v.max_steps as u64 / p.chunk as u64 + 2) * 64;
        let mut gpu_s = 0.0;
        for _ in 0..rounds {
            let rb = run(
                ctx,
                "transport trace",
                std::slice::from_ref(&pass),
                &[&rays],
            )?;
            gpu_s += rb.gpu_s;
            let st: Vec<GpuRayState> = rb.take(0, n as usize)?;
            if st.iter().all(|s| s.phase == PHASE_DONE) {
                return Ok((st.into_iter().map(|s| s.trace).collect(), gpu_s));
            }
        }
        Err(Error::Gpu(format!(
            "transport trace: rays still undecided after {rounds} dispatches of {} attempts",
            p.chunk
        )))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn params_carry_events_and_tier_in_kernel_slots() {
        let ev = [
            GpuEvent {
                kind: GpuEventKind::Coord {
                    index: 1,
                    value: 1000.0,
                },
                rising: true,
            },
            GpuEvent {
                kind: GpuEventKind::Approach {
                    point: [-2.0, 0.5, 0.0],
                },
                rising: false,
            },
        ];
        let starts = [[0.0f32; 8]; 3];
        let v = TraceInput {
            system: GpuSystem::Fibre {
                n0: 1.5,
                alpha: 0.5,
            },
            tier: GpuTier::Rk4(GpuLaw::Fixed { h: 0.01 }),
            project: false,
            max_steps: 7,
            events: &ev,
            starts: &starts,
        };
        let p = TraceParams::new(&v, Some(65_535));
        assert_eq!((p.system, p.n_dim, p.n, p.n_events), (13, 6, 3, 2));
        assert_eq!(p.chunk, 1024);
        assert_eq!(TraceParams::new(&v, None).chunk, 8192);
        assert_eq!(
            (p.ev_kind, p.ev_index, p.ev_rising),
            ([0, 2, 0, 0], [1, 0, 0, 0], [1, 0, 0, 0])
        );
        assert_eq!((p.ev_val[0], p.ev_pt[1]), (1000.0, [-2.0, 0.5, 0.0, 0.0]));
        assert_eq!((p.law_kind, p.law[0], p.max_steps), (0, 0.01, 7));
        assert!(validate(&v).is_ok());
        let bad = TraceInput {
            tier: GpuTier::Rk4(GpuLaw::Fixed { h: -1.0 }),
            ..v
        };
        assert!(validate(&bad).is_err());
        let far = [GpuEvent {
            kind: GpuEventKind::Coord {
                index: 7,
                value: 0.0,
            },
            rising: true,
        }];
        assert!(validate(&TraceInput { events: &far, ..v }).is_err());
    }
}
