//! Artifacts: every output tensor as `.npy`; an (H, W, 3) float image
//! (named `rgb`, `image`, `*_rgb`, `*_image`) also as
//!
//! - `<name>.exr`: the linear values as 32-bit float RGB OpenEXR (lossless
//!   within f32; NaN and infinities kept; row 0 at the top), for HDR viewers
//!   and compositing tools. Plots (`plot*`) get no EXR: they are not data.
//! - `<name>.png`: an 8-bit preview. Tone mapping: each linear value is
//!   clamped to [0, 1] (non-finite values become 0) and encoded with the sRGB
//!   transfer function of IEC 61966-2-1 ([`srgb_encode`]: `12.92 x` below
//!   0.0031308, else `1.055 x^(1/2.4) - 0.055`), then rounded to 8 bits. No
//!   exposure or curve beyond the clamp: a value of 1 is white, so HDR
//!   highlights clip in the PNG and survive in the EXR and `.npy`.

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

/// The inverse of [`srgb_encode`]: the linear value of an sRGB-encoded one in [0, 1].
pub fn srgb_decode(v: f64) -> f64 {
    let v = v.clamp(0.0, 1.0);
    if v <= 0.04045 {
        v / 12.92
    } else {
        ((v + 0.055) / 1.055).powf(2.4)
    }
}

/// Whether a tensor name is an image to preview (`rgb`, `image`, `x.rgb`, ...).
fn is_image_name(name: &str) -> bool {
    let base = name.rsplit('.').next().unwrap_or(name);
    matches!(base, "rgb" | "image") || base.ends_with("_rgb") || base.ends_with("_image")
}

/// Writes `t` as `<dir>/<name>.npy`, plus `<name>.png` and (not for plots)
/// `<name>.exr` when it is an (H, W, 3) float image named like one (`rgb`,
/// `image`). Returns the paths written.
pub fn write_tensor(dir: &Path, name: &str, t: &Tensor) -> Result<Vec<PathBuf>> {
    let mut written = Vec::new();
    let npy = dir.join(format!("{name}.npy"));
    t.write_npy(&npy)?;
    written.push(npy);
    let s = t.shape();
    if is_image_name(name) && t.is_float() && s.len() == 3 && s[2] == 3 && s[0] > 0 && s[1] > 0 {
        let rgb = t.to_f64_vec();
        let base = name.rsplit('.').next().unwrap_or(name);
        if !base.starts_with("plot") {
            let exr = dir.join(format!("{name}.exr"));
            write_exr(&exr, s[0], s[1], &rgb)?;
            written.push(exr);
        }
        let png = dir.join(format!("{name}.png"));
        write_png(&png, s[0], s[1], &rgb)?;
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

/// Writes linear RGB (row-major, 3 values a pixel) as 32-bit float OpenEXR.
pub fn write_exr(path: &Path, h: usize, w: usize, rgb: &[f64]) -> Result<()> {
    let data: Vec<f32> = rgb.iter().map(|&x| x as f32).collect();
    let img = image::Rgb32FImage::from_raw(w as u32, h as u32, data).ok_or_else(|| {
        Error::invalid(
            path.display().to_string(),
            "image buffer does not match its size",
        )
    })?;
    img.save_with_format(path, image::ImageFormat::OpenExr)
        .map_err(|e| Error::invalid(path.display().to_string(), format!("cannot write EXR: {e}")))
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

    #[test]
    fn srgb_decode_inverts_encode_on_every_8bit_level() {
        for v in 0..=255u32 {
            let x = srgb_decode(v as f64 / 255.0);
            assert_eq!((srgb_encode(x) * 255.0).round() as u32, v);
        }
    }

    #[test]
    fn exr_keeps_linear_hdr_values_and_png_clips_them() {
        let dir = std::env::temp_dir().join(format!("hp-exr-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        // 1 x 2 pixels: an HDR value 7.5 and a dark 0.001.
        let v = vec![7.5, 0.25, 0.001, 0.001, 1.0, 0.5];
        let t = Tensor::real(&[1, 2, 3], v.clone()).unwrap();
        let files = write_tensor(&dir, "rgb", &t).unwrap();
        assert_eq!(files.len(), 3);
        let exr = image::open(dir.join("rgb.exr")).unwrap().into_rgb32f();
        let back: Vec<f64> = exr.as_raw().iter().map(|&x| x as f64).collect();
        assert_eq!(back, v.iter().map(|&x| x as f32 as f64).collect::<Vec<_>>());
        let png = image::open(dir.join("rgb.png")).unwrap().into_rgb8();
        assert_eq!(png.as_raw()[0], 255);
        assert_eq!(png.as_raw()[2], (srgb_encode(0.001) * 255.0).round() as u8);
        let plot = write_tensor(&dir, "plot_rgb", &t).unwrap();
        assert!(plot.iter().all(|p| p.extension().unwrap() != "exr"));
        std::fs::remove_dir_all(&dir).unwrap();
    }
}
