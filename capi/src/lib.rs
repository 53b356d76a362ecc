//! hotpath's C ABI: the volume stages as `hp_*` functions (seed 000,
//! sections 6, 7 and 10), declared in `include/hotpath.h` and documented in
//! `docs/c-api.md`.
//!
//! | file | entry points |
//! | --- | --- |
//! | `plan.rs` | `hp_get_header`, `hp_ctx_*`, `hp_last_error`, `hp_camera_*`, `hp_plan_*`, `hp_workspace_size` |
//! | `field.rs` | `hp_field_create_grid_sigma`, `_grid_color`, `_hash_mlp`, `_analytic`, `_color_constant`, `hp_field_destroy` |
//! | `stages.rs` | `hp_ray`, `hp_samp`, `hp_int`, `hp_img`, `hp_diff` |
//! | `view.rs` | `hp_tensor` validation and strided access |
//! | `fail.rs` | status codes, messages, panics caught at the boundary |
//! | `abi.rs` | `#[repr(C)]` mirrors of the header's structs and constants |
//!
//! Every entry point validates its arguments before reading or writing
//! anything and catches panics: a wrong call returns `HP_ERROR` or
//! `HP_NOT_SUPPORTED` with a message (`hp_ctx_last_error`), never crashes.

// The entry points are `unsafe extern "C"`: their safety contract is the C
// one written in docs/c-api.md (valid pointers, views that match memory).
#![allow(clippy::missing_safety_doc)]

pub mod abi;
pub mod fail;
pub mod field;
pub mod plan;
pub mod stages;
pub mod view;
