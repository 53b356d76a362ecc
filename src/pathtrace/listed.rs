//! Listed-ray intersection problems: rays and shapes given as numbers (a
//! case's `params.rays` and `params.shapes`), and the hit list both the
//! renderer (`judge/ops/pathtrace.rs`) and the f64 referee
//! (`referee/geometry.rs`) return for them. Descriptions only: no stage.

use serde::Deserialize;

use crate::error::Result;
use crate::tensor::{Outputs, Tensor};

/// One listed shape, in f64.
#[derive(Clone, Debug, Deserialize)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ShapeParam {
    Sphere {
        center: [f64; 3],
        radius: f64,
    },
    Quad {
        corner: [f64; 3],
        u: [f64; 3],
        v: [f64; 3],
    },
}

/// Origin and unit direction of a listed ray `[ox, oy, oz, dx, dy, dz]`.
pub fn unit(r: &[f64; 6]) -> ([f64; 3], [f64; 3]) {
    let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
    ([r[0], r[1], r[2]], [r[3] / n, r[4] / n, r[5] / n])
}

/// First hits of listed rays: `t` (-1 on a miss), the shape `index` (-1 on a
/// miss) and the unit `normal` (0 on a miss).
#[derive(Clone, Debug, Default)]
pub struct HitList {
    pub t: Vec<f64>,
    pub index: Vec<i32>,
    pub normal: Vec<[f64; 3]>,
}

impl HitList {
    /// Appends one ray's hit (`Some((t, index, normal))`) or miss.
    pub fn push(&mut self, hit: Option<(f64, usize, [f64; 3])>) {
        match hit {
            Some((th, k, n)) => {
                self.t.push(th);
                self.index.push(k as i32);
                self.normal.push(n);
            }
            None => {
                self.t.push(-1.0);
                self.index.push(-1);
                self.normal.push([0.0; 3]);
            }
        }
    }

    /// Tensors `t`, `normal` (float32 when `f32_out`, else float64), `hit`
    /// (u8) and `index` (i32).
    pub fn to_outputs(self, f32_out: bool) -> Result<Outputs> {
        hit_outputs(self.t, self.index, self.normal, f32_out)
    }
}

fn hit_outputs(
    t: Vec<f64>,
    index: Vec<i32>,
    normal: Vec<[f64; 3]>,
    f32_out: bool,
) -> Result<Outputs> {
    let n = [t.len()];
    let hit: Vec<u8> = index.iter().map(|&i| (i >= 0) as u8).collect();
    let mut out = Outputs::default();
    if f32_out {
        out.tensor(
            "t",
            Tensor::real(&n, t.iter().map(|&x| x as f32).collect())?,
        );
        out.tensor(
            "normal",
            Tensor::real3(
                &n,
                &normal
                    .iter()
                    .map(|v| v.map(|x| x as f32))
                    .collect::<Vec<_>>(),
            )?,
        );
    } else {
        out.tensor("t", Tensor::real(&n, t)?);
        out.tensor("normal", Tensor::real3(&n, &normal)?);
    }
    out.tensor("hit", Tensor::from_shape_vec(&n, hit)?);
    out.tensor("index", Tensor::from_shape_vec(&n, index)?);
    Ok(out)
}
