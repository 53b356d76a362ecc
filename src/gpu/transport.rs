//! Curved rays on the GPU: `kernels/transport.wgsl` entry `trace`, one
//! thread per ray, for GRIN media and static spherical spacetimes
//! (Minkowski, Schwarzschild, Ellis) with the RK4, fixed-step
//! Dormand–Prince 5 and adaptive Dormand–Prince 5(4) tiers, events located
//! as on the CPU.
//!
//! CPU twin: `src/transport/integrate.rs` `trace`; the inputs are the
//! kernel's own typed parameters ([`TraceInput`]), built by
//! `src/transport/gpu.rs` from the same start states the CPU traces (so
//! nothing here imports the renderer). Parity cases `trgpu_*` in
//! `TESTS/transport/gpu.yaml`; contract in `docs/transport_gpu.md`.
//! Float32 only.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};

/// The Hamiltonian system a ray follows (kernel `SYS_*` codes).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum GpuSystem {
    Minkowski,
    Schwarzschild { mass: f32 },
    Ellis { b0: f32 },
    Luneburg { radius: f32 },
    LuneburgCore { radius: f32 },
    FishEye { n0: f32, radius: f32 },
    Fibre { n0: f32, alpha: f32 },
    Sech { n0: f32, alpha: f32 },
}

impl GpuSystem {
    /// Kernel code, parameters, and the phase-space dimension (6 GRIN, 8
    /// spacetimes).
    fn code(&self) -> (u32, [f32; 2], u32) {
        match *self {
            GpuSystem::Minkowski => (0, [0.0; 2], 8),
            GpuSystem::Schwarzschild { mass } => (1, [mass, 0.0], 8),
            GpuSystem::Ellis { b0 } => (2, [b0, 0.0], 8),
            GpuSystem::Luneburg { radius } => (10, [radius, 0.0], 6),
            GpuSystem::LuneburgCore { radius } => (11, [radius, 0.0], 6),
            GpuSystem::FishEye { n0, radius } => (12, [n0, radius], 6),
            GpuSystem::Fibre { n0, alpha } => (13, [n0, alpha], 6),
            GpuSystem::Sech { n0, alpha } => (14, [n0, alpha], 6),
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
    Coord { index: u32, value: f32 },
    Sphere { radius: f32 },
    Approach { point: [f32; 3] },
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
/// there): 9 vec4<f32>, 8 u32, 3 vec4<u32>; 224 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct TraceParams {
    pub sys: [f32; 4],
    pub law: [f32; 4],
    pub ctl: [f32; 4],
    pub ctl2: [f32; 4],
    pub ev_val: [f32; 4],
    pub ev_pt: [[f32; 4]; 4],
    pub system: u32,
    pub tier: u32,
    pub law_kind: u32,
    pub project: u32,
    pub max_steps: u32,
    pub n: u32,
    pub n_dim: u32,
    pub n_events: u32,
    pub ev_kind: [u32; 4],
    pub ev_index: [u32; 4],
    pub ev_rising: [u32; 4],
}
const _: () = assert!(std::mem::size_of::<TraceParams>() == 224);

/// One ray's result (`struct TraceOut` of the kernel; 64 bytes): the CPU's
/// `integrate::Trace` in f32.
#[repr(C)]
#[derive(Clone, Copy, Debug, Default, PartialEq, Pod, Zeroable)]
pub struct GpuTrace {
    pub y: [f32; 8],
    pub lambda: f32,
    /// `integrate::End::code` (never the kernel's internal `END_CUT`).
    pub end: i32,
    pub steps: u32,
    pub rejected: u32,
    pub h_drift: f32,
    pub err_est: f32,
    pub _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<GpuTrace>() == 64);

/// Kernel code of a ray cut short by a driver loop cap.
const END_CUT: i32 = -6;

fn law(l: GpuLaw) -> (u32, [f32; 4]) {
    match l {
        GpuLaw::Fixed { h } => (0, [h, 0.0, 0.0, 0.0]),
        GpuLaw::Scaled { eta, h_min, h_max } => (1, [eta, h_min, h_max, 0.0]),
    }
}

impl TraceParams {
    /// The kernel's parameters for `v` (validated by [`validate`]).
    pub fn new(v: &TraceInput) -> TraceParams {
        let mut p = TraceParams::zeroed();
        let (system, sys, n_dim) = v.system.code();
        (p.system, p.n_dim) = (system, n_dim);
        p.sys = [sys[0], sys[1], 0.0, 0.0];
        match v.tier {
            GpuTier::Rk4(l) => (p.tier, (p.law_kind, p.law)) = (0, law(l)),
            GpuTier::Dopri5Fixed(l) => (p.tier, (p.law_kind, p.law)) = (1, law(l)),
            GpuTier::Dopri5 {
                rtol,
                eta,
                atol,
                h0,
                h_min,
                h_max,
            } => {
                p.tier = 2;
                p.ctl = [rtol, eta, atol, h0];
                p.ctl2 = [h_min, h_max, 0.0, 0.0];
            }
        }
        p.project = v.project as u32;
        p.max_steps = v.max_steps;
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

/// The `trace` pipeline (built once per process by the registry).
pub struct TracePipeline {
    pipe: wgpu::ComputePipeline,
}

impl TracePipeline {
    pub fn new(ctx: &GpuContext) -> Result<TracePipeline> {
        Ok(TracePipeline {
            pipe: pipeline(ctx, "transport", "trace")?,
        })
    }

    /// Traces every start of `v`: one [`GpuTrace`] per ray in input order,
    /// and the seconds the kernel and readback took. A ray that a driver's
    /// loop cap stopped before it ended is an error naming the ray, never
    /// a silently short result.
    pub fn run(
        &self,
        ctx: &GpuContext,
        v: &TraceInput,
        budget: &MemBudget,
    ) -> Result<(Vec<GpuTrace>, f64)> {
        validate(v)?;
        let n = v.starts.len() as u64;
        let out_bytes = n * std::mem::size_of::<GpuTrace>() as u64;
        // Upload copy, result buffer and its readback.
        budget.check("gpu transport rays", bytes_for(n, 32 + 2 * 64))?;
        let u = uniform(ctx, "trace params", &TraceParams::new(v));
        let s = storage_in(ctx, "trace starts", v.starts)?;
        let o = storage_out(ctx, "trace results", out_bytes)?;
        let pass = Pass {
            label: "trace",
            pipeline: &self.pipe,
            buffers: &[(0, &u), (1, &s), (2, &o)],
            n,
            wg: 64,
        };
        let rb = run(ctx, "transport trace", &[pass], &[&o])?;
        let traces: Vec<GpuTrace> = rb.take(0, n as usize)?;
        if let Some((i, t)) = traces.iter().enumerate().find(|(_, t)| t.end == END_CUT) {
            let cap = ctx
                .max_loop_iterations()
                .map_or("its loop cap".to_string(), |c| {
                    format!("its loop cap ({c} iterations per invocation)")
                });
            return Err(Error::NotSupported(format!(
                "ray {i} was cut after {} steps by this driver's {cap}; trace fewer steps per ray \
                 (a coarser step law) or use the CPU backend",
                t.steps
            )));
        }
        Ok((traces, rb.gpu_s))
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
        let p = TraceParams::new(&v);
        assert_eq!((p.system, p.n_dim, p.n, p.n_events), (13, 6, 3, 2));
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
