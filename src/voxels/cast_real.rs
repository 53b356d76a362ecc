//! [`CastReal`]: the floats the voxel casts run in (f32, f64), with the
//! bit-pattern helpers the Laine–Karras loop needs and the f32-only SSE and
//! lane casts as optional methods.

use crate::real::Real;

use super::cast::{Addressing, CastHit, CastParams};

/// A float the cast runs in: the bit-pattern tricks need its layout.
pub trait CastReal: Real {
    /// Mantissa bits beyond f32's 23.
    const EXTRA: u32;
    /// log2 of the direction epsilon (-23 for f32, -52 for f64).
    const EPS_LOG2: i32;
    fn bits(self) -> u64;
    fn from_bits(b: u64) -> Self;
    /// `2^k`, exact, for k in the normal exponent range.
    fn exp2i(k: i32) -> Self;
    /// The SSE cast ([`super::cast_sse`]): `Some` in f32 (bit-identical to
    /// [`super::cast::cast_with`] without contours), `None` in other precisions.
    fn cast_sse<A: Addressing>(
        _nodes: &[u32],
        _depth: u32,
        _o: [Self; 3],
        _d: [Self; 3],
        _p: &CastParams,
    ) -> Option<CastHit<Self>> {
        None
    }
    /// Whether [`CastReal::cast_sse`] and [`CastReal::cast_lanes`] cast
    /// (f32) or leave their outputs alone (other precisions).
    const SIMD: bool = false;
    /// The lane cast ([`super::cast_lanes`]) of rays `(o[i], d[i])` into
    /// `out[i]` in f32 (bit-identical to [`super::cast::cast_with`] without
    /// contours; per-ray starts `near[i]` when given); nothing in other
    /// precisions.
    fn cast_lanes<A: Addressing>(
        _nodes: &[u32],
        _depth: u32,
        _o: &[[Self; 3]],
        _d: &[[Self; 3]],
        _p: &CastParams,
        _near: Option<&[f64]>,
        _out: &mut [CastHit<Self>],
    ) {
    }
}

impl CastReal for f32 {
    const EXTRA: u32 = 0;
    const EPS_LOG2: i32 = -23;
    #[inline]
    fn bits(self) -> u64 {
        self.to_bits() as u64
    }
    #[inline]
    fn from_bits(b: u64) -> Self {
        f32::from_bits(b as u32)
    }
    #[inline]
    fn exp2i(k: i32) -> Self {
        f32::from_bits(((k + 127) as u32) << 23)
    }
    #[inline]
    fn cast_sse<A: Addressing>(
        nodes: &[u32],
        depth: u32,
        o: [f32; 3],
        d: [f32; 3],
        p: &CastParams,
    ) -> Option<CastHit<f32>> {
        Some(super::cast_sse::cast_sse::<A>(nodes, depth, o, d, p))
    }
    const SIMD: bool = true;
    fn cast_lanes<A: Addressing>(
        nodes: &[u32],
        depth: u32,
        o: &[[f32; 3]],
        d: &[[f32; 3]],
        p: &CastParams,
        near: Option<&[f64]>,
        out: &mut [CastHit<f32>],
    ) {
        super::cast_lanes::cast_lanes::<A>(nodes, depth, o, d, p, near, out)
    }
}

impl CastReal for f64 {
    const EXTRA: u32 = 29;
    const EPS_LOG2: i32 = -52;
    #[inline]
    fn bits(self) -> u64 {
        self.to_bits()
    }
    #[inline]
    fn from_bits(b: u64) -> Self {
        f64::from_bits(b)
    }
    #[inline]
    fn exp2i(k: i32) -> Self {
        f64::from_bits(((k + 1023) as u64) << 52)
    }
}
