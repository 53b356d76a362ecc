//! `perf_scenarios.yaml` and perf regression triage (`hpjudge perf`,
//! `hpjudge compare`). Benchmarks are reported, not timed tests: a change is
//! a regression only when it is past both a relative threshold and the noise
//! (the spread of the repeats), like criterion's confidence-interval rule.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_yaml::Value;

use super::load::{load_yaml_typed, JudgeInputError};
use super::manifest::CaseSize;
use super::ops::{self, BackendKind};
use super::stats::quartiles;
use crate::real::Precision;

/// One benchmark.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Scenario {
    pub id: String,
    pub op: String,
    #[serde(default)]
    pub scene: Option<String>,
    #[serde(default)]
    pub set: BTreeMap<String, Value>,
    #[serde(default)]
    pub params: Value,
    #[serde(default = "cpu")]
    pub backend: BackendKind,
    #[serde(default)]
    pub precision: Precision,
    #[serde(default = "one")]
    pub warmup: usize,
    #[serde(default = "five")]
    pub repeats: usize,
    /// Metrics of the op to report (all when empty).
    #[serde(default)]
    pub metrics: Vec<String>,
    #[serde(default)]
    pub size: CaseSize,
    #[serde(default)]
    pub doc: String,
}

fn cpu() -> BackendKind {
    BackendKind::Cpu
}
fn one() -> usize {
    1
}
fn five() -> usize {
    5
}

#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
struct ScenariosFile {
    schema_version: u32,
    #[serde(default)]
    scenarios: Vec<Scenario>,
}

/// All scenarios, with the folder their scene paths are relative to.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
pub struct PerfScenarios {
    pub path: PathBuf,
    pub scenarios: Vec<Scenario>,
}

impl PerfScenarios {
    /// Loads and validates the file (operations exist, scenes exist, ids unique).
    pub fn load(path: &Path) -> Result<PerfScenarios, JudgeInputError> {
        let (f, _): (ScenariosFile, String) = load_yaml_typed(path)?;
        let at = path.display().to_string();
        if f.schema_version != 1 {
            return Err(JudgeInputError::new(&at, "schema_version", "must be 1"));
        }
        let dir = path.parent().unwrap_or(Path::new("."));
        let mut seen = std::collections::BTreeSet::new();
        for (i, s) in f.scenarios.iter().enumerate() {
            let key = |k: &str| format!("scenarios[{i}].{k}");
            if !super::manifest::valid_id(&s.id) || !seen.insert(s.id.clone()) {
                return Err(JudgeInputError::new(
                    &at,
                    &key("id"),
                    format!("{:?} is invalid or repeated", s.id),
                ));
            }
            let Some(entry) = ops::find(&s.op) else {
                return Err(JudgeInputError::new(
                    &at,
                    &key("op"),
                    format!("unknown operation {:?}", s.op),
                ));
            };
            if let Some(why) = entry.refuses(s.backend, s.precision) {
                return Err(JudgeInputError::new(&at, &key("op"), why));
            }
            if let Some(sc) = &s.scene {
                if !dir.join(sc).is_file() {
                    return Err(JudgeInputError::new(
                        &at,
                        &key("scene"),
                        super::manifest::not_a_file(&dir.join(sc)),
                    ));
                }
            }
            if s.repeats == 0 {
                return Err(JudgeInputError::new(
                    &at,
                    &key("repeats"),
                    "must be at least 1",
                ));
            }
        }
        Ok(PerfScenarios {
            path: path.to_path_buf(),
            scenarios: f.scenarios,
        })
    }

    pub fn find(&self, id: &str) -> Option<&Scenario> {
        self.scenarios.iter().find(|s| s.id == id)
    }

    pub fn dir(&self) -> &Path {
        self.path.parent().unwrap_or(Path::new("."))
    }
}

/// Summary of one metric's repeats.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct MetricStats {
    pub median: f64,
    pub p25: f64,
    pub p75: f64,
    /// Interquartile range over the median: the noise.
    pub spread_rel: f64,
    pub samples: Vec<f64>,
}

impl MetricStats {
    pub fn of(samples: Vec<f64>) -> MetricStats {
        let (median, p25, p75) = quartiles(&samples);
        let spread_rel = if median != 0.0 {
            ((p75 - p25) / median).abs()
        } else {
            0.0
        };
        MetricStats {
            median,
            p25,
            p75,
            spread_rel,
            samples,
        }
    }
}

/// One scenario's result in perf.json.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct ScenarioResult {
    pub id: String,
    pub op: String,
    pub backend: BackendKind,
    pub precision: Precision,
    pub metrics: BTreeMap<String, MetricStats>,
    #[serde(default)]
    pub error: Option<String>,
}

/// perf.json.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct PerfReport {
    pub schema_version: u32,
    pub environment: serde_json::Value,
    pub scenarios: Vec<ScenarioResult>,
}

/// Which way is better for a metric, judged from its name.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Direction {
    HigherIsBetter,
    LowerIsBetter,
    Neutral,
}

pub fn direction(metric: &str) -> Direction {
    if metric.ends_with("_per_s") || metric.contains("speedup") || metric.contains("throughput") {
        Direction::HigherIsBetter
    } else if metric.ends_with("_s") || metric.ends_with("_ms") || metric.contains("time") {
        Direction::LowerIsBetter
    } else {
        Direction::Neutral
    }
}

/// The verdict on one metric.
#[derive(Clone, Copy, Debug, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Change {
    Regression,
    Improvement,
    WithinNoise,
    Unchanged,
    NotJudged,
}

/// One row of `hpjudge compare`.
#[derive(Clone, Debug, Serialize)]
pub struct CompareRow {
    pub key: String,
    pub base: f64,
    pub new: f64,
    /// `(new - base) / base`.
    pub change: f64,
    pub noise: f64,
    pub verdict: Change,
}

/// The relative change `(new - base) / |base|`, explicit at the edges: both
/// zero is no change; a zero base with a non-zero new value is an infinite
/// change in the direction of the new value.
pub fn relative_change(base: f64, new: f64) -> f64 {
    if base == new {
        0.0
    } else if base == 0.0 {
        f64::INFINITY.copysign(new)
    } else {
        (new - base) / base.abs()
    }
}

/// Compares two metric sets: a change is a regression (or improvement) only
/// when it is worse (better) by more than `threshold` and by more than
/// `noise_k` times the larger relative spread of the two. A non-finite new
/// value is a regression; a non-finite base value is not judged.
pub fn compare(
    base: &BTreeMap<String, MetricStats>,
    new: &BTreeMap<String, MetricStats>,
    threshold: f64,
    noise_k: f64,
) -> Vec<CompareRow> {
    let mut rows = Vec::new();
    for (k, b) in base {
        let Some(n) = new.get(k) else { continue };
        let metric = k.rsplit('/').next().unwrap_or(k);
        let dir = direction(metric);
        let change = relative_change(b.median, n.median);
        let noise = b.spread_rel.max(n.spread_rel);
        let better = match dir {
            Direction::HigherIsBetter => change,
            Direction::LowerIsBetter => -change,
            Direction::Neutral => 0.0,
        };
        let past = |x: f64| x > threshold && x > noise_k * noise;
        let verdict = if dir == Direction::Neutral {
            Change::NotJudged
        } else if !n.median.is_finite() {
            Change::Regression
        } else if !b.median.is_finite() {
            Change::NotJudged
        } else if past(-better) {
            Change::Regression
        } else if past(better) {
            Change::Improvement
        } else if change != 0.0 {
            Change::WithinNoise
        } else {
            Change::Unchanged
        };
        rows.push(CompareRow {
            key: k.clone(),
            base: b.median,
            new: n.median,
            change,
            noise,
            verdict,
        });
    }
    rows
}

/// Which file `compare` read.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ReportKind {
    Perf,
    Scoreboard,
}

/// Metrics of a perf.json or scoreboard.json, with the ids it holds and
/// those that errored.
#[derive(Clone, Debug)]
pub struct MetricsFile {
    pub kind: ReportKind,
    /// `scenario/metric` or `case/backend/metric`.
    pub metrics: BTreeMap<String, MetricStats>,
    /// Scenario ids or `case/backend`.
    pub ids: std::collections::BTreeSet<String>,
    /// Those of `ids` that errored or timed out, with why.
    pub errored: BTreeMap<String, String>,
}

/// A row of `compare` about a scenario or case rather than a metric.
#[derive(Clone, Debug, Serialize)]
pub struct MissingRow {
    pub id: String,
    pub why: String,
}

/// Checks `--threshold` and `--noise-k`: finite and >= 0.
pub fn validate_compare_args(threshold: f64, noise_k: f64) -> Result<(), JudgeInputError> {
    for (k, v) in [("--threshold", threshold), ("--noise-k", noise_k)] {
        if !(v.is_finite() && v >= 0.0) {
            return Err(JudgeInputError::new(
                k,
                "",
                format!("{v} is not a finite number >= 0"),
            ));
        }
    }
    Ok(())
}

/// Scenarios or cases of `base` that `new` lacks or that errored in `new`:
/// each is a regression.
pub fn missing_or_errored(base: &MetricsFile, new: &MetricsFile) -> Vec<MissingRow> {
    let mut rows = Vec::new();
    for id in &base.ids {
        if !new.ids.contains(id) {
            rows.push(MissingRow {
                id: id.clone(),
                why: "missing from the new file".into(),
            });
        } else if let Some(why) = new.errored.get(id) {
            if !base.errored.contains_key(id) {
                rows.push(MissingRow {
                    id: id.clone(),
                    why: format!("errored in the new file: {why}"),
                });
            }
        }
    }
    rows
}

/// Reads both files of `compare`; refuses a mix of perf report and scoreboard.
pub fn read_pair(base: &Path, new: &Path) -> Result<(MetricsFile, MetricsFile), JudgeInputError> {
    let (b, n) = (read_metrics(base)?, read_metrics(new)?);
    if b.kind != n.kind {
        return Err(JudgeInputError::new(
            &new.display().to_string(),
            "",
            format!(
                "is a {:?} file but {} is a {:?} file: compare like with like",
                n.kind,
                base.display(),
                b.kind
            ),
        ));
    }
    Ok((b, n))
}

/// Reads metrics from a perf.json (`scenario/metric`) or a scoreboard.json
/// (`case/backend/metric`, one sample each); refuses unknown schema versions.
pub fn read_metrics(path: &Path) -> Result<MetricsFile, JudgeInputError> {
    let at = path.display().to_string();
    let text = std::fs::read_to_string(path)
        .map_err(|e| JudgeInputError::new(&at, "", format!("cannot read: {e}")))?;
    let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| {
        JudgeInputError::new(&at, "", format!("not JSON: {e}")).at_line(Some(e.line()))
    })?;
    let version = v.get("schema_version").and_then(|x| x.as_u64());
    let mut f = MetricsFile {
        kind: ReportKind::Perf,
        metrics: BTreeMap::new(),
        ids: Default::default(),
        errored: BTreeMap::new(),
    };
    if let Some(sc) = v.get("scenarios") {
        if version != Some(1) {
            return Err(JudgeInputError::new(
                &at,
                "schema_version",
                format!("{version:?} is not a perf report version this hpjudge reads (1)"),
            ));
        }
        let r: Vec<ScenarioResult> = serde_json::from_value(sc.clone()).map_err(|e| {
            JudgeInputError::new(&at, "scenarios", format!("not a perf report: {e}"))
        })?;
        for s in r {
            f.ids.insert(s.id.clone());
            if let Some(e) = &s.error {
                f.errored.insert(s.id.clone(), e.clone());
            }
            for (m, st) in s.metrics {
                f.metrics.insert(format!("{}/{m}", s.id), st);
            }
        }
    } else if let Some(cases) = v.get("cases").and_then(|c| c.as_array()) {
        f.kind = ReportKind::Scoreboard;
        let known = super::scoreboard::KNOWN_SCHEMA_VERSIONS;
        if !version.is_some_and(|x| known.iter().any(|k| u64::from(*k) == x)) {
            return Err(JudgeInputError::new(
                &at,
                "schema_version",
                format!("{version:?} is not a scoreboard version this hpjudge reads ({known:?})"),
            ));
        }
        for c in cases {
            let id = c.get("id").and_then(|x| x.as_str()).unwrap_or("?");
            for r in c
                .get("results")
                .and_then(|r| r.as_array())
                .into_iter()
                .flatten()
            {
                let be = r.get("backend").and_then(|x| x.as_str()).unwrap_or("?");
                let key = format!("{id}/{be}");
                f.ids.insert(key.clone());
                let verdict = r.get("verdict").and_then(|x| x.as_str()).unwrap_or("?");
                if matches!(verdict, "ERROR" | "TIMEOUT") {
                    let why = r.get("reason").and_then(|x| x.as_str()).unwrap_or("");
                    f.errored.insert(key.clone(), format!("{verdict} {why}"));
                }
                for (m, x) in r
                    .get("metrics")
                    .and_then(|m| m.as_object())
                    .into_iter()
                    .flatten()
                {
                    if let Some(x) = x.as_f64() {
                        f.metrics
                            .insert(format!("{key}/{m}"), MetricStats::of(vec![x]));
                    }
                }
            }
        }
    } else {
        return Err(JudgeInputError::new(
            &at,
            "",
            "neither a perf report (`scenarios`) nor a scoreboard (`cases`)",
        ));
    }
    Ok(f)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn noisy(center: f64, rel: f64) -> MetricStats {
        MetricStats::of(
            (0..9)
                .map(|i| center * (1.0 + rel * ((i as f64 - 4.0) / 4.0)))
                .collect(),
        )
    }

    #[test]
    fn a_thirty_percent_throughput_drop_is_a_regression() {
        let base = BTreeMap::from([("s/samples_per_s".to_string(), noisy(100.0, 0.03))]);
        let new = BTreeMap::from([("s/samples_per_s".to_string(), noisy(70.0, 0.03))]);
        assert_eq!(
            compare(&base, &new, 0.1, 2.0)[0].verdict,
            Change::Regression
        );
    }

    #[test]
    fn a_change_inside_the_noise_is_not_a_regression() {
        let base = BTreeMap::from([("s/time_s".to_string(), noisy(1.0, 0.4))]);
        let new = BTreeMap::from([("s/time_s".to_string(), noisy(1.15, 0.4))]);
        assert_eq!(
            compare(&base, &new, 0.1, 2.0)[0].verdict,
            Change::WithinNoise
        );
    }

    #[test]
    fn zero_and_non_finite_values_are_judged_explicitly() {
        assert_eq!(relative_change(0.0, 0.0), 0.0);
        assert_eq!(relative_change(0.0, 2.0), f64::INFINITY);
        let zero = BTreeMap::from([("s/time_s".to_string(), noisy(0.0, 0.0))]);
        let slow = BTreeMap::from([("s/time_s".to_string(), noisy(1.0, 0.0))]);
        assert_eq!(
            compare(&zero, &slow, 0.1, 2.0)[0].verdict,
            Change::Regression
        );
        let nan = BTreeMap::from([("s/time_s".to_string(), MetricStats::of(vec![f64::NAN]))]);
        assert_eq!(
            compare(&slow, &nan, 0.1, 2.0)[0].verdict,
            Change::Regression
        );
        assert_eq!(compare(&nan, &slow, 0.1, 2.0)[0].verdict, Change::NotJudged);
        assert!(validate_compare_args(f64::NAN, 2.0).is_err());
        assert!(validate_compare_args(0.1, -1.0).is_err());
    }

    #[test]
    fn faster_times_are_improvements() {
        let base = BTreeMap::from([("s/time_s".to_string(), noisy(1.0, 0.02))]);
        let new = BTreeMap::from([("s/time_s".to_string(), noisy(0.5, 0.02))]);
        assert_eq!(
            compare(&base, &new, 0.1, 2.0)[0].verdict,
            Change::Improvement
        );
    }
}
