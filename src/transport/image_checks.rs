//! Checks of the curved-spacetime images as named tensors: Bardeen's
//! shadow and the Kerr radii by closed form (`referee_kerr`), the image's
//! mirror images (a symmetric scene must equal them), and the per-pixel
//! difference between two renders (the scene's integrator against the
//! research preset `validate`).

use crate::error::{Error, Result};
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};

use super::image::{ImageOut, KerrImage, Observer, Pixels};
use super::outputs::t1;
use super::referee_kerr as rk;

/// Scalars `horizon`, `ergosphere_equator`, `photon_pro`, `photon_retro`,
/// `isco`, `isco_retro`; for a distant observer per pixel Bardeen's verdict
/// `shadow_class` (0 escapes, 1 captured, 2 the curve crosses the pixel),
/// `shadow_decided`, `shadow_captured`.
pub fn kerr_closed_form(k: &KerrImage) -> Result<Outputs> {
    let (m, a) = (k.kerr.mass, k.kerr.a.abs());
    let mut out = Outputs::default();
    let (rp, _) = rk::horizons(m, a);
    let (pp, pr) = rk::photon_orbits(m, a);
    let (ip, ir) = rk::isco(m, a);
    let ergo = rk::ergosphere(m, a, std::f64::consts::FRAC_PI_2);
    out.tensor("horizon", t1(rp))
        .tensor("ergosphere_equator", t1(ergo));
    out.tensor("photon_pro", t1(pp))
        .tensor("photon_retro", t1(pr));
    out.tensor("isco", t1(ip)).tensor("isco_retro", t1(ir));
    let Observer::Distant { obs, half } = k.observer else {
        return Ok(out);
    };
    // Bardeen's curve is drawn for the spin's sign: a < 0 mirrors alpha.
    let flip = if k.kerr.a < 0.0 { -1.0 } else { 1.0 };
    let (classes, shape) = match &k.pixels {
        Pixels::Grid { width, height } => {
            let c = rk::shadow_classes(m, a, obs.theta_o, *width, *height, half, half);
            let c = if flip < 0.0 {
                (0..width * height)
                    .map(|i| c[(i / width) * width + (width - 1 - i % width)])
                    .collect()
            } else {
                c
            };
            (c, vec![*height, *width])
        }
        Pixels::List(l) => {
            let poly = rk::critical_curve(m, a, obs.theta_o, 1 << 18);
            let c = l
                .iter()
                .map(|p| rk::inside(&poly, flip * p[0], p[1]) as u8)
                .collect();
            (c, vec![l.len()])
        }
    };
    let decided = classes.iter().map(|&c| (c != 2) as u8).collect();
    out.tensor("shadow_decided", Tensor::from_shape_vec(&shape, decided)?);
    let captured = classes.iter().map(|&c| (c == 1) as u8).collect();
    out.tensor("shadow_captured", Tensor::from_shape_vec(&shape, captured)?);
    out.tensor("shadow_class", Tensor::from_shape_vec(&shape, classes)?);
    Ok(out)
}

impl<F: Real> ImageOut<F> {
    /// `image` (H, W, 3) and its flips left-right (`image_lr`) and
    /// top-bottom (`image_ud`); a ray list is refused.
    pub fn mirror_outputs(&self) -> Result<Outputs> {
        let [h, w] = self.shape[..] else {
            return Err(Error::invalid("task", "image_mirror needs a pixel grid"));
        };
        let img: Vec<F> = self.image.iter().flatten().copied().collect();
        let at = |v: usize, u: usize, c: usize| img[(v * w + u) * 3 + c];
        let lr: Vec<F> = (0..h * w * 3)
            .map(|i| at(i / 3 / w, w - 1 - (i / 3) % w, i % 3))
            .collect();
        let ud: Vec<F> = (0..h * w * 3)
            .map(|i| at(h - 1 - i / 3 / w, (i / 3) % w, i % 3))
            .collect();
        let mut out = Outputs::default();
        out.tensor("image", Tensor::real(&[h, w, 3], img)?);
        out.tensor("image_lr", Tensor::real(&[h, w, 3], lr)?);
        out.tensor("image_ud", Tensor::real(&[h, w, 3], ud)?);
        Ok(out)
    }

    /// Per pixel against `b`: `dir_diff` (angle between final directions,
    /// rad), `captured_diff`, `disk_r_diff` (with a disk); metrics
    /// `max_dir_diff`, `captured_diff_count`.
    pub fn diff_outputs(&self, b: &ImageOut<F>) -> Result<Outputs> {
        let sh = &self.shape;
        let dir: Vec<f64> = self
            .final_dir
            .iter()
            .zip(&b.final_dir)
            .map(|(p, q)| {
                let d: f64 = (0..3).map(|i| p[i].f64() * q[i].f64()).sum();
                let np: f64 = (0..3).map(|i| p[i].f64().powi(2)).sum();
                let nq: f64 = (0..3).map(|i| q[i].f64().powi(2)).sum();
                if np > 0.0 && nq > 0.0 {
                    d.clamp(-1.0, 1.0).acos()
                } else {
                    0.0
                }
            })
            .collect();
        let cap: Vec<u8> = self
            .captured
            .iter()
            .zip(&b.captured)
            .map(|(x, y)| (x != y) as u8)
            .collect();
        let mut out = Outputs::default();
        out.metric("max_dir_diff", dir.iter().fold(0.0, |m: f64, v| m.max(*v)));
        out.metric("captured_diff_count", cap.iter().map(|&c| c as f64).sum());
        if !self.disk_r.is_empty() {
            let d: Vec<f64> = self
                .disk_r
                .iter()
                .zip(&b.disk_r)
                .map(|(x, y)| (x.f64() - y.f64()).abs())
                .collect();
            out.tensor("disk_r_diff", Tensor::from_shape_vec(sh, d)?);
        }
        out.tensor("dir_diff", Tensor::from_shape_vec(sh, dir)?);
        out.tensor("captured_diff", Tensor::from_shape_vec(sh, cap)?);
        Ok(out)
    }
}
