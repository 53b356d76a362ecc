//! `field: {type: hash_mlp, ...}` of a volume scene (SCENES.md "Volume";
//! the field itself: `volume/field/hash.rs`). Its colour is the network's
//! colour head: the scene says `color: {type: mlp}`.
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `levels` | L, 1..=16 | 8 |
//! | `features` | F per level, 1..=8 (L F <= 64) | 2 |
//! | `log2_table` | T = 2^log2_table entries per level, 4..=22 | 12 |
//! | `n_min`, `n_max` | coarsest and finest resolution | 4, 64 |
//! | `density` | `softplus` or `relu` | softplus |
//! | `hidden` | hidden widths (1..=3 layers, 16..=64 each), for `init` | [32] |
//! | `table` | .npy (L, T, F) float32/float64 | - |
//! | `layers` | .npy files, layer q of shape (out, in + 1): weights, then the bias as the last column; the last layer has 4 outputs | - |
//! | `init` | `{seed, table_scale (default 1e-1), density_bias (default 0)}`: the seeded initialiser of `HashMlpDesc::init` | - |
//!
//! Either `table` + `layers` or `init`. The encoding spans the scene's `aabb`.

use serde::Deserialize;

use super::SceneDoc;
use crate::error::{Error, Result};
use crate::tensor::Tensor;
use crate::volume::field::hash::{DensityAct, HashConfig, HashMlpDesc, LayerDesc};

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum DensitySpec {
    #[default]
    Softplus,
    Relu,
}

#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct InitSpec {
    pub seed: u32,
    #[serde(default = "default_table_scale")]
    pub table_scale: f64,
    #[serde(default)]
    pub density_bias: f64,
}

fn default_table_scale() -> f64 {
    0.1
}

/// The `hash_mlp` keys (the `type` tag is the enum's).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct HashSpec {
    #[serde(default = "d_levels")]
    pub levels: usize,
    #[serde(default = "d_features")]
    pub features: usize,
    #[serde(default = "d_log2")]
    pub log2_table: u32,
    #[serde(default = "d_nmin")]
    pub n_min: u32,
    #[serde(default = "d_nmax")]
    pub n_max: u32,
    #[serde(default)]
    pub density: DensitySpec,
    #[serde(default)]
    pub hidden: Option<Vec<usize>>,
    #[serde(default)]
    pub table: Option<String>,
    #[serde(default)]
    pub layers: Option<Vec<String>>,
    #[serde(default)]
    pub init: Option<InitSpec>,
}

fn d_levels() -> usize {
    8
}
fn d_features() -> usize {
    2
}
fn d_log2() -> u32 {
    12
}
fn d_nmin() -> u32 {
    4
}
fn d_nmax() -> u32 {
    64
}

impl HashSpec {
    /// The validated description over the box `bmin..bmax` (reads files);
    /// `at` names the scene key.
    pub fn build(
        &self,
        doc: &SceneDoc,
        at: &str,
        bmin: [f64; 3],
        bmax: [f64; 3],
    ) -> Result<HashMlpDesc> {
        let cfg = HashConfig {
            levels: self.levels,
            features: self.features,
            log2_table: self.log2_table,
            n_min: self.n_min,
            n_max: self.n_max,
        };
        cfg.validate(at)?;
        let density = match self.density {
            DensitySpec::Softplus => DensityAct::Softplus,
            DensitySpec::Relu => DensityAct::Relu,
        };
        let d = match (&self.table, &self.layers, &self.init) {
            (None, None, Some(i)) => {
                let hidden = self.hidden.clone().unwrap_or_else(|| vec![32]);
                if !(i.table_scale.is_finite() && i.density_bias.is_finite()) {
                    return Err(Error::invalid(
                        format!("{at}.init"),
                        "values must be finite",
                    ));
                }
                HashMlpDesc::init(
                    cfg,
                    density,
                    &hidden,
                    bmin,
                    bmax,
                    i.seed,
                    i.table_scale,
                    i.density_bias,
                )
            }
            (Some(t), Some(ls), None) => {
                let path = doc.resolve(t);
                let dims = [Some(cfg.levels), Some(cfg.table_size()), Some(cfg.features)];
                let table = Tensor::read_npy_checked(&path, &["float32", "float64"], &dims)?;
                finite(&table, &path.display().to_string())?;
                let mut layers = Vec::with_capacity(ls.len());
                let mut inp = cfg.width();
                for (q, f) in ls.iter().enumerate() {
                    let p = doc.resolve(f);
                    let out = if q + 1 == ls.len() { Some(4) } else { None };
                    let t = Tensor::read_npy_checked(
                        &p,
                        &["float32", "float64"],
                        &[out, Some(inp + 1)],
                    )?;
                    finite(&t, &p.display().to_string())?;
                    let (o, v) = (t.shape()[0], t.to_f64_vec());
                    let mut w = Vec::with_capacity(o * inp);
                    let mut b = Vec::with_capacity(o);
                    for row in v.chunks(inp + 1) {
                        w.extend_from_slice(&row[..inp]);
                        b.push(row[inp]);
                    }
                    layers.push(LayerDesc { out: o, inp, w, b });
                    inp = o;
                }
                HashMlpDesc {
                    cfg,
                    density,
                    bmin,
                    bmax,
                    table: table.to_f64_vec(),
                    layers,
                }
            }
            _ => {
                return Err(Error::invalid(
                    at,
                    "a hash_mlp field needs either `table` + `layers` or `init`",
                ))
            }
        };
        d.validate(at)?;
        Ok(d)
    }
}

/// Refuses a tensor with a non-finite value, naming the file and the index.
fn finite(t: &Tensor, at: &str) -> Result<()> {
    match t
        .to_f64_vec()
        .iter()
        .enumerate()
        .find(|(_, v)| !v.is_finite())
    {
        Some((i, v)) => Err(Error::invalid(
            at,
            format!(
                "value {v} at flat index {i} (shape {:?}) is not finite",
                t.shape()
            ),
        )),
        None => Ok(()),
    }
}
