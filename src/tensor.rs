//! Named, typed n-dimensional outputs: what a stage hands the judge and what
//! `.npy` files hold. The judge's assertions are generic over these.

use std::collections::BTreeMap;
use std::path::Path;

use ndarray::{ArrayD, IxDyn};
use serde::{Deserialize, Serialize};

use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::npy::{self, Dtype};
use crate::real::Real;

/// An n-dimensional array of one of the dtypes outputs use (SCENES.md "Files":
/// floats f32/f64, masks u8, counts and indices i32; u32 for raw RNG words).
#[derive(Clone, Debug, PartialEq)]
pub enum Tensor {
    F32(ArrayD<f32>),
    F64(ArrayD<f64>),
    I32(ArrayD<i32>),
    U32(ArrayD<u32>),
    U8(ArrayD<u8>),
}

macro_rules! each {
    ($t:expr, $a:ident => $e:expr) => {
        match $t {
            Tensor::F32($a) => $e,
            Tensor::F64($a) => $e,
            Tensor::I32($a) => $e,
            Tensor::U32($a) => $e,
            Tensor::U8($a) => $e,
        }
    };
}

/// A tensor as a manifest lists it; `shape` defaults to `[data.len()]`.
#[derive(serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct ListedTensor {
    pub dtype: String,
    #[serde(default)]
    pub shape: Option<Vec<usize>>,
    pub data: Vec<f64>,
}

impl Tensor {
    /// Builds a tensor from a flat row-major vector and a shape.
    pub fn from_shape_vec<T>(shape: &[usize], v: Vec<T>) -> Result<Tensor>
    where
        ArrayD<T>: Into<Tensor>,
    {
        let n = v.len();
        ArrayD::from_shape_vec(IxDyn(shape), v)
            .map(Into::into)
            .map_err(|e| {
                Error::invalid(
                    "tensor",
                    format!("{n} values do not fit shape {shape:?}: {e}"),
                )
            })
    }

    /// A tensor of render floats (f32 or f64 as `F`) from a flat vector.
    pub fn real<F: Real>(shape: &[usize], v: Vec<F>) -> Result<Tensor> {
        let n = v.len();
        ArrayD::from_shape_vec(IxDyn(shape), v)
            .map(F::tensor)
            .map_err(|e| {
                Error::invalid(
                    "tensor",
                    format!("{n} values do not fit shape {shape:?}: {e}"),
                )
            })
    }

    /// A tensor of shape `shape ++ [3]` from 3-vectors.
    pub fn real3<F: Real>(shape: &[usize], v: &[[F; 3]]) -> Result<Tensor> {
        let mut s = shape.to_vec();
        s.push(3);
        Tensor::real(&s, v.iter().flatten().copied().collect())
    }

    /// `data` converted to `dtype` (float32, float64, int32 or uint8; `as`
    /// casts), shaped `shape`; `None` for another dtype name.
    pub fn from_f64_as(dtype: &str, shape: &[usize], data: Vec<f64>) -> Option<Result<Tensor>> {
        Some(match dtype {
            "float32" => Tensor::from_shape_vec(shape, data.iter().map(|&x| x as f32).collect()),
            "float64" => Tensor::from_shape_vec(shape, data),
            "int32" => Tensor::from_shape_vec(shape, data.iter().map(|&x| x as i32).collect()),
            "uint8" => Tensor::from_shape_vec(shape, data.iter().map(|&x| x as u8).collect()),
            _ => return None,
        })
    }

    /// A tensor written out in a manifest (`const` op): `{dtype, shape, data}`.
    pub fn from_listed(c: ListedTensor) -> std::result::Result<Tensor, String> {
        let shape = c.shape.unwrap_or_else(|| vec![c.data.len()]);
        let dtype = c.dtype;
        match Tensor::from_f64_as(&dtype, &shape, c.data) {
            None => Err(format!(
                "dtype {dtype:?} is not float32, float64, int32 or uint8"
            )),
            Some(t) => t.map_err(|e| e.to_string()),
        }
    }

    /// A 0-d tensor holding one f64.
    pub fn scalar(x: f64) -> Tensor {
        Tensor::F64(ArrayD::from_elem(IxDyn(&[]), x))
    }

    pub fn shape(&self) -> &[usize] {
        each!(self, a => a.shape())
    }

    pub fn len(&self) -> usize {
        each!(self, a => a.len())
    }

    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    /// The numpy-style dtype name.
    pub fn dtype(&self) -> &'static str {
        match self {
            Tensor::F32(_) => "float32",
            Tensor::F64(_) => "float64",
            Tensor::I32(_) => "int32",
            Tensor::U32(_) => "uint32",
            Tensor::U8(_) => "uint8",
        }
    }

    pub fn is_float(&self) -> bool {
        matches!(self, Tensor::F32(_) | Tensor::F64(_))
    }

    /// Every element widened to f64, in row-major order.
    pub fn to_f64_vec(&self) -> Vec<f64> {
        match self {
            Tensor::F32(a) => a.iter().map(|&x| x as f64).collect(),
            Tensor::F64(a) => a.iter().copied().collect(),
            Tensor::I32(a) => a.iter().map(|&x| x as f64).collect(),
            Tensor::U32(a) => a.iter().map(|&x| x as f64).collect(),
            Tensor::U8(a) => a.iter().map(|&x| x as f64).collect(),
        }
    }

    /// The raw bytes of every element in row-major order (native endianness),
    /// for memcmp-style determinism checks.
    pub fn to_bytes(&self) -> Vec<u8> {
        match self {
            Tensor::F32(a) => a.iter().flat_map(|x| x.to_bits().to_le_bytes()).collect(),
            Tensor::F64(a) => a.iter().flat_map(|x| x.to_bits().to_le_bytes()).collect(),
            Tensor::I32(a) => a.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Tensor::U32(a) => a.iter().flat_map(|x| x.to_le_bytes()).collect(),
            Tensor::U8(a) => a.iter().copied().collect(),
        }
    }

    /// Bytes of one element.
    pub fn elem_size(&self) -> usize {
        match self {
            Tensor::F64(_) => 8,
            Tensor::F32(_) | Tensor::I32(_) | Tensor::U32(_) => 4,
            Tensor::U8(_) => 1,
        }
    }

    /// Writes the tensor as a `.npy` file.
    pub fn write_npy(&self, path: &Path) -> Result<()> {
        let r = each!(self, a => ndarray_npy::write_npy(path, a));
        r.map_err(|e| {
            Error::invalid(
                path.display().to_string(),
                format!("cannot write .npy: {e}"),
            )
        })
    }

    /// Reads a `.npy` file of any supported dtype, within the machine's
    /// memory budget (see [`Tensor::read_npy_within`]).
    pub fn read_npy(path: &Path) -> Result<Tensor> {
        Tensor::read_npy_within(path, MemBudget::from_machine())
    }

    /// Reads a `.npy` file: the header is parsed and its byte size checked
    /// against the file length and `budget` before the data is allocated.
    pub fn read_npy_within(path: &Path, budget: MemBudget) -> Result<Tensor> {
        let raw = npy::read(path, budget, |_| Ok(()))?;
        Tensor::from_raw(raw, path)
    }

    fn from_raw(raw: npy::Raw, path: &Path) -> Result<Tensor> {
        fn words<const N: usize, T>(b: &[u8], f: fn([u8; N]) -> T) -> Vec<T> {
            b.chunks_exact(N)
                .map(|c| f(c.try_into().unwrap_or([0; N])))
                .collect()
        }
        let s = raw.header.shape.as_slice();
        let b = raw.data.as_slice();
        let t = match raw.header.dtype {
            Dtype::F32 => Tensor::from_shape_vec(s, words(b, f32::from_le_bytes)),
            Dtype::F64 => Tensor::from_shape_vec(s, words(b, f64::from_le_bytes)),
            Dtype::I32 => Tensor::from_shape_vec(s, words(b, i32::from_le_bytes)),
            Dtype::U32 => Tensor::from_shape_vec(s, words(b, u32::from_le_bytes)),
            Dtype::U8 => Tensor::from_shape_vec(s, b.to_vec()),
        };
        t.map_err(|e| Error::invalid(path.display().to_string(), e.to_string()))
    }

    /// Reads a `.npy` file and checks its dtype and shape (`None` in `shape`
    /// matches any extent) from the header, before the data is read.
    pub fn read_npy_checked(
        path: &Path,
        dtype: &[&str],
        shape: &[Option<usize>],
    ) -> Result<Tensor> {
        let at = path.display().to_string();
        let raw = npy::read(path, MemBudget::from_machine(), |h| {
            if !dtype.contains(&h.dtype.name()) {
                return Err(Error::invalid(
                    at.clone(),
                    format!("dtype is {}, expected one of {dtype:?}", h.dtype.name()),
                ));
            }
            let ok = h.shape.len() == shape.len()
                && h.shape
                    .iter()
                    .zip(shape)
                    .all(|(&s, e)| e.is_none_or(|e| e == s));
            if !ok {
                let want: Vec<String> = shape
                    .iter()
                    .map(|e| e.map_or("*".into(), |e| e.to_string()))
                    .collect();
                return Err(Error::invalid(
                    at.clone(),
                    format!("shape is {:?}, expected ({})", h.shape, want.join(", ")),
                ));
            }
            Ok(())
        })?;
        Tensor::from_raw(raw, path)
    }
}

impl From<ArrayD<f32>> for Tensor {
    fn from(a: ArrayD<f32>) -> Self {
        Tensor::F32(a)
    }
}
impl From<ArrayD<f64>> for Tensor {
    fn from(a: ArrayD<f64>) -> Self {
        Tensor::F64(a)
    }
}
impl From<ArrayD<i32>> for Tensor {
    fn from(a: ArrayD<i32>) -> Self {
        Tensor::I32(a)
    }
}
impl From<ArrayD<u32>> for Tensor {
    fn from(a: ArrayD<u32>) -> Self {
        Tensor::U32(a)
    }
}
impl From<ArrayD<u8>> for Tensor {
    fn from(a: ArrayD<u8>) -> Self {
        Tensor::U8(a)
    }
}

/// What one operation returns: named tensors (written as artifacts and read
/// by assertions), scalar metrics (timings, throughputs, speedups) and
/// integer counters (rays, samples, early stops, ...).
#[derive(Clone, Debug, Default)]
pub struct Outputs {
    pub tensors: BTreeMap<String, Tensor>,
    pub metrics: BTreeMap<String, f64>,
    pub counters: BTreeMap<String, u64>,
}

impl Outputs {
    /// Outputs holding `tensors` (no metrics or counters).
    pub fn of<const N: usize>(tensors: [(&str, Tensor); N]) -> Outputs {
        let mut out = Outputs::default();
        for (name, t) in tensors {
            out.tensor(name, t);
        }
        out
    }

    pub fn tensor(&mut self, name: &str, t: impl Into<Tensor>) -> &mut Self {
        self.tensors.insert(name.to_string(), t.into());
        self
    }
    pub fn metric(&mut self, name: &str, v: f64) -> &mut Self {
        self.metrics.insert(name.to_string(), v);
        self
    }
    pub fn counter(&mut self, name: &str, v: u64) -> &mut Self {
        self.counters.insert(name.to_string(), v);
        self
    }
}

/// Shape and dtype of a tensor, for reports.
#[derive(Clone, Debug, Serialize, Deserialize)]
pub struct TensorInfo {
    pub dtype: String,
    pub shape: Vec<usize>,
}

impl From<&Tensor> for TensorInfo {
    fn from(t: &Tensor) -> Self {
        TensorInfo {
            dtype: t.dtype().to_string(),
            shape: t.shape().to_vec(),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn npy_round_trip_keeps_dtype_shape_and_bits() {
        let dir = std::env::temp_dir().join(format!("hp-tensor-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let cases = [
            Tensor::from_shape_vec(
                &[2, 3],
                vec![0.5f32, -1.0, 3.25, f32::MIN_POSITIVE, 0.0, 7.0],
            )
            .unwrap(),
            Tensor::from_shape_vec(&[3], vec![1e-300f64, 2.0, -0.0]).unwrap(),
            Tensor::from_shape_vec(&[2, 2], vec![1i32, -2, 3, 4]).unwrap(),
            Tensor::from_shape_vec(&[1], vec![u32::MAX]).unwrap(),
            Tensor::from_shape_vec(&[2], vec![0u8, 1]).unwrap(),
        ];
        for (i, t) in cases.iter().enumerate() {
            let p = dir.join(format!("t{i}.npy"));
            t.write_npy(&p).unwrap();
            let back = Tensor::read_npy(&p).unwrap();
            assert_eq!(back.dtype(), t.dtype());
            assert_eq!(back.to_bytes(), t.to_bytes());
        }
        let err =
            Tensor::read_npy_checked(&dir.join("t0.npy"), &["float64"], &[None, None]).unwrap_err();
        assert!(err.to_string().contains("dtype is float32"), "{err}");
        let err = Tensor::read_npy_checked(&dir.join("t0.npy"), &["float32"], &[Some(3), None])
            .unwrap_err();
        assert!(err.to_string().contains("shape is [2, 3]"), "{err}");
        std::fs::remove_dir_all(&dir).ok();
    }
}
