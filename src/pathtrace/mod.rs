//! `pathtrace`: Monte Carlo path tracing of surfaces (seed 004, the Cornell
//! box with three spheres; SCENES.md "Cornell box with three spheres").
//!
//! Stages, after the seed's components: [`shapes`] (geometry: spheres,
//! quads, the one intersection function; [`packed`] runs it four shapes at
//! a time for rendering), [`bsdf`] (materials: a closed
//! enum), [`integrator`] (NEE + MIS path loop, Russian roulette, tiles over
//! rayon), [`chi2`] (the statistical test the judge runs on every sampler),
//! [`gpu`] (the same render on the GPU: `kernels/pathtrace.wgsl`),
//! [`soa8`] and [`trace8`] (eight samples of a pixel at a time, SIMD across
//! rays; the scalar `integrator::trace` is their referee).
//! The renderer takes typed parameters; `scene/pathtrace.rs` builds them.

pub mod bsdf;
pub mod chi2;
pub mod gpu;
pub mod integrator;
pub mod packed;
pub mod shapes;
pub mod soa8;
pub mod trace8;

pub use bsdf::Material;
pub use integrator::{render, Image, RenderParams, Scene};
pub use shapes::{Quad, Shape, Sphere};
