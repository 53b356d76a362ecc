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
/// touches it, else 0, nor the kinked unit's fan-in weights and bias, nor,
/// for a unit past the first layer, any parameter of the layers before it
/// (their gradients pass through the unit's jump: on an H200 two kink
/// samples on hidden unit 20 moved b0[20] by 7e-3 and W0[20][4] by 7.7e-2
/// of their values); and the number of such samples. Other weights stay 1:
/// they see the unit's relu(z), continuous at the kink.
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
        if let Some(kink) = m.near_kink(x, margin) {
            kinks += 1;
            for rows in &kink.corners.rows[..m.levels.len()] {
                for &row in rows {
                    let e = row as usize * m.features;
                    smooth[e..e + m.features].fill(0);
                }
            }
            for (layer, unit) in kink.units {
                excuse_unit(&m, layer, unit, &mut smooth);
            }
        }
    }
    Ok((smooth, kinks))
}

/// Zeroes, in `smooth` (flat order: table, then each layer's weights and
/// biases), unit `unit` of layer `layer`'s fan-in weights and bias, and
/// every parameter of the layers before it.
fn excuse_unit<F>(m: &HashMlp<F>, layer: usize, unit: usize, smooth: &mut [u8]) {
    let mut off = m.table.len();
    for (q, l) in m.layers.iter().enumerate() {
        let (nw, nb) = (l.w.len(), l.b.len());
        if q < layer {
            smooth[off..off + nw + nb].fill(0);
        } else if q == layer {
            smooth[off + unit * l.inp..off + (unit + 1) * l.inp].fill(0);
            smooth[off + nw + unit] = 0;
        }
        off += nw + nb;
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::field::hash::{DensityAct, HashConfig};

    fn mlp() -> HashMlp<f64> {
        let cfg = HashConfig {
            levels: 2,
            features: 2,
            log2_table: 4,
            n_min: 2,
            n_max: 4,
        };
        let d = HashMlpDesc::init(
            cfg,
            DensityAct::Softplus,
            &[8, 8],
            [-1.0; 3],
            [1.0; 3],
            3,
            0.8,
            0.2,
        );
        HashMlp::from_desc(&d)
    }

    /// A kink on hidden unit 3 of layer 0 excuses that unit's fan-in row
    /// and bias only; one on layer 1 excuses its own row and bias and all
    /// of layer 0, never the table (the corners do that) or the layers after.
    #[test]
    fn a_kink_excuses_its_units_fan_in_and_bias_and_the_layers_before() {
        let m = mlp();
        let n = m.table.len()
            + m.layers
                .iter()
                .map(|l| l.w.len() + l.b.len())
                .sum::<usize>();
        let l0 = &m.layers[0];
        let (w0, b0) = (m.table.len(), m.table.len() + l0.w.len());
        let w1 = b0 + l0.b.len();
        let l1 = &m.layers[1];
        let b1 = w1 + l1.w.len();

        let mut s = vec![1u8; n];
        excuse_unit(&m, 0, 3, &mut s);
        let zeros: Vec<usize> = (0..n).filter(|&i| s[i] == 0).collect();
        let mut want: Vec<usize> = (w0 + 3 * l0.inp..w0 + 4 * l0.inp).collect();
        want.push(b0 + 3);
        assert_eq!(zeros, want);

        let mut s = vec![1u8; n];
        excuse_unit(&m, 1, 2, &mut s);
        let zeros: Vec<usize> = (0..n).filter(|&i| s[i] == 0).collect();
        let mut want: Vec<usize> = (w0..w1).collect();
        want.extend(w1 + 2 * l1.inp..w1 + 3 * l1.inp);
        want.push(b1 + 2);
        assert_eq!(zeros, want);
    }
}
