//! The `#[repr(C)]` mirrors of `include/hotpath.h`'s structs and constants.
//! Keep in sync with the header: `tests/header.rs` compiles a C program that
//! prints every struct's size and field offsets and every constant, and
//! compares them with these declarations; it also checks the header's
//! prototypes against the `extern "C"` functions of this crate.

use std::ffi::c_void;

pub const ABI_VERSION: u32 = 1;

pub const OK: i32 = 0;
pub const ERROR: i32 = 1;
pub const NOT_SUPPORTED: i32 = 2;

pub const DTYPE_F32: u32 = 0;
pub const DTYPE_F64: u32 = 1;
pub const DTYPE_I32: u32 = 2;
pub const DTYPE_U32: u32 = 3;
pub const DTYPE_U8: u32 = 4;

pub const MEM_HOST: u32 = 0;
pub const MEM_DEVICE: u32 = 1;

pub const MAX_DIMS: usize = 4;

pub const BACKEND_CPU: u32 = 0;
pub const BACKEND_GPU: u32 = 1;

pub const CAMERA_PINHOLE: u32 = 0;
pub const CAMERA_ORTHO: u32 = 1;

pub const SAMPLING_FIXED: u32 = 0;
pub const SAMPLING_STRATIFIED: u32 = 1;

pub const TRANS_PRODUCT: u32 = 0;
pub const TRANS_LOG: u32 = 1;

pub const INTERP_TRILINEAR: u32 = 0;

pub const OOB_ZERO: u32 = 0;
pub const OOB_CLAMP: u32 = 1;

pub const ANALYTIC_CONSTANT: u32 = 0;
pub const ANALYTIC_SLABS: u32 = 1;
pub const ANALYTIC_GAUSSIAN: u32 = 2;
pub const ANALYTIC_SHELL: u32 = 3;
pub const ANALYTIC_LINEAR: u32 = 4;

pub const STAGE_RAY: u32 = 0;
pub const STAGE_SAMP: u32 = 1;
pub const STAGE_INT: u32 = 2;
pub const STAGE_IMG: u32 = 3;
pub const STAGE_DIFF: u32 = 4;

pub const CAP_CPU: u64 = 1;
pub const CAP_GPU: u64 = 2;
pub const CAP_F32: u64 = 4;
pub const CAP_F64: u64 = 8;
pub const CAP_FIELD_GRID: u64 = 16;
pub const CAP_FIELD_ANALYTIC: u64 = 32;
pub const CAP_FIELD_HASH_MLP: u64 = 64;
pub const CAP_DIFF: u64 = 128;

/// The header's `#define`s with their values, for the header test.
pub const DEFINES: &[(&str, u64)] = &[
    ("HP_ABI_VERSION", ABI_VERSION as u64),
    ("HP_OK", OK as u64),
    ("HP_ERROR", ERROR as u64),
    ("HP_NOT_SUPPORTED", NOT_SUPPORTED as u64),
    ("HP_DTYPE_F32", DTYPE_F32 as u64),
    ("HP_DTYPE_F64", DTYPE_F64 as u64),
    ("HP_DTYPE_I32", DTYPE_I32 as u64),
    ("HP_DTYPE_U32", DTYPE_U32 as u64),
    ("HP_DTYPE_U8", DTYPE_U8 as u64),
    ("HP_MEM_HOST", MEM_HOST as u64),
    ("HP_MEM_DEVICE", MEM_DEVICE as u64),
    ("HP_MAX_DIMS", MAX_DIMS as u64),
    ("HP_BACKEND_CPU", BACKEND_CPU as u64),
    ("HP_BACKEND_GPU", BACKEND_GPU as u64),
    ("HP_CAMERA_PINHOLE", CAMERA_PINHOLE as u64),
    ("HP_CAMERA_ORTHO", CAMERA_ORTHO as u64),
    ("HP_SAMPLING_FIXED", SAMPLING_FIXED as u64),
    ("HP_SAMPLING_STRATIFIED", SAMPLING_STRATIFIED as u64),
    ("HP_TRANS_PRODUCT", TRANS_PRODUCT as u64),
    ("HP_TRANS_LOG", TRANS_LOG as u64),
    ("HP_INTERP_TRILINEAR", INTERP_TRILINEAR as u64),
    ("HP_OOB_ZERO", OOB_ZERO as u64),
    ("HP_OOB_CLAMP", OOB_CLAMP as u64),
    ("HP_ANALYTIC_CONSTANT", ANALYTIC_CONSTANT as u64),
    ("HP_ANALYTIC_SLABS", ANALYTIC_SLABS as u64),
    ("HP_ANALYTIC_GAUSSIAN", ANALYTIC_GAUSSIAN as u64),
    ("HP_ANALYTIC_SHELL", ANALYTIC_SHELL as u64),
    ("HP_ANALYTIC_LINEAR", ANALYTIC_LINEAR as u64),
    ("HP_STAGE_RAY", STAGE_RAY as u64),
    ("HP_STAGE_SAMP", STAGE_SAMP as u64),
    ("HP_STAGE_INT", STAGE_INT as u64),
    ("HP_STAGE_IMG", STAGE_IMG as u64),
    ("HP_STAGE_DIFF", STAGE_DIFF as u64),
    ("HP_CAP_CPU", CAP_CPU),
    ("HP_CAP_GPU", CAP_GPU),
    ("HP_CAP_F32", CAP_F32),
    ("HP_CAP_F64", CAP_F64),
    ("HP_CAP_FIELD_GRID", CAP_FIELD_GRID),
    ("HP_CAP_FIELD_ANALYTIC", CAP_FIELD_ANALYTIC),
    ("HP_CAP_FIELD_HASH_MLP", CAP_FIELD_HASH_MLP),
    ("HP_CAP_DIFF", CAP_DIFF),
];

/// `hp_header`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpHeader {
    pub abi_version: u32,
    pub reserved: u32,
    pub caps: u64,
}

/// `hp_tensor`: an unowned view, strides in elements.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpTensor {
    pub data: *mut c_void,
    pub dtype: u32,
    pub memspace: u32,
    pub ndim: u32,
    pub reserved: u32,
    pub shape: [i64; MAX_DIMS],
    pub stride: [i64; MAX_DIMS],
}

impl HpTensor {
    /// The absent tensor (data NULL, rank 0).
    pub fn empty() -> HpTensor {
        HpTensor {
            data: std::ptr::null_mut(),
            dtype: 0,
            memspace: MEM_HOST,
            ndim: 0,
            reserved: 0,
            shape: [0; MAX_DIMS],
            stride: [0; MAX_DIMS],
        }
    }
}

/// `hp_camera`: pinhole intrinsics in pixels or orthographic half extents,
/// and the row-major 3x4 camera-to-world matrix.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpCamera {
    pub kind: u32,
    pub width: u32,
    pub height: u32,
    pub reserved: u32,
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
    pub half_width: f64,
    pub half_height: f64,
    pub c2w: [f64; 12],
}

/// `hp_plan_desc`.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpPlanDesc {
    pub next: *const c_void,
    pub backend: u32,
    pub precision: u32,
    pub camera: HpCamera,
    pub aabb_min: [f64; 3],
    pub aabb_max: [f64; 3],
    pub near_t: f64,
    pub far_t: f64,
    pub dt: f64,
    pub early_stop: f64,
    pub background: [f64; 3],
    pub max_steps: u32,
    pub sampling: u32,
    pub seed: u32,
    pub trans_path: u32,
}

/// `hp_rays_t`: N rays, structure of arrays.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpRays {
    pub next: *const c_void,
    pub count: u64,
    pub o: HpTensor,
    pub d: HpTensor,
    pub t0: HpTensor,
    pub t1: HpTensor,
    pub pixel: HpTensor,
}

/// `hp_samp_t`: packed samples; `capacity` in, `count` out.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpSamp {
    pub next: *const c_void,
    pub capacity: u64,
    pub count: u64,
    pub off: HpTensor,
    pub flags: HpTensor,
    pub ray_id: HpTensor,
    pub t: HpTensor,
    pub dt: HpTensor,
    pub sigma: HpTensor,
    pub color: HpTensor,
}

/// `hp_intl_t`: per-ray results and the persisted per-sample buffers.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpIntl {
    pub next: *const c_void,
    pub rgb: HpTensor,
    pub trans: HpTensor,
    pub logtrans: HpTensor,
    pub depth: HpTensor,
    pub opacity: HpTensor,
    pub nsamples: HpTensor,
    pub flags: HpTensor,
    pub alpha: HpTensor,
    pub log_t: HpTensor,
}

/// `hp_img_t`: (H, W) images; an empty tensor is not written.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpImg {
    pub next: *const c_void,
    pub rgb: HpTensor,
    pub trans: HpTensor,
    pub logtrans: HpTensor,
    pub depth: HpTensor,
    pub opacity: HpTensor,
    pub hit: HpTensor,
    pub nsamples: HpTensor,
}

/// `hp_grads_t`: what is differentiated (fields, rays) and the outputs.
#[repr(C)]
#[derive(Clone, Copy, Debug)]
pub struct HpGrads {
    pub next: *const c_void,
    pub fs: *const crate::field::HpField,
    pub fc: *const crate::field::HpField,
    pub rays: *const HpRays,
    pub dsigma: HpTensor,
    pub dcolor: HpTensor,
    pub dcam: HpTensor,
}

const _: () = assert!(std::mem::size_of::<HpHeader>() == 16);
const _: () = assert!(std::mem::size_of::<HpTensor>() == 88);
const _: () = assert!(std::mem::size_of::<HpCamera>() == 160);
const _: () = assert!(std::mem::size_of::<HpPlanDesc>() == 296);
const _: () = assert!(std::mem::size_of::<HpRays>() == 456);
const _: () = assert!(std::mem::size_of::<HpSamp>() == 640);
const _: () = assert!(std::mem::size_of::<HpIntl>() == 800);
const _: () = assert!(std::mem::size_of::<HpImg>() == 624);
const _: () = assert!(std::mem::size_of::<HpGrads>() == 296);
