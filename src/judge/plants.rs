//! Planted wrong outputs the judge must fail (STYLE.md "The judge tests
//! itself"), each with the verdict `TESTS/selftest/manifest.yaml` expects:
//! a NaN image, non-monotone t, broken offsets, a run that differs between
//! executions, a sign-flipped gradient (FAIL); a panic, an abort (ERROR); a
//! runaway loop (TIMEOUT); an unsupported backend (SKIP); and a good output
//! (PASS) so that a judge failing everything is caught too.
//!
//! The plants are the rows of `judge/ops/selftest.rs`; they live here, not
//! among the renderer wiring of `judge/ops/`, because they compute nothing
//! of a renderer.

use crate::error::{Error, Result};
use crate::judge::op::OpCtx;
use crate::tensor::{Outputs, Tensor};

fn image(nan: bool) -> Result<Tensor> {
    let mut v: Vec<f32> = (0..4 * 4 * 3).map(|i| i as f32 / 48.0).collect();
    if nan {
        v[17] = f32::NAN;
    }
    Tensor::from_shape_vec(&[4, 4, 3], v)
}

fn packed(t: Vec<f32>, off: Vec<i32>) -> Result<Outputs> {
    let mut o = Outputs::default();
    let (n, m) = (t.len(), off.len());
    o.tensor("t", Tensor::from_shape_vec(&[n], t)?)
        .tensor("off", Tensor::from_shape_vec(&[m], off)?);
    Ok(o)
}

pub fn good(_: &OpCtx) -> Result<Outputs> {
    let mut o = packed(vec![0.1, 0.2, 0.3, 0.5, 0.7], vec![0, 3, 5])?;
    o.tensor("rgb", image(false)?)
        .tensor("nothing", Tensor::from_shape_vec(&[4, 4], vec![0u8; 16])?)
        .tensor(
            "inside",
            Tensor::from_shape_vec(&[5], vec![1u8, 1, 1, 0, 0])?,
        );
    Ok(o)
}

pub fn nan_image(_: &OpCtx) -> Result<Outputs> {
    let mut o = Outputs::default();
    o.tensor("rgb", image(true)?);
    Ok(o)
}

pub fn non_monotone(_: &OpCtx) -> Result<Outputs> {
    packed(vec![0.1, 0.3, 0.2, 0.5, 0.7], vec![0, 3, 5])
}

pub fn broken_offsets(_: &OpCtx) -> Result<Outputs> {
    packed(vec![0.1, 0.2, 0.3, 0.5, 0.7], vec![0, 3, 2, 4])
}

pub fn nondeterministic(_: &OpCtx) -> Result<Outputs> {
    let nanos = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .map_or(0, |d| d.as_nanos());
    let v = vec![(nanos % 1_000_003) as i32, std::process::id() as i32];
    let mut o = Outputs::default();
    o.tensor("value", Tensor::from_shape_vec(&[2], v)?);
    Ok(o)
}

pub fn gradient(ctx: &OpCtx) -> Result<Outputs> {
    let flip: bool = ctx.param_or("flip", false)?;
    let x: Vec<f64> = (0..8).map(|i| 0.25 + i as f64 * 0.5).collect();
    let f = |x: &[f64]| x.iter().map(|v| v * v).sum::<f64>();
    let sign = if flip { -1.0 } else { 1.0 };
    let grad: Vec<f64> = x.iter().map(|v| sign * 2.0 * v).collect();
    let h = 1e-5;
    let fd: Vec<f64> = (0..x.len())
        .map(|i| {
            let (mut p, mut m) = (x.clone(), x.clone());
            p[i] += h;
            m[i] -= h;
            (f(&p) - f(&m)) / (2.0 * h)
        })
        .collect();
    let mut o = Outputs::default();
    o.tensor("grad", Tensor::from_shape_vec(&[8], grad)?)
        .tensor("fd", Tensor::from_shape_vec(&[8], fd)?);
    Ok(o)
}

pub fn panics(_: &OpCtx) -> Result<Outputs> {
    panic!("planted panic (judge self-test)")
}

pub fn aborts(_: &OpCtx) -> Result<Outputs> {
    std::process::abort()
}

pub fn hangs(_: &OpCtx) -> Result<Outputs> {
    loop {
        std::thread::sleep(std::time::Duration::from_millis(50));
    }
}

pub fn unsupported(_: &OpCtx) -> Result<Outputs> {
    Err(Error::NotSupported(
        "planted: this operation has no implementation on this backend".into(),
    ))
}
