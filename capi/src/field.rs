//! Fields: `hp_field_create_*`, `hp_field_destroy`.
//!
//! A field owns a copy of its values (the caller's tensor may be freed after
//! the call). Grids span the world box of the plan they are rendered with
//! (node-aligned, SCENES.md "Dense grid"), so one field serves plans with
//! different boxes. Analytic kinds take their parameters as a flat double
//! array:
//!
//! | kind | params |
//! | --- | --- |
//! | `HP_ANALYTIC_CONSTANT` | s |
//! | `HP_ANALYTIC_SLABS` | axis, nb, breaks[nb], sigma[nb - 1] |
//! | `HP_ANALYTIC_GAUSSIAN` | amplitude, mean x, y, z, std |
//! | `HP_ANALYTIC_SHELL` | centre x, y, z, r0, r1, s |
//! | `HP_ANALYTIC_LINEAR` | a, g x, y, z |

use hotpath::rays::Aabb;
use hotpath::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc, Oob};

use crate::abi::*;
use crate::fail::{guard, Fail, Result};
use crate::plan::{in_ref, out_ptr, HpCtx};
use crate::view::{DType, View, Want};

/// `hp_field`: a density or a colour field, box-free.
pub enum HpField {
    Density(FieldDesc),
    Color(ColorDesc),
}

impl HpField {
    /// The density description for a plan's box; `at` names the argument.
    pub fn density(&self, aabb: &Aabb, at: &str) -> Result<FieldDesc> {
        match self {
            HpField::Density(FieldDesc::Grid(g)) => Ok(FieldDesc::Grid(boxed(g, aabb))),
            HpField::Density(FieldDesc::Analytic(a)) => {
                a.validate(at, aabb.min, aabb.max)?;
                Ok(FieldDesc::Analytic(a.clone()))
            }
            HpField::Density(FieldDesc::HashMlp(_)) => Err(Fail::error(format!(
                "{at}: hash_mlp fields are not offered through the C ABI"
            ))),
            HpField::Color(_) => Err(Fail::error(format!(
                "{at}: a colour field where a density field is needed"
            ))),
        }
    }

    /// The colour description for a plan's box.
    pub fn color(&self, aabb: &Aabb, at: &str) -> Result<ColorDesc> {
        match self {
            HpField::Color(ColorDesc::Grid(g)) => Ok(ColorDesc::Grid(boxed(g, aabb))),
            HpField::Color(c) => Ok(c.clone()),
            HpField::Density(_) => Err(Fail::error(format!(
                "{at}: a density field where a colour field is needed"
            ))),
        }
    }
}

fn boxed(g: &GridDesc, aabb: &Aabb) -> GridDesc {
    GridDesc {
        bmin: aabb.min,
        bmax: aabb.max,
        ..g.clone()
    }
}

fn oob_of(oob: u32) -> Result<Oob> {
    match oob {
        OOB_ZERO => Ok(Oob::Zero),
        OOB_CLAMP => Ok(Oob::Clamp),
        o => Err(Fail::error(format!("oob: unknown code {o}"))),
    }
}

/// A grid from a (nz, ny, nx) or (nz, ny, nx, 3) tensor, values validated.
fn grid_of(t: &HpTensor, interp: u32, oob: u32, ch: usize) -> Result<GridDesc> {
    if interp != INTERP_TRILINEAR {
        return Err(Fail::not_supported(format!(
            "interp: code {interp} (only HP_INTERP_TRILINEAR in this version)"
        )));
    }
    let oob = oob_of(oob)?;
    let shape: &[Option<usize>] = if ch == 1 {
        &[None, None, None]
    } else {
        &[None, None, None, Some(3)]
    };
    let v = View::check(
        t,
        &Want {
            name: "grid",
            dtypes: &[DType::F32, DType::F64],
            shape,
            output: false,
        },
    )?;
    let data: Vec<f64> = (0..v.len()).map(|i| unsafe { v.get(i) }).collect();
    let g = GridDesc {
        shape: [v.shape[0], v.shape[1], v.shape[2]],
        ch,
        data,
        oob,
        bmin: Aabb::UNIT.min,
        bmax: Aabb::UNIT.max,
    };
    g.validate("grid", ch == 1)?;
    Ok(g)
}

unsafe fn create(
    ctx: *const HpCtx,
    what: &str,
    out: *mut *mut HpField,
    make: impl FnOnce() -> Result<HpField>,
) -> i32 {
    let last = ctx.as_ref().map(|c| &c.last);
    guard(last, what, || {
        let out = out_ptr(out, "out")?;
        *out = std::ptr::null_mut();
        in_ref(ctx, "ctx")?;
        *out = Box::into_raw(Box::new(make()?));
        Ok(())
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_create_grid_sigma(
    ctx: *const HpCtx,
    grid: *const HpTensor,
    interp: u32,
    oob: u32,
    out: *mut *mut HpField,
) -> i32 {
    create(ctx, "hp_field_create_grid_sigma", out, || {
        let g = grid_of(in_ref(grid, "grid")?, interp, oob, 1)?;
        Ok(HpField::Density(FieldDesc::Grid(g)))
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_create_grid_color(
    ctx: *const HpCtx,
    grid: *const HpTensor,
    interp: u32,
    oob: u32,
    out: *mut *mut HpField,
) -> i32 {
    create(ctx, "hp_field_create_grid_color", out, || {
        let g = grid_of(in_ref(grid, "grid")?, interp, oob, 3)?;
        Ok(HpField::Color(ColorDesc::Grid(g)))
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_create_hash_mlp(
    ctx: *const HpCtx,
    params: *const HpTensor,
    out: *mut *mut HpField,
) -> i32 {
    create(ctx, "hp_field_create_hash_mlp", out, || {
        in_ref(params, "params")?;
        Err(Fail::not_supported(
            "the hash-grid + MLP field is not in this build (HP_CAP_FIELD_HASH_MLP is unset)",
        ))
    })
}

/// Parses the flat parameter array of an analytic kind (table above).
fn analytic_of(kind: u32, p: &[f64]) -> Result<Analytic> {
    let need = |n: usize, name: &str| -> Result<()> {
        if p.len() == n {
            Ok(())
        } else {
            Err(Fail::error(format!(
                "params: {name} takes {n} values, got {}",
                p.len()
            )))
        }
    };
    let v3 = |i: usize| [p[i], p[i + 1], p[i + 2]];
    Ok(match kind {
        ANALYTIC_CONSTANT => {
            need(1, "constant")?;
            Analytic::Constant { s: p[0] }
        }
        ANALYTIC_GAUSSIAN => {
            need(5, "gaussian")?;
            Analytic::Gaussian {
                amplitude: p[0],
                mean: v3(1),
                std: p[4],
            }
        }
        ANALYTIC_SHELL => {
            need(6, "shell")?;
            Analytic::Shell {
                centre: v3(0),
                r0: p[3],
                r1: p[4],
                s: p[5],
            }
        }
        ANALYTIC_LINEAR => {
            need(4, "linear")?;
            Analytic::Linear { a: p[0], g: v3(1) }
        }
        ANALYTIC_SLABS => {
            if p.len() < 2 || !(p[1] >= 2.0 && p[1] <= 1e6 && p[1].fract() == 0.0) {
                return Err(Fail::error(
                    "params: slabs takes axis, nb (>= 2), breaks[nb], sigma[nb - 1]",
                ));
            }
            let nb = p[1] as usize;
            need(2 + nb + nb - 1, "slabs with this nb")?;
            if !(p[0] == 0.0 || p[0] == 1.0 || p[0] == 2.0) {
                return Err(Fail::error(format!(
                    "params: slabs axis {} (0, 1 or 2)",
                    p[0]
                )));
            }
            Analytic::Slabs {
                axis: p[0] as usize,
                breaks: p[2..2 + nb].to_vec(),
                sigma: p[2 + nb..].to_vec(),
            }
        }
        k => return Err(Fail::error(format!("kind: unknown code {k}"))),
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_create_analytic(
    ctx: *const HpCtx,
    kind: u32,
    params: *const f64,
    n_params: usize,
    out: *mut *mut HpField,
) -> i32 {
    create(ctx, "hp_field_create_analytic", out, || {
        if params.is_null() && n_params > 0 {
            return Err(Fail::error("params is NULL"));
        }
        if n_params > 4_000_000 {
            return Err(Fail::error(format!("n_params {n_params} is too large")));
        }
        let p: &[f64] = if n_params == 0 {
            &[]
        } else {
            std::slice::from_raw_parts(params, n_params)
        };
        let a = analytic_of(kind, p)?;
        // Box-independent checks now; `linear`'s sign condition is checked
        // against the plan's box when the field is rendered.
        if !matches!(a, Analytic::Linear { .. }) {
            a.validate("params", Aabb::UNIT.min, Aabb::UNIT.max)?;
        } else if p.iter().any(|v| !v.is_finite()) {
            return Err(Fail::error("params: linear values must be finite"));
        }
        Ok(HpField::Density(FieldDesc::Analytic(a)))
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_create_color_constant(
    ctx: *const HpCtx,
    rgb: *const f64,
    out: *mut *mut HpField,
) -> i32 {
    create(ctx, "hp_field_create_color_constant", out, || {
        if rgb.is_null() {
            return Err(Fail::error("rgb is NULL"));
        }
        let c = [*rgb, *rgb.add(1), *rgb.add(2)];
        if c.iter().any(|v| !v.is_finite()) {
            return Err(Fail::error("rgb: values must be finite"));
        }
        Ok(HpField::Color(ColorDesc::Constant(c)))
    })
}

#[no_mangle]
pub unsafe extern "C" fn hp_field_destroy(field: *mut HpField) -> i32 {
    crate::plan::destroy(field, "hp_field_destroy")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn analytic_parameter_counts_are_checked() {
        assert!(analytic_of(ANALYTIC_GAUSSIAN, &[20.0, 0.0, 0.0, 0.0, 0.3]).is_ok());
        let e = analytic_of(ANALYTIC_GAUSSIAN, &[20.0]).unwrap_err();
        assert!(
            e.msg.contains("gaussian takes 5 values, got 1"),
            "{}",
            e.msg
        );
        let s = analytic_of(ANALYTIC_SLABS, &[0.0, 3.0, -1.0, 0.0, 1.0, 2.0, 3.0]).unwrap();
        assert!(matches!(s, Analytic::Slabs { ref sigma, .. } if sigma == &[2.0, 3.0]));
        assert!(analytic_of(ANALYTIC_SLABS, &[0.0, 3.0, -1.0]).is_err());
        assert!(analytic_of(99, &[]).is_err());
    }
}
