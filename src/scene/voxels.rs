//! `renderer: voxels` scenes (SCENES.md "Sparse voxels"): a voxelised shape
//! cast by the ESVO octree, plus the shared view block (`scene/rays.rs`).
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `shape` | `{type: sphere, radius}` (centre-inside test), `{type: menger, level}`, `{type: boxes, boxes: [{min: [i, j, k], max: [i, j, k]}, ..]}` (inclusive voxel boxes) or `{type: mesh, path}` (an .obj or .ply file, relative to the scene file, placed as SCENES.md's bunny and surface-voxelised; an absent file is `not supported` (a skip) unless `CI=true`) | required |
//! | `depth` | octree depth d: 2^d voxels per axis over [-1, 1]^3, 1..=22; the shape's surface cells at most 2^28 (`MAX_BUILD_CELLS`) | required |
//! | `lod` | `{orig_size, dir_size}`: LOD cut when `orig_size + t dir_size` >= voxel size (world units) | off |
//! | `max_iter` | cast iteration cap per ray | max(2^16, 16 * 2^depth) |
//! | `contours` | `true`: intersect each surface voxel's contour slab (sphere only; octree only); SCENES.md outputs are defined without | `false` |
//! | `attributes` | `none` (shade by the entered face's axis), `plain` or `dxt`: shade `image` with the hit leaf's decoded colour and normal in that stored form (sphere and mesh shapes; `voxels::attributes`) | `none` |
//! | `structure` | `octree` (ESVO, relative addressing) or `dag` (identical subtrees merged, absolute addressing; same outputs) | `octree` |
//! | view keys | `camera`, `width`, `height`, `roi`, `near`, `far`, ... | see `scene/rays.rs` |

use serde::Deserialize;

use super::rays::{ViewSpec, VIEW_KEYS};
use super::SceneDoc;
use std::sync::Arc;

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::rays::RayGen;
use crate::real::Real;
use crate::voxels::attributes::AttrForm;
use crate::voxels::batch::{Batch, RaySource};
use crate::voxels::cast::{default_max_iter, Lod};
use crate::voxels::contour::fit_all;
use crate::voxels::dag::{build_dag, Dag};
use crate::voxels::mesh::Mesh;
use crate::voxels::octree::Octree;
use crate::voxels::render::Structure;
use crate::voxels::shape::{Shape, VoxelBox};
use crate::voxels::voxelise::voxelise;

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct BoxSpec {
    pub min: [u32; 3],
    pub max: [u32; 3],
}

/// The `shape:` block.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ShapeSpec {
    Sphere { radius: f64 },
    Menger { level: u32 },
    Boxes { boxes: Vec<BoxSpec> },
    Mesh { path: String },
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct LodSpec {
    pub orig_size: f64,
    pub dir_size: f64,
}

/// The non-view keys of a voxel scene.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct VoxelsRest {
    pub renderer: String,
    pub shape: ShapeSpec,
    pub depth: u32,
    #[serde(default)]
    pub lod: Option<LodSpec>,
    #[serde(default)]
    pub max_iter: Option<u32>,
    #[serde(default)]
    pub structure: Structure,
    #[serde(default)]
    pub contours: bool,
    #[serde(default)]
    pub attributes: AttrForm,
}

/// A parsed, validated voxel scene.
#[derive(Clone, Debug, PartialEq)]
pub struct VoxelScene {
    pub view: ViewSpec,
    pub shape: Shape,
    pub depth: u32,
    pub lod: Option<Lod>,
    pub max_iter: u32,
    pub structure: Structure,
    pub contours: bool,
    pub attributes: AttrForm,
}

impl VoxelScene {
    /// The scene's camera and generator, at `size` x `size` pixels when given.
    pub fn view_at(&self, size: Option<u32>) -> Result<(Camera, RayGen)> {
        let (cam, mut gen) = self.view.build()?;
        let Some(s) = size else { return Ok((cam, gen)) };
        (gen.width, gen.height, gen.roi) = (s, s, None);
        Ok((self.view.camera.build(s, s)?, gen))
    }

    /// The scene's DAG (`structure: dag`) and contours (`contours: true`),
    /// built from `tree` when it asks for them.
    pub fn extras(
        &self,
        tree: &Octree,
        budget: &MemBudget,
    ) -> Result<(Option<Dag>, Option<Vec<u32>>)> {
        let dag = match self.structure {
            Structure::Octree => None,
            Structure::Dag => Some(build_dag(tree, budget)?),
        };
        let contours = self
            .contours
            .then(|| fit_all(&self.shape, tree))
            .transpose()?;
        Ok((dag, contours))
    }

    /// The rays of `src` in precision `F` (`count` and `seed` for the
    /// generated sets), after a budget check.
    pub fn batch<F: Real>(
        &self,
        src: RaySource,
        count: u32,
        seed: u32,
        budget: &MemBudget,
    ) -> Result<Batch<F>> {
        if src == RaySource::Camera {
            let (cam, gen) = self.view_at(None)?;
            return Batch::camera(&cam, &gen, budget);
        }
        Batch::<F>::check_budget(count, src == RaySource::Hard, budget)?;
        Ok(match src {
            RaySource::Hard => Batch::hard(&self.shape, self.depth, count, seed),
            _ => Batch::incoherent(count, seed),
        })
    }
}

/// The work budget of one octree build: leaf cells on the shape's surface
/// (estimated before building: its area in voxel faces, or for the Menger
/// sponge its 20^level solid voxels), 2^28 (2.7e8). Measured on a loaded
/// 2-core machine: a depth-12 sphere of radius 0.8 (3.4e7 cells) builds in
/// 2.3 s, the level-6 sponge at depth 12 (6.4e7) in 7.7 s, the level-7
/// sponge (1.3e9) took over a minute, the bunny at depth 12 (3.3e7, the
/// largest committed) voxelises in about 93 s; depth 22 would take days.
pub const MAX_BUILD_CELLS: u64 = 1 << 28;

/// Refuses a build over [`MAX_BUILD_CELLS`] surface cells (`key depth`).
fn check_build(doc: &SceneDoc, cells: f64) -> Result<()> {
    let work = [(cells.ceil().min(u64::MAX as f64) as u64, "surface cells")];
    let at = format!("{} key `depth`", doc.at());
    crate::budget::check_work(&at, &work, "cells per build", MAX_BUILD_CELLS)
}

/// Surface cells of a non-mesh shape at `depth` (see [`MAX_BUILD_CELLS`]):
/// a sphere's area (its radius capped at the box's half-diagonal), each
/// box's faces, the sponge's solid voxels.
fn build_cells(shape: &ShapeSpec, depth: u32) -> f64 {
    let n = (1u64 << depth.min(63)) as f64;
    match shape {
        ShapeSpec::Sphere { radius } => {
            std::f64::consts::PI * radius.min(3f64.sqrt()).powi(2) * n * n
        }
        ShapeSpec::Menger { level } => 20f64.powi(*level as i32),
        ShapeSpec::Boxes { boxes } => boxes
            .iter()
            .map(|b| {
                let e = [0, 1, 2].map(|a| b.max[a].saturating_sub(b.min[a]) as f64 + 1.0);
                2.0 * (e[0] * e[1] + e[1] * e[2] + e[2] * e[0])
            })
            .sum(),
        ShapeSpec::Mesh { .. } => 0.0,
    }
}

fn tri_area(t: &[[f64; 3]; 3]) -> f64 {
    let (u, v) = (
        [0, 1, 2].map(|a| t[1][a] - t[0][a]),
        [0, 1, 2].map(|a| t[2][a] - t[0][a]),
    );
    let c = [
        u[1] * v[2] - u[2] * v[1],
        u[2] * v[0] - u[0] * v[2],
        u[0] * v[1] - u[1] * v[0],
    ];
    0.5 * (c[0] * c[0] + c[1] * c[1] + c[2] * c[2]).sqrt()
}

/// Loads and places the mesh at `path` (relative to the scene's folder) and
/// refuses a voxelisation over the build budget.
fn load_mesh(doc: &SceneDoc, path: &str, depth: u32) -> Result<Mesh> {
    let at = format!("{} key `shape.path`", doc.at());
    let full = doc
        .path
        .parent()
        .map_or_else(|| path.into(), |d| d.join(path));
    if !full.exists() {
        let why = format!(
            "{at}: mesh {} is absent (the bunny comes with the Debian package glmark2-data)",
            full.display()
        );
        if std::env::var("CI").is_ok_and(|v| v == "true") {
            return Err(Error::invalid(at, why));
        }
        return Err(Error::NotSupported(why));
    }
    let mesh = Mesh::load(&full)?.placed()?;
    let half = (1u64 << (depth - 1)) as f64;
    check_build(
        doc,
        mesh.tris.iter().map(tri_area).sum::<f64>() * half * half,
    )?;
    Ok(mesh)
}

/// Parses and validates a `renderer: voxels` scene, voxelising its mesh.
pub fn parse(doc: &SceneDoc) -> Result<VoxelScene> {
    parse_as(doc, true)
}

/// Validates a `renderer: voxels` scene as [`parse`] does, but a mesh is
/// loaded and held to the build budget without being voxelised (`hpjudge
/// check`: the bunny at depth 10 took 6.6 s of `check TESTS/manifest.yaml`).
pub fn check(doc: &SceneDoc) -> Result<()> {
    parse_as(doc, false).map(drop)
}

fn parse_as(doc: &SceneDoc, voxelise_mesh: bool) -> Result<VoxelScene> {
    let (view, rest): (ViewSpec, VoxelsRest) = doc.parse_split(VIEW_KEYS)?;
    let at = doc.at();
    let cells = build_cells(&rest.shape, rest.depth);
    let shape = match rest.shape {
        ShapeSpec::Sphere { radius } => Shape::Sphere { radius },
        ShapeSpec::Menger { level } => Shape::Menger { level },
        ShapeSpec::Boxes { boxes } => Shape::Boxes {
            boxes: boxes
                .iter()
                .map(|b| VoxelBox {
                    min: b.min,
                    max: b.max,
                })
                .collect(),
        },
        ShapeSpec::Mesh { ref path } => {
            if rest.depth == 0 || rest.depth > crate::voxels::shape::MAX_DEPTH {
                return Err(Error::invalid(
                    format!("{at} key `depth`"),
                    format!("{} is not in 1..=22", rest.depth),
                ));
            }
            let mesh = load_mesh(doc, path, rest.depth)?;
            if voxelise_mesh {
                let cells = voxelise(mesh, rest.depth, &MemBudget::from_machine())?;
                Shape::Mesh(Arc::new(cells))
            } else {
                // Stands in for the checked mesh: what follows asks only
                // whether its kind takes attributes, as a sphere's does.
                Shape::Sphere { radius: 1.0 }
            }
        }
    };
    shape
        .validate(rest.depth)
        .map_err(|e| Error::invalid(at.clone(), e.to_string()))?;
    check_build(doc, cells)?;
    let lod = match rest.lod {
        Some(l) => {
            if !(l.orig_size >= 0.0
                && l.dir_size >= 0.0
                && l.orig_size.is_finite()
                && l.dir_size.is_finite())
            {
                return Err(Error::invalid(
                    format!("{at} key `lod`"),
                    "orig_size and dir_size must be finite and >= 0",
                ));
            }
            Some(Lod {
                orig_size: l.orig_size,
                dir_size: l.dir_size,
            })
        }
        None => None,
    };
    let max_iter = rest.max_iter.unwrap_or(default_max_iter(rest.depth));
    if max_iter == 0 {
        return Err(Error::invalid(
            format!("{at} key `max_iter`"),
            "must be at least 1",
        ));
    }
    if rest.attributes != AttrForm::None && !matches!(shape, Shape::Sphere { .. } | Shape::Mesh(_))
    {
        return Err(Error::invalid(
            format!("{at} key `attributes`"),
            "colour and normal attributes are defined for sphere and mesh shapes",
        ));
    }
    if rest.contours && rest.structure == Structure::Dag {
        return Err(Error::invalid(
            format!("{at} key `contours`"),
            "contours are per-leaf data: use them with `structure: octree`",
        ));
    }
    view.build()?;
    Ok(VoxelScene {
        view,
        shape,
        depth: rest.depth,
        lod,
        max_iter,
        structure: rest.structure,
        contours: rest.contours,
        attributes: rest.attributes,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn doc(text: &str) -> SceneDoc {
        SceneDoc {
            path: "t.yaml".into(),
            value: serde_yaml::from_str(text).unwrap(),
        }
    }

    const SPHERE: &str = "renderer: voxels\nshape: {type: sphere, radius: 0.8}\ndepth: 8\n\
        camera: {type: pinhole, position: [2.0, 1.5, 2.5], target: [0, 0, 0], fov_y: 45}\nwidth: 512\nheight: 512\n";

    #[test]
    fn sphere_scene_parses_and_bad_keys_are_named() {
        let s = parse(&doc(SPHERE)).unwrap();
        assert_eq!((s.depth, s.view.width), (8, 512));
        assert_eq!(s.shape, Shape::Sphere { radius: 0.8 });
        let e = parse(&doc(&SPHERE.replace("depth: 8", "depth: 23")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("t.yaml") && e.contains("depth"), "{e}");
        let e = parse(&doc(&format!("{SPHERE}colour: 1\n")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("colour"), "{e}");
        let e = parse(&doc(&SPHERE.replace("radius: 0.8", "level: 3")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("shape"), "{e}");
        assert_eq!(s.structure, Structure::Octree);
        let d = parse(&doc(&format!("{SPHERE}structure: dag\n"))).unwrap();
        assert_eq!(d.structure, Structure::Dag);
        let e = parse(&doc(&format!("{SPHERE}structure: tree\n")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("structure"), "{e}");
    }
}
