//! `renderer: volume` scenes (SCENES.md "Volume"): the shared view block
//! (`scene/rays.rs`) plus the keys below. Defaults are SCENES.md's.
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `field` | density, `{type: ...}`, see below | required |
//! | `color` | `{type: constant, value: [r, g, b]}` or `{type: grid, ...}` | constant (1, 0.5, 0.25) |
//! | `background` | colour behind the volume | (0, 0, 0) |
//! | `dt` | sample spacing along the ray | 0.01 |
//! | `max_steps` | most lattice points per ray; pixels x `max_steps` at most 2^40 (`MAX_SAMPLES`) | 1024 |
//! | `early_stop` | stop before sample k when `T_k` is below this (0 = off) | 1e-4 |
//! | `sampling` | `fixed` (midpoints) or `stratified` | fixed |
//! | `seed` | seed of the stratified offsets `rand(seed, pixel, 0, k)` | 0 |
//! | `transmittance` | `product` (`T (1 - alpha)`) or `log` (`exp(log T)`) | product |
//! | `occupancy` | occupancy bitfield cells per axis for empty-space skipping (0 = off) | 0 |
//!
//! Density fields (`field.type`):
//!
//! | type | keys |
//! | --- | --- |
//! | `constant` | `s` |
//! | `slabs` | `axis` (x, y, z; default x), `breaks` (n + 1, increasing), `sigma` (n) |
//! | `gaussian` | `amplitude`, `mean` (default origin), `std` |
//! | `shell` | `r0`, `r1`, `s`, `centre` (default origin) |
//! | `linear` | `a`, `g` (`a + g . x >= 0` on the box) |
//! | `grid` | `file` (.npy, float32/float64, (nz, ny, nx)) or `shape` [nz, ny, nx] + `from` (an analytic field sampled at the nodes); `oob` zero or clamp (default zero) |
//! | `hash_mlp` | hash-grid + MLP: keys in `scene/volume_hash.rs`; needs `color: {type: mlp}` |
//!
//! Colour grids: `{type: grid, file}` ((nz, ny, nx, 3)) or `{type: grid,
//! shape, value: [r, g, b]}`, with `oob`. Grids span the scene's `aabb`.
//! Relative files are resolved against the scene's folder.

use serde::Deserialize;

use super::rays::{ViewSpec, VIEW_KEYS};
use super::volume_hash::HashSpec;
use super::SceneDoc;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::tensor::Tensor;
use crate::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc, Oob};
use crate::volume::sample::{Sampling, TransPath};
use crate::volume::VolumeParams;

/// Largest grid built from a scene (nodes), a sanity bound before the budget.
pub const MAX_GRID_NODES: usize = 1 << 27;

/// The work budget of one render: pixels x `max_steps` samples, 2^40
/// (1.1e12; about 12 hours at 2.6e7 samples per CPU-second). The largest
/// committed is 1.1e9 (perf `gpu_fused_grid128_1024`, 1024^2 x 1024).
pub const MAX_SAMPLES: u64 = 1 << 40;

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum AxisSpec {
    #[default]
    X,
    Y,
    Z,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum OobSpec {
    #[default]
    Zero,
    Clamp,
}

impl From<OobSpec> for Oob {
    fn from(o: OobSpec) -> Oob {
        match o {
            OobSpec::Zero => Oob::Zero,
            OobSpec::Clamp => Oob::Clamp,
        }
    }
}

/// A density field as written in a scene.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum FieldSpec {
    Constant {
        s: f64,
    },
    Slabs {
        #[serde(default)]
        axis: AxisSpec,
        breaks: Vec<f64>,
        sigma: Vec<f64>,
    },
    Gaussian {
        amplitude: f64,
        #[serde(default)]
        mean: [f64; 3],
        std: f64,
    },
    Shell {
        #[serde(default)]
        centre: [f64; 3],
        r0: f64,
        r1: f64,
        s: f64,
    },
    Linear {
        a: f64,
        g: [f64; 3],
    },
    Grid {
        #[serde(default)]
        file: Option<String>,
        #[serde(default)]
        shape: Option<[usize; 3]>,
        #[serde(default)]
        from: Option<Box<FieldSpec>>,
        #[serde(default)]
        oob: OobSpec,
    },
    /// Keys: `scene/volume_hash.rs`.
    HashMlp(Box<HashSpec>),
}

/// A colour field as written in a scene.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ColorSpec {
    Constant {
        value: [f64; 3],
    },
    Grid {
        #[serde(default)]
        file: Option<String>,
        #[serde(default)]
        shape: Option<[usize; 3]>,
        #[serde(default)]
        value: Option<[f64; 3]>,
        #[serde(default)]
        oob: OobSpec,
    },
    /// The colour head of a `hash_mlp` field.
    Mlp,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum SamplingSpec {
    #[default]
    Fixed,
    Stratified,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq, Eq, Default)]
#[serde(rename_all = "lowercase")]
pub enum TransSpec {
    #[default]
    Product,
    Log,
}

fn default_color() -> ColorSpec {
    ColorSpec::Constant {
        value: [1.0, 0.5, 0.25],
    }
}
fn default_dt() -> f64 {
    0.01
}
fn default_max_steps() -> u32 {
    1024
}
fn default_early_stop() -> f64 {
    1e-4
}

/// The volume keys of a scene (everything but the view block).
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VolumeSpec {
    pub renderer: String,
    pub field: FieldSpec,
    #[serde(default = "default_color")]
    pub color: ColorSpec,
    #[serde(default)]
    pub background: [f64; 3],
    #[serde(default = "default_dt")]
    pub dt: f64,
    #[serde(default = "default_max_steps")]
    pub max_steps: u32,
    #[serde(default = "default_early_stop")]
    pub early_stop: f64,
    #[serde(default)]
    pub sampling: SamplingSpec,
    #[serde(default)]
    pub seed: u32,
    #[serde(default)]
    pub transmittance: TransSpec,
    #[serde(default)]
    pub occupancy: u32,
}

/// A parsed volume scene.
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeScene {
    pub view: ViewSpec,
    pub spec: VolumeSpec,
}

/// Parses a `renderer: volume` scene (no files read yet).
pub fn parse(doc: &SceneDoc) -> Result<VolumeScene> {
    let (view, spec): (ViewSpec, VolumeSpec) = doc.parse_split(VIEW_KEYS)?;
    Ok(VolumeScene { view, spec })
}

/// The continuum field behind a spec: the analytic field itself, or the one
/// a grid was sampled `from:` (a grid read from a file has none).
pub fn continuum(spec: &FieldSpec, at: &str) -> Result<Analytic> {
    let f = match spec {
        FieldSpec::Grid { from: Some(f), .. } => f.as_ref(),
        FieldSpec::Grid { .. } => {
            return Err(Error::NotSupported(format!(
                "{at}: no closed form for a grid read from a file"
            )))
        }
        other => other,
    };
    analytic(f, at)
}

/// The analytic field a spec names (a grid spec is an error).
pub fn analytic(spec: &FieldSpec, at: &str) -> Result<Analytic> {
    Ok(match spec {
        FieldSpec::Constant { s } => Analytic::Constant { s: *s },
        FieldSpec::Slabs {
            axis,
            breaks,
            sigma,
        } => Analytic::Slabs {
            axis: *axis as usize,
            breaks: breaks.clone(),
            sigma: sigma.clone(),
        },
        FieldSpec::Gaussian {
            amplitude,
            mean,
            std,
        } => Analytic::Gaussian {
            amplitude: *amplitude,
            mean: *mean,
            std: *std,
        },
        FieldSpec::Shell { centre, r0, r1, s } => Analytic::Shell {
            centre: *centre,
            r0: *r0,
            r1: *r1,
            s: *s,
        },
        FieldSpec::Linear { a, g } => Analytic::Linear { a: *a, g: *g },
        FieldSpec::Grid { .. } | FieldSpec::HashMlp(_) => {
            return Err(Error::invalid(
                at,
                "a grid can only be sampled from an analytic field",
            ))
        }
    })
}

fn check_shape(shape: [usize; 3], at: &str) -> Result<()> {
    let n = shape.iter().try_fold(1usize, |a, &s| a.checked_mul(s));
    if shape.iter().any(|&s| s < 2) || n.is_none_or(|n| n > MAX_GRID_NODES) {
        return Err(Error::invalid(
            at,
            format!("shape {shape:?} needs >= 2 nodes per axis and at most {MAX_GRID_NODES} nodes"),
        ));
    }
    Ok(())
}

fn grid_from_file(
    doc: &SceneDoc,
    file: &str,
    ch: usize,
    oob: Oob,
    bmin: [f64; 3],
    bmax: [f64; 3],
) -> Result<GridDesc> {
    let path = doc.resolve(file);
    let dims: Vec<Option<usize>> = if ch == 1 {
        vec![None; 3]
    } else {
        vec![None, None, None, Some(ch)]
    };
    let t = Tensor::read_npy_checked(&path, &["float32", "float64"], &dims)?;
    let s = t.shape();
    let g = GridDesc {
        shape: [s[0], s[1], s[2]],
        ch,
        data: t.to_f64_vec(),
        oob,
        bmin,
        bmax,
    };
    check_shape(g.shape, &path.display().to_string())?;
    Ok(g)
}

impl VolumeScene {
    /// Camera, ray generator and typed, validated render parameters (reads
    /// grid files).
    pub fn build(&self, doc: &SceneDoc) -> Result<(Camera, RayGen, VolumeParams)> {
        let (cam, gen) = self.view.build()?;
        let at = doc.at();
        let s = &self.spec;
        if s.renderer != "volume" {
            return Err(Error::invalid(
                format!("{at} key `renderer`"),
                format!("{:?} is not volume", s.renderer),
            ));
        }
        let (bmin, bmax) = (gen.aabb.min, gen.aabb.max);
        let fat = format!("{at} key `field`");
        let field = match &s.field {
            FieldSpec::Grid {
                file,
                shape,
                from,
                oob,
            } => {
                let g = match (file, shape, from) {
                    (Some(f), None, None) => grid_from_file(doc, f, 1, (*oob).into(), bmin, bmax)?,
                    (None, Some(shape), Some(from)) => {
                        check_shape(*shape, &fat)?;
                        let a = analytic(from, &fat)?;
                        a.validate(&format!("{fat}.from"), bmin, bmax)?;
                        GridDesc::sample(*shape, bmin, bmax, (*oob).into(), |x| a.eval(x))
                    }
                    _ => {
                        return Err(Error::invalid(
                            &fat,
                            "a grid needs either `file` or `shape` + `from`",
                        ))
                    }
                };
                g.validate(&fat, true)?;
                FieldDesc::Grid(g)
            }
            FieldSpec::HashMlp(h) => FieldDesc::HashMlp(Box::new(h.build(doc, &fat, bmin, bmax)?)),
            other => {
                let a = analytic(other, &fat)?;
                a.validate(&fat, bmin, bmax)?;
                FieldDesc::Analytic(a)
            }
        };
        let cat = format!("{at} key `color`");
        let color = match &s.color {
            ColorSpec::Constant { value } => ColorDesc::Constant(*value),
            ColorSpec::Mlp => ColorDesc::Mlp,
            ColorSpec::Grid {
                file,
                shape,
                value,
                oob,
            } => {
                let g = match (file, shape, value) {
                    (Some(f), None, None) => grid_from_file(doc, f, 3, (*oob).into(), bmin, bmax)?,
                    (None, Some(shape), Some(v)) => {
                        check_shape(*shape, &cat)?;
                        GridDesc::filled(*shape, v, bmin, bmax, (*oob).into())
                    }
                    _ => {
                        return Err(Error::invalid(
                            &cat,
                            "a colour grid needs either `file` or `shape` + `value`",
                        ))
                    }
                };
                g.validate(&cat, false)?;
                ColorDesc::Grid(g)
            }
        };
        if let ColorDesc::Constant(c) = color {
            if c.iter().any(|v| !v.is_finite()) {
                return Err(Error::invalid(cat, "colour must be finite"));
            }
        }
        crate::volume::field::check_pairing(&field, &color, &cat)?;
        let params = VolumeParams {
            field,
            color,
            dt: s.dt,
            max_steps: s.max_steps,
            early_stop: s.early_stop,
            sampling: match s.sampling {
                SamplingSpec::Fixed => Sampling::Fixed,
                SamplingSpec::Stratified => Sampling::Stratified { seed: s.seed },
            },
            path: match s.transmittance {
                TransSpec::Product => TransPath::Product,
                TransSpec::Log => TransPath::Log,
            },
            background: s.background,
            occupancy: s.occupancy,
        };
        params
            .march::<f64>()
            .validate()
            .map_err(|e| Error::invalid(at.clone(), e.to_string()))?;
        let [h, w] = gen.shape().map(|n| n as u64);
        let work = [
            (w, "width"),
            (h, "height"),
            (s.max_steps as u64, "max_steps"),
        ];
        crate::budget::check_work(
            &format!("{at} key `max_steps`"),
            &work,
            "samples per render",
            MAX_SAMPLES,
        )?;
        if params.occupancy > crate::volume::occupancy::MAX_RES {
            return Err(Error::invalid(
                format!("{at} key `occupancy`"),
                format!(
                    "{} is over {}",
                    params.occupancy,
                    crate::volume::occupancy::MAX_RES
                ),
            ));
        }
        Ok((cam, gen, params))
    }
}

/// Parses and builds a volume scene (for `scene::validate`).
pub fn load(doc: &SceneDoc) -> Result<(Camera, RayGen, VolumeParams)> {
    parse(doc)?.build(doc)
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::path::PathBuf;

    fn doc(text: &str) -> SceneDoc {
        SceneDoc {
            path: PathBuf::from("t.yaml"),
            value: serde_yaml::from_str(text).unwrap(),
        }
    }

    #[test]
    fn defaults_follow_scenes_md() {
        let d = doc("renderer: volume\ncamera: {type: ortho, position: [0,0,3], target: [0,0,0]}\nfield: {type: constant, s: 2}\n");
        let (_, gen, p) = load(&d).unwrap();
        assert_eq!((gen.width, gen.height), (64, 64));
        assert_eq!((p.dt, p.max_steps, p.early_stop), (0.01, 1024, 1e-4));
        assert_eq!(p.color, ColorDesc::Constant([1.0, 0.5, 0.25]));
        assert_eq!(
            (p.background, p.sampling, p.path),
            ([0.0; 3], Sampling::Fixed, TransPath::Product)
        );
    }

    #[test]
    fn bad_fields_name_their_key() {
        let d = doc("renderer: volume\ncamera: {type: ortho, position: [0,0,3], target: [0,0,0]}\nfield: {type: constant, s: -2}\n");
        let e = load(&d).unwrap_err().to_string();
        assert!(e.contains("field") && e.contains("-2"), "{e}");
        let d = doc("renderer: volume\ncamera: {type: ortho, position: [0,0,3], target: [0,0,0]}\nfield: {type: constant, s: 2, q: 1}\n");
        assert!(load(&d).is_err());
        let d = doc("renderer: volume\ncamera: {type: ortho, position: [0,0,3], target: [0,0,0]}\nfield: {type: grid, shape: [4,4,4]}\n");
        assert!(load(&d).unwrap_err().to_string().contains("shape` + `from"));
    }

    #[test]
    fn grid_files_are_checked_for_dtype_shape_and_values() {
        let dir = std::env::temp_dir().join(format!("hp-volscene-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = Tensor::from_shape_vec(&[2, 3, 4], vec![1.0f32; 24]).unwrap();
        good.write_npy(&dir.join("g.npy")).unwrap();
        let mut bad = vec![1.0f64; 24];
        bad[5] = f64::NAN;
        Tensor::from_shape_vec(&[2, 3, 4], bad)
            .unwrap()
            .write_npy(&dir.join("nan.npy"))
            .unwrap();
        Tensor::from_shape_vec(&[24], vec![1i32; 24])
            .unwrap()
            .write_npy(&dir.join("int.npy"))
            .unwrap();
        let mk = |f: &str| {
            SceneDoc {
            path: dir.join("s.yaml"),
            value: serde_yaml::from_str(&format!(
                "renderer: volume\ncamera: {{type: ortho, position: [0,0,3], target: [0,0,0]}}\nfield: {{type: grid, file: {f}}}\n"
            ))
            .unwrap(),
        }
        };
        let (_, _, p) = load(&mk("g.npy")).unwrap();
        assert!(matches!(p.field, FieldDesc::Grid(ref g) if g.shape == [2, 3, 4]));
        assert!(load(&mk("nan.npy"))
            .unwrap_err()
            .to_string()
            .contains("not finite"));
        assert!(load(&mk("int.npy"))
            .unwrap_err()
            .to_string()
            .contains("dtype"));
        std::fs::remove_dir_all(&dir).ok();
    }
}
