//! Every plot the judge draws: small line rasters (linear RGB, no text, so
//! no fonts) that the judge writes as PNG next to the data they show. Axis
//! labels live in the report that shows a plot.

use crate::error::Result;
use crate::tensor::Tensor;

/// Speed against error as a 320 x 240 raster (no text, so no fonts): x =
/// log10 seconds, y = log10 max error, both spanning the data's decades
/// (grey lines at each decade); f32 points red, f64 blue, joined in dt
/// order. The judge writes it as `plot_rgb.png`.
pub fn sweep_plot(cols: &[Vec<f64>; 4]) -> Result<Tensor> {
    const W: usize = 320;
    const H: usize = 240;
    const PAD: f64 = 16.0;
    let mut img = vec![[1.0f64; 3]; W * H];
    let lg = |v: f64| v.max(1e-300).log10();
    let (xs, ys): (Vec<f64>, Vec<f64>) = (
        cols[0].iter().chain(&cols[2]).map(|&v| lg(v)).collect(),
        cols[1].iter().chain(&cols[3]).map(|&v| lg(v)).collect(),
    );
    let span = |v: &[f64]| {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min).floor();
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil();
        (lo, if hi > lo { hi } else { lo + 1.0 })
    };
    let ((x0, x1), (y0, y1)) = (span(&xs), span(&ys));
    let px = |x: f64| PAD + (x - x0) / (x1 - x0) * (W as f64 - 2.0 * PAD);
    let py = |y: f64| H as f64 - PAD - (y - y0) / (y1 - y0) * (H as f64 - 2.0 * PAD);
    let mut put = |x: f64, y: f64, c: [f64; 3]| {
        let (i, j) = (x.round() as i64, y.round() as i64);
        if i >= 0 && j >= 0 && (i as usize) < W && (j as usize) < H {
            img[j as usize * W + i as usize] = c;
        }
    };
    let grey = [0.6; 3];
    for d in (x0 as i64)..=(x1 as i64) {
        for j in 0..H {
            put(px(d as f64), j as f64, grey);
        }
    }
    for d in (y0 as i64)..=(y1 as i64) {
        for i in 0..W {
            put(i as f64, py(d as f64), grey);
        }
    }
    for (t, e, c) in [
        (&cols[0], &cols[1], [0.8, 0.05, 0.05]),
        (&cols[2], &cols[3], [0.05, 0.1, 0.8]),
    ] {
        let pts: Vec<(f64, f64)> = t
            .iter()
            .zip(e.iter())
            .map(|(&a, &b)| (px(lg(a)), py(lg(b))))
            .collect();
        for w in pts.windows(2) {
            for k in 0..=200 {
                let f = k as f64 / 200.0;
                put(
                    w[0].0 + f * (w[1].0 - w[0].0),
                    w[0].1 + f * (w[1].1 - w[0].1),
                    c,
                );
            }
        }
        for &(x, y) in &pts {
            for dy in -3..=3 {
                for dx in -3..=3 {
                    put(x + dx as f64, y + dy as f64, c);
                }
            }
        }
    }
    Tensor::real3(&[H, W], &img)
}

pub const PLOT_W: usize = 480;
pub const PLOT_H: usize = 360;

/// A log-log line plot (linear RGB, white background) of `ys` against `xs`:
/// axes span whole decades around the data, light grey lines mark each
/// decade, the data are a blue polyline with square markers, and a dashed
/// grey line of slope -1/2 through the first point shows the ideal Monte
/// Carlo rate. Axis labels live in the report that shows the plot.
pub fn plot_loglog(xs: &[f64], ys: &[f64]) -> Vec<[f32; 3]> {
    let mut img = vec![[1.0f32; 3]; PLOT_W * PLOT_H];
    let lx: Vec<f64> = xs.iter().map(|v| v.max(1e-12).log10()).collect();
    let ly: Vec<f64> = ys.iter().map(|v| v.max(1e-12).log10()).collect();
    let span = |v: &[f64]| {
        let lo = v.iter().cloned().fold(f64::INFINITY, f64::min).floor();
        let hi = v.iter().cloned().fold(f64::NEG_INFINITY, f64::max).ceil();
        if lo.is_finite() && hi > lo {
            (lo, hi)
        } else {
            (-1.0, 1.0)
        }
    };
    let ((x0, x1), (y0, y1)) = (span(&lx), span(&ly));
    let m = 20.0;
    let px = |x: f64| m + (x - x0) / (x1 - x0) * (PLOT_W as f64 - 2.0 * m);
    let py = |y: f64| PLOT_H as f64 - m - (y - y0) / (y1 - y0) * (PLOT_H as f64 - 2.0 * m);
    let put = |img: &mut Vec<[f32; 3]>, x: f64, y: f64, c: [f32; 3]| {
        let (u, v) = (x.round(), y.round());
        if u >= 0.0 && v >= 0.0 && (u as usize) < PLOT_W && (v as usize) < PLOT_H {
            img[v as usize * PLOT_W + u as usize] = c;
        }
    };
    let grey = [0.8f32; 3];
    for d in (x0 as i32)..=(x1 as i32) {
        for v in 0..PLOT_H {
            put(&mut img, px(d as f64), v as f64, grey);
        }
    }
    for d in (y0 as i32)..=(y1 as i32) {
        for u in 0..PLOT_W {
            put(&mut img, u as f64, py(d as f64), grey);
        }
    }
    let line =
        |img: &mut Vec<[f32; 3]>, a: (f64, f64), b: (f64, f64), c: [f32; 3], dashed: bool| {
            let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) as usize).max(1);
            for i in 0..=n {
                if dashed && (i / 6) % 2 == 1 {
                    continue;
                }
                let t = i as f64 / n as f64;
                put(img, a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
            }
        };
    if let (Some(&fx), Some(&fy)) = (lx.first(), ly.first()) {
        let y_at = |x: f64| fy - 0.5 * (x - fx);
        line(
            &mut img,
            (px(x0), py(y_at(x0))),
            (px(x1), py(y_at(x1))),
            [0.45; 3],
            true,
        );
    }
    let blue = [0.05f32, 0.15, 0.8];
    for i in 1..lx.len() {
        line(
            &mut img,
            (px(lx[i - 1]), py(ly[i - 1])),
            (px(lx[i]), py(ly[i])),
            blue,
            false,
        );
    }
    for (&x, &y) in lx.iter().zip(&ly) {
        for du in -3..=3 {
            for dv in -3..=3 {
                put(&mut img, px(x) + du as f64, py(y) + dv as f64, blue);
            }
        }
    }
    img
}
