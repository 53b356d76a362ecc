//! Checks that a rough conductor's Fresnel reflectance reaches both ways a
//! path uses the material: `eval` (light sampling) and `sample`'s weight
//! (BSDF sampling). `pathtrace.bsdf_checks` runs at reflectance 1, where
//! a dropped reflectance cannot show.
//!
//! | op | what |
//! | --- | --- |
//! | `pathtrace.reflectance_applied` | per `wo` angle and channel: `eval_ratio`, `weight_ratio` (reflectance r over reflectance 1, same directions) and `expected` (r) |

use glam::Vec3A;

use super::{OpCtx, OpEntry, Support};
use crate::error::{Error, Result};
use crate::pathtrace::Material;
use crate::rng::rand_f32;
use crate::tensor::{Outputs, Tensor};

pub const OPS: &[OpEntry] = &[OpEntry {
    name: "pathtrace.reflectance_applied",
    doc: "rough conductor: eval_ratio and weight_ratio (reflectance r over 1, same directions) and expected = r, per wo angle and channel",
    params: &["thetas", "samples", "alpha", "reflectance"],
    support: Support::Cpu,
    run: reflectance_applied,
}];

/// For each `wo` polar angle (degrees) and `samples` random draws: the
/// sums over draws of `f` (at `wi` from a cosine-weighted direction) and of
/// the sampled weight, with reflectance `r` and with reflectance 1 on the
/// same random numbers; their per-channel ratios must equal `r`.
fn reflectance_applied(ctx: &OpCtx) -> Result<Outputs> {
    let thetas: Vec<f32> = ctx.param_or("thetas", vec![0.0, 30.0, 60.0, 85.0])?;
    let n: u32 = ctx.param_or("samples", 10_000)?;
    let alpha: f32 = ctx.param_or("alpha", 0.1)?;
    let r: [f32; 3] = ctx.param_or("reflectance", [0.8, 0.8, 0.9])?;
    if thetas.iter().any(|t| !(0.0..90.0).contains(t)) || n == 0 || alpha.is_nan() || alpha <= 0.0 {
        return Err(Error::invalid(
            format!("{} params", ctx.case_id),
            "thetas in [0, 90) degrees, samples >= 1, alpha > 0",
        ));
    }
    let with = |refl: Vec3A| Material::RoughConductor {
        alpha,
        reflectance: refl,
    };
    let (m, one) = (with(Vec3A::from_array(r)), with(Vec3A::ONE));
    let (mut eval_ratio, mut weight_ratio, mut expected) = (vec![], vec![], vec![]);
    for (row, &th) in thetas.iter().enumerate() {
        let t = th.to_radians();
        let wo = Vec3A::new(t.sin() * 0.4f32.cos(), t.sin() * 0.4f32.sin(), t.cos());
        // f64 sums: f32 sums of 2e4 terms would differ by rounding alone.
        let (mut e, mut e1, mut w, mut w1) = ([0.0f64; 3], [0.0f64; 3], [0.0f64; 3], [0.0f64; 3]);
        let acc = |s: &mut [f64; 3], v: Vec3A| (0..3).for_each(|c| s[c] += v[c] as f64);
        for i in 0..n {
            let u = |k| rand_f32(ctx.seed ^ 0x5eed, i, row as u32, k);
            let wi = crate::pathtrace::bsdf::cosine_hemisphere([u(0), u(1)]);
            acc(&mut e, m.eval(wo, wi));
            acc(&mut e1, one.eval(wo, wi));
            let (a, b) = (
                m.sample(wo, u(2), [u(3), u(4)]),
                one.sample(wo, u(2), [u(3), u(4)]),
            );
            if let (Some(a), Some(b)) = (a, b) {
                acc(&mut w, a.weight);
                acc(&mut w1, b.weight);
            }
        }
        for c in 0..3 {
            eval_ratio.push(e[c] / e1[c]);
            weight_ratio.push(w[c] / w1[c]);
            expected.push(r[c] as f64);
        }
    }
    let shape = [thetas.len(), 3];
    let mut out = Outputs::default();
    out.tensor("eval_ratio", Tensor::real(&shape, eval_ratio)?);
    out.tensor("weight_ratio", Tensor::real(&shape, weight_ratio)?);
    out.tensor("expected", Tensor::real(&shape, expected)?);
    Ok(out)
}
