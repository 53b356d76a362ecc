//! The `camera:` block every rendering scene shares.
//!
//! | key | meaning | default |
//! | --- | --- | --- |
//! | `type` | `pinhole` (look-at), `pinhole_k` (explicit K and C2W) or `ortho` | required |
//! | `position`, `target`, `up` | look-at frame (pinhole, ortho) | up = [0, 1, 0] |
//! | `fov_y` | vertical field of view in degrees (pinhole) | required |
//! | `k`, `c2w` | 9 and 12 numbers, row-major (pinhole_k) | required |
//! | `half_width`, `half_height` | ortho half extents | 1, 1 |

use serde::Deserialize;

use crate::camera::{Camera, Intrinsics};
use crate::error::{Error, Result};

fn up_y() -> [f64; 3] {
    [0.0, 1.0, 0.0]
}
fn one() -> f64 {
    1.0
}

/// A camera as written in a scene file.
#[derive(Clone, Debug, Deserialize, PartialEq)]
#[serde(tag = "type", rename_all = "snake_case", deny_unknown_fields)]
pub enum CameraSpec {
    Pinhole {
        position: [f64; 3],
        target: [f64; 3],
        #[serde(default = "up_y")]
        up: [f64; 3],
        fov_y: f64,
    },
    PinholeK {
        k: [f64; 9],
        c2w: [f64; 12],
    },
    Ortho {
        position: [f64; 3],
        target: [f64; 3],
        #[serde(default = "up_y")]
        up: [f64; 3],
        #[serde(default = "one")]
        half_width: f64,
        #[serde(default = "one")]
        half_height: f64,
    },
}

impl CameraSpec {
    /// The camera for a `width` x `height` image.
    pub fn build(&self, width: u32, height: u32) -> Result<Camera> {
        match *self {
            CameraSpec::Pinhole {
                position,
                target,
                up,
                fov_y,
            } => Camera::pinhole_look_at(position, target, up, fov_y, width, height),
            CameraSpec::PinholeK { k, c2w } => {
                if k[1] != 0.0 || k[3] != 0.0 || k[6] != 0.0 || k[7] != 0.0 || k[8] != 1.0 {
                    return Err(Error::invalid(
                        "camera.k",
                        "must be [fx 0 cx; 0 fy cy; 0 0 1]",
                    ));
                }
                let cam = Camera::Pinhole {
                    k: Intrinsics {
                        fx: k[0],
                        fy: k[4],
                        cx: k[2],
                        cy: k[5],
                    },
                    c2w: [
                        [c2w[0], c2w[1], c2w[2], c2w[3]],
                        [c2w[4], c2w[5], c2w[6], c2w[7]],
                        [c2w[8], c2w[9], c2w[10], c2w[11]],
                    ],
                };
                cam.validate()?;
                Ok(cam)
            }
            CameraSpec::Ortho {
                position,
                target,
                up,
                half_width,
                half_height,
            } => Camera::ortho_look_at(position, target, up, half_width, half_height),
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unknown_camera_keys_and_types_are_rejected() {
        let bad: std::result::Result<CameraSpec, _> = serde_yaml::from_str(
            "{type: pinhole, position: [0,0,3], target: [0,0,0], fov_y: 40, fovy: 3}",
        );
        assert!(bad.is_err());
        let bad: std::result::Result<CameraSpec, _> = serde_yaml::from_str("{type: fisheye}");
        assert!(bad.is_err());
        let ok: CameraSpec =
            serde_yaml::from_str("{type: ortho, position: [0,0,3], target: [0,0,0]}").unwrap();
        assert!(ok.build(4, 4).is_ok());
    }
}
