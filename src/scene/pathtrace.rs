//! `renderer: pathtrace` scenes (SCENES.md "Cornell box with three spheres").
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `camera`, `width`, `height` | the shared view block (`scene/rays.rs`); `roi`, `aabb`, `near`, `far`, `jitter` are not used here and refused | 64 x 64 |
//! | `spp` | samples per pixel (box filter, one jittered position each); width x height x spp at most 2^36 paths (`MAX_PATHS`) | 64 |
//! | `seed` | first key of `rand(seed, pixel, sample, dim)` | 0 |
//! | `max_bounces` | most scattering events on a path (camera ray hitting a light = 0) | 64 |
//! | `rr_depth` | bounces before Russian roulette starts | 5 |
//! | `tracer` | `wavefront` (paths 8 at a time, whole vertices in 8 SIMD lanes), `packet` (8 rays per intersection test, shading per lane) or `scalar` (one path at a time, the referee); the same image from each | wavefront |
//! | `sampler` | `{type: independent}` (`rand(seed, pixel, sample, dim)`, one hash per dimension) or `{type: sobol}` (padded 2-D Owen-scrambled Sobol' after Burley 2020: pixel jitter, light point and BSDF direction as 2-D pairs; lower error at equal spp); a pure function of (seed, pixel, sample, dim) either way, the same on every tracer and the GPU | independent |
//! | `environment` | uniform radiance of every ray that leaves the scene | [0, 0, 0] |
//! | `materials` | name -> material (below) | required |
//! | `shapes` | list of shapes (below) | required |
//!
//! Materials (`type:`): `lambertian {albedo: [r, g, b]}`,
//! `rough_conductor {alpha, reflectance: [r, g, b]}` (GGX, separable Smith G,
//! constant Fresnel), `dielectric {ior}` (smooth, exact Fresnel; `ior`
//! inside, 1 outside), `emitter {radiance: [r, g, b]}` (one-sided towards
//! the quad's `normalize(u x v)`, black both sides otherwise; quads only).
//!
//! Shapes (`type:`): `sphere {center, radius, material}`,
//! `quad {corner, u, v, material}` (the parallelogram `corner + a u + b v`,
//! a, b in [0, 1]); each may carry a `name` for reports.

use std::collections::BTreeMap;

use glam::Vec3A;
use serde::Deserialize;

use super::rays::{ViewSpec, VIEW_KEYS};
use super::SceneDoc;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::pathtrace::integrator::Tracer;
use crate::pathtrace::sampler::Sampler;
use crate::pathtrace::{Material, Quad, RenderParams, Scene, Shape, Sphere};

fn default_spp() -> u32 {
    64
}
fn sixty_four() -> u32 {
    64
}
fn five() -> u32 {
    5
}

/// A material as written in a scene file.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum MaterialSpec {
    Lambertian { albedo: [f32; 3] },
    RoughConductor { alpha: f32, reflectance: [f32; 3] },
    Dielectric { ior: f32 },
    Emitter { radiance: [f32; 3] },
}

/// A shape as written in a scene file.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum ShapeSpec {
    Sphere {
        center: [f32; 3],
        radius: f32,
        material: String,
        #[serde(default)]
        name: Option<String>,
    },
    Quad {
        corner: [f32; 3],
        u: [f32; 3],
        v: [f32; 3],
        material: String,
        #[serde(default)]
        name: Option<String>,
    },
}

/// Everything of a pathtrace scene but the view.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct PathtraceRest {
    pub renderer: String,
    #[serde(default = "default_spp")]
    pub spp: u32,
    #[serde(default)]
    pub seed: u32,
    #[serde(default = "sixty_four")]
    pub max_bounces: u32,
    #[serde(default = "five")]
    pub rr_depth: u32,
    #[serde(default)]
    pub tracer: Tracer,
    #[serde(default)]
    pub sampler: Sampler,
    #[serde(default)]
    pub environment: [f32; 3],
    pub materials: BTreeMap<String, MaterialSpec>,
    pub shapes: Vec<ShapeSpec>,
}

/// A parsed, validated pathtrace scene.
#[derive(Clone, Debug)]
pub struct PathtraceScene {
    pub scene: Scene,
    pub camera: Camera,
    pub params: RenderParams,
    /// Each shape's `name` (or `shapes[i]`), in shape order.
    pub names: Vec<String>,
}

fn material(m: &MaterialSpec) -> Material {
    let v = Vec3A::from_array;
    match *m {
        MaterialSpec::Lambertian { albedo } => Material::Lambertian { albedo: v(albedo) },
        MaterialSpec::RoughConductor { alpha, reflectance } => Material::RoughConductor {
            alpha,
            reflectance: v(reflectance),
        },
        MaterialSpec::Dielectric { ior } => Material::Dielectric { ior },
        MaterialSpec::Emitter { radiance } => Material::Emitter {
            radiance: v(radiance),
        },
    }
}

/// Parses and validates a `renderer: pathtrace` scene.
pub fn parse(doc: &SceneDoc) -> Result<PathtraceScene> {
    let at = doc.at();
    let (view, rest): (ViewSpec, PathtraceRest) = doc.parse_split(VIEW_KEYS)?;
    if view.roi.is_some()
        || view.aabb.is_some()
        || view.jitter.is_some()
        || view.near != 0.0
        || view.far != f64::INFINITY
    {
        return Err(Error::invalid(
            &at,
            "pathtrace scenes use camera, width and height only (not roi, aabb, near, far, jitter)",
        ));
    }
    let camera = view
        .camera
        .build(view.width, view.height)
        .map_err(|e| Error::invalid(&at, e.to_string()))?;
    let names_m: Vec<&String> = rest.materials.keys().collect();
    let materials: Vec<Material> = rest.materials.values().map(material).collect();
    let mut objects = Vec::with_capacity(rest.shapes.len());
    let mut names = Vec::with_capacity(rest.shapes.len());
    for (i, s) in rest.shapes.iter().enumerate() {
        let key = format!("{at} key `shapes[{i}]`");
        let (shape, mat, name) = match s {
            ShapeSpec::Sphere {
                center,
                radius,
                material,
                name,
            } => (
                Shape::Sphere(Sphere {
                    centre: Vec3A::from_array(*center),
                    radius: *radius,
                }),
                material,
                name,
            ),
            ShapeSpec::Quad {
                corner,
                u,
                v,
                material,
                name,
            } => {
                let q = Quad::new(
                    Vec3A::from_array(*corner),
                    Vec3A::from_array(*u),
                    Vec3A::from_array(*v),
                )
                .ok_or_else(|| {
                    Error::invalid(&key, "quad edges u and v must be finite and not parallel")
                })?;
                (Shape::Quad(q), material, name)
            }
        };
        let m = names_m.iter().position(|n| *n == mat).ok_or_else(|| {
            Error::invalid(&key, format!("unknown material {mat:?} (have {names_m:?})"))
        })?;
        objects.push((shape, m));
        names.push(name.clone().unwrap_or_else(|| format!("shapes[{i}]")));
    }
    let scene = Scene::new(&objects, materials, rest.environment).map_err(|e| match e {
        Error::InvalidInput { at: k, what } => Error::invalid(format!("{at} {k}"), what),
        other => other,
    })?;
    let params = RenderParams {
        width: view.width,
        height: view.height,
        spp: rest.spp,
        seed: rest.seed,
        max_bounces: rest.max_bounces,
        rr_depth: rest.rr_depth,
        tracer: rest.tracer,
        sampler: rest.sampler,
    };
    params
        .validate()
        .map_err(|e| Error::invalid(&at, e.to_string()))?;
    Ok(PathtraceScene {
        scene,
        camera,
        params,
        names,
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

    const MINI: &str = "renderer: pathtrace\ncamera: {type: pinhole, position: [0, 0, 3.5], target: [0, 0, 0], fov_y: 40}\n\
        materials: {w: {type: lambertian, albedo: [0.7, 0.7, 0.7]}, l: {type: emitter, radiance: [15, 15, 15]}}\n\
        shapes:\n  - {type: sphere, center: [0, 0, 0], radius: 0.5, material: w}\n\
        \x20 - {type: quad, corner: [-0.25, 0.99, -0.25], u: [0.5, 0, 0], v: [0, 0, 0.5], material: l, name: light}\n";

    #[test]
    fn minimal_scene_parses_with_defaults() {
        let s = parse(&doc(MINI)).unwrap();
        assert_eq!(
            (
                s.params.spp,
                s.params.max_bounces,
                s.params.rr_depth,
                s.params.width
            ),
            (64, 64, 5, 64)
        );
        assert_eq!(s.names, vec!["shapes[0]".to_string(), "light".to_string()]);
    }

    #[test]
    fn unknown_keys_materials_and_bad_quads_are_errors() {
        let e = parse(&doc(&format!("{MINI}sppp: 3\n")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("sppp"), "{e}");
        let e = parse(&doc(&MINI.replace("material: w", "material: x")))
            .unwrap_err()
            .to_string();
        assert!(
            e.contains("shapes[0]") && e.contains("unknown material"),
            "{e}"
        );
        let e = parse(&doc(&MINI.replace("v: [0, 0, 0.5]", "v: [1, 0, 0]")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("shapes[1]") && e.contains("parallel"), "{e}");
        let e = parse(&doc(&format!("{MINI}jitter: {{seed: 1}}\n")))
            .unwrap_err()
            .to_string();
        assert!(e.contains("jitter"), "{e}");
    }
}
