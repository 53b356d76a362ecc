//! Contexts, cameras and plans: `hp_ctx_*`, `hp_camera_*`, `hp_plan_*`,
//! `hp_workspace_size`, `hp_get_header`.
//!
//! A plan fixes everything a frame needs besides the fields: backend,
//! precision, camera, world box, near/far, the march (dt, max_steps,
//! early_stop, sampling, transmittance path) and the background. It is
//! immutable after creation, so stage calls on one plan may run concurrently.

use std::ffi::c_char;

use hotpath::camera::{Camera, Intrinsics};
use hotpath::rays::{Aabb, RayGen};
use hotpath::real::Precision;
use hotpath::volume::sample::{March, Sampling, TransPath};

use crate::abi::*;
use crate::fail::{guard, thread_last_ptr, Fail, LastError, Result};

/// `hp_ctx`: owns the last-error slot of the calls made through it.
pub struct HpCtx {
    pub last: LastError,
}

/// `hp_plan`.
pub struct HpPlan {
    pub ctx: *const HpCtx,
    pub precision: Precision,
    pub cam: Camera,
    pub gen: RayGen,
    pub march: March<f64>,
}

impl HpPlan {
    /// The context's error slot.
    ///
    /// # Safety
    /// The context must outlive the plan (documented contract).
    pub unsafe fn last(&self) -> Option<&LastError> {
        self.ctx.as_ref().map(|c| &c.last)
    }

    /// The march in precision `F` (the same rounding `VolumeParams::march` does).
    pub fn march<F: hotpath::real::Real>(&self) -> March<F> {
        let m = &self.march;
        March {
            dt: F::of(m.dt),
            max_steps: m.max_steps,
            early_stop: F::of(m.early_stop),
            sampling: m.sampling,
            path: m.path,
            background: m.background.map(F::of),
        }
    }

    /// Rays of a camera frame (the whole image).
    pub fn ray_count(&self) -> u64 {
        self.gen.width as u64 * self.gen.height as u64
    }
}

pub(crate) fn caps() -> u64 {
    CAP_CPU | CAP_F32 | CAP_F64 | CAP_FIELD_GRID | CAP_FIELD_ANALYTIC | CAP_DIFF
}

/// Turns a null output pointer into an error naming it.
pub(crate) fn out_ptr<'a, T>(p: *mut T, name: &str) -> Result<&'a mut T> {
    unsafe { p.as_mut() }.ok_or_else(|| Fail::error(format!("{name} is NULL")))
}

/// A required input pointer.
pub(crate) fn in_ref<'a, T>(p: *const T, name: &str) -> Result<&'a T> {
    unsafe { p.as_ref() }.ok_or_else(|| Fail::error(format!("{name} is NULL")))
}

/// Refuses extension chains this version does not know.
pub(crate) fn no_next(next: *const std::ffi::c_void, name: &str) -> Result<()> {
    if next.is_null() {
        Ok(())
    } else {
        Err(Fail::not_supported(format!(
            "{name}.next: this version (ABI {ABI_VERSION}) knows no extension structs"
        )))
    }
}

#[no_mangle]
pub unsafe extern "C" fn hp_get_header(out: *mut HpHeader) -> i32 {
    guard(None, "hp_get_header", || {
        *out_ptr(out, "out")? = HpHeader {
            abi_version: ABI_VERSION,
            reserved: 0,
            caps: caps(),
        };
        Ok(())
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_ctx_create(abi_version: u32, out: *mut *mut HpCtx) -> i32 {
    guard(None, "hp_ctx_create", || {
        let out = out_ptr(out, "out")?;
        *out = std::ptr::null_mut();
        if abi_version != ABI_VERSION {
            return Err(Fail::not_supported(format!(
                "the caller was built for ABI {abi_version}, this library is ABI {ABI_VERSION}"
            )));
        }
        *out = Box::into_raw(Box::new(HpCtx {
            last: LastError::default(),
        }));
        Ok(())
    })
}

/// Frees a handle made by `Box::into_raw` (NULL is accepted and ignored).
///
/// # Safety
/// `p` is NULL or a handle of type `T` from this library, not freed before.
pub(crate) unsafe fn destroy<T>(p: *mut T, what: &str) -> i32 {
    guard(None, what, || {
        if !p.is_null() {
            drop(Box::from_raw(p));
        }
        Ok(())
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_ctx_destroy(ctx: *mut HpCtx) -> i32 {
    destroy(ctx, "hp_ctx_destroy")
}

#[no_mangle]
pub unsafe extern "C" fn hp_ctx_last_error(ctx: *const HpCtx) -> *const c_char {
    match ctx.as_ref() {
        Some(c) => c.last.as_ptr(),
        None => thread_last_ptr(),
    }
}

#[no_mangle]
pub extern "C" fn hp_last_error() -> *const c_char {
    thread_last_ptr()
}

unsafe fn vec3(p: *const f64, name: &str) -> Result<[f64; 3]> {
    if p.is_null() {
        return Err(Fail::error(format!("{name} is NULL")));
    }
    Ok([*p, *p.add(1), *p.add(2)])
}

fn camera_out(cam: &Camera, width: u32, height: u32) -> HpCamera {
    let c2w = cam.c2w();
    let mut m = [0.0; 12];
    for r in 0..3 {
        m[r * 4..r * 4 + 4].copy_from_slice(&c2w[r]);
    }
    let mut out = HpCamera {
        kind: CAMERA_PINHOLE,
        width,
        height,
        reserved: 0,
        fx: 0.0,
        fy: 0.0,
        cx: 0.0,
        cy: 0.0,
        half_width: 0.0,
        half_height: 0.0,
        c2w: m,
    };
    match cam {
        Camera::Pinhole { k, .. } => {
            (out.fx, out.fy, out.cx, out.cy) = (k.fx, k.fy, k.cx, k.cy);
        }
        Camera::Orthographic {
            half_width,
            half_height,
            ..
        } => {
            out.kind = CAMERA_ORTHO;
            (out.half_width, out.half_height) = (*half_width, *half_height);
        }
    }
    out
}

#[no_mangle]
pub unsafe extern "C" fn hp_camera_pinhole_look_at(
    position: *const f64,
    target: *const f64,
    up: *const f64,
    fov_y_deg: f64,
    width: u32,
    height: u32,
    out: *mut HpCamera,
) -> i32 {
    guard(None, "hp_camera_pinhole_look_at", || {
        let out = out_ptr(out, "out")?;
        let cam = Camera::pinhole_look_at(
            vec3(position, "position")?,
            vec3(target, "target")?,
            vec3(up, "up")?,
            fov_y_deg,
            width,
            height,
        )?;
        *out = camera_out(&cam, width, height);
        Ok(())
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_camera_ortho_look_at(
    position: *const f64,
    target: *const f64,
    up: *const f64,
    half_width: f64,
    half_height: f64,
    width: u32,
    height: u32,
    out: *mut HpCamera,
) -> i32 {
    guard(None, "hp_camera_ortho_look_at", || {
        let out = out_ptr(out, "out")?;
        let cam = Camera::ortho_look_at(
            vec3(position, "position")?,
            vec3(target, "target")?,
            vec3(up, "up")?,
            half_width,
            half_height,
        )?;
        *out = camera_out(&cam, width, height);
        Ok(())
    })
}

/// SCENES.md volume defaults: box [-1, 1]^3, near 0, far +inf, dt 0.01,
/// max_steps 1024, early stop 1e-4, fixed sampling, product transmittance,
/// black background, f32, CPU; the camera is left zeroed (width 0) so a
/// plan made without setting it is refused.
fn default_desc() -> HpPlanDesc {
    HpPlanDesc {
        next: std::ptr::null(),
        backend: BACKEND_CPU,
        precision: DTYPE_F32,
        camera: HpCamera {
            kind: CAMERA_PINHOLE,
            width: 0,
            height: 0,
            reserved: 0,
            fx: 0.0,
            fy: 0.0,
            cx: 0.0,
            cy: 0.0,
            half_width: 0.0,
            half_height: 0.0,
            c2w: [0.0; 12],
        },
        aabb_min: [-1.0; 3],
        aabb_max: [1.0; 3],
        near_t: 0.0,
        far_t: f64::INFINITY,
        dt: 0.01,
        early_stop: 1e-4,
        background: [0.0; 3],
        max_steps: 1024,
        sampling: SAMPLING_FIXED,
        seed: 0,
        trans_path: TRANS_PRODUCT,
    }
}

#[no_mangle]
pub unsafe extern "C" fn hp_plan_desc_default(out: *mut HpPlanDesc) -> i32 {
    guard(None, "hp_plan_desc_default", || {
        *out_ptr(out, "out")? = default_desc();
        Ok(())
    })
}

fn plan_of(ctx: *const HpCtx, d: &HpPlanDesc) -> Result<HpPlan> {
    no_next(d.next, "desc")?;
    if d.backend == BACKEND_GPU {
        return Err(Fail::not_supported(
            "desc.backend: HP_BACKEND_GPU (this version runs the CPU backend; see hp_get_header caps)",
        ));
    }
    if d.backend != BACKEND_CPU {
        return Err(Fail::error(format!(
            "desc.backend: unknown code {}",
            d.backend
        )));
    }
    let precision = match d.precision {
        DTYPE_F32 => Precision::F32,
        DTYPE_F64 => Precision::F64,
        p => {
            return Err(Fail::error(format!(
                "desc.precision: {p} (HP_DTYPE_F32 or HP_DTYPE_F64)"
            )))
        }
    };
    let c = &d.camera;
    let mut c2w = [[0.0; 4]; 3];
    for (r, row) in c2w.iter_mut().enumerate() {
        row.copy_from_slice(&c.c2w[r * 4..r * 4 + 4]);
    }
    let cam = match c.kind {
        CAMERA_PINHOLE => Camera::Pinhole {
            k: Intrinsics {
                fx: c.fx,
                fy: c.fy,
                cx: c.cx,
                cy: c.cy,
            },
            c2w,
        },
        CAMERA_ORTHO => Camera::Orthographic {
            c2w,
            half_width: c.half_width,
            half_height: c.half_height,
        },
        k => return Err(Fail::error(format!("desc.camera.kind: unknown code {k}"))),
    };
    cam.validate()
        .map_err(|e| Fail::error(format!("desc.camera: {e}")))?;
    let aabb = Aabb {
        min: d.aabb_min,
        max: d.aabb_max,
    };
    aabb.validate()
        .map_err(|e| Fail::error(format!("desc.{e}")))?;
    if !(d.near_t >= 0.0 && d.near_t.is_finite() && d.far_t > d.near_t) {
        return Err(Fail::error(format!(
            "desc.near_t/far_t: need 0 <= near_t < far_t, got {} and {}",
            d.near_t, d.far_t
        )));
    }
    let mut gen = RayGen::new(c.width, c.height);
    gen.aabb = aabb;
    gen.near = d.near_t;
    gen.far = d.far_t;
    gen.validate()
        .map_err(|e| Fail::error(format!("desc.camera.{e}")))?;
    let sampling = match d.sampling {
        SAMPLING_FIXED => Sampling::Fixed,
        SAMPLING_STRATIFIED => Sampling::Stratified { seed: d.seed },
        s => return Err(Fail::error(format!("desc.sampling: unknown code {s}"))),
    };
    let path = match d.trans_path {
        TRANS_PRODUCT => TransPath::Product,
        TRANS_LOG => TransPath::Log,
        p => return Err(Fail::error(format!("desc.trans_path: unknown code {p}"))),
    };
    let march = March {
        dt: d.dt,
        max_steps: d.max_steps,
        early_stop: d.early_stop,
        sampling,
        path,
        background: d.background,
    };
    march
        .validate()
        .map_err(|e| Fail::error(format!("desc.{e}")))?;
    Ok(HpPlan {
        ctx,
        precision,
        cam,
        gen,
        march,
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_plan_create(
    ctx: *mut HpCtx,
    desc: *const HpPlanDesc,
    out: *mut *mut HpPlan,
) -> i32 {
    let last = ctx.as_ref().map(|c| &c.last);
    guard(last, "hp_plan_create", || {
        let out = out_ptr(out, "out")?;
        *out = std::ptr::null_mut();
        if ctx.is_null() {
            return Err(Fail::error("ctx is NULL"));
        }
        let plan = plan_of(ctx, in_ref(desc, "desc")?)?;
        *out = Box::into_raw(Box::new(plan));
        Ok(())
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_plan_destroy(plan: *mut HpPlan) -> i32 {
    destroy(plan, "hp_plan_destroy")
}

#[no_mangle]
pub unsafe extern "C" fn hp_plan_ray_count(plan: *const HpPlan, count: *mut u64) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_plan_ray_count", || {
        *out_ptr(count, "count")? = in_ref(plan, "plan")?.ray_count();
        Ok(())
    })
}

/// Scratch bytes that always suffice for a stage with `n_rays` rays and
/// `n_samples` samples in the plan's precision. The CPU backend allocates its
/// scratch itself and refuses a step whose allocation is over `ws_bytes`
/// (the stage's memory budget): exact for `hp_ray`, `hp_samp` and `hp_int`
/// (their copies and buffers), an upper bound for `hp_diff` (its per-sample
/// records and reduction state), none for `hp_img`.
pub fn workspace_bytes(plan: &HpPlan, stage: u32, n_rays: u64, n_samples: u64) -> Result<u64> {
    let f = match plan.precision {
        Precision::F32 => 4u64,
        Precision::F64 => 8u64,
    };
    let per_ray = 8 * f + 4; // Rays<F>::BYTES_PER_RAY
    let per_sample = 4 + 6 * f; // Samples<F>::BYTES_PER_SAMPLE
    let per_intl = 2 * f; // Integrated<F>::BYTES_PER_SAMPLE
                          // f_diff's per-sample state: forward buffers, both grid reductions'
                          // records and the per-sample gradients.
    let per_diff = per_sample + per_intl + (4 + 4 * f) + (4 + 6 * f) + 4 * f;
    let mul = |a: u64, b: u64| a.checked_mul(b);
    let max = |a: Option<u64>, b: Option<u64>| Some(a?.max(b?));
    let bytes = match stage {
        STAGE_RAY => mul(n_rays, per_ray),
        STAGE_SAMP => max(mul(n_samples, per_sample), mul(n_rays, per_ray)),
        STAGE_INT => max(mul(n_samples, per_sample), mul(n_samples, per_intl)),
        STAGE_IMG => Some(0),
        STAGE_DIFF => mul(n_samples, per_diff).and_then(|b| b.checked_add(mul(n_rays, per_ray)?)),
        s => return Err(Fail::error(format!("stage: unknown code {s}"))),
    };
    bytes.ok_or_else(|| Fail::error("workspace size overflows"))
}

#[no_mangle]
pub unsafe extern "C" fn hp_workspace_size(
    plan: *const HpPlan,
    stage: u32,
    n_rays: u64,
    n_samples: u64,
    bytes: *mut usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_workspace_size", || {
        let out = out_ptr(bytes, "bytes")?;
        let b = workspace_bytes(in_ref(plan, "plan")?, stage, n_rays, n_samples)?;
        *out = usize::try_from(b).map_err(|_| Fail::error("workspace size overflows size_t"))?;
        Ok(())
    })
}
