//! The report's GPU vs CPU parity section: for every case run on both
//! backends, each float output both wrote as `.npy` is compared (max
//! |gpu - cpu| and max |cpu|), listed in a table and drawn (inline SVG
//! charts: the largest difference per case, and GPU against CPU seconds
//! with the y = x guide). The images themselves are compared in each GPU
//! result's detail (ours = GPU, reference = CPU).

use std::path::Path;

use super::page::{esc, num};
use crate::judge::ops::BackendKind;
use crate::judge::plot::{render_svg, Chart, Series};
use crate::judge::scoreboard::{BackendResult, CaseEntry, Scoreboard};
use crate::tensor::Tensor;

/// One output compared across backends.
#[derive(Clone, Debug, PartialEq)]
pub struct Pair {
    pub case: String,
    pub tensor: String,
    pub shape: Vec<usize>,
    pub max_diff: f64,
    pub max_cpu: f64,
}

/// Max |a - b| (NaN on either side counts as infinite) and max |b|.
pub fn diff(a: &[f64], b: &[f64]) -> (f64, f64) {
    let d = a
        .iter()
        .zip(b)
        .map(|(x, y)| {
            let d = (x - y).abs();
            if d.is_nan() {
                f64::INFINITY
            } else {
                d
            }
        })
        .fold(0.0, f64::max);
    (d, b.iter().map(|x| x.abs()).fold(0.0, f64::max))
}

fn npy_names(r: &BackendResult) -> Vec<String> {
    r.artifacts
        .iter()
        .filter_map(|a| {
            Path::new(a)
                .file_name()?
                .to_str()?
                .strip_suffix(".npy")
                .map(String::from)
        })
        .filter(|n| !n.contains('.'))
        .collect()
}

/// Every output both backends of `c` wrote, compared.
fn pairs(out: &Path, c: &CaseEntry) -> Vec<Pair> {
    let find = |k: BackendKind| c.results.iter().find(|r| r.backend == k);
    let (Some(cpu), Some(gpu)) = (find(BackendKind::Cpu), find(BackendKind::Gpu)) else {
        return vec![];
    };
    let cpu_names = npy_names(cpu);
    let mut v = vec![];
    for n in npy_names(gpu).into_iter().filter(|n| cpu_names.contains(n)) {
        let read = |b: BackendKind| {
            Tensor::read_npy(&out.join(&c.id).join(b.name()).join(format!("{n}.npy"))).ok()
        };
        let (Some(g), Some(k)) = (read(BackendKind::Gpu), read(BackendKind::Cpu)) else {
            continue;
        };
        if !g.is_float() || g.shape() != k.shape() {
            continue;
        }
        let (max_diff, max_cpu) = diff(&g.to_f64_vec(), &k.to_f64_vec());
        v.push(Pair {
            case: c.id.clone(),
            tensor: n,
            shape: k.shape().to_vec(),
            max_diff,
            max_cpu,
        });
    }
    v
}

/// The section: charts and the table.
pub fn section(out: &Path, b: &Scoreboard) -> String {
    let mut s = String::from("<h2 id=\"parity\">GPU vs CPU parity</h2>");
    let both: Vec<&CaseEntry> = b
        .cases
        .iter()
        .filter(|c| {
            [BackendKind::Cpu, BackendKind::Gpu]
                .iter()
                .all(|k| c.results.iter().any(|r| r.backend == *k))
        })
        .collect();
    if both.is_empty() {
        return s + "<p>No case of this run ran on both backends.</p>";
    }
    let all: Vec<Pair> = both.iter().flat_map(|c| pairs(out, c)).collect();
    let (mut xs, mut ys) = (vec![], vec![]);
    for (i, c) in both.iter().enumerate() {
        let worst = all
            .iter()
            .filter(|p| p.case == c.id)
            .map(|p| p.max_diff)
            .fold(f64::NAN, f64::max);
        if worst.is_finite() {
            xs.push((i + 1) as f64);
            ys.push(worst.max(1e-12));
        }
    }
    let secs = |k: BackendKind| {
        both.iter().map(move |c| {
            c.results
                .iter()
                .find(|r| r.backend == k)
                .map_or(f64::NAN, |r| r.wall_s)
        })
    };
    let (cs, gs): (Vec<f64>, Vec<f64>) = (
        secs(BackendKind::Cpu).collect(),
        secs(BackendKind::Gpu).collect(),
    );
    let lo = cs
        .iter()
        .chain(&gs)
        .cloned()
        .filter(|x| *x > 0.0)
        .fold(f64::INFINITY, f64::min);
    let hi = cs.iter().chain(&gs).cloned().fold(0.0, f64::max);
    let charts = [
        Chart {
            title: "largest |GPU - CPU| over a case's outputs".into(),
            x_label: "case (table order)".into(),
            y_label: "max abs difference (1e-12 floor)".into(),
            log_x: false,
            log_y: true,
            series: vec![Series::scatter("max |gpu - cpu|", xs, ys)],
        },
        Chart::loglog(
            "worker seconds per case",
            "CPU seconds",
            "GPU seconds",
            vec![
                Series::scatter("cases", cs, gs),
                Series::guide("equal time", vec![lo, hi], vec![lo, hi]),
            ],
        ),
    ];
    s += "<div class=\"plots\">";
    for ch in &charts {
        if let Ok(svg) = render_svg(ch) {
            s += &format!("<figure class=\"parity-chart\">{svg}</figure>");
        }
    }
    s += "</div><table id=\"parity-table\"><tr><th>#</th><th>case</th><th>output</th><th>shape</th><th>max |gpu - cpu|</th><th>max |cpu|</th></tr>";
    for (i, c) in both.iter().enumerate() {
        for p in all.iter().filter(|p| p.case == c.id) {
            s += &format!(
                "<tr><td class=\"num\">{}</td><td><code>{}</code></td><td>{}</td><td>{:?}</td><td class=\"num\">{}</td><td class=\"num\">{}</td></tr>",
                i + 1, esc(&p.case), esc(&p.tensor), p.shape, num(Some(p.max_diff)), num(Some(p.max_cpu))
            );
        }
    }
    s + "</table>"
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn diff_finds_the_largest_gap_and_counts_nan_as_infinite() {
        assert_eq!(diff(&[1.0, 2.0, 3.5], &[1.0, 2.5, 3.0]), (0.5, 3.0));
        assert_eq!(diff(&[f64::NAN], &[1.0]).0, f64::INFINITY);
    }
}
