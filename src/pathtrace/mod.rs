//! `pathtrace`: Monte Carlo path tracing of surfaces (seed 004, the Cornell
//! box with three spheres; SCENES.md "Cornell box with three spheres").
//!
//! Stages, after the seed's components: [`shapes`] (geometry: spheres,
//! quads, the one intersection function), [`bsdf`] (materials: a closed
//! enum), [`integrator`] (NEE + MIS path loop, Russian roulette, tiles over
//! rayon), [`chi2`] (the statistical test the judge runs on every sampler).
//! The renderer takes typed parameters; `scene/pathtrace.rs` builds them.

pub mod bsdf;
pub mod chi2;
pub mod integrator;
pub mod shapes;

pub use bsdf::Material;
pub use integrator::{render, Image, RenderParams, Scene};
pub use shapes::{Quad, Shape, Sphere};
