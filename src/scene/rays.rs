//! `renderer: rays` scenes: camera rays clipped to a box (the `f_ray` stage
//! alone), and the image/box block that rendering scenes reuse.
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `camera` | see `scene/camera.rs` | required |
//! | `width`, `height` | image size in pixels | 64, 64 |
//! | `roi` | `{x, y, width, height}` sub-rectangle | whole image |
//! | `aabb` | `{min: [..], max: [..]}` world box | [-1, 1]^3 |
//! | `near`, `far` | ray interval before clipping | 0, .inf |
//! | `jitter` | `{seed, sample}` anti-aliasing jitter | pixel centres |

use serde::Deserialize;

use super::camera::CameraSpec;
use super::SceneDoc;
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{Aabb, Jitter, RayGen, Roi};

fn sixty_four() -> u32 {
    64
}
fn inf() -> f64 {
    f64::INFINITY
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct AabbSpec {
    pub min: [f64; 3],
    pub max: [f64; 3],
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RoiSpec {
    pub x: u32,
    pub y: u32,
    pub width: u32,
    pub height: u32,
}

#[derive(Clone, Copy, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct JitterSpec {
    pub seed: u32,
    #[serde(default)]
    pub sample: u32,
}

/// The keys every ray-cast scene shares: camera, image, box, interval, jitter.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct ViewSpec {
    pub camera: CameraSpec,
    #[serde(default = "sixty_four")]
    pub width: u32,
    #[serde(default = "sixty_four")]
    pub height: u32,
    #[serde(default)]
    pub roi: Option<RoiSpec>,
    #[serde(default)]
    pub aabb: Option<AabbSpec>,
    #[serde(default)]
    pub near: f64,
    #[serde(default = "inf")]
    pub far: f64,
    #[serde(default)]
    pub jitter: Option<JitterSpec>,
}

impl ViewSpec {
    /// The camera and the ray generator this block describes (validated).
    pub fn build(&self) -> Result<(Camera, RayGen)> {
        let gen = RayGen {
            width: self.width,
            height: self.height,
            roi: self.roi.map(|r| Roi {
                x: r.x,
                y: r.y,
                width: r.width,
                height: r.height,
            }),
            aabb: self.aabb.map_or(Aabb::UNIT, |b| Aabb {
                min: b.min,
                max: b.max,
            }),
            near: self.near,
            far: self.far,
            jitter: self.jitter.map(|j| Jitter {
                seed: j.seed,
                sample: j.sample,
            }),
        };
        gen.validate()?;
        let cam = self.camera.build(self.width, self.height)?;
        Ok((cam, gen))
    }
}

/// The top-level keys [`ViewSpec`] owns; a scene that embeds a view parses
/// these with [`SceneDoc::parse_split`] and the rest with its own struct.
pub const VIEW_KEYS: &[&str] = &[
    "camera", "width", "height", "roi", "aabb", "near", "far", "jitter",
];

/// A `renderer: rays` scene: nothing but the view.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct RaysRest {
    pub renderer: String,
}

/// Parses a `renderer: rays` scene.
pub fn parse(doc: &SceneDoc) -> Result<ViewSpec> {
    let (view, _rest): (ViewSpec, RaysRest) = doc.parse_split(VIEW_KEYS)?;
    Ok(view)
}
