//! The report's image comparisons: ours, the reference and their
//! difference as a heatmap, read from the run's `.npy` artifacts and
//! embedded as PNG data URIs. Ours and the reference share one colour
//! scale (the artifacts' PNG mapping: linear clamped to [0, 1], sRGB
//! encoded); the heatmap maps 0..max |ours - reference| (the largest
//! channel difference of each pixel) through [`HEAT_STOPS`], and the page
//! draws the same stops as its colour bar.

use std::path::Path;

use base64::Engine;

use crate::judge::artifacts::srgb_encode;
use crate::tensor::Tensor;

/// Longest side of an embedded image; larger ones are reduced (box mean
/// for images, max for the heatmap so one differing pixel stays visible).
pub const MAX_SIDE: usize = 192;

/// The heatmap's colour stops (sRGB) from 0 to the maximum difference.
pub const HEAT_STOPS: [[u8; 3]; 5] = [
    [0, 0, 4],
    [87, 16, 110],
    [188, 55, 84],
    [249, 142, 9],
    [252, 255, 164],
];

/// A linear RGB image, row-major, 3 values a pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Rgb {
    pub h: usize,
    pub w: usize,
    pub v: Vec<f64>,
}

/// Reads an (H, W, 3) float `.npy`; None when it is not one.
pub fn read_rgb(path: &Path) -> Option<Rgb> {
    let t = Tensor::read_npy(path).ok()?;
    let s = t.shape().to_vec();
    (t.is_float() && s.len() == 3 && s[2] == 3 && s[0] > 0 && s[1] > 0).then(|| Rgb {
        h: s[0],
        w: s[1],
        v: t.to_f64_vec(),
    })
}

/// The reduction factor that brings the longest side to at most [`MAX_SIDE`].
fn factor(h: usize, w: usize) -> usize {
    h.max(w).div_ceil(MAX_SIDE).max(1)
}

/// Reduces `vals` (h x w, `c` values a pixel) by `f` in each direction:
/// each block's mean (`mean`; non-finite values count as 0) or maximum
/// (an infinite difference stays infinite: the heatmap's top colour).
fn reduce(
    h: usize,
    w: usize,
    c: usize,
    vals: &[f64],
    f: usize,
    mean: bool,
) -> (usize, usize, Vec<f64>) {
    let (rh, rw) = (h.div_ceil(f), w.div_ceil(f));
    let mut out = vec![0.0; rh * rw * c];
    let mut n = vec![0usize; rh * rw];
    for y in 0..h {
        for x in 0..w {
            let o = (y / f) * rw + x / f;
            n[o] += 1;
            for k in 0..c {
                let v = vals[(y * w + x) * c + k];
                let v = if v.is_finite() || !mean { v } else { 0.0 };
                let slot = &mut out[o * c + k];
                *slot = if mean { *slot + v } else { slot.max(v) };
            }
        }
    }
    if mean {
        for (o, &cnt) in n.iter().enumerate() {
            for k in 0..c {
                out[o * c + k] /= cnt as f64;
            }
        }
    }
    (rh, rw, out)
}

/// Per pixel: the largest |a - b| over the channels (non-finite -> infinity).
pub fn abs_diff(a: &Rgb, b: &Rgb) -> Vec<f64> {
    a.v.chunks_exact(3)
        .zip(b.v.chunks_exact(3))
        .map(|(p, q)| {
            (0..3)
                .map(|k| {
                    let d = (p[k] - q[k]).abs();
                    if d.is_nan() {
                        f64::INFINITY
                    } else {
                        d
                    }
                })
                .fold(0.0, f64::max)
        })
        .collect()
}

/// The heatmap colour of `t` in [0, 1] (linear interpolation of the stops).
pub fn heat(t: f64) -> [u8; 3] {
    let t = if t.is_finite() {
        t.clamp(0.0, 1.0)
    } else {
        1.0
    };
    let x = t * (HEAT_STOPS.len() - 1) as f64;
    let i = (x.floor() as usize).min(HEAT_STOPS.len() - 2);
    let f = x - i as f64;
    let (a, b) = (HEAT_STOPS[i], HEAT_STOPS[i + 1]);
    [0, 1, 2].map(|k| (a[k] as f64 + f * (b[k] as f64 - a[k] as f64)).round() as u8)
}

/// 8-bit RGB pixels as a `data:image/png;base64,` URI.
pub fn png_uri(h: usize, w: usize, bytes: Vec<u8>) -> Option<String> {
    let img = image::RgbImage::from_raw(w as u32, h as u32, bytes)?;
    let mut png = std::io::Cursor::new(Vec::new());
    img.write_to(&mut png, image::ImageFormat::Png).ok()?;
    Some(format!(
        "data:image/png;base64,{}",
        base64::engine::general_purpose::STANDARD.encode(png.into_inner())
    ))
}

/// A linear image as a reduced sRGB PNG URI (the artifacts' mapping).
pub fn image_uri(img: &Rgb) -> Option<String> {
    let (h, w, v) = reduce(img.h, img.w, 3, &img.v, factor(img.h, img.w), true);
    png_uri(
        h,
        w,
        v.iter()
            .map(|&x| (srgb_encode(x) * 255.0).round() as u8)
            .collect(),
    )
}

/// One comparison: the three images and the heatmap's scale.
pub struct Comparison {
    pub ours: String,
    pub reference: String,
    pub heatmap: String,
    /// The heatmap's top: the largest per-pixel difference.
    pub max_diff: f64,
    pub mean_diff: f64,
}

/// Ours against a reference of the same shape; None when either is
/// missing or the shapes differ.
pub fn compare(ours: &Rgb, reference: &Rgb) -> Option<Comparison> {
    if (ours.h, ours.w) != (reference.h, reference.w) {
        return None;
    }
    let d = abs_diff(ours, reference);
    let max_diff = d.iter().cloned().fold(0.0, f64::max);
    let mean_diff = d.iter().filter(|x| x.is_finite()).sum::<f64>() / d.len() as f64;
    let (h, w, r) = reduce(ours.h, ours.w, 1, &d, factor(ours.h, ours.w), false);
    let scale = if max_diff > 0.0 && max_diff.is_finite() {
        max_diff
    } else {
        1.0
    };
    let heat_px: Vec<u8> = r.iter().flat_map(|&x| heat(x / scale)).collect();
    Some(Comparison {
        ours: image_uri(ours)?,
        reference: image_uri(reference)?,
        heatmap: png_uri(h, w, heat_px)?,
        max_diff,
        mean_diff,
    })
}

/// The CSS gradient of the heatmap's stops (the colour bar).
pub fn heat_gradient() -> String {
    let stops: Vec<String> = HEAT_STOPS
        .iter()
        .map(|c| format!("rgb({},{},{})", c[0], c[1], c[2]))
        .collect();
    format!("linear-gradient(to right, {})", stops.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn img(h: usize, w: usize, f: impl Fn(usize) -> f64) -> Rgb {
        Rgb {
            h,
            w,
            v: (0..h * w * 3).map(f).collect(),
        }
    }

    #[test]
    fn heat_runs_from_the_first_stop_to_the_last() {
        assert_eq!(heat(0.0), HEAT_STOPS[0]);
        assert_eq!(heat(1.0), HEAT_STOPS[4]);
        assert_eq!(heat(0.5), HEAT_STOPS[2]);
        assert_eq!(heat(f64::NAN), HEAT_STOPS[4]);
    }

    #[test]
    fn one_differing_pixel_sets_the_scale_and_survives_reduction() {
        let a = img(400, 300, |_| 0.5);
        let mut b = a.clone();
        b.v[3 * (123 * 300 + 77) + 1] = 0.75;
        let c = compare(&a, &b).unwrap();
        assert_eq!(c.max_diff, 0.25);
        assert!((c.mean_diff - 0.25 / 120000.0).abs() < 1e-12);
        let d = abs_diff(&a, &b);
        let (h, w, r) = reduce(400, 300, 1, &d, factor(400, 300), false);
        assert_eq!((h, w), (134, 100));
        assert_eq!(r.iter().filter(|&&x| x == 0.25).count(), 1);
    }

    #[test]
    fn shapes_that_differ_are_not_compared() {
        assert!(compare(&img(2, 2, |_| 0.0), &img(2, 3, |_| 0.0)).is_none());
    }

    #[test]
    fn nan_differences_are_infinite() {
        let a = img(1, 1, |_| 0.0);
        let b = img(1, 1, |_| f64::NAN);
        assert_eq!(abs_diff(&a, &b), vec![f64::INFINITY]);
    }
}
