//! `hpjudge report OUT_DIR`: one static HTML page of a run, for a person
//! with a browser (no server, no network; every image embedded as a data
//! URI, artifact links relative to OUT_DIR where the page is written):
//!
//! - the run: summary counts, manifest, completeness, environment, input hashes;
//! - the verdict table, one row per case and backend, with filters
//!   (verdict, renderer, backend, id text) and per-result detail: every
//!   check's metric, value, limit, worst index and message, the repro
//!   command, metrics, artifacts, and for image outputs ours / reference /
//!   difference heatmap (images.rs);
//! - the plots the run drew (outputs named `plot*`: speed against error,
//!   convergence);
//! - GPU vs CPU parity (parity.rs).

pub mod images;
pub mod page;
pub mod parity;

use std::collections::BTreeSet;
use std::path::Path;

use base64::Engine;

use super::load::JudgeInputError;
use super::merge::read_board;
use super::ops::BackendKind;
use super::runner::shell_quote;
use super::scoreboard::{BackendResult, CaseEntry, Scoreboard, Verdict};
use page::{esc, kv_table, num};

/// The renderer of an op (`volume.forward` -> `volume`).
pub fn renderer(op: &str) -> &str {
    op.split('.').next().unwrap_or(op)
}

/// Image artifacts of a result (`.png` previews that are not plots), by tensor name.
fn image_names(r: &BackendResult) -> Vec<String> {
    r.artifacts
        .iter()
        .filter_map(|a| {
            Path::new(a)
                .file_name()?
                .to_str()?
                .strip_suffix(".png")
                .map(String::from)
        })
        .filter(|n| !is_plot(n))
        .collect()
}

fn is_plot(name: &str) -> bool {
    name.rsplit('.').next().unwrap_or(name).starts_with("plot")
}

/// The folder of a result's artifacts (`<out>/<case>/<backend>`).
fn result_dir(out: &Path, c: &CaseEntry, r: &BackendResult) -> std::path::PathBuf {
    out.join(&c.id).join(r.backend.name())
}

/// Builds the page for the run in `out` (reads `out/scoreboard.json`).
pub fn build(out: &Path) -> Result<String, JudgeInputError> {
    let board = read_board(&out.join("scoreboard.json"))?;
    let mut s = page::head(&format!("hpjudge report: {}", board.manifest));
    s += &summary(&board);
    s += &table(out, &board);
    s += &plots(out, &board);
    s += &parity::section(out, &board);
    s += page::SCRIPT;
    Ok(s)
}

fn summary(b: &Scoreboard) -> String {
    let m = &b.summary;
    let mut s = format!(
        "<h1>hpjudge report</h1><p id=\"summary\">{} passed, {} failed, {} errored, {} timed out, {} skipped; {} of {} results{}</p>",
        m.passed, m.failed, m.errored, m.timed_out, m.skipped, b.cases_done, b.cases_total,
        if b.complete { "" } else { " (INCOMPLETE)" }
    );
    let mut rows = vec![
        ("manifest".to_string(), b.manifest.clone()),
        ("hpjudge".into(), b.hpjudge_version.clone()),
        ("schema_version".into(), b.schema_version.to_string()),
    ];
    if let Some(why) = &b.stopped {
        rows.push(("stopped".into(), why.clone()));
    }
    flatten("", &b.environment, &mut rows);
    rows.push((
        "manifest_tree_sha256".into(),
        b.inputs.manifest_tree_sha256.clone(),
    ));
    rows.push((
        "thresholds_sha256".into(),
        b.inputs.thresholds_sha256.clone(),
    ));
    rows.push(("scenes_sha256".into(), b.inputs.scenes_sha256.clone()));
    s += "<h2>Run and environment</h2>";
    s += &kv_table(&rows);
    s
}

/// JSON leaves as `a.b.c` rows.
fn flatten(prefix: &str, v: &serde_json::Value, rows: &mut Vec<(String, String)>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                let key = if prefix.is_empty() {
                    k.clone()
                } else {
                    format!("{prefix}.{k}")
                };
                flatten(&key, x, rows);
            }
        }
        serde_json::Value::Array(a) => {
            for (i, x) in a.iter().enumerate() {
                flatten(&format!("{prefix}[{i}]"), x, rows);
            }
        }
        serde_json::Value::String(t) => rows.push((prefix.to_string(), t.clone())),
        other => rows.push((prefix.to_string(), other.to_string())),
    }
}

fn table(out: &Path, b: &Scoreboard) -> String {
    let all = |f: &dyn Fn(&CaseEntry, &BackendResult) -> String| -> Vec<String> {
        let set: BTreeSet<String> = b
            .cases
            .iter()
            .flat_map(|c| c.results.iter().map(|r| f(c, r)))
            .collect();
        set.into_iter().collect()
    };
    let verdicts = all(&|_, r| r.verdict.name().to_string());
    let renderers = all(&|c, _| renderer(&c.op).to_string());
    let backends = all(&|_, r| r.backend.name().to_string());
    let mut s = format!(
        "<h2>Verdicts</h2><p class=\"filters\">{}{}{}<label>id <input id=\"f-text\" type=\"search\"></label> <span id=\"shown\"></span> shown</p>",
        page::select("f-verdict", "verdict", &verdicts),
        page::select("f-renderer", "renderer", &renderers),
        page::select("f-backend", "backend", &backends)
    );
    s += "<table id=\"verdicts\"><thead><tr><th>verdict</th><th>case</th><th>op</th><th>backend</th><th>seconds</th><th>note</th></tr></thead>";
    for c in &b.cases {
        for r in &c.results {
            s += &row(out, b, c, r);
        }
    }
    s + "</table>"
}

fn row(out: &Path, b: &Scoreboard, c: &CaseEntry, r: &BackendResult) -> String {
    let v = r.verdict.name();
    let expect = match c.expect {
        Some(e) if r.verdict.matches(e) => " (as expected)".to_string(),
        Some(e) => format!(" (EXPECTED {e:?})"),
        None => String::new(),
    };
    let note = if !r.reason.is_empty() {
        r.reason.clone()
    } else {
        r.checks
            .iter()
            .find(|k| !k.passed)
            .map(|k| format!("{}: {}", k.assertion, k.message))
            .unwrap_or_default()
    };
    format!(
        "<tbody class=\"result\" data-case=\"{id}\" data-verdict=\"{v}\" data-renderer=\"{ren}\" data-backend=\"{be}\">\
         <tr><td class=\"v-{v}\">{v}{exp}</td><td><code>{id}</code></td><td>{op}</td><td>{be}</td><td class=\"num\">{t:.2}</td><td>{note}</td></tr>\
         <tr><td colspan=\"6\"><details{open}><summary>detail</summary>{detail}</details></td></tr></tbody>",
        open = if matches!(r.verdict, Verdict::Pass | Verdict::Skip) { "" } else { " open" },
        id = esc(&c.id),
        ren = esc(renderer(&c.op)),
        be = r.backend.name(),
        exp = esc(&expect),
        op = esc(&c.op),
        t = r.wall_s,
        note = esc(&note.chars().take(200).collect::<String>()),
        detail = detail(out, b, c, r)
    )
}

fn detail(out: &Path, b: &Scoreboard, c: &CaseEntry, r: &BackendResult) -> String {
    let mut s = format!("<p>defined at <code>{}</code>", esc(&c.defined_at));
    if let Some(sc) = &c.scene {
        s += &format!(", scene <code>{}</code>", esc(sc));
    }
    s += "</p>";
    let repro = if r.repro.is_empty() {
        format!(
            "hpjudge run {} --filter={} --backend={}",
            shell_quote(&b.manifest),
            shell_quote(&c.id),
            r.backend.name()
        )
    } else {
        r.repro.clone()
    };
    s += &format!("<p>repro: <code class=\"repro\">{}</code></p>", esc(&repro));
    if !r.reason.is_empty() {
        s += &format!("<pre>{}</pre>", esc(&r.reason));
    }
    if !r.checks.is_empty() {
        s += "<table class=\"checks\"><tr><th>assertion</th><th>metric</th><th>value</th><th>limit</th><th>worst index</th><th>passed</th><th>message</th></tr>";
        for k in &r.checks {
            let passed = match (k.passed, k.enforced) {
                (true, _) => "yes",
                (false, true) => "NO",
                (false, false) => "no (not enforced)",
            };
            s += &format!(
                "<tr><td>{}</td><td>{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td class=\"num\">{}</td><td>{passed}</td><td>{}</td></tr>",
                esc(&k.assertion), esc(&k.metric), num(k.value), num(k.limit),
                k.worst_index.map_or("-".into(), |i| i.to_string()), esc(&k.message)
            );
        }
        s += "</table>";
    }
    if !r.metrics.is_empty() {
        let rows: Vec<(String, String)> = r
            .metrics
            .iter()
            .map(|(k, v)| (k.clone(), num(Some(*v))))
            .collect();
        s += &format!(
            "<details><summary>{} metrics</summary>{}</details>",
            rows.len(),
            kv_table(&rows)
        );
    }
    s += &comparisons(out, c, r);
    if !r.artifacts.is_empty() {
        s += "<p>artifacts: ";
        for a in &r.artifacts {
            s += &format!("<a href=\"{0}\">{0}</a> ", esc(a));
        }
        s += "</p>";
    }
    s
}

/// Ours / reference / heatmap for every image output that has a
/// reference: a ref's output of the same name (`<ref>.<name>` beside it),
/// else for a GPU result the CPU result's output.
fn comparisons(out: &Path, c: &CaseEntry, r: &BackendResult) -> String {
    let dir = result_dir(out, c, r);
    let cpu = c
        .results
        .iter()
        .find(|x| x.backend == BackendKind::Cpu && r.backend == BackendKind::Gpu);
    let mut s = String::new();
    let names = image_names(r);
    for n in names.iter().filter(|n| !n.contains('.')) {
        let Some(ours) = images::read_rgb(&dir.join(format!("{n}.npy"))) else {
            continue;
        };
        let suffix = format!(".{n}");
        let reference = names
            .iter()
            .find(|m| m.ends_with(&suffix))
            .map(|m| {
                (
                    m.trim_end_matches(&suffix).to_string(),
                    dir.join(format!("{m}.npy")),
                )
            })
            .or_else(|| {
                cpu.map(|x| {
                    (
                        "CPU".to_string(),
                        result_dir(out, c, x).join(format!("{n}.npy")),
                    )
                })
            });
        let cmp = reference
            .and_then(|(label, p)| Some((label, images::compare(&ours, &images::read_rgb(&p)?)?)));
        s += &match cmp {
            Some((label, k)) => triple(n, &label, &k),
            None => match images::image_uri(&ours) {
                Some(u) => format!("<figure><img src=\"{u}\" alt=\"{0}\"><figcaption>{0} (no reference)</figcaption></figure>", esc(n)),
                None => String::new(),
            },
        };
    }
    s
}

/// One ours / reference / heatmap row with the heatmap's colour bar.
pub fn triple(name: &str, ref_label: &str, k: &images::Comparison) -> String {
    format!(
        "<div class=\"triple\" data-image=\"{n}\">\
         <figure><img src=\"{o}\" alt=\"ours\"><figcaption>{n}: ours</figcaption></figure>\
         <figure><img src=\"{r}\" alt=\"reference\"><figcaption>reference ({rl})</figcaption></figure>\
         <figure><img src=\"{h}\" alt=\"difference\"><figcaption>max |ours - reference| per pixel</figcaption>\
         <div class=\"bar\" style=\"background: {g}\"></div><div class=\"barlabels\"><span>0</span><span>{mx}</span></div>\
         <figcaption>mean {mean}</figcaption></figure></div>",
        n = esc(name),
        o = k.ours,
        r = k.reference,
        rl = esc(ref_label),
        h = k.heatmap,
        g = images::heat_gradient(),
        mx = num(Some(k.max_diff)),
        mean = num(Some(k.mean_diff)),
    )
}

/// Every plot the run drew (PNG artifacts named `plot*`), embedded.
fn plots(out: &Path, b: &Scoreboard) -> String {
    let mut s = String::from("<h2>Plots</h2><div class=\"plots\">");
    let mut n = 0;
    for c in &b.cases {
        for r in &c.results {
            for a in r.artifacts.iter().filter(|a| a.ends_with(".png")) {
                let name = Path::new(a)
                    .file_stem()
                    .and_then(|x| x.to_str())
                    .unwrap_or("");
                if !is_plot(name) {
                    continue;
                }
                let Ok(bytes) = std::fs::read(out.join(a)) else {
                    continue;
                };
                n += 1;
                s += &format!(
                    "<figure><img src=\"data:image/png;base64,{}\" alt=\"{1}\"><figcaption><code>{1}</code> [{2}]</figcaption></figure>",
                    base64::engine::general_purpose::STANDARD.encode(bytes),
                    esc(&c.id),
                    r.backend.name()
                );
            }
        }
    }
    if n == 0 {
        s += "<p>No case of this run drew a plot.</p>";
    }
    s + "</div>"
}
