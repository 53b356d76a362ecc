//! `hpjudge perf`: runs each scenario of perf_scenarios.yaml in a worker
//! process (time limit `perf` of thresholds.yaml) and writes perf.json.

use std::path::{Path, PathBuf};

use crate::judge::env;
use crate::judge::job::{run_child, ChildEnd, Job, Task, DEADLINE_GRACE_S};
use crate::judge::load::{load_yaml_typed, JudgeInputError};
use crate::judge::perf::{PerfReport, PerfScenarios, Scenario, ScenarioResult};
use crate::judge::thresholds::{pick_profile, Thresholds, ThresholdsFile};

/// Why a perf run stopped (a scenario's own failure is in its result instead).
#[derive(Debug, thiserror::Error)]
pub enum PerfRunError {
    #[error(transparent)]
    Input(#[from] JudgeInputError),
    #[error(transparent)]
    Io(#[from] std::io::Error),
    #[error(transparent)]
    Json(#[from] serde_json::Error),
}

/// Runs the scenarios of `scenarios` whose id contains `filter`, calling
/// `each` with every result as it arrives; writes `out/perf.json` and returns
/// the report and that path. A progress bar with ETA is drawn unless
/// `json` (or CI, or no terminal). thresholds.yaml is read beside the scenarios
/// file, profile `ci` when CI is set, else `default`.
pub fn run_scenarios(
    scenarios: &Path,
    out: &Path,
    filter: Option<&str>,
    threads: usize,
    seed: u32,
    mem_limit: Option<u64>,
    json: bool,
    mut each: impl FnMut(&ScenarioResult),
) -> Result<(PerfReport, PathBuf), PerfRunError> {
    let perf = PerfScenarios::load(scenarios)?;
    let root = scenarios.parent().unwrap_or(Path::new("."));
    let root = if root.as_os_str().is_empty() {
        Path::new(".")
    } else {
        root
    };
    let th_path = root.join("thresholds.yaml");
    let (tf, _): (ThresholdsFile, String) = load_yaml_typed(&th_path)?;
    let (profile, _) = pick_profile(&tf, std::env::var_os("CI").is_some(), None);
    let th = Thresholds::load(&th_path, &profile)?;
    std::fs::create_dir_all(out)?;
    let mut results = Vec::new();
    let selected: Vec<&Scenario> = perf
        .scenarios
        .iter()
        .filter(|s| filter.is_none_or(|f| s.id.contains(f)))
        .collect();
    let bar = crate::judge::progress::bar(selected.len() as u64, json);
    for s in selected {
        bar.set_message(s.id.clone());
        let dir = out.join("perf").join(&s.id);
        std::fs::create_dir_all(&dir)?;
        let limit = th
            .timeout("perf")
            .or_else(|| th.timeout("default"))
            .unwrap_or(600.0);
        let job = Job {
            task: Task::Scenario { id: s.id.clone() },
            scenes: Default::default(),
            thresholds: th.clone(),
            perf: perf.clone(),
            out: out.to_path_buf(),
            goldens: root.join("GOLDENS"),
            seed,
            threads,
            mem_limit,
            dump: false,
            bless: false,
            deadline_s: limit + DEADLINE_GRACE_S,
        };
        let r = match run_child(
            &job,
            limit,
            &dir.join("worker.log"),
            &dir.join("result.json"),
        ) {
            ChildEnd::Done(t) => serde_json::from_str(&t)?,
            ChildEnd::TimedOut => failed_scenario(s, format!("timed out after {limit:.0} s")),
            ChildEnd::Failed(why) => failed_scenario(s, why),
        };
        bar.suspend(|| each(&r));
        bar.inc(1);
        results.push(r);
    }
    bar.finish_and_clear();
    let threads = if threads > 0 {
        threads
    } else {
        env::logical_cpus()
    };
    let report = PerfReport {
        schema_version: 1,
        environment: env::describe(threads, seed, &profile, "-", &th.sha256, None),
        scenarios: results,
    };
    let path = out.join("perf.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)? + "\n")?;
    Ok((report, path))
}

fn failed_scenario(s: &Scenario, e: String) -> ScenarioResult {
    ScenarioResult {
        id: s.id.clone(),
        op: s.op.clone(),
        backend: s.backend,
        precision: s.precision,
        metrics: Default::default(),
        error: Some(e),
    }
}
