//! The GPU layer (wgpu, WGSL compute kernels): one context per process
//! ([`context`]), the kernel registry ([`kernels`]), buffers and the one
//! readback helper ([`buffers`]), and one file per kernel family, each the
//! host side of a `kernels/*.wgsl` file and the GPU twin of a CPU stage.
//!
//! Imports point down only: renderers call into this module with their
//! kernels' inputs; nothing here imports a renderer's CPU code.

pub mod buffers;
pub mod context;
pub mod kernels;
pub mod math;
pub mod pathtrace;
pub mod rays;
pub mod volume;

pub use context::{adapters, describe, AdapterSummary, GpuContext};
