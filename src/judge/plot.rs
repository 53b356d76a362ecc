//! Every plot the judge draws. An op describes a plot as data (a [`Chart`]:
//! title, axis labels, log or linear axes, named series) and [`render`]
//! turns it into an (H, W, 3) linear-RGB raster that the judge writes as a
//! PNG next to the numbers it shows (name the output `*_rgb` or `*_image`);
//! [`render_svg`] draws the same chart as SVG (the HTML report, docs).
//! Both are drawn by plotters: title, axes with ticks and tick labels, axis
//! labels, a grid, a legend naming every series. Text uses the bundled
//! DejaVu Sans subset (`assets/fonts`, its licence beside it), so no system
//! font is needed. Charts load from YAML or JSON (`hpjudge plot`).

use std::sync::Once;

use plotters::coord::Shift;
use plotters::prelude::*;
use serde::Deserialize;

use super::artifacts::srgb_decode;
use super::load::JudgeInputError;
use crate::error::{Error, Result};
use crate::tensor::Tensor;

/// Raster width and height of every plot.
pub const PLOT_W: usize = 640;
pub const PLOT_H: usize = 440;

/// The font every plot's text is drawn with (DejaVu Sans, ASCII subset).
const FONT: &[u8] = include_bytes!("../../assets/fonts/DejaVuSans-subset.ttf");
const FONT_NAME: &str = "sans-serif";

/// One named line of a plot: points joined in the given order.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Series {
    pub name: String,
    pub xs: Vec<f64>,
    pub ys: Vec<f64>,
    /// Drawn dashed without markers (a guide such as an ideal rate).
    #[serde(default)]
    pub guide: bool,
    /// Drawn as markers only, not joined (points without an order).
    #[serde(default)]
    pub scatter: bool,
}

impl Series {
    pub fn new(name: &str, xs: Vec<f64>, ys: Vec<f64>) -> Series {
        Series {
            name: name.to_string(),
            xs,
            ys,
            guide: false,
            scatter: false,
        }
    }

    /// A dashed guide line (no markers), e.g. an ideal convergence rate.
    pub fn guide(name: &str, xs: Vec<f64>, ys: Vec<f64>) -> Series {
        Series {
            guide: true,
            ..Series::new(name, xs, ys)
        }
    }

    /// Markers only, not joined (e.g. one point per case).
    pub fn scatter(name: &str, xs: Vec<f64>, ys: Vec<f64>) -> Series {
        Series {
            scatter: true,
            ..Series::new(name, xs, ys)
        }
    }
}

/// A plot as data.
#[derive(Clone, Debug, PartialEq, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Chart {
    pub title: String,
    pub x_label: String,
    pub y_label: String,
    #[serde(default)]
    pub log_x: bool,
    #[serde(default)]
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

/// Line colours (sRGB), one per series in order (then repeating).
pub const PALETTE: [[u8; 3]; 6] = [
    [31, 89, 210],
    [210, 40, 40],
    [30, 150, 60],
    [230, 130, 0],
    [140, 50, 170],
    [90, 90, 90],
];

/// A value's position on an axis: itself (linear) or its log10 (log);
/// None when it cannot be drawn (non-finite, or non-positive on a log axis).
pub fn axis_position(v: f64, log: bool) -> Option<f64> {
    if !v.is_finite() || (log && v <= 0.0) {
        None
    } else if log {
        Some(v.log10())
    } else {
        Some(v)
    }
}

/// The drawn range of an axis from its positions: whole decades on a log
/// axis, 5% padding on a linear one; one unit either side of a single
/// value, (0, 1) with no values.
pub fn axis_span(pos: &[f64], log: bool) -> (f64, f64) {
    let lo = pos.iter().cloned().fold(f64::INFINITY, f64::min);
    let hi = pos.iter().cloned().fold(f64::NEG_INFINITY, f64::max);
    if !lo.is_finite() {
        return (0.0, 1.0);
    }
    if hi <= lo {
        return (lo - 1.0, lo + 1.0);
    }
    if log {
        (lo.floor(), hi.ceil().max(lo.floor() + 1.0))
    } else {
        let pad = 0.05 * (hi - lo);
        (lo - pad, hi + pad)
    }
}

/// A tick label for an axis position: the value (10^p on a log axis)
/// with at most 3 significant digits, in exponent form (`1e-5`, `2.5e-6`)
/// outside [1e-3, 1e4).
pub fn tick_label(p: f64, log: bool) -> String {
    let v = if log { 10f64.powf(p) } else { p };
    let a = v.abs();
    if a == 0.0 {
        return "0".to_string();
    }
    if (1e-3..1e4).contains(&a) {
        let digits = (2 - a.log10().floor() as i32).max(0) as usize;
        let s = format!("{v:.digits$}");
        let s = if s.contains('.') {
            s.trim_end_matches('0').trim_end_matches('.').to_string()
        } else {
            s
        };
        return s;
    }
    let s = format!("{v:.1e}");
    let (m, e) = s.split_once('e').unwrap_or((&s, "0"));
    let m = m.trim_end_matches('0').trim_end_matches('.');
    format!("{m}e{e}")
}

/// Reads a chart from a YAML or JSON file (the [`Chart`] fields), naming
/// file, line and key on any error.
pub fn load_chart(path: &std::path::Path) -> std::result::Result<Chart, JudgeInputError> {
    Ok(super::load::load_yaml_typed::<Chart>(path)?.0)
}

/// The legend's corner: the quarter of the plot area holding the fewest
/// points (upper right on a tie), so the legend covers as little as it can.
pub fn legend_corner(pts: &[&(f64, f64)], x: (f64, f64), y: (f64, f64)) -> SeriesLabelPosition {
    let (mx, my) = (0.5 * (x.0 + x.1), 0.5 * (y.0 + y.1));
    let count = |right: bool, upper: bool| {
        pts.iter()
            .filter(|p| (p.0 >= mx) == right && (p.1 >= my) == upper)
            .count()
    };
    [
        (count(true, true), SeriesLabelPosition::UpperRight),
        (count(false, true), SeriesLabelPosition::UpperLeft),
        (count(false, false), SeriesLabelPosition::LowerLeft),
        (count(true, false), SeriesLabelPosition::LowerRight),
    ]
    .into_iter()
    .min_by_key(|c| c.0)
    .map_or(SeriesLabelPosition::UpperRight, |c| c.1)
}

/// How many tick labels to ask plotters for: on a log axis one per decade
/// (so ticks fall on decades: plotters picks round steps of the log), else 8.
pub fn tick_count(lo: f64, hi: f64, log: bool) -> usize {
    if log {
        ((hi - lo).round() as usize + 1).clamp(2, 11)
    } else {
        8
    }
}

fn register_font() -> Result<()> {
    static ONCE: Once = Once::new();
    let mut ok = true;
    ONCE.call_once(|| {
        ok = plotters::style::register_font(FONT_NAME, FontStyle::Normal, FONT).is_ok();
    });
    if ok {
        Ok(())
    } else {
        Err(Error::invalid(
            "plot font",
            "the bundled font does not load",
        ))
    }
}

fn draw_err<E: std::fmt::Debug>(title: &str) -> impl Fn(E) -> Error + '_ {
    move |e| Error::invalid(format!("plot `{title}`"), format!("drawing failed: {e:?}"))
}

/// Draws `chart` on a drawing area of any plotters backend.
fn draw<DB: DrawingBackend>(root: &DrawingArea<DB, Shift>, chart: &Chart) -> Result<()> {
    for s in &chart.series {
        if s.xs.len() != s.ys.len() {
            return Err(Error::invalid(
                format!("plot `{}` series `{}`", chart.title, s.name),
                format!("{} x values but {} y values", s.xs.len(), s.ys.len()),
            ));
        }
    }
    register_font()?;
    let e = draw_err(&chart.title);
    let pts: Vec<Vec<(f64, f64)>> = chart
        .series
        .iter()
        .map(|s| {
            s.xs.iter()
                .zip(&s.ys)
                .filter_map(|(&x, &y)| {
                    Some((
                        axis_position(x, chart.log_x)?,
                        axis_position(y, chart.log_y)?,
                    ))
                })
                .collect()
        })
        .collect();
    let all: Vec<&(f64, f64)> = pts.iter().flatten().collect();
    let (x0, x1) = axis_span(&all.iter().map(|p| p.0).collect::<Vec<_>>(), chart.log_x);
    let (y0, y1) = axis_span(&all.iter().map(|p| p.1).collect::<Vec<_>>(), chart.log_y);
    root.fill(&WHITE).map_err(&e)?;
    let mut ctx = ChartBuilder::on(root)
        .caption(&chart.title, (FONT_NAME, 18))
        .margin(12)
        .x_label_area_size(44)
        .y_label_area_size(64)
        .build_cartesian_2d(x0..x1, y0..y1)
        .map_err(&e)?;
    let (lx, ly) = (chart.log_x, chart.log_y);
    let fx = move |v: &f64| tick_label(*v, lx);
    let fy = move |v: &f64| tick_label(*v, ly);
    let with_scale = |label: &str, log: bool| {
        if log {
            format!("{label} (log)")
        } else {
            label.to_string()
        }
    };
    ctx.configure_mesh()
        .x_desc(with_scale(&chart.x_label, lx))
        .y_desc(with_scale(&chart.y_label, ly))
        .x_label_formatter(&fx)
        .y_label_formatter(&fy)
        .x_labels(tick_count(x0, x1, lx))
        .y_labels(tick_count(y0, y1, ly))
        .label_style((FONT_NAME, 13))
        .axis_desc_style((FONT_NAME, 14))
        .light_line_style(WHITE)
        .bold_line_style(RGBColor(200, 200, 200))
        .draw()
        .map_err(&e)?;
    for (k, (s, p)) in chart.series.iter().zip(&pts).enumerate() {
        let [r, g, b] = PALETTE[k % PALETTE.len()];
        let c = RGBColor(r, g, b);
        let legend = move |(x, y): (i32, i32)| {
            PathElement::new(vec![(x, y), (x + 20, y)], c.stroke_width(2))
        };
        if s.guide {
            ctx.draw_series(DashedLineSeries::new(
                p.iter().cloned(),
                8,
                6,
                c.stroke_width(2),
            ))
            .map_err(&e)?
            .label(&s.name)
            .legend(legend);
        } else {
            let line = if s.scatter { vec![] } else { p.clone() };
            ctx.draw_series(LineSeries::new(line, c.stroke_width(2)))
                .map_err(&e)?
                .label(&s.name)
                .legend(legend);
            ctx.draw_series(p.iter().map(|&q| Circle::new(q, 4, c.filled())))
                .map_err(&e)?;
        }
    }
    if !chart.series.is_empty() {
        ctx.configure_series_labels()
            .label_font((FONT_NAME, 13))
            .background_style(WHITE.mix(0.85))
            .border_style(BLACK)
            .position(legend_corner(&all, (x0, x1), (y0, y1)))
            .draw()
            .map_err(&e)?;
    }
    root.present().map_err(&e)?;
    Ok(())
}

/// Draws `chart` as a PLOT_H x PLOT_W linear-RGB raster (the sRGB pixels
/// plotters draws, decoded to linear so the artifact writer's sRGB encoding
/// gives them back): white background, title, axes with tick labels (the
/// value, 10^p on log axes), axis labels (`(log)` marked), a grid, each
/// series a line in its palette colour with round markers, guides dashed
/// without markers, a legend. Non-finite points (and non-positive ones on a
/// log axis) are left out. A series whose xs and ys differ in length is refused.
pub fn render(chart: &Chart) -> Result<Tensor> {
    let mut buf = vec![255u8; PLOT_W * PLOT_H * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buf, (PLOT_W as u32, PLOT_H as u32))
            .into_drawing_area();
        draw(&root, chart)?;
    }
    let rgb: Vec<[f64; 3]> = buf
        .chunks_exact(3)
        .map(|p| [0, 1, 2].map(|i| srgb_decode(p[i] as f64 / 255.0)))
        .collect();
    Tensor::real3(&[PLOT_H, PLOT_W], &rgb)
}

/// Draws `chart` as an SVG document of PLOT_W x PLOT_H (same drawing as [`render`]).
pub fn render_svg(chart: &Chart) -> Result<String> {
    let mut svg = String::new();
    {
        let root =
            SVGBackend::with_string(&mut svg, (PLOT_W as u32, PLOT_H as u32)).into_drawing_area();
        draw(&root, chart)?;
    }
    Ok(svg)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn count_colour(t: &Tensor, c: [u8; 3]) -> usize {
        let want = c.map(|v| srgb_decode(v as f64 / 255.0));
        t.to_f64_vec()
            .chunks_exact(3)
            .filter(|p| (0..3).all(|i| (p[i] - want[i]).abs() < 1e-9))
            .count()
    }

    fn chart() -> Chart {
        Chart::loglog(
            "speed vs error",
            "seconds",
            "max error",
            vec![
                Series::new("f32", vec![0.1, 1.0, 10.0], vec![1e-3, 1e-4, 1e-5]),
                Series::guide("ideal", vec![0.1, 10.0], vec![2e-3, 2e-5]),
            ],
        )
    }

    #[test]
    fn render_draws_each_series_in_its_palette_colour() {
        let t = render(&chart()).unwrap();
        assert_eq!(t.shape(), &[PLOT_H, PLOT_W, 3]);
        assert!(count_colour(&t, PALETTE[0]) > 200);
        assert!(count_colour(&t, PALETTE[1]) > 50);
        assert_eq!(count_colour(&t, PALETTE[2]), 0);
    }

    #[test]
    fn render_writes_text_left_of_the_plot_area() {
        // Tick labels and the y label are dark pixels in the left margin.
        let t = render(&chart()).unwrap();
        let d = t.to_f64_vec();
        let dark = (0..PLOT_H)
            .flat_map(|v| (0..60).map(move |u| 3 * (v * PLOT_W + u)))
            .filter(|&i| d[i] < 0.2 && d[i + 1] < 0.2 && d[i + 2] < 0.2)
            .count();
        assert!(dark > 300, "{dark} dark pixels");
    }

    #[test]
    fn svg_names_title_axes_legend_and_decade_ticks() {
        let svg = render_svg(&chart()).unwrap();
        let texts: Vec<&str> = svg
            .split("<text")
            .skip(1)
            .filter_map(|t| Some(t.split_once('>')?.1.split_once("</text>")?.0.trim()))
            .collect();
        for want in [
            "speed vs error",
            "seconds (log)",
            "max error (log)",
            "f32",
            "ideal",
            "1e-5",
            "0.001",
            "10",
        ] {
            assert!(
                texts.contains(&want),
                "no text {want:?} in the SVG: {texts:?}"
            );
        }
    }

    #[test]
    fn render_refuses_a_series_with_unequal_lengths() {
        let c = Chart::loglog("t", "x", "y", vec![Series::new("a", vec![1.0], vec![])]);
        assert!(render(&c).unwrap_err().to_string().contains("series `a`"));
    }

    #[test]
    fn nonpositive_points_have_no_position_on_log_axes() {
        assert_eq!(axis_position(0.0, true), None);
        assert_eq!(axis_position(-1.0, false), Some(-1.0));
        assert_eq!(axis_position(f64::NAN, false), None);
        assert_eq!(axis_position(100.0, true), Some(2.0));
        let c = Chart::loglog(
            "t",
            "x",
            "y",
            vec![Series::new("a", vec![0.0, 1.0, 10.0], vec![1.0, 1.0, 10.0])],
        );
        assert!(render(&c).is_ok());
    }

    #[test]
    fn log_spans_are_whole_decades_and_linear_spans_padded() {
        assert_eq!(axis_span(&[-4.3, -1.2], true), (-5.0, -1.0));
        assert_eq!(axis_span(&[0.0, 10.0], false), (-0.5, 10.5));
        assert_eq!(axis_span(&[2.0], true), (1.0, 3.0));
        assert_eq!(axis_span(&[], false), (0.0, 1.0));
    }

    #[test]
    fn the_legend_goes_to_the_emptiest_corner() {
        let pts = [(0.9, 0.9), (0.8, 0.7), (0.1, 0.9), (0.9, 0.1)];
        let refs: Vec<&(f64, f64)> = pts.iter().collect();
        assert!(matches!(
            legend_corner(&refs, (0.0, 1.0), (0.0, 1.0)),
            SeriesLabelPosition::LowerLeft
        ));
        assert!(matches!(
            legend_corner(&[], (0.0, 1.0), (0.0, 1.0)),
            SeriesLabelPosition::UpperRight
        ));
    }

    #[test]
    fn log_axes_ask_for_one_tick_per_decade() {
        assert_eq!(tick_count(-8.0, -4.0, true), 5);
        assert_eq!(tick_count(-2.0, -1.0, true), 2);
        assert_eq!(tick_count(0.0, 30.0, true), 11);
        assert_eq!(tick_count(0.0, 30.0, false), 8);
    }

    #[test]
    fn tick_labels_show_values_not_logs() {
        assert_eq!(tick_label(-5.0, true), "1e-5");
        assert_eq!(tick_label(-3.0, true), "0.001");
        assert_eq!(tick_label(1.0, true), "10");
        assert_eq!(tick_label(2.5, false), "2.5");
        assert_eq!(tick_label(0.0, false), "0");
        assert_eq!(tick_label(25000.0, false), "2.5e4");
        assert_eq!(tick_label(1234.0, false), "1234");
    }
}
