//! Which hash-table values of a render's gradient sit on a ReLU kink: the
//! table rows touched by a lattice sample where the network is within a
//! margin of a kink (`HashMlp::near_kink`). There the f64 reference and an
//! f32 backend may take different sides of the jump, and a parity check
//! excuses those values (`dhash_smooth` = 0) as the volume cases excuse
//! samples on occupancy faces or at the lattice end.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{f_ray, RayGen};

use super::field::hash::{HashMlp, HashMlpDesc};
use super::sample::f_samp;
use super::{prepare, VolumeParams};

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
