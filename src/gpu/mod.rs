//! The GPU layer (wgpu, WGSL compute kernels): one context per process
//! ([`context`]), the kernel registry ([`kernels`]), buffers and the one
//! readback helper ([`buffers`]), and one file per kernel family, each the
//! host side of a `kernels/*.wgsl` file and the GPU twin of a CPU stage.
//! Codes both sides share (field kinds, ray flags) are defined once in
//! [`codes`] and checked against the WGSL constants.
//!
//! Imports point down only: renderers call into this module with their
//! kernels' inputs; nothing here imports a renderer's CPU code.

pub mod buffers;
pub mod codes;
pub mod context;
pub mod kernels;
pub mod math;
pub mod pathtrace;
pub mod rays;
pub mod transport;
pub mod volume;
pub mod volume_diff;
pub mod volume_hash;
pub mod volume_session;
pub mod voxel_attrs;
pub mod voxels;

pub use context::{adapters, describe, AdapterSummary, GpuContext};
