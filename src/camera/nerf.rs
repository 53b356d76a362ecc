//! NeRF camera files: the `transforms.json` of the NeRF synthetic
//! datasets, Instant-NGP and nerfstudio, read as pinhole cameras.
//!
//! | key (file, or per frame) | meaning |
//! | --- | --- |
//! | `fl_x`, `fl_y` | focal lengths in pixels (`fl_y` defaults to `fl_x`) |
//! | `camera_angle_x`, `camera_angle_y` | horizontal / vertical field of view in radians, used when `fl_x` / `fl_y` are absent: `f = (w / 2) / tan(angle / 2)` |
//! | `cx`, `cy` | principal point in pixels (default `w / 2`, `h / 2`) |
//! | `w`, `h` | image size in pixels (default: the scene's `width`, `height`) |
//! | `frames[i].transform_matrix` | 4x4 (or 3x4) camera-to-world, rows; last row `0 0 0 1` |
//! | `frames[i].file_path` | the frame's name (its image, not read) |
//! | `k1` `k2` `k3` `k4` `p1` `p2`, `camera_model` | lens distortion: refused unless zero (`PINHOLE`, `SIMPLE_PINHOLE`, `OPENCV`) |
//!
//! The files' camera convention is the project's (NeRF/OpenGL: the camera
//! looks along -Z, +Y up, +X right), so `transform_matrix` is our C2W as
//! written. Instant-NGP's `scale`/`offset`/`aabb_scale` (its own mapping
//! into a unit cube) are not applied: poses stay in the file's world
//! units. Rendered at a size other than `w` x `h`, the intrinsics scale by
//! `width / w` and `height / h` (the same image plane, resampled).

use serde::Deserialize;

use super::{Camera, Intrinsics, Mat34};
use crate::error::{Error, Result};

/// The intrinsic keys a file or a frame may carry.
#[derive(Clone, Debug, Default, Deserialize)]
struct Lens {
    fl_x: Option<f64>,
    fl_y: Option<f64>,
    camera_angle_x: Option<f64>,
    camera_angle_y: Option<f64>,
    cx: Option<f64>,
    cy: Option<f64>,
    w: Option<f64>,
    h: Option<f64>,
    k1: Option<f64>,
    k2: Option<f64>,
    k3: Option<f64>,
    k4: Option<f64>,
    p1: Option<f64>,
    p2: Option<f64>,
    camera_model: Option<String>,
}

impl Lens {
    /// `self`'s keys over `base`'s.
    fn over(&self, base: &Lens) -> Lens {
        macro_rules! pick {
            ($($f:ident),*) => { Lens { $($f: self.$f.clone().or_else(|| base.$f.clone()),)* } };
        }
        pick!(
            fl_x,
            fl_y,
            camera_angle_x,
            camera_angle_y,
            cx,
            cy,
            w,
            h,
            k1,
            k2,
            k3,
            k4,
            p1,
            p2,
            camera_model
        )
    }
}

#[derive(Debug, Deserialize)]
struct FrameJson {
    #[serde(default)]
    file_path: Option<String>,
    transform_matrix: Vec<Vec<f64>>,
    #[serde(flatten)]
    lens: Lens,
}

#[derive(Debug, Deserialize)]
struct FileJson {
    frames: Vec<FrameJson>,
    #[serde(flatten)]
    lens: Lens,
}

/// One frame: its name, intrinsics at its own size, and pose.
#[derive(Clone, Debug, PartialEq)]
pub struct NerfFrame {
    pub name: String,
    pub k: Intrinsics,
    pub width: f64,
    pub height: f64,
    pub c2w: Mat34,
}

impl NerfFrame {
    /// The pinhole camera of this frame for a `width` x `height` render.
    pub fn camera(&self, width: u32, height: u32) -> Camera {
        let (sx, sy) = (width as f64 / self.width, height as f64 / self.height);
        Camera::Pinhole {
            k: Intrinsics {
                fx: self.k.fx * sx,
                fy: self.k.fy * sy,
                cx: self.k.cx * sx,
                cy: self.k.cy * sy,
            },
            c2w: self.c2w,
        }
    }
}

/// Reads the frames of a `transforms.json` text (`at` names the file in
/// errors). `size` is the scene's (width, height), used when the file has
/// no `w`/`h`. Errors name the file, line (syntax) or key (`frames[3].fl_x`).
pub fn parse(text: &str, at: &str, size: (u32, u32)) -> Result<Vec<NerfFrame>> {
    let f: FileJson = serde_json::from_str(text)
        .map_err(|e| Error::invalid(format!("{at}:{}", e.line()), e.to_string()))?;
    if f.frames.is_empty() {
        return Err(Error::invalid(at, "`frames` is empty"));
    }
    f.frames
        .iter()
        .enumerate()
        .map(|(i, fr)| {
            frame(
                fr,
                &fr.lens.over(&f.lens),
                &format!("{at}: frames[{i}]"),
                i,
                size,
            )
        })
        .collect()
}

fn frame(fr: &FrameJson, l: &Lens, at: &str, i: usize, size: (u32, u32)) -> Result<NerfFrame> {
    let bad = |key: &str, what: String| Error::invalid(format!("{at}.{key}"), what);
    for (key, v) in [
        ("k1", l.k1),
        ("k2", l.k2),
        ("k3", l.k3),
        ("k4", l.k4),
        ("p1", l.p1),
        ("p2", l.p2),
    ] {
        if v.is_some_and(|v| v != 0.0) {
            return Err(bad(
                key,
                "lens distortion is not supported (pinhole cameras only)".into(),
            ));
        }
    }
    if let Some(m) = &l.camera_model {
        if !["PINHOLE", "SIMPLE_PINHOLE", "OPENCV"].contains(&m.as_str()) {
            return Err(bad("camera_model", format!("{m:?} is not a pinhole model")));
        }
    }
    let w = l.w.unwrap_or(size.0 as f64);
    let h = l.h.unwrap_or(size.1 as f64);
    if !(w.is_finite() && h.is_finite() && w >= 1.0 && h >= 1.0) {
        return Err(bad(
            "w",
            format!("image size {w} x {h} must be at least 1 x 1"),
        ));
    }
    let focal =
        |fl: Option<f64>, angle: Option<f64>, extent: f64, key: &str| -> Result<Option<f64>> {
            match (fl, angle) {
                (Some(f), _) => Ok(Some(f)),
                (None, Some(a)) if a > 0.0 && a < std::f64::consts::PI => {
                    Ok(Some(0.5 * extent / (0.5 * a).tan()))
                }
                (None, Some(a)) => Err(bad(key, format!("{a} is not an angle in (0, pi) radians"))),
                (None, None) => Ok(None),
            }
        };
    let fx = focal(l.fl_x, l.camera_angle_x, w, "camera_angle_x")?.ok_or_else(|| {
        bad(
            "fl_x",
            "needs `fl_x` or `camera_angle_x` (in the file or the frame)".into(),
        )
    })?;
    let fy = focal(l.fl_y, l.camera_angle_y, h, "camera_angle_y")?.unwrap_or(fx);
    let k = Intrinsics {
        fx,
        fy,
        cx: l.cx.unwrap_or(0.5 * w),
        cy: l.cy.unwrap_or(0.5 * h),
    };
    let m = &fr.transform_matrix;
    if !(m.len() == 3 || m.len() == 4) || m.iter().any(|r| r.len() != 4) {
        return Err(bad(
            "transform_matrix",
            "must be 4 rows (or 3) of 4 numbers".into(),
        ));
    }
    if m.len() == 4
        && m[3]
            .iter()
            .zip([0.0, 0.0, 0.0, 1.0])
            .any(|(a, b)| (a - b).abs() > 1e-6)
    {
        return Err(bad(
            "transform_matrix",
            format!("last row {:?} is not [0, 0, 0, 1]", m[3]),
        ));
    }
    let c2w: Mat34 = [0, 1, 2].map(|r| [m[r][0], m[r][1], m[r][2], m[r][3]]);
    let cam = Camera::Pinhole { k, c2w };
    cam.validate()
        .map_err(|e| bad("transform_matrix", e.to_string()))?;
    Ok(NerfFrame {
        name: fr
            .file_path
            .clone()
            .unwrap_or_else(|| format!("frame_{i:04}")),
        k,
        width: w,
        height: h,
        c2w,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    const BLENDER: &str = r#"{
      "camera_angle_x": 0.6911112070083618,
      "frames": [
        {"file_path": "./train/r_0", "rotation": 0.012,
         "transform_matrix": [[-0.9999, 0.0042, -0.0133, -0.0538],
                              [-0.0140, -0.2997, 0.9539, 3.8455],
                              [0.0, 0.9540, 0.2997, 1.2081],
                              [0.0, 0.0, 0.0, 1.0]]}
      ]
    }"#;

    #[test]
    fn blender_files_take_focal_from_the_angle_and_size_from_the_scene() {
        let f = parse(BLENDER, "t.json", (800, 800)).unwrap();
        assert_eq!(f.len(), 1);
        assert_eq!(f[0].name, "./train/r_0");
        // The synthetic datasets' focal: 0.5 * 800 / tan(0.5 * camera_angle_x).
        assert!((f[0].k.fx - 1111.1110311937682).abs() < 1e-9);
        assert_eq!((f[0].k.fy, f[0].k.cx, f[0].k.cy), (f[0].k.fx, 400.0, 400.0));
        assert_eq!(f[0].c2w[1], [-0.0140, -0.2997, 0.9539, 3.8455]);
    }

    #[test]
    fn nerfstudio_per_frame_intrinsics_override_the_file_and_scale_with_the_render() {
        let text = r#"{"fl_x": 100, "w": 200, "h": 100, "camera_model": "OPENCV", "k1": 0,
          "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]], "fl_y": 90, "cx": 110, "cy": 40}]}"#;
        let f = parse(text, "t.json", (1, 1)).unwrap();
        assert_eq!(
            f[0].k,
            Intrinsics {
                fx: 100.0,
                fy: 90.0,
                cx: 110.0,
                cy: 40.0
            }
        );
        let Camera::Pinhole { k, .. } = f[0].camera(100, 50) else {
            panic!()
        };
        assert_eq!(
            k,
            Intrinsics {
                fx: 50.0,
                fy: 45.0,
                cx: 55.0,
                cy: 20.0
            }
        );
    }

    #[test]
    fn bad_files_are_refused_naming_the_key() {
        let cases = [
            ("{\"frames\": [", "t.json:1"),
            ("{\"frames\": []}", "`frames` is empty"),
            (
                r#"{"frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#,
                "frames[0].fl_x",
            ),
            (
                r#"{"fl_x": 1, "k1": 0.1, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#,
                "frames[0].k1",
            ),
            (
                r#"{"fl_x": 1, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0],[1,0,0,1]]}]}"#,
                "not [0, 0, 0, 1]",
            ),
            (
                r#"{"fl_x": 1, "frames": [{"transform_matrix": [[1,0,0],[0,1,0],[0,0,1]]}]}"#,
                "frames[0].transform_matrix",
            ),
            (
                r#"{"camera_angle_x": 4, "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#,
                "not an angle",
            ),
            (
                r#"{"fl_x": 1, "camera_model": "OPENCV_FISHEYE", "frames": [{"transform_matrix": [[1,0,0,0],[0,1,0,0],[0,0,1,0]]}]}"#,
                "camera_model",
            ),
        ];
        for (text, want) in cases {
            let e = parse(text, "t.json", (8, 8)).unwrap_err().to_string();
            assert!(e.contains(want), "{want:?} not in {e}");
        }
    }
}
