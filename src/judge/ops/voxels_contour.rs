//! Contour operation of the `voxels` renderer (issue 14): wiring only.
//!
//! | op | what |
//! | --- | --- |
//! | `voxels.contour_error` | sphere scenes: the camera rays cast with cubes and with contours; `t` error of each against the analytic sphere (`cube_err_max`, `cube_err_p99`, `contour_err_max`, `contour_err_p99`, world units, over rays that meet the sphere and hit in both casts); per ray `box_excess` (how far the contour hit point lies outside its voxel's box) and `slab_excess` (outside its slab), both in voxel edges, 0 on rays without a contour hit |

use super::voxels::{ball_entry, camera_batch};
use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::real::Precision;
use crate::tensor::{Outputs, Tensor};
use crate::voxels::cast::{CastParams, CastReal};
use crate::voxels::contour::{decode, fit_all};
use crate::voxels::octree::build;
use crate::voxels::render::{cast_all, cast_all_contours};
use crate::voxels::shape::Shape;

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "voxels.contour_error",
    doc: "t error of cubes vs contours against the analytic sphere (max, p99); per ray box_excess and slab_excess of contour hits",
    params: &[],
    support: Support::Cpu,
    run: contour_error,
}];

/// Max and 99th percentile (nearest rank) of `v` (0, 0 when empty).
fn max_p99(mut v: Vec<f64>) -> (f64, f64) {
    if v.is_empty() {
        return (0.0, 0.0);
    }
    v.sort_by(f64::total_cmp);
    let k = ((0.99 * v.len() as f64).ceil() as usize).clamp(1, v.len()) - 1;
    (v[v.len() - 1], v[k])
}

fn run_in<F: CastReal>(ctx: &OpCtx, radius: f64) -> Result<Outputs> {
    let sc = crate::scene::voxels::parse(ctx.scene()?)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let cs = fit_all(&sc.shape, &tree)?;
    let b = camera_batch::<F>(ctx, &sc, None)?;
    let p = CastParams {
        near: b.near,
        far: b.far,
        lod: None,
        max_iter: sc.max_iter,
    };
    let cube = cast_all::<F>(&tree, &b.o, &b.d, &p);
    let (con, used) = cast_all_contours::<F>(&tree, &cs, &b.o, &b.d, &p);
    let s = 2.0 / (1u64 << sc.depth) as f64;
    let n = b.o.len();
    let (mut e_cube, mut e_con) = (Vec::new(), Vec::new());
    let mut box_excess = vec![0.0f64; n];
    let mut slab_excess = vec![0.0f64; n];
    for i in 0..n {
        let o = b.o[i].map(|x| x.f64());
        let d = b.d[i].map(|x| x.f64());
        let l = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
        let exact = ball_entry(o, d.map(|x| x / l), radius, b.near).map(|t| t / l);
        if let Some(te) = exact {
            if cube.hit[i] == 1 && con.hit[i] == 1 {
                e_cube.push((cube.t[i].f64() - te).abs());
                e_con.push((con.t[i].f64() - te).abs());
            }
        }
        if con.hit[i] == 1 && used[i] != 0 {
            let t = con.t[i].f64();
            let x = [0, 1, 2].map(|a| o[a] + t * d[a]);
            let lo = con.leaf[i].map(|v| -1.0 + v as f64 * s);
            box_excess[i] = (0..3)
                .map(|a| (lo[a] - x[a]).max(x[a] - lo[a] - s).max(0.0) / s)
                .fold(0.0, f64::max);
            let (nn, pp, hh) = decode::<f64>(used[i]);
            let f = (0..3)
                .map(|a| nn[a] * (x[a] - lo[a] - 0.5 * s))
                .sum::<f64>()
                / s;
            slab_excess[i] = ((f - pp).abs() - hh).max(0.0);
        }
    }
    let (cmax, cp99) = max_p99(e_cube);
    let (kmax, kp99) = max_p99(e_con);
    let mut out = Outputs::default();
    for (name, v) in [
        ("cube_err_max", cmax),
        ("cube_err_p99", cp99),
        ("contour_err_max", kmax),
        ("contour_err_p99", kp99),
    ] {
        out.metric(name, v);
        out.tensor(name, Tensor::scalar(v));
    }
    out.metric("voxel_size", s);
    out.counter(
        "contour_hits",
        used.iter().filter(|&&v| v != 0).count() as u64,
    );
    out.counter("contours", cs.iter().filter(|&&v| v != 0).count() as u64);
    out.tensor("box_excess", Tensor::from_shape_vec(&b.shape, box_excess)?);
    out.tensor(
        "slab_excess",
        Tensor::from_shape_vec(&b.shape, slab_excess)?,
    );
    out.tensor("t", Tensor::real(&b.shape, con.t)?);
    out.tensor("hit", Tensor::from_shape_vec(&b.shape, con.hit)?);
    Ok(out)
}

fn contour_error(ctx: &OpCtx) -> Result<Outputs> {
    let sc = crate::scene::voxels::parse(ctx.scene()?)?;
    let Shape::Sphere { radius } = sc.shape else {
        return Err(Error::invalid(
            ctx.scene()?.at(),
            "voxels.contour_error needs a `shape: {type: sphere}` scene",
        ));
    };
    match ctx.precision {
        Precision::F32 => run_in::<f32>(ctx, radius),
        Precision::F64 => run_in::<f64>(ctx, radius),
    }
}
