//! Every plot the judge draws. An op describes a plot as data (a [`Chart`]:
//! title, axis labels, log or linear axes, named series) and [`render`]
//! turns it into an (H, W, 3) linear-RGB raster that the judge writes as a
//! PNG next to the numbers it shows (name the output `*_rgb` or `*_image`).
//! The raster has no text yet (no fonts): issue 21 draws axes, ticks,
//! labels and a legend from the same [`Chart`].

use crate::error::{Error, Result};
use crate::tensor::Tensor;

/// Raster width and height of every plot.
pub const PLOT_W: usize = 480;
pub const PLOT_H: usize = 360;

/// One named line of a plot: points joined in the given order.
#[derive(Clone, Debug, PartialEq)]
pub struct Series {
    pub name: String,
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// Drawn dashed without markers (a guide such as an ideal rate).
    pub guide: bool,
}

impl Series {
    pub fn new(name: &str, xs: Vec<f64>, ys: Vec<f64>) -> Series {
        Series {
            name: name.to_string(),
            xs,
            ys,
            guide: false,
        }
    }

    /// A dashed guide line (no markers), e.g. an ideal convergence rate.
    pub fn guide(name: &str, xs: Vec<f64>, ys: Vec<f64>) -> Series {
        Series {
            guide: true,
            ..Series::new(name, xs, ys)
        }
    }
}

/// A plot as data.
#[derive(Clone, Debug, PartialEq)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    pub log_x: bool,
    pub log_y: bool,
    pub series: Vec<Series>,
}

impl Chart {
    /// A log-log chart (speed against error, convergence).
    pub fn loglog(title: &str, x_label: &str, y_label: &str, series: Vec<Series>) -> Chart {
        Chart {
            title: title.to_string(),
            x_label: x_label.to_string(),
            y_label: y_label.to_string(),
            log_x: true,
            log_y: true,
            series,
        }
    }
}

/// Line colours, one per series in order (then repeating).
const PALETTE: [[f64; 3]; 6] = [
    [0.05, 0.15, 0.8],
    [0.8, 0.05, 0.05],
    [0.05, 0.55, 0.1],
    [0.85, 0.45, 0.0],
    [0.5, 0.1, 0.6],
    [0.3, 0.3, 0.3],
];

/// Draws `chart` as a PLOT_H x PLOT_W linear-RGB raster: white background,
/// grey lines at each decade (log axes) or at the data's ends (linear),
/// each series a polyline in its palette colour with square markers,
/// guides dashed. Non-finite points (and non-positive ones on a log axis)
/// are left out. A series whose xs and ys differ in length is refused.
pub fn render(chart: &Chart) -> Result<Tensor> {
    for s in &chart.series {
        if s.xs.len() != s.ys.len() {
            return Err(Error::invalid(
                format!("plot `{}` series `{}`", chart.title, s.name),
                format!("{} x values but {} y values", s.xs.len(), s.ys.len()),
            ));
        }
    }
    let map = |v: f64, log: bool| {
        if !log {
            Some(v).filter(|v| v.is_finite())
        } else if v > 0.0 && v.is_finite() {
            Some(v.log10())
        } else {
            None
        }
    };
    let pts: Vec<Vec<(f64, f64)>> = chart
        .series
        .iter()
        .map(|s| {
            s.xs.iter()
                .zip(&s.ys)
                .filter_map(|(&x, &y)| Some((map(x, chart.log_x)?, map(y, chart.log_y)?)))
                .collect()
        })
        .collect();
    let span = |vals: Vec<f64>, log: bool| {
        let lo = vals.iter().cloned().fold(f64::INFINITY, f64::min);
        let hi = vals.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
        let (lo, hi) = if log {
            (lo.floor(), hi.ceil())
        } else {
            (lo, hi)
        };
        if lo.is_finite() && hi > lo {
            (lo, hi)
        } else if lo.is_finite() {
            (lo - 1.0, lo + 1.0)
        } else {
            (-1.0, 1.0)
        }
    };
    let all = pts.iter().flatten();
    let (x0, x1) = span(all.clone().map(|p| p.0).collect(), chart.log_x);
    let (y0, y1) = span(all.map(|p| p.1).collect(), chart.log_y);
    let m = 20.0;
    let px = |x: f64| m + (x - x0) / (x1 - x0) * (PLOT_W as f64 - 2.0 * m);
    let py = |y: f64| PLOT_H as f64 - m - (y - y0) / (y1 - y0) * (PLOT_H as f64 - 2.0 * m);
    let mut img = vec![[1.0f64; 3]; PLOT_W * PLOT_H];
    let mut put = |x: f64, y: f64, c: [f64; 3]| {
        let (u, v) = (x.round(), y.round());
        if u >= 0.0 && v >= 0.0 && (u as usize) < PLOT_W && (v as usize) < PLOT_H {
            img[v as usize * PLOT_W + u as usize] = c;
        }
    };
    let grid = |lo: f64, hi: f64, log: bool| -> Vec<f64> {
        if log {
            (lo as i64..=hi as i64).map(|d| d as f64).collect()
        } else {
            vec![lo, hi]
        }
    };
    let grey = [0.8; 3];
    for x in grid(x0, x1, chart.log_x) {
        for v in 0..PLOT_H {
            put(px(x), v as f64, grey);
        }
    }
    for y in grid(y0, y1, chart.log_y) {
        for u in 0..PLOT_W {
            put(u as f64, py(y), grey);
        }
    }
    for (k, (s, p)) in chart.series.iter().zip(&pts).enumerate() {
        let c = PALETTE[k % PALETTE.len()];
        for w in p.windows(2) {
            let (a, b) = ((px(w[0].0), py(w[0].1)), (px(w[1].0), py(w[1].1)));
            let n = ((b.0 - a.0).abs().max((b.1 - a.1).abs()) as usize).max(1);
            for i in 0..=n {
                if s.guide && (i / 6) % 2 == 1 {
                    continue;
                }
                let t = i as f64 / n as f64;
                put(a.0 + t * (b.0 - a.0), a.1 + t * (b.1 - a.1), c);
            }
        }
        if !s.guide {
            for &(x, y) in p {
                for du in -3..=3 {
                    for dv in -3..=3 {
                        put(px(x) + du as f64, py(y) + dv as f64, c);
                    }
                }
            }
        }
    }
    Tensor::real3(&[PLOT_H, PLOT_W], &img)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn pixel(t: &Tensor, v: usize, u: usize) -> [f64; 3] {
        let d = t.to_f64_vec();
        let i = 3 * (v * PLOT_W + u);
        [d[i], d[i + 1], d[i + 2]]
    }

    #[test]
    fn render_puts_a_loglog_series_marker_at_its_mapped_pixel() {
        let c = Chart::loglog(
            "t",
            "x",
            "y",
            vec![Series::new("a", vec![1.0, 100.0], vec![10.0, 1000.0])],
        );
        let t = render(&c).unwrap();
        assert_eq!(t.shape(), &[PLOT_H, PLOT_W, 3]);
        // x spans decades 0..2 and y 1..3: the first point is the bottom-left corner.
        assert_eq!(pixel(&t, PLOT_H - 20, 20), PALETTE[0]);
        assert_eq!(pixel(&t, 20, PLOT_W - 20), PALETTE[0]);
        assert_eq!(pixel(&t, PLOT_H / 2 + 40, 60), [1.0; 3]);
    }

    #[test]
    fn render_refuses_a_series_with_unequal_lengths() {
        let c = Chart::loglog("t", "x", "y", vec![Series::new("a", vec![1.0], vec![])]);
        assert!(render(&c).unwrap_err().to_string().contains("series `a`"));
    }

    #[test]
    fn render_leaves_out_nonpositive_points_on_log_axes() {
        let c = Chart::loglog(
            "t",
            "x",
            "y",
            vec![Series::new("a", vec![0.0, 1.0, 10.0], vec![1.0, 1.0, 10.0])],
        );
        assert!(render(&c).is_ok());
    }
}
