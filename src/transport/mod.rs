//! Curved-ray transport (seed 002): one Hamiltonian core for gradient-index
//! optics and null geodesics, with tiered integrators.
//!
//! - [`hamiltonian`]: the interface (`H`, Hamilton's equations, step scale,
//!   constraint projection) on stack-array states `y = (x, p)`.
//! - [`grin`]: GRIN media (Luneburg, Maxwell fish-eye, parabolic fibre,
//!   sech, dense grid), `H = (|p|^2 - n^2) / 2`.
//! - [`metric`]: spacetimes (Minkowski, Schwarzschild, Ellis wormhole),
//!   `H = g^{mu nu} p_mu p_nu / 2`.
//! - [`kerr`]: Kerr in Kerr–Schild Cartesian coordinates, Boyer–Lindquist
//!   conversions and constants of motion; [`referee_kerr`]: its closed forms.
//! - [`referee_kernel`]: the per-stage kernels the fused ones replaced, as
//!   their referees; [`kernel_perf`]: both in one timed run.
//! - [`integrate`]: tiers (RK4, Dormand–Prince 5(4), Störmer–Verlet,
//!   Yoshida 4, implicit midpoint), located events, the per-ray loop.
//! - [`tasks`]: what a scene asks for (deflection lists, observer angle
//!   scans, GRIN ray lists), fanned out over rays.
//! - [`gpu`]: the same tasks and the images traced by `kernels/transport.wgsl`
//!   (f32); [`gpu_parity`]: the band of its image contract.
//! - [`outputs`]: a traced task as named tensors; [`checks`]: observed
//!   order and drift growth (the integrators against themselves).
//! - [`referee`]: closed forms and quadratures in f64 that check the above
//!   and share no code with them.

pub mod checks;
pub mod disk;
pub mod gpu;
pub mod gpu_parity;
pub mod grin;
pub mod hamiltonian;
pub mod image;
pub mod image_checks;
pub mod integrate;
pub mod kernel_perf;
pub mod kerr;
pub mod kerr_speed_error;
pub mod kerr_trace;
pub mod lane_trace;
pub mod metric;
pub mod observer;
pub mod outputs;
pub mod referee;
pub mod referee_kernel;
pub mod referee_kerr;
pub mod simd4;
pub mod tasks;
