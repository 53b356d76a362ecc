//! Monte Carlo path tracing of surfaces: the Cornell box with three spheres (seed 004).
