//! `f_diff` on the GPU backend: [`f_diff_gpu`] takes what [`super::f_diff`]
//! takes for the unfused chain and returns the same [`Grads<f32>`], computed
//! by `kernels/volume_diff.wgsl` through `crate::gpu::volume_diff`
//! (issue 19). Dense-grid, constant and slab densities; grid and constant
//! colours; the pose. The fields are rounded to f32 as the CPU f32 render
//! rounds them (`crate::volume::gpu::GpuScene`).
//!
//! The fixed-point scales need a bound of each gradient value's sum of
//! magnitudes, derived here from the upstream gradients alone:
//! - colour: `|dL/dc_k| = |g| w_k` and `sum_k w_k <= 1` per ray, so any
//!   colour value's sum is at most `B_c = sum_rays max_ch |g|`;
//! - density: `dL/dtau_k = T_{k+1} e_k - s_k + g_O T_N` with
//!   `|e_k| <= E = |g|_1 c_max + |g_D| t_1` (`c_max` bounds the colours and
//!   the background) and `|s_k| <= E` (weights and `T_N` sum to 1), so
//!   `|dL/dsigma_k| <= (2E + |g_O|) dt_k` and `sum_k dt_k <= t_1 - t_0`:
//!   `B_s = sum_rays (2E + |g_O|)(t_1 - t_0)`.
//!
//! Trilinear corner weights are at most 1 and sum to 1, so a node's sum is
//! bounded by the same figures. `t_0`, `t_1` come from `f_ray` in f32.
//!
//! A hash-grid + MLP field (colours in (0, 1), so `c_max = max(1, bg)`):
//! any one parameter's gradient at a sample is at most `S max(|dL/dsigma_k|,
//! max_ch |dL/dc_k|)`, `S` the field's sensitivity ([`hash_sensitivity`]),
//! so its sum over samples is at most `B_h = S (B_s + B_c)`.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::volume_diff::{f_diff as gpu_f_diff, DiffInput};
use crate::gpu::GpuContext;
use crate::rays::{f_ray, RayGen};

use super::super::field::hash::HashMlp;
use super::super::field::{ColorField, Field};
use super::super::gpu::GpuScene;
use super::super::VolumeParams;
use super::{Grads, Upstream};
use crate::gpu::volume::UNFUSED_BYTES_PER_SAMPLE;

/// A GPU backward pass and the seconds of the forward chain it ran first.
pub struct GpuDiff {
    pub grads: Grads<f32>,
    pub forward_s: f64,
}

/// The backward pass of `params` on the GPU for upstream gradients `up`
/// (one per ray of the region); `float_atomic` takes the f32
/// compare-exchange fast path instead of the deterministic fixed point.
pub fn f_diff_gpu(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    up: &Upstream<f32>,
    float_atomic: bool,
    budget: &MemBudget,
) -> Result<GpuDiff> {
    let scene = GpuScene::new(params, gen, budget)?;
    let input = scene.input()?;
    let rays = f_ray::<f32>(cam, gen, budget)?;
    let n = rays.len();
    if up.rgb.len() != n
        || up.depth.as_ref().is_some_and(|v| v.len() != n)
        || up.opacity.as_ref().is_some_and(|v| v.len() != n)
    {
        return Err(crate::error::Error::invalid(
            "f_diff upstream",
            format!("need one gradient per ray ({n})"),
        ));
    }
    let gd = |r: usize| up.depth.as_ref().map_or(0.0, |v| v[r]);
    let go = |r: usize| up.opacity.as_ref().map_or(0.0, |v| v[r]);
    let packed: Vec<[f32; 4]> = (0..n)
        .flat_map(|r| {
            let g = up.rgb[r];
            [[g[0], g[1], g[2], gd(r)], [go(r), 0.0, 0.0, 0.0]]
        })
        .collect();
    let bg = scene.m.background;
    let cmax = match &scene.color {
        ColorField::Constant(c) => c.iter().fold(0.0f32, |a, v| a.max(v.abs())),
        ColorField::Grid(g) => g.data.iter().fold(0.0f32, |a, v| a.max(v.abs())),
        ColorField::Mlp => 1.0,
    }
    .max(bg.iter().fold(0.0f32, |a, v| a.max(v.abs()))) as f64;
    let (mut bound_sigma, mut bound_color) = (0.0f64, 0.0f64);
    for r in 0..n {
        let (t0, t1) = (rays.t0[r] as f64, rays.t1[r] as f64);
        if t1 <= t0 {
            continue;
        }
        let g = up.rgb[r].map(|v| v.abs() as f64);
        let e = (g[0] + g[1] + g[2]) * cmax + (gd(r).abs() as f64) * t1.abs();
        bound_sigma += (2.0 * e + go(r).abs() as f64) * (t1 - t0);
        bound_color += g[0].max(g[1]).max(g[2]);
    }
    let m = cam.c2w();
    let f3 = |a: [f64; 3]| a.map(|v| v as f32);
    let d = DiffInput {
        up: &packed,
        pose_r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| m[i][j] as f32)),
        pose_c: [0, 1, 2].map(|i| m[i][3] as f32),
        bmin: f3(gen.aabb.min),
        bmax: f3(gen.aabb.max),
        near: gen.near as f32,
        far: gen.far as f32,
        bound_sigma,
        bound_color,
        bound_hash: match &scene.field {
            Field::HashMlp(h) => hash_sensitivity(h) * (bound_sigma + bound_color),
            _ => 0.0,
        },
        float_atomic,
    };
    let g = gpu_f_diff(ctx, cam, gen, &input, &d, budget)?;
    let grid_density = matches!(scene.field, Field::Grid(_));
    let params_density = matches!(scene.field, Field::Constant { .. } | Field::Slabs { .. });
    Ok(GpuDiff {
        grads: Grads {
            dsigma: grid_density.then_some(g.sigma),
            dsigma_param: params_density.then_some(g.param),
            dcolor: matches!(scene.color, ColorField::Grid(_)).then_some(g.color),
            dcolor_const: matches!(scene.color, ColorField::Constant(_)).then_some(g.color_const),
            dhash: matches!(scene.field, Field::HashMlp(_)).then_some(g.hash),
            dsigma_samples: None,
            dcolor_samples: None,
            dcam: g.dcam.map(|v| v as f32),
            samples: g.samples,
            bytes_per_sample: UNFUSED_BYTES_PER_SAMPLE,
            time_s: g.backward_s,
        },
        forward_s: g.forward_s,
    })
}

/// A bound `S` of any one parameter's gradient per unit of
/// `max |dL/d(sigma, rgb)|` at one point, by interval bounds through the
/// network: activations `|a_q| <= A_q` forward (`A_0 = max |table|`, the
/// trilinear weights sum to 1), then `|dL/dz| <= D_q` backward (`D = 1` at
/// the outputs: softplus' and relu' <= 1, sigmoid' <= 1/4; `D_{q-1} =
/// max_i sum_o |W_oi| D_q`); weights get `D_q A_q`, biases `D_q`, table
/// entries `D` at the encoding.
pub fn hash_sensitivity(h: &HashMlp<f32>) -> f64 {
    let amax = |v: &[f32]| v.iter().fold(0.0f64, |m, x| m.max(x.abs() as f64));
    let mut a = vec![amax(&h.table)];
    for l in &h.layers[..h.layers.len() - 1] {
        let top = a[a.len() - 1];
        let z = (0..l.out)
            .map(|o| {
                amax(&l.b[o..=o])
                    + l.w[o * l.inp..(o + 1) * l.inp]
                        .iter()
                        .map(|w| w.abs() as f64)
                        .sum::<f64>()
                        * top
            })
            .fold(0.0f64, f64::max);
        a.push(z);
    }
    let (mut d, mut s) = (1.0f64, 0.0f64);
    for (q, l) in h.layers.iter().enumerate().rev() {
        s = s.max(d * a[q].max(1.0));
        d *= (0..l.inp)
            .map(|i| {
                (0..l.out)
                    .map(|o| l.w[o * l.inp + i].abs() as f64)
                    .sum::<f64>()
            })
            .fold(0.0f64, f64::max);
    }
    s.max(d)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rand_f64;
    use crate::volume::diff::{f_diff, DiffOptions, Reduce};
    use crate::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc, Oob};
    use crate::volume::sample::{Sampling, TransPath};
    use crate::volume::Chain;

    fn params(field: FieldDesc, color: ColorDesc) -> VolumeParams {
        VolumeParams {
            field,
            color,
            dt: 0.05,
            max_steps: 1024,
            early_stop: 1e-4,
            sampling: Sampling::Stratified { seed: 3 },
            path: TransPath::Log,
            background: [0.1, 0.2, 0.3],
            occupancy: 0,
        }
    }

    fn grid() -> VolumeParams {
        let sig = GridDesc::sample([5, 6, 7], [-1.0; 3], [1.0; 3], Oob::Zero, |x| {
            3.0 + 2.0 * x[0] - x[1] * x[2]
        });
        let mut col = GridDesc::filled([4, 4, 4], &[0.5; 3], [-1.0; 3], [1.0; 3], Oob::Clamp);
        for (i, v) in col.data.iter_mut().enumerate() {
            *v = 0.2 + 0.6 * rand_f64(3, i as u32, 0, 0);
        }
        params(FieldDesc::Grid(sig), ColorDesc::Grid(col))
    }

    fn up<F: crate::real::Real>(n: usize) -> Upstream<F> {
        let r = |i: usize, c: u32| F::of(rand_f64(7, i as u32, 0, c) - 0.3);
        Upstream {
            rgb: (0..n).map(|i| [0, 1, 2].map(|c| r(i, c))).collect(),
            depth: Some((0..n).map(|i| r(i, 3)).collect()),
            opacity: Some((0..n).map(|i| r(i, 4)).collect()),
        }
    }

    fn max_rel(a: &[f32], b: &[f64]) -> f64 {
        let scale = b.iter().fold(0.0f64, |m, v| m.max(v.abs())).max(1e-30);
        a.iter()
            .zip(b)
            .fold(0.0f64, |m, (x, y)| m.max((*x as f64 - y).abs()))
            / scale
    }

    /// GPU f32 against CPU f64 (both unfused), and two GPU runs.
    fn check(p: &VolumeParams) {
        let Ok(ctx) = GpuContext::get() else {
            eprintln!("no GPU adapter: skipped");
            return;
        };
        let cam = Camera::pinhole_look_at([0.3, 0.2, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 16, 12)
            .unwrap();
        let gen = RayGen::new(16, 12);
        let budget = MemBudget::fixed(1 << 28);
        let opt = DiffOptions {
            chain: Chain::Unfused,
            reduce: Reduce::Sorted,
            per_sample: false,
        };
        let cpu = f_diff::<f64>(&cam, &gen, p, &up(192), &opt, None, &budget).unwrap();
        let a = f_diff_gpu(ctx, &cam, &gen, p, &up(192), false, &budget).unwrap();
        let b = f_diff_gpu(ctx, &cam, &gen, p, &up(192), false, &budget).unwrap();
        assert_eq!(
            a.grads,
            Grads {
                time_s: a.grads.time_s,
                ..b.grads.clone()
            }
        );
        assert_eq!(a.grads.samples, cpu.samples);
        let g = &a.grads;
        for (name, x, y) in [
            ("dsigma", &g.dsigma, &cpu.dsigma),
            ("dcolor", &g.dcolor, &cpu.dcolor),
            ("dsigma_param", &g.dsigma_param, &cpu.dsigma_param),
        ] {
            assert_eq!(x.is_some(), y.is_some(), "{name}");
            if let (Some(x), Some(y)) = (x, y) {
                let e = max_rel(x, y);
                eprintln!("{name}: max |gpu - cpu f64| / max |cpu| = {e:.3e}");
                assert!(e < 5e-6, "{name}: max error {e} of the largest |value|");
            }
        }
        if let (Some(x), Some(y)) = (g.dcolor_const, cpu.dcolor_const) {
            assert!(max_rel(&x, &y) < 5e-6, "{x:?} vs {y:?}");
        }
        let e = max_rel(&g.dcam, &cpu.dcam);
        eprintln!("dcam: {e:.3e}");
        assert!(e < 2e-5, "dcam {:?} vs {:?}: {e}", g.dcam, cpu.dcam);
    }

    #[test]
    fn gpu_backward_matches_cpu_f64_on_grids_and_repeats_bit_for_bit() {
        check(&grid());
    }

    #[test]
    fn gpu_backward_matches_cpu_f64_on_slabs_and_constant_colour() {
        check(&params(
            FieldDesc::Analytic(Analytic::Slabs {
                axis: 2,
                breaks: vec![-0.6, -0.1, 0.3, 0.7],
                sigma: vec![0.8, 2.5, 1.2],
            }),
            ColorDesc::Constant([0.9, 0.4, 0.2]),
        ));
    }
}
