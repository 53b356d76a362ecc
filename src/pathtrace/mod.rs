//! `pathtrace`: Monte Carlo path tracing of surfaces (seed 004, the Cornell
//! box with three spheres; SCENES.md "Cornell box with three spheres").
//!
//! Stages, after the seed's components: [`shapes`] (geometry: spheres,
//! quads, the one intersection function; [`packed`] runs it four shapes at
//! a time for rendering), [`bsdf`] (materials: a closed
//! enum), [`integrator`] (NEE + MIS path loop, random numbers from [`sampler`], Russian roulette, tiles over
//! rayon), [`gpu`] (the same render on the GPU: `kernels/pathtrace.wgsl`),
//! [`soa8`] and [`trace8`] (paths eight at a time, lanes refilled as paths
//! end, SIMD across rays), [`wave8`] with [`lanes`] and [`bsdf8`] (whole
//! vertices eight lanes at a time: shading, light sampling, BSDFs, RNG and
//! roulette under masks); the scalar `integrator::trace` is their referee. Beside them:
//! [`referee`] (independent f64 references that never call these stages),
//! [`checks`] (harnesses that run the stages against the referees and
//! `crate::stats`) and [`listed`] (listed-ray problems).
//! The renderer takes typed parameters; `scene/pathtrace.rs` builds them.

pub mod bsdf;
pub mod bsdf8;
pub mod checks;
pub mod gpu;
pub mod integrator;
#[cfg(test)]
mod lane_referee_tests;
pub mod lanes;
pub mod listed;
pub mod outputs;
pub mod packed;
pub mod referee;
pub mod sampler;
pub mod shapes;
pub mod soa8;
pub mod trace8;
pub mod wave8;

pub use bsdf::Material;
pub use integrator::{render, Image, RenderParams, Scene};
pub use shapes::{Quad, Shape, Sphere};
