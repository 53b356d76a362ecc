//! Unowned tensor views (`hp_tensor`): validation and strided element access.
//!
//! A view is `data` + `dtype` + `shape[ndim]` + `stride[ndim]`, strides in
//! elements (not bytes), C order when `stride[i] = prod(shape[i+1..])`. The
//! library never owns, frees or keeps a view past the call that received it.
//! Every check happens before the first element is read or written: a view
//! with a null pointer, another dtype or rank, a shape other than the one the
//! stage needs, a negative stride, a zero stride on an output, or a device
//! pointer is refused with a message naming the argument.

use crate::abi::{
    HpTensor, DTYPE_F32, DTYPE_F64, DTYPE_I32, DTYPE_U32, DTYPE_U8, MAX_DIMS, MEM_HOST,
};
use crate::fail::{Fail, Result};

/// Element types a view may hold.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DType {
    F32,
    F64,
    I32,
    U32,
    U8,
}

impl DType {
    pub fn of_code(code: u32) -> Option<DType> {
        Some(match code {
            DTYPE_F32 => DType::F32,
            DTYPE_F64 => DType::F64,
            DTYPE_I32 => DType::I32,
            DTYPE_U32 => DType::U32,
            DTYPE_U8 => DType::U8,
            _ => return None,
        })
    }

    pub fn name(self) -> &'static str {
        match self {
            DType::F32 => "F32",
            DType::F64 => "F64",
            DType::I32 => "I32",
            DType::U32 => "U32",
            DType::U8 => "U8",
        }
    }
}

/// A checked view: rank, shape and strides known good for its use.
#[derive(Clone, Copy, Debug)]
pub struct View {
    ptr: *mut u8,
    pub dtype: DType,
    pub ndim: usize,
    pub shape: [usize; MAX_DIMS],
    stride: [usize; MAX_DIMS],
}

/// What a stage needs of one argument: its name for messages, the dtypes it
/// accepts and the shape (`None` = any extent on that axis).
pub struct Want<'a> {
    pub name: &'a str,
    pub dtypes: &'a [DType],
    pub shape: &'a [Option<usize>],
    pub output: bool,
}

impl View {
    /// Checks `t` against `w`. `t` must not be null (callers turn an absent
    /// optional tensor into `None` before this with [`is_empty`]).
    pub fn check(t: &HpTensor, w: &Want) -> Result<View> {
        if t.memspace != MEM_HOST {
            return Err(Fail::not_supported(format!(
                "{}: memspace {} (only HP_MEM_HOST in this version)",
                w.name, t.memspace
            )));
        }
        let dtype = DType::of_code(t.dtype)
            .ok_or_else(|| Fail::error(format!("{}: unknown dtype code {}", w.name, t.dtype)))?;
        if !w.dtypes.contains(&dtype) {
            let names: Vec<_> = w.dtypes.iter().map(|d| d.name()).collect();
            return Err(Fail::error(format!(
                "{}: dtype {} where {} is needed",
                w.name,
                dtype.name(),
                names.join(" or ")
            )));
        }
        let ndim = t.ndim as usize;
        if ndim != w.shape.len() {
            return Err(Fail::error(format!(
                "{}: rank {} where {} is needed",
                w.name,
                t.ndim,
                w.shape.len()
            )));
        }
        let mut shape = [0usize; MAX_DIMS];
        let mut stride = [0usize; MAX_DIMS];
        let mut count: usize = 1;
        for i in 0..ndim {
            let (n, s) = (t.shape[i], t.stride[i]);
            if n < 0 || s < 0 {
                return Err(Fail::error(format!(
                    "{}: negative extent or stride on axis {i} (shape {n}, stride {s})",
                    w.name
                )));
            }
            if let Some(want) = w.shape[i] {
                if n as u64 != want as u64 {
                    return Err(Fail::error(format!(
                        "{}: extent {n} on axis {i} where {want} is needed (shape {})",
                        w.name,
                        shape_str(t)
                    )));
                }
            }
            if w.output && s == 0 && n > 1 {
                return Err(Fail::error(format!(
                    "{}: zero stride on axis {i} of an output (elements would overlap)",
                    w.name
                )));
            }
            shape[i] = n as usize;
            stride[i] = s as usize;
            count = count
                .checked_mul(n as usize)
                .ok_or_else(|| Fail::error(format!("{}: element count overflows", w.name)))?;
        }
        if count > 0 && t.data.is_null() {
            return Err(Fail::error(format!("{}: data is NULL", w.name)));
        }
        // The largest element offset must be addressable.
        let mut last: usize = 0;
        for i in 0..ndim {
            if shape[i] > 0 {
                last = (shape[i] - 1)
                    .checked_mul(stride[i])
                    .and_then(|v| v.checked_add(last))
                    .ok_or_else(|| Fail::error(format!("{}: strides overflow", w.name)))?;
            }
        }
        if last
            .checked_mul(size_of(dtype))
            .is_none_or(|b| b > isize::MAX as usize)
        {
            return Err(Fail::error(format!("{}: strides overflow", w.name)));
        }
        Ok(View {
            ptr: t.data as *mut u8,
            dtype,
            ndim,
            shape,
            stride,
        })
    }

    /// Number of elements (a view of none is legal: an empty frame).
    #[allow(clippy::len_without_is_empty)]
    pub fn len(&self) -> usize {
        self.shape[..self.ndim].iter().product()
    }

    /// Element offset of flat C-order index `i`.
    fn offset(&self, mut i: usize) -> usize {
        let mut off = 0;
        for a in (0..self.ndim).rev() {
            let n = self.shape[a];
            off += (i % n) * self.stride[a];
            i /= n;
        }
        off
    }

    /// Element `i` (flat C order) as f64; any dtype.
    ///
    /// # Safety
    /// The view's memory must be readable over its shape and strides (the
    /// caller's contract for every `hp_tensor` it passes).
    pub unsafe fn get(&self, i: usize) -> f64 {
        let o = self.offset(i);
        match self.dtype {
            DType::F32 => *(self.ptr as *const f32).add(o) as f64,
            DType::F64 => *(self.ptr as *const f64).add(o),
            DType::I32 => *(self.ptr as *const i32).add(o) as f64,
            DType::U32 => *(self.ptr as *const u32).add(o) as f64,
            DType::U8 => *self.ptr.add(o) as f64,
        }
    }

    /// Element `i` of a U32 or I32 view as u32 (callers check the dtype).
    ///
    /// # Safety
    /// As [`View::get`].
    pub unsafe fn get_u32(&self, i: usize) -> u32 {
        let o = self.offset(i);
        match self.dtype {
            DType::U32 => *(self.ptr as *const u32).add(o),
            DType::I32 => *(self.ptr as *const i32).add(o) as u32,
            DType::U8 => *self.ptr.add(o) as u32,
            DType::F32 | DType::F64 => self.get(i) as u32,
        }
    }

    /// Element `i` of a float view in its own precision (F32 or F64 as `F`).
    ///
    /// # Safety
    /// As [`View::get`]; the view's dtype must be `F`'s.
    pub unsafe fn get_real<F: Copy + 'static>(&self, i: usize) -> F {
        *(self.ptr as *const F).add(self.offset(i))
    }

    /// Writes `v` (of the view's own element type `T`) at flat index `i`.
    ///
    /// # Safety
    /// The view's memory must be writable over its shape and strides and its
    /// dtype must be `T`'s.
    pub unsafe fn put<T: Copy>(&self, i: usize, v: T) {
        *(self.ptr as *mut T).add(self.offset(i)) = v;
    }
}

/// Whether an optional tensor is absent (`data == NULL` and rank 0).
pub fn is_empty(t: &HpTensor) -> bool {
    t.data.is_null() && t.ndim == 0
}

fn size_of(d: DType) -> usize {
    match d {
        DType::F32 | DType::I32 | DType::U32 => 4,
        DType::F64 => 8,
        DType::U8 => 1,
    }
}

fn shape_str(t: &HpTensor) -> String {
    let n = (t.ndim as usize).min(MAX_DIMS);
    let dims: Vec<String> = t.shape[..n].iter().map(|v| v.to_string()).collect();
    format!("({})", dims.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn tensor(data: *mut u8, dtype: u32, shape: &[i64], stride: &[i64]) -> HpTensor {
        let mut t = HpTensor::empty();
        t.data = data as *mut std::ffi::c_void;
        t.dtype = dtype;
        t.ndim = shape.len() as u32;
        t.shape[..shape.len()].copy_from_slice(shape);
        t.stride[..stride.len()].copy_from_slice(stride);
        t
    }

    const F32_ONLY: &[DType] = &[DType::F32];

    #[test]
    fn strided_reads_follow_the_strides() {
        // A (2, 3) view of every other element of a 12-float buffer.
        let mut buf: Vec<f32> = (0..12).map(|v| v as f32).collect();
        let t = tensor(buf.as_mut_ptr() as *mut u8, DTYPE_F32, &[2, 3], &[6, 2]);
        let w = Want {
            name: "x",
            dtypes: F32_ONLY,
            shape: &[Some(2), Some(3)],
            output: false,
        };
        let v = View::check(&t, &w).unwrap();
        let got: Vec<f64> = (0..6).map(|i| unsafe { v.get(i) }).collect();
        assert_eq!(got, vec![0.0, 2.0, 4.0, 6.0, 8.0, 10.0]);
    }

    #[test]
    fn wrong_dtype_rank_shape_and_null_are_refused_by_name() {
        let mut buf = [0f32; 4];
        let p = buf.as_mut_ptr() as *mut u8;
        let w = Want {
            name: "rays.t0",
            dtypes: F32_ONLY,
            shape: &[Some(4)],
            output: true,
        };
        let msg = |t: HpTensor| View::check(&t, &w).unwrap_err().msg;
        assert!(msg(tensor(p, DTYPE_F64, &[4], &[1])).contains("rays.t0: dtype F64"));
        assert!(msg(tensor(p, DTYPE_F32, &[2, 2], &[2, 1])).contains("rank 2"));
        assert!(msg(tensor(p, DTYPE_F32, &[3], &[1])).contains("extent 3"));
        assert!(msg(tensor(std::ptr::null_mut(), DTYPE_F32, &[4], &[1])).contains("NULL"));
        assert!(msg(tensor(p, DTYPE_F32, &[4], &[0])).contains("zero stride"));
        assert!(msg(tensor(p, DTYPE_F32, &[4], &[-1])).contains("negative"));
        assert!(msg(tensor(p, 99, &[4], &[1])).contains("unknown dtype"));
    }

    #[test]
    fn device_memory_is_not_supported() {
        let mut buf = [0f32; 1];
        let mut t = tensor(buf.as_mut_ptr() as *mut u8, DTYPE_F32, &[1], &[1]);
        t.memspace = crate::abi::MEM_DEVICE;
        let w = Want {
            name: "x",
            dtypes: F32_ONLY,
            shape: &[None],
            output: false,
        };
        assert_eq!(
            View::check(&t, &w).unwrap_err().status,
            crate::abi::NOT_SUPPORTED
        );
    }
}
