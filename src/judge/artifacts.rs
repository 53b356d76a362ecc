//! Artifacts: every output tensor as `.npy`, and (H, W, 3) float images also
//! as sRGB `.png` previews clamped to [0, 1].

use std::path::{Path, PathBuf};

use crate::error::{Error, Result};
use crate::tensor::Tensor;

/// The sRGB transfer function of a linear value in [0, 1].
pub fn srgb_encode(x: f64) -> f64 {
    let x = x.clamp(0.0, 1.0);
    if x <= 0.0031308 {
        12.92 * x
    } else {
        1.055 * x.powf(1.0 / 2.4) - 0.055
    }
}

/// Whether a tensor name is an image to preview (`rgb`, `image`, `x.rgb`, ...).
fn is_image_name(name: &str) -> bool {
    let base = name.rsplit('.').next().unwrap_or(name);
    matches!(base, "rgb" | "image") || base.ends_with("_rgb") || base.ends_with("_image")
}

/// Writes `t` as `<dir>/<name>.npy`, plus `<name>.png` when it is an
/// (H, W, 3) float image named like one (`rgb`, `image`). Returns the paths written.
pub fn write_tensor(dir: &Path, name: &str, t: &Tensor) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    let npy = dir.join(format!("{name}.npy"));
    t.write_npy(&npy)?;
    written.push(npy);
    let s = t.shape();
    if is_image_name(name) && t.is_float() && s.len() == 3 && s[2] == 3 && s[0] > 0 && s[1] > 0 {
        let png = dir.join(format!("{name}.png"));
        write_png(&png, s[0], s[1], &t.to_f64_vec())?;
        written.push(png);
    }
    Ok(written)
}

/// Writes linear RGB (row-major, 3 values a pixel) as an 8-bit sRGB PNG.
pub fn write_png(path: &Path, h: usize, w: usize, rgb: &[f64]) -> Result<()> {
    let bytes: Vec<u8> = rgb
        .iter()
        .map(|&x| (srgb_encode(if x.is_finite() { x } else { 0.0 }) * 255.0).round() as u8)
        .collect();
    let img = image::RgbImage::from_raw(w as u32, h as u32, bytes).ok_or_else(|| {
        Error::invalid(
            path.display().to_string(),
            "image buffer does not match its size",
        )
    })?;
    img.save(path)
        .map_err(|e| Error::invalid(path.display().to_string(), format!("cannot write PNG: {e}")))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_endpoints_and_knee() {
        assert_eq!(srgb_encode(0.0), 0.0);
        assert!((srgb_encode(1.0) - 1.0).abs() < 1e-12);
        assert!((srgb_encode(0.0031308) - 0.040449936).abs() < 1e-6);
        assert_eq!(srgb_encode(7.0), srgb_encode(1.0));
    }
}
