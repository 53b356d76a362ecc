//! Referee of ray generation and box clipping: f64 rays computed directly
//! from the camera's K and C2W (not through `camera::RealCamera`) and box
//! entry/exit by intersecting the six face planes (not the slab method of
//! `rays::clip_aabb`). A test below holds this file to that.

use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{Aabb, RayGen};
use crate::rng::rand_f64;
use crate::tensor::{Outputs, Tensor};

/// Entry and exit of `o + t d` with a closed box by intersecting each of
/// the six face planes and keeping the hits inside the face rectangle
/// (relative slack 1e-12 for the f64 rounding of the hit point). Written
/// apart from `rays::clip_aabb` (slab method) so that each checks the other.
pub fn faces_clip(o: [f64; 3], d: [f64; 3], b: &Aabb, near: f64, far: f64) -> (f64, f64, bool) {
    let mut ts: Vec<f64> = Vec::with_capacity(6);
    for axis in 0..3 {
        if d[axis] == 0.0 {
            continue;
        }
        for plane in [b.min[axis], b.max[axis]] {
            let t = (plane - o[axis]) / d[axis];
            // Along an axis the ray does not move in, the coordinate is exact.
            let on_face = (0..3).filter(|&k| k != axis).all(|k| {
                let p = o[k] + t * d[k];
                let slack = if d[k] == 0.0 {
                    0.0
                } else {
                    1e-12 * (1.0 + p.abs())
                };
                p >= b.min[k] - slack && p <= b.max[k] + slack
            });
            if on_face {
                ts.push(t);
            }
        }
    }
    // An axis-parallel ray lying in a face plane meets that face along a
    // segment; its entry/exit come from the other axes' planes, found above.
    let (lo, hi) = match (
        ts.iter().cloned().reduce(f64::min),
        ts.iter().cloned().reduce(f64::max),
    ) {
        (Some(a), Some(b)) => (a.max(near), b.min(far)),
        _ => return (near, near, false),
    };
    if hi > lo {
        (lo, hi, true)
    } else {
        (near, near, false)
    }
}

/// The ray through pixel position (px, py), computed directly from the
/// camera's K and C2W in f64 (independent of `camera::RealCamera`).
pub fn reference_ray(cam: &Camera, px: f64, py: f64, w: u32, h: u32) -> ([f64; 3], [f64; 3]) {
    let m = cam.c2w();
    let rot = |v: [f64; 3]| -> [f64; 3] {
        [0, 1, 2].map(|r| m[r][0] * v[0] + m[r][1] * v[1] + m[r][2] * v[2])
    };
    let pos = [m[0][3], m[1][3], m[2][3]];
    match cam {
        Camera::Pinhole { k, .. } => {
            let d = rot([(px - k.cx) / k.fx, (k.cy - py) / k.fy, -1.0]);
            let n = d.iter().map(|x| x * x).sum::<f64>().sqrt();
            (pos, d.map(|x| x / n))
        }
        Camera::Orthographic {
            half_width,
            half_height,
            ..
        } => {
            let x = half_width * (2.0 * px / w as f64 - 1.0);
            let y = half_height * (1.0 - 2.0 * py / h as f64);
            let oc = rot([x, y, 0.0]);
            (
                [oc[0] + pos[0], oc[1] + pos[1], oc[2] + pos[2]],
                rot([0.0, 0.0, -1.0]),
            )
        }
    }
}

/// Reference rays and clip of every pixel of `gen`'s region (row-major).
pub struct ClipReference {
    pub t0: Vec<f64>,
    pub t1: Vec<f64>,
    pub hit: Vec<u8>,
    pub d: Vec<[f64; 3]>,
}

impl ClipReference {
    /// Tensors `t0`, `t1`, `hit`, `d` of image shape `shape` (H, W).
    pub fn to_outputs(self, shape: &[usize]) -> Result<Outputs> {
        let mut out = Outputs::default();
        out.tensor("t0", Tensor::real(shape, self.t0)?);
        out.tensor("t1", Tensor::real(shape, self.t1)?);
        out.tensor("hit", Tensor::from_shape_vec(shape, self.hit)?);
        out.tensor("d", Tensor::real3(shape, &self.d)?);
        Ok(out)
    }
}

/// One reference ray per pixel of `gen`'s region (jittered as `gen` says),
/// clipped by [`faces_clip`].
pub fn clip_reference(cam: &Camera, gen: &RayGen) -> ClipReference {
    let roi = gen.region();
    let n = roi.width as usize * roi.height as usize;
    let (mut t0, mut t1, mut hit, mut ds) =
        (vec![0.0; n], vec![0.0; n], vec![0u8; n], vec![[0.0; 3]; n]);
    for i in 0..n {
        let u = roi.x + (i as u32 % roi.width);
        let v = roi.y + (i as u32 / roi.width);
        let pixel = v * gen.width + u;
        let (jx, jy) = gen.jitter.map_or((0.5, 0.5), |j| {
            (
                rand_f64(j.seed, pixel, j.sample, 0),
                rand_f64(j.seed, pixel, j.sample, 1),
            )
        });
        let (o, d) = reference_ray(cam, u as f64 + jx, v as f64 + jy, gen.width, gen.height);
        let (a, b, h) = faces_clip(o, d, &gen.aabb, gen.near, gen.far);
        (t0[i], t1[i], hit[i], ds[i]) = (a, b, h as u8, d);
    }
    ClipReference { t0, t1, hit, d: ds }
}

/// Reference clip of listed rays `[ox, oy, oz, dx, dy, dz]`: `(t0, t1, hit)`.
pub fn clip_list_reference(
    rays: &[[f64; 6]],
    b: &Aabb,
    near: f64,
    far: f64,
) -> (Vec<f64>, Vec<f64>, Vec<u8>) {
    let (mut t0, mut t1, mut hit) = (vec![], vec![], vec![]);
    for r in rays {
        let n = (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]).sqrt();
        let (o, d) = ([r[0], r[1], r[2]], [r[3] / n, r[4] / n, r[5] / n]);
        let (a, c, h) = faces_clip(o, d, b, near, far);
        t0.push(a);
        t1.push(c);
        hit.push(h as u8);
    }
    (t0, t1, hit)
}

#[cfg(test)]
mod tests {
    #[test]
    fn this_referee_never_uses_the_stages_it_checks() {
        let allowed = [
            "crate::camera::Camera",
            "crate::rays::Aabb",
            "crate::rays::RayGen",
            "crate::rng",
            "crate::error",
            "crate::tensor",
        ];
        assert_eq!(
            crate::independence::foreign_paths(include_str!("referee.rs"), &allowed),
            Vec::<String>::new()
        );
    }
}
