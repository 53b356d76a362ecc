//! A backward pass (`f_diff`) as named tensors: `dsigma` (grid-shaped),
//! `dcolor` (nz, ny, nx, 3), their probe values `dsigma_probe` and
//! `dcolor_probe` (the probes of `volume::loss`), `dsigma_param`,
//! `dcolor_const`, `dhash` (a hash field's parameters, flat order),
//! per-sample gradients, `dcam` (6); counter `samples`,
//! metrics `grad_time_s`, `grads_per_s`, `bytes_per_sample`.

use crate::error::Result;
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};
use crate::volume::diff::Grads;
use crate::volume::field::{ColorDesc, FieldDesc};
use crate::volume::loss::{probe_colors, probe_nodes, ProbeSpec};
use crate::volume::VolumeParams;

pub fn grid_shape(f: &FieldDesc) -> Option<[usize; 3]> {
    match f {
        FieldDesc::Grid(g) => Some(g.shape),
        FieldDesc::Analytic(_) | FieldDesc::HashMlp(_) => None,
    }
}

pub fn color_shape(c: &ColorDesc) -> Option<[usize; 3]> {
    match c {
        ColorDesc::Grid(g) => Some(g.shape),
        ColorDesc::Constant(_) | ColorDesc::Mlp => None,
    }
}

/// Writes a backward pass's tensors (and probe values) into `out`.
pub fn grad_outputs<F: Real>(
    g: &Grads<F>,
    p: &VolumeParams,
    probes: &ProbeSpec,
    out: &mut Outputs,
) -> Result<()> {
    if let (Some(d), Some(s)) = (&g.dsigma, grid_shape(&p.field)) {
        out.tensor("dsigma", Tensor::real(&s, d.clone())?);
        let idx = probe_nodes(s, probes.sigma, probes.seed, 0);
        if !idx.is_empty() {
            out.tensor(
                "dsigma_probe",
                Tensor::real(&[idx.len()], idx.iter().map(|&i| d[i]).collect())?,
            );
        }
    }
    if let (Some(d), Some(s)) = (&g.dcolor, color_shape(&p.color)) {
        out.tensor("dcolor", Tensor::real(&[s[0], s[1], s[2], 3], d.clone())?);
        let idx = probe_colors(s, probes.color, probes.seed);
        if !idx.is_empty() {
            out.tensor(
                "dcolor_probe",
                Tensor::real(&[idx.len()], idx.iter().map(|&i| d[i]).collect())?,
            );
        }
    }
    if let Some(v) = &g.dsigma_param {
        out.tensor("dsigma_param", Tensor::real(&[v.len()], v.clone())?);
    }
    if let Some(v) = &g.dhash {
        out.tensor("dhash", Tensor::real(&[v.len()], v.clone())?);
    }
    if let Some(c) = g.dcolor_const {
        out.tensor("dcolor_const", Tensor::real(&[3], c.to_vec())?);
    }
    if let Some(v) = &g.dsigma_samples {
        out.tensor("dsigma_samples", Tensor::real(&[v.len()], v.clone())?);
    }
    if let Some(v) = &g.dcolor_samples {
        out.tensor("dcolor_samples", Tensor::real3(&[v.len()], v)?);
    }
    out.tensor("dcam", Tensor::real(&[6], g.dcam.to_vec())?);
    out.counter("samples", g.samples);
    out.metric("grad_time_s", g.time_s);
    out.metric("grads_per_s", g.samples as f64 / g.time_s.max(1e-12));
    out.metric("bytes_per_sample", g.bytes_per_sample as f64);
    Ok(())
}

/// The hash-grid gradients of `g`: `dhash_probe` at the flat indices
/// `idx`, all of `dhash`, `dcam` (6), metric `time_s`.
pub fn hash_outputs<F: Real>(g: Grads<F>, idx: &[usize], out: &mut Outputs) -> Result<()> {
    let dh = g.dhash.ok_or_else(|| {
        crate::error::Error::invalid("volume.hash_grad", "f_diff returned no dhash")
    })?;
    out.tensor(
        "dhash_probe",
        Tensor::real(&[idx.len()], idx.iter().map(|&i| dh[i]).collect())?,
    );
    out.tensor("dhash", Tensor::real(&[dh.len()], dh)?);
    out.tensor("dcam", Tensor::real(&[6], g.dcam.to_vec())?);
    out.metric("time_s", g.time_s);
    Ok(())
}
