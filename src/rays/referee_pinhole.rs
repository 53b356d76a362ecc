//! Referee of pinhole ray directions from the scene's own numbers: the
//! look-at basis and `fx = fy = (H / 2) / tan(fov_y / 2)` (SCENES.md), centre
//! `(W / 2, H / 2)`, worked out here from `position`, `target`, `up`,
//! `fov_y`, `width`, `height`, never through `crate::camera`. On a non-square
//! image it tells a focal length taken from the width from one taken from
//! the height, which a referee reading the camera's own K cannot.

use serde::Deserialize;

use crate::error::{Error, Result};
use crate::scene::SceneDoc;
use crate::tensor::{Outputs, Tensor};

#[derive(Deserialize)]
struct Pinhole {
    position: [f64; 3],
    target: [f64; 3],
    up: [f64; 3],
    fov_y: f64,
}

#[derive(Deserialize)]
struct View {
    camera: Pinhole,
    width: u32,
    height: u32,
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn unit(a: [f64; 3]) -> [f64; 3] {
    let n = (a[0] * a[0] + a[1] * a[1] + a[2] * a[2]).sqrt();
    a.map(|x| x / n)
}

/// Unit direction through the centre of every pixel, row-major `(H, W, 3)`.
pub fn pinhole_directions(
    c: &[[f64; 3]; 3],
    fov_y_deg: f64,
    width: u32,
    height: u32,
) -> Vec<[f64; 3]> {
    let [position, target, up] = *c;
    let forward = unit([0, 1, 2].map(|a| target[a] - position[a]));
    let right = unit(cross(forward, up));
    let true_up = cross(right, forward);
    let f = (height as f64 / 2.0) / (fov_y_deg.to_radians() / 2.0).tan();
    let mut d = Vec::with_capacity(width as usize * height as usize);
    for v in 0..height {
        for u in 0..width {
            let x = (u as f64 + 0.5 - width as f64 / 2.0) / f;
            let y = (height as f64 / 2.0 - (v as f64 + 0.5)) / f;
            d.push(unit(
                [0, 1, 2].map(|a| x * right[a] + y * true_up[a] + forward[a]),
            ));
        }
    }
    d
}

/// Tensor `d` of [`pinhole_directions`] for a pinhole scene.
pub fn pinhole_reference(doc: &SceneDoc) -> Result<Outputs> {
    let v: View = serde_yaml::from_value(doc.value.clone())
        .map_err(|e| Error::invalid(doc.at(), format!("pinhole referee: {e}")))?;
    let c = &v.camera;
    let d = pinhole_directions(&[c.position, c.target, c.up], c.fov_y, v.width, v.height);
    let mut out = Outputs::default();
    let shape = [v.height as usize, v.width as usize];
    out.tensor("d", Tensor::real3(&shape, &d)?);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_centre_ray_looks_at_the_target_and_the_corner_ray_spans_half_the_fov() {
        let c = [[0.0, 0.0, 3.0], [0.0, 0.0, 0.0], [0.0, 1.0, 0.0]];
        let d = pinhole_directions(&c, 90.0, 4, 2);
        // Pixel (1, 0) centre is at x = -0.5, y = 0.5 over f = 1.
        let e = unit([-0.5, 0.5, -1.0]);
        assert!((0..3).all(|a| (d[1][a] - e[a]).abs() < 1e-15), "{:?}", d[1]);
    }

    #[test]
    fn this_referee_never_uses_the_stages_it_checks() {
        let allowed = ["crate::error", "crate::scene::SceneDoc", "crate::tensor"];
        assert_eq!(
            crate::independence::foreign_paths(include_str!("referee_pinhole.rs"), &allowed),
            Vec::<String>::new()
        );
    }
}
