//! Camera models (SCENES.md "Camera" and "Orthographic camera").
//!
//! Intrinsics `K = [fx 0 cx; 0 fy cy; 0 0 1]`, extrinsics `C2W` (3x4,
//! row-major, camera-to-world). Camera space is NeRF/OpenGL: the camera looks
//! along -Z, +Y up, +X right. Pixel (u, v) has its centre at (u + 0.5, v + 0.5),
//! v counting rows from the top.

pub mod nerf;

use crate::error::{Error, Result};
use crate::real::Real;

/// Row-major 3x4 camera-to-world matrix `[R | t]`.
pub type Mat34 = [[f64; 4]; 3];

/// Pinhole intrinsics in pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Intrinsics {
    pub fx: f64,
    pub fy: f64,
    pub cx: f64,
    pub cy: f64,
}

/// A camera: where rays start and which way they go for a pixel position.
#[derive(Clone, Debug, PartialEq)]
pub enum Camera {
    /// Rays from the camera centre `t` through `((px - cx)/fx, -(py - cy)/fy, -1)`.
    Pinhole { k: Intrinsics, c2w: Mat34 },
    /// Parallel rays along camera -Z from `(x, y, 0)`,
    /// `x = -hw + 2 hw px / W`, `y = hh - 2 hh py / H`.
    Orthographic {
        c2w: Mat34,
        half_width: f64,
        half_height: f64,
    },
}

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
fn norm(a: [f64; 3]) -> f64 {
    (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt()
}
fn scale(a: [f64; 3], s: f64) -> [f64; 3] {
    [a[0] * s, a[1] * s, a[2] * s]
}

/// C2W for a camera at `position` looking at `target` with `up` roughly up:
/// columns are right `x = normalize(f x up)`, up `y = x x f`, back `z = -f`
/// (f the unit forward direction), and the position.
pub fn look_at_c2w(position: [f64; 3], target: [f64; 3], up: [f64; 3]) -> Result<Mat34> {
    let all = position.iter().chain(&target).chain(&up);
    if all.clone().any(|v| !v.is_finite()) {
        return Err(Error::invalid(
            "camera",
            "position, target and up must be finite",
        ));
    }
    let fwd = sub(target, position);
    let fl = norm(fwd);
    if fl == 0.0 {
        return Err(Error::invalid(
            "camera",
            "target equals position: no viewing direction",
        ));
    }
    let f = scale(fwd, 1.0 / fl);
    let r = cross(f, up);
    let rl = norm(r);
    if rl <= 1e-12 * norm(up).max(1e-300) {
        return Err(Error::invalid(
            "camera.up",
            "up is zero or parallel to the viewing direction",
        ));
    }
    let x = scale(r, 1.0 / rl);
    let y = cross(x, f);
    let z = scale(f, -1.0);
    Ok([
        [x[0], y[0], z[0], position[0]],
        [x[1], y[1], z[1], position[1]],
        [x[2], y[2], z[2], position[2]],
    ])
}

impl Camera {
    /// SCENES.md `look_at`: `fx = fy = (H / 2) / tan(fov_y / 2)`, `cx = W / 2`, `cy = H / 2`.
    pub fn pinhole_look_at(
        position: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        fov_y_deg: f64,
        width: u32,
        height: u32,
    ) -> Result<Camera> {
        if !(fov_y_deg > 0.0 && fov_y_deg < 180.0) {
            return Err(Error::invalid(
                "camera.fov_y",
                format!("{fov_y_deg} is not in (0, 180) degrees"),
            ));
        }
        let f = (height as f64 / 2.0) / (fov_y_deg.to_radians() / 2.0).tan();
        let k = Intrinsics {
            fx: f,
            fy: f,
            cx: width as f64 / 2.0,
            cy: height as f64 / 2.0,
        };
        Ok(Camera::Pinhole {
            k,
            c2w: look_at_c2w(position, target, up)?,
        })
    }

    /// Orthographic camera with the same C2W as `look_at`.
    pub fn ortho_look_at(
        position: [f64; 3],
        target: [f64; 3],
        up: [f64; 3],
        half_width: f64,
        half_height: f64,
    ) -> Result<Camera> {
        if !(half_width > 0.0
            && half_height > 0.0
            && half_width.is_finite()
            && half_height.is_finite())
        {
            return Err(Error::invalid(
                "camera.half_width/half_height",
                "must be finite and positive",
            ));
        }
        Ok(Camera::Orthographic {
            c2w: look_at_c2w(position, target, up)?,
            half_width,
            half_height,
        })
    }

    pub fn c2w(&self) -> &Mat34 {
        match self {
            Camera::Pinhole { c2w, .. } | Camera::Orthographic { c2w, .. } => c2w,
        }
    }

    /// The same camera with another C2W (a moved pose).
    pub fn with_c2w(&self, c2w: Mat34) -> Camera {
        match self {
            Camera::Pinhole { k, .. } => Camera::Pinhole { k: *k, c2w },
            Camera::Orthographic {
                half_width,
                half_height,
                ..
            } => Camera::Orthographic {
                c2w,
                half_width: *half_width,
                half_height: *half_height,
            },
        }
    }

    /// Checks that every number is finite and the intrinsics are usable.
    pub fn validate(&self) -> Result<()> {
        if self.c2w().iter().flatten().any(|v| !v.is_finite()) {
            return Err(Error::invalid("camera.c2w", "every entry must be finite"));
        }
        if let Camera::Pinhole { k, .. } = self {
            let ok = [k.fx, k.fy, k.cx, k.cy].iter().all(|v| v.is_finite())
                && k.fx != 0.0
                && k.fy != 0.0;
            if !ok {
                return Err(Error::invalid(
                    "camera.k",
                    "fx, fy must be non-zero and every entry finite",
                ));
            }
        }
        Ok(())
    }

    /// The camera with its numbers rounded to `F`, ready to make rays.
    pub fn to_real<F: Real>(&self, width: u32, height: u32) -> RealCamera<F> {
        let c = self.c2w();
        let m = |r: usize, col: usize| F::of(c[r][col]);
        let rot = [
            [m(0, 0), m(0, 1), m(0, 2)],
            [m(1, 0), m(1, 1), m(1, 2)],
            [m(2, 0), m(2, 1), m(2, 2)],
        ];
        let t = [m(0, 3), m(1, 3), m(2, 3)];
        let model = match self {
            Camera::Pinhole { k, .. } => RealModel::Pinhole {
                fx: F::of(k.fx),
                fy: F::of(k.fy),
                cx: F::of(k.cx),
                cy: F::of(k.cy),
            },
            Camera::Orthographic {
                half_width,
                half_height,
                ..
            } => RealModel::Ortho {
                hw: F::of(*half_width),
                hh: F::of(*half_height),
                w: F::of(width as f64),
                h: F::of(height as f64),
            },
        };
        RealCamera { rot, t, model }
    }
}

#[derive(Clone, Copy, Debug)]
enum RealModel<F> {
    Pinhole { fx: F, fy: F, cx: F, cy: F },
    Ortho { hw: F, hh: F, w: F, h: F },
}

/// A camera in the precision of the render (see [`Camera::to_real`]).
#[derive(Clone, Copy, Debug)]
pub struct RealCamera<F> {
    rot: [[F; 3]; 3],
    t: [F; 3],
    model: RealModel<F>,
}

impl<F: Real> RealCamera<F> {
    fn rotate(&self, v: [F; 3]) -> [F; 3] {
        let r = &self.rot;
        [
            r[0][0] * v[0] + r[0][1] * v[1] + r[0][2] * v[2],
            r[1][0] * v[0] + r[1][1] * v[1] + r[1][2] * v[2],
            r[2][0] * v[0] + r[2][1] * v[1] + r[2][2] * v[2],
        ]
    }

    /// World-space origin and unit direction of the ray through pixel
    /// position (px, py).
    #[inline]
    pub fn ray(&self, px: F, py: F) -> ([F; 3], [F; 3]) {
        match self.model {
            RealModel::Pinhole { fx, fy, cx, cy } => {
                let dc = [(px - cx) / fx, -(py - cy) / fy, -F::one()];
                let d = self.rotate(dc);
                let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt();
                (self.t, [d[0] / n, d[1] / n, d[2] / n])
            }
            RealModel::Ortho { hw, hh, w, h } => {
                let two = F::of(2.0);
                let x = -hw + two * hw * px / w;
                let y = hh - two * hh * py / h;
                let oc = self.rotate([x, y, F::zero()]);
                let o = [oc[0] + self.t[0], oc[1] + self.t[1], oc[2] + self.t[2]];
                let d = self.rotate([F::zero(), F::zero(), -F::one()]);
                (o, d)
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn look_at_down_minus_z_is_identity_rotation() {
        let c = look_at_c2w([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0]).unwrap();
        let expect = [
            [1.0, 0.0, 0.0, 0.0],
            [0.0, 1.0, 0.0, 0.0],
            [0.0, 0.0, 1.0, 3.0],
        ];
        for r in 0..3 {
            for k in 0..4 {
                assert!((c[r][k] - expect[r][k]).abs() < 1e-15, "{c:?}");
            }
        }
    }

    #[test]
    fn centre_pixel_looks_at_target_and_corners_span_the_fov() {
        let cam = Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 64, 64)
            .unwrap();
        let rc = cam.to_real::<f64>(64, 64);
        let (o, d) = rc.ray(32.0, 32.0);
        assert_eq!(o, [0.0, 0.0, 3.0]);
        assert!((d[2] + 1.0).abs() < 1e-15 && d[0].abs() < 1e-15);
        // Top edge of the image (py = 0) is 20 degrees above the axis, +Y.
        let (_, d) = rc.ray(32.0, 0.0);
        assert!((d[1].atan2(-d[2]).to_degrees() - 20.0).abs() < 1e-12);
    }

    #[test]
    fn ortho_maps_pixel_edges_to_half_extents() {
        let cam =
            Camera::ortho_look_at([3.0, 0.0, 0.0], [0.0; 3], [0.0, 1.0, 0.0], 1.0, 1.0).unwrap();
        let rc = cam.to_real::<f64>(64, 64);
        let (o, d) = rc.ray(0.0, 0.0);
        // Looking along -X with +Y up: camera +X (right) is world -Z.
        assert!(
            (o[0] - 3.0).abs() < 1e-15 && (o[1] - 1.0).abs() < 1e-15 && (o[2] - 1.0).abs() < 1e-15,
            "{o:?}"
        );
        assert!((d[0] + 1.0).abs() < 1e-15);
    }

    #[test]
    fn degenerate_cameras_are_refused() {
        assert!(look_at_c2w([0.0; 3], [0.0; 3], [0.0, 1.0, 0.0]).is_err());
        assert!(look_at_c2w([0.0, 3.0, 0.0], [0.0; 3], [0.0, 1.0, 0.0]).is_err());
        assert!(
            Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 0.0, 4, 4).is_err()
        );
    }
}
