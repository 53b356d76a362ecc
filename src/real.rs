//! The float type a CPU stage computes in: f32 (the GPU's precision) or f64
//! (the referee's). Stages are generic over [`Real`].

use std::fmt::{Debug, Display};
use std::iter::Sum;

use ndarray::ArrayD;
use serde::{Deserialize, Serialize};

use crate::tensor::Tensor;

/// Which float a render uses.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "lowercase")]
pub enum Precision {
    #[default]
    F32,
    F64,
}

impl Precision {
    pub fn name(self) -> &'static str {
        match self {
            Precision::F32 => "f32",
            Precision::F64 => "f64",
        }
    }
}

/// A float a stage can be generic over.
pub trait Real:
    num_traits::Float
    + num_traits::FloatConst
    + num_traits::NumAssign
    + Copy
    + Send
    + Sync
    + Default
    + Debug
    + Display
    + Sum
    + 'static
{
    const PRECISION: Precision;
    /// Rounds an f64 to this type.
    fn of(x: f64) -> Self;
    /// Widens (or keeps) to f64.
    fn f64(self) -> f64;
    /// Wraps an array of this type as a [`Tensor`].
    fn tensor(a: ArrayD<Self>) -> Tensor;
    /// The slice as `f32` when `Self` is `f32` (the hot loops' SIMD paths
    /// are written for f32 lanes; f64 keeps the scalar path).
    fn as_f32_slice(s: &[Self]) -> Option<&[f32]>;
    /// [`Real::as_f32_slice`], mutable.
    fn as_f32_slice_mut(s: &mut [Self]) -> Option<&mut [f32]>;
}

impl Real for f32 {
    const PRECISION: Precision = Precision::F32;
    #[inline]
    fn of(x: f64) -> Self {
        x as f32
    }
    #[inline]
    fn f64(self) -> f64 {
        self as f64
    }
    fn tensor(a: ArrayD<Self>) -> Tensor {
        Tensor::F32(a)
    }
    #[inline(always)]
    fn as_f32_slice(s: &[f32]) -> Option<&[f32]> {
        Some(s)
    }
    #[inline(always)]
    fn as_f32_slice_mut(s: &mut [f32]) -> Option<&mut [f32]> {
        Some(s)
    }
}

impl Real for f64 {
    const PRECISION: Precision = Precision::F64;
    #[inline]
    fn of(x: f64) -> Self {
        x
    }
    #[inline]
    fn f64(self) -> f64 {
        self
    }
    fn tensor(a: ArrayD<Self>) -> Tensor {
        Tensor::F64(a)
    }
    #[inline(always)]
    fn as_f32_slice(_: &[f64]) -> Option<&[f32]> {
        None
    }
    #[inline(always)]
    fn as_f32_slice_mut(_: &mut [f64]) -> Option<&mut [f32]> {
        None
    }
}
