//! Which hash-table values of a render's gradient sit on a ReLU kink: the
//! table rows touched by a lattice sample where the network is within a
//! margin of a kink (`HashMlp::near_kink`). There the f64 reference and an
//! f32 backend may take different sides of the jump, and a parity check
//! excuses those values (`dhash_smooth` = 0) as the volume cases excuse
//! samples on occupancy faces or at the lattice end.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::{f_ray, RayGen};
use crate::tensor::{Outputs, Tensor};

use super::field::hash::{HashMlp, HashMlpDesc};
use super::sample::f_samp;
use super::{prepare, VolumeParams};

/// Default `kink_margin`: 4e-6 of a pre-activation's terms, about six f32
/// ulps of the sample position (one ulp of x moved the H100's kink sample
/// by 6.3e-7 of its terms).
pub const KINK_MARGIN: f64 = 4e-6;

/// [`dhash_smooth`] as outputs: tensor `dhash_smooth`, counters
/// `kink_samples` and `kink_params` (table values left out).
pub fn smooth_outputs(
    (cam, gen, params): (&Camera, &RayGen, &VolumeParams),
    desc: &HashMlpDesc,
    margin: f64,
    budget: &MemBudget,
    out: &mut Outputs,
) -> Result<()> {
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(Error::invalid("kink_margin", "must be finite and >= 0"));
    }
    let (smooth, kinks) = dhash_smooth(cam, gen, params, desc, margin, budget)?;
    let left_out = smooth.iter().filter(|&&v| v == 0).count() as u64;
    out.counter("kink_samples", kinks)
        .counter("kink_params", left_out);
    out.tensor(
        "dhash_smooth",
        Tensor::from_shape_vec(&[smooth.len()], smooth)?,
    );
    Ok(())
}

/// Per parameter of `desc` (flat order): 1 where no lattice sample of the
/// f64 render of `params` through `cam` / `gen` within `margin` of a kink
/// touches it, else 0; and the number of such samples. Network weights
/// stay 1 (they sum every sample, so one sample's side moves them little).
pub fn dhash_smooth(
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    desc: &HashMlpDesc,
    margin: f64,
    budget: &MemBudget,
) -> Result<(Vec<u8>, u64)> {
    let prep = prepare::<f64>(params, &gen.aabb, budget)?;
    let rays = f_ray::<f64>(cam, gen, budget)?;
    let s = f_samp(&rays, &prep.medium, &prep.march, prep.occ.as_ref(), budget)?;
    let m = HashMlp::<f64>::from_desc(desc);
    let mut smooth = vec![1u8; desc.param_count()];
    let mut kinks = 0;
    for k in 0..s.len() {
        let r = s.ray_id[k] as usize;
        let x = [0, 1, 2].map(|a| rays.o[r][a] + s.t[k] * rays.d[r][a]);
        if let Some(c) = m.near_kink(x, margin) {
            kinks += 1;
            for rows in &c.rows[..m.levels.len()] {
                for &row in rows {
                    let e = row as usize * m.features;
                    smooth[e..e + m.features].fill(0);
                }
            }
        }
    }
    Ok((smooth, kinks))
}
