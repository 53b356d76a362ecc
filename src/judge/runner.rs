//! The runner: loads and validates every input, then runs each case on each
//! backend in a worker process (`hpjudge` re-executing itself), with a time
//! limit, and writes the scoreboard atomically after every case.

use std::collections::BTreeSet;
use std::io::IsTerminal;
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use super::env;
use super::junit::to_junit;
use super::load::JudgeInputError;
use super::manifest::{LoadedCase, Manifest};
use super::ops::BackendKind;
use super::perf::PerfScenarios;
use super::scoreboard::{BackendResult, CaseEntry, Scoreboard, Summary, Verdict, SCHEMA_VERSION};
use super::thresholds::{pick_profile, Thresholds, ThresholdsFile};
use super::worker::case_dir;
use crate::scene::{self, SceneDoc};

/// Which backends a run covers.
#[derive(Clone, Copy, Debug, PartialEq, Eq, clap::ValueEnum)]
pub enum BackendFilter {
    Cpu,
    Gpu,
    All,
}

impl BackendFilter {
    pub fn allows(self, b: BackendKind) -> bool {
        matches!(
            (self, b),
            (BackendFilter::All, _)
                | (BackendFilter::Cpu, BackendKind::Cpu)
                | (BackendFilter::Gpu, BackendKind::Gpu)
        )
    }
}

/// Everything `hpjudge run` was asked.
#[derive(Clone, Debug)]
pub struct RunOptions {
    pub manifest: PathBuf,
    pub out: PathBuf,
    pub filter: Option<String>,
    pub backend: BackendFilter,
    pub threads: usize,
    pub seed: u32,
    pub json: bool,
    pub junit: Option<PathBuf>,
    pub dump_failing: bool,
    pub require_gpu: bool,
    pub profile: Option<String>,
    pub thresholds: Option<PathBuf>,
    pub mem_limit: Option<u64>,
}

/// The judge's inputs, loaded and cross-checked.
pub struct Inputs {
    pub manifest: Manifest,
    pub thresholds: Thresholds,
    pub perf: PerfScenarios,
    /// Folder of thresholds.yaml: the project root (GOLDENS/ lives there).
    pub root: PathBuf,
    pub profile_reason: String,
}

/// Finds `name` in `start` or the nearest folder above it.
pub fn find_upwards(start: &Path, name: &str) -> Option<PathBuf> {
    let start = start.canonicalize().ok()?;
    start
        .ancestors()
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// Loads the manifest, thresholds (with the profile applied) and perf
/// scenarios, and validates every case and scene before anything runs.
pub fn load_inputs(
    manifest: &Path,
    thresholds: Option<&Path>,
    profile: Option<&str>,
) -> Result<Inputs, JudgeInputError> {
    let at = manifest.display().to_string();
    if !manifest.is_file() {
        return Err(JudgeInputError::new(&at, "", "no such manifest file"));
    }
    let mdir = manifest.parent().unwrap_or(Path::new("."));
    let mdir = if mdir.as_os_str().is_empty() {
        Path::new(".")
    } else {
        mdir
    };
    let th_path = match thresholds {
        Some(p) => p.to_path_buf(),
        None => find_upwards(mdir, "thresholds.yaml").ok_or_else(|| {
            JudgeInputError::new(
                &at,
                "",
                "no thresholds.yaml in its folder or any folder above",
            )
        })?,
    };
    let root = th_path.parent().unwrap_or(Path::new(".")).to_path_buf();
    let (profile, reason) = match profile {
        Some(p) => (p.to_string(), "--profile".to_string()),
        None => {
            let (f, _): (ThresholdsFile, String) = super::load::load_yaml_typed(&th_path)?;
            let wants_gpu = f.profiles.values().any(|p| p.match_gpu.is_some());
            let gpu = if wants_gpu {
                crate::gpu::GpuContext::get().ok().map(|g| g.summary().name)
            } else {
                None
            };
            pick_profile(&f, std::env::var_os("CI").is_some(), gpu.as_deref())
        }
    };
    let th = Thresholds::load(&th_path, &profile)?;
    let perf_path = root.join("perf_scenarios.yaml");
    let perf = if perf_path.is_file() {
        PerfScenarios::load(&perf_path)?
    } else {
        PerfScenarios::default()
    };
    let m = Manifest::load(manifest)?;
    m.validate(&th, &perf)?;
    for lc in &m.cases {
        if let Some(s) = &lc.case.scene {
            let sets: Vec<(String, serde_yaml::Value)> = lc
                .case
                .set
                .iter()
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect();
            let doc = SceneDoc::load_values(&lc.dir().join(s), &sets)
                .map_err(|e| JudgeInputError::new(&lc.at(), "scene", e.to_string()))?;
            scene::validate(&doc).map_err(|e| {
                JudgeInputError::new(
                    &lc.at(),
                    &format!("cases[{}].scene", lc.case.id),
                    e.to_string(),
                )
            })?;
        }
    }
    Ok(Inputs {
        manifest: m,
        thresholds: th,
        perf,
        root,
        profile_reason: reason,
    })
}

/// The GPU block of the environment, when the run has GPU cases.
fn gpu_env(inputs: &Inputs, opts: &RunOptions) -> Option<serde_json::Value> {
    let any = inputs
        .manifest
        .cases
        .iter()
        .any(|c| c.case.backends.contains(&BackendKind::Gpu));
    (any && opts.backend.allows(BackendKind::Gpu)).then(crate::gpu::describe)
}

/// Whether to draw a progress bar: only on a terminal, never under `--json`
/// or when `CI` is set.
pub fn show_progress(json: bool, ci_set: bool, stderr_is_terminal: bool) -> bool {
    !json && !ci_set && stderr_is_terminal
}

/// The command that reruns one case on one backend.
pub fn repro(opts: &RunOptions, profile: &str, id: &str, b: BackendKind) -> String {
    format!(
        "hpjudge run {} --filter {id} --backend {} --profile {profile} --seed {} --dump-failing",
        opts.manifest.display(),
        b.name(),
        opts.seed
    )
}

/// What a dead worker's log says: its panic message when it panicked (the
/// `panicked at` line and the message after it), else its last lines.
fn tail(path: &Path, lines: usize) -> String {
    let s = std::fs::read_to_string(path).unwrap_or_default();
    let v: Vec<&str> = s.lines().collect();
    if let Some(i) = v.iter().position(|l| l.contains("panicked at")) {
        return v[i..(i + 2).min(v.len())].join("\n");
    }
    v[v.len().saturating_sub(lines)..].join("\n")
}

#[cfg(unix)]
fn describe_status(s: std::process::ExitStatus) -> String {
    use std::os::unix::process::ExitStatusExt;
    match (s.code(), s.signal()) {
        (Some(101), _) => "panicked (exit 101)".into(),
        (Some(c), _) => format!("exited with status {c}"),
        (None, Some(6)) => "aborted (SIGABRT)".into(),
        (None, Some(11)) => "crashed (SIGSEGV)".into(),
        (None, Some(sig)) => format!("killed by signal {sig}"),
        _ => "ended abnormally".into(),
    }
}

#[cfg(not(unix))]
fn describe_status(s: std::process::ExitStatus) -> String {
    format!("exited with {s}")
}

/// How a child worker ended.
pub enum ChildEnd {
    /// Exited 0 and wrote its result file (its text).
    Done(String),
    /// Killed at the time limit.
    TimedOut,
    /// Anything else, described.
    Failed(String),
}

/// Runs `hpjudge worker ARGS --result FILE` with stderr to `log`, killing it
/// after `limit` seconds.
pub fn run_child(args: &[String], limit: f64, log_path: &Path, result_path: &Path) -> ChildEnd {
    let _ = std::fs::remove_file(result_path);
    // /proc/self/exe stays valid when the binary is rebuilt during a run.
    let proc_exe = Path::new("/proc/self/exe");
    let exe = if proc_exe.exists() {
        proc_exe.to_path_buf()
    } else {
        match std::env::current_exe() {
            Ok(e) => e,
            Err(e) => return ChildEnd::Failed(format!("cannot find the hpjudge executable: {e}")),
        }
    };
    let log = match std::fs::File::create(log_path) {
        Ok(f) => f,
        Err(e) => return ChildEnd::Failed(format!("cannot create {}: {e}", log_path.display())),
    };
    let mut cmd = Command::new(exe);
    cmd.arg("worker")
        .args(args)
        .arg("--result")
        .arg(result_path)
        .stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(log);
    let started = Instant::now();
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => return ChildEnd::Failed(format!("cannot start a worker: {e}")),
    };
    let status = loop {
        match child.try_wait() {
            Ok(Some(s)) => break s,
            Ok(None) if started.elapsed().as_secs_f64() > limit => {
                let _ = child.kill();
                let _ = child.wait();
                return ChildEnd::TimedOut;
            }
            Ok(None) => std::thread::sleep(Duration::from_millis(10)),
            Err(e) => return ChildEnd::Failed(format!("lost the worker: {e}")),
        }
    };
    match (status.success(), std::fs::read_to_string(result_path)) {
        (true, Ok(text)) => ChildEnd::Done(text),
        (ok, _) => {
            let why = if ok {
                "wrote no result".to_string()
            } else {
                describe_status(status)
            };
            ChildEnd::Failed(format!(
                "worker {why}: {}",
                tail(log_path, 6).replace('\n', " | ")
            ))
        }
    }
}

/// Runs one case on one backend in a worker process.
fn spawn_worker(
    inputs: &Inputs,
    opts: &RunOptions,
    lc: &LoadedCase,
    b: BackendKind,
    dump: bool,
) -> BackendResult {
    let dir = case_dir(&opts.out, &lc.case.id, b);
    let started = Instant::now();
    let fail = |v: Verdict, reason: String, wall: f64| BackendResult {
        backend: b,
        verdict: v,
        reason,
        checks: vec![],
        metrics: Default::default(),
        counters: Default::default(),
        tensors: Default::default(),
        artifacts: vec![],
        wall_s: wall,
        repro: String::new(),
    };
    if let Err(e) = std::fs::create_dir_all(&dir) {
        return fail(
            Verdict::Error,
            format!("cannot create {}: {e}", dir.display()),
            0.0,
        );
    }
    let mut args: Vec<String> = vec![
        "--manifest".into(),
        inputs.manifest.path.display().to_string(),
        "--case".into(),
        lc.case.id.clone(),
        "--backend".into(),
        b.name().into(),
        "--out".into(),
        opts.out.display().to_string(),
        "--thresholds".into(),
        inputs.thresholds.path.display().to_string(),
        "--profile".into(),
        inputs.thresholds.profile_name.clone(),
        "--seed".into(),
        opts.seed.to_string(),
        "--threads".into(),
        opts.threads.to_string(),
    ];
    if let Some(m) = opts.mem_limit {
        args.extend(["--mem-limit".into(), m.to_string()]);
    }
    if dump {
        args.push("--dump".into());
    }
    let limit = inputs.thresholds.timeout(&lc.case.timeout).unwrap_or(120.0);
    let end = run_child(
        &args,
        limit,
        &dir.join("worker.log"),
        &dir.join("result.json"),
    );
    let wall = started.elapsed().as_secs_f64();
    match end {
        ChildEnd::Done(text) => match serde_json::from_str::<BackendResult>(&text) {
            Ok(mut r) => {
                r.wall_s = wall;
                r
            }
            Err(e) => fail(
                Verdict::Error,
                format!("unreadable worker result: {e}"),
                wall,
            ),
        },
        ChildEnd::TimedOut => fail(
            Verdict::Timeout,
            format!(
                "killed after the {limit:.0} s limit (timeout `{}`)",
                lc.case.timeout
            ),
            wall,
        ),
        ChildEnd::Failed(why) => fail(Verdict::Error, why, wall),
    }
}

/// `hpjudge run`: the whole suite. Returns the finished scoreboard.
pub fn run(opts: &RunOptions) -> Result<Scoreboard, JudgeInputError> {
    let inputs = load_inputs(
        &opts.manifest,
        opts.thresholds.as_deref(),
        opts.profile.as_deref(),
    )?;
    let th = &inputs.thresholds;
    let size = match th.profile.size {
        super::thresholds::SizeProfile::Ci => "ci",
        super::thresholds::SizeProfile::Full => "full",
    };
    tracing::info!(
        "profile {} ({}), size {size}",
        th.profile_name,
        inputs.profile_reason
    );
    eprintln!(
        "hpjudge: profile {} ({}), size profile {size}",
        th.profile_name, inputs.profile_reason
    );
    let out = &opts.out;
    std::fs::create_dir_all(out).map_err(|e| {
        JudgeInputError::new(
            &out.display().to_string(),
            "",
            format!("cannot create: {e}"),
        )
    })?;
    let threads = if opts.threads > 0 {
        opts.threads
    } else {
        env::logical_cpus()
    };
    let mut board = Scoreboard {
        schema_version: SCHEMA_VERSION,
        hpjudge_version: env::VERSION.to_string(),
        manifest: opts.manifest.display().to_string(),
        environment: env::describe(
            threads,
            opts.seed,
            &th.profile_name,
            size,
            &th.sha256,
            gpu_env(&inputs, opts),
        ),
        summary: Summary::default(),
        cases: vec![],
    };
    let selected: Vec<&LoadedCase> = inputs
        .manifest
        .cases
        .iter()
        .filter(|c| {
            opts.filter
                .as_ref()
                .is_none_or(|f| c.case.id.contains(f.as_str()))
        })
        .collect();
    let total: u64 = selected
        .iter()
        .map(|c| {
            c.case
                .backends
                .iter()
                .filter(|b| opts.backend.allows(**b))
                .count() as u64
        })
        .sum();
    let bar = if show_progress(
        opts.json,
        std::env::var_os("CI").is_some(),
        std::io::stderr().is_terminal(),
    ) {
        indicatif::ProgressBar::new(total)
    } else {
        indicatif::ProgressBar::hidden()
    };
    let board_path = out.join("scoreboard.json");
    let mut seen_backends = BTreeSet::new();
    for lc in selected {
        let c = &lc.case;
        let mut entry = CaseEntry {
            id: c.id.clone(),
            op: c.op.clone(),
            scene: c.scene.clone(),
            defined_at: lc.at(),
            expect: c.expect,
            results: vec![],
        };
        for &b in c.backends.iter().filter(|b| opts.backend.allows(**b)) {
            seen_backends.insert(b);
            bar.set_message(format!("{} [{}]", c.id, b.name()));
            let mut r = spawn_worker(&inputs, opts, lc, b, false);
            if opts.require_gpu
                && b == BackendKind::Gpu
                && r.verdict == Verdict::Skip
                && !r.reason.starts_with("size full")
            {
                r.verdict = Verdict::Fail;
                r.reason = format!("--require-gpu: {}", r.reason);
            }
            let bad = matches!(r.verdict, Verdict::Fail | Verdict::Error | Verdict::Timeout);
            let unexpected = c.expect.is_some_and(|e| !r.verdict.matches(e));
            if (bad && c.expect.is_none()) || unexpected {
                r.repro = repro(opts, &th.profile_name, &c.id, b);
                if opts.dump_failing && r.verdict != Verdict::Timeout {
                    let d = spawn_worker(&inputs, opts, lc, b, true);
                    r.artifacts = d.artifacts;
                }
            }
            if !opts.json {
                bar.suspend(|| print_row(&entry, &r));
            }
            entry.results.push(r);
            bar.inc(1);
        }
        if !entry.results.is_empty() {
            board.cases.push(entry);
        }
        save(&mut board, &board_path)?;
    }
    bar.finish_and_clear();
    save(&mut board, &board_path)?;
    if let Some(j) = &opts.junit {
        std::fs::write(j, to_junit(&board)).map_err(|e| {
            JudgeInputError::new(&j.display().to_string(), "", format!("cannot write: {e}"))
        })?;
    }
    Ok(board)
}

/// Finishes the board (sort, summary) and writes it atomically.
fn save(board: &mut Scoreboard, path: &Path) -> Result<(), JudgeInputError> {
    board.finish();
    board.write_atomic(path).map_err(|e| {
        JudgeInputError::new(
            &path.display().to_string(),
            "",
            format!("cannot write: {e}"),
        )
    })
}

fn print_row(entry: &CaseEntry, r: &BackendResult) {
    let note = if !r.reason.is_empty() {
        r.reason.clone()
    } else if let Some(k) = r.checks.iter().find(|k| !k.passed) {
        format!("{}: {}", k.assertion, k.message)
    } else {
        String::new()
    };
    let exp = match entry.expect {
        Some(e) if r.verdict.matches(e) => " (as expected)".to_string(),
        Some(e) => format!(" (EXPECTED {e:?})").to_uppercase(),
        None => String::new(),
    };
    let note: String = note.chars().take(160).collect();
    println!(
        "{:<7} {:<44} {:<4} {:>7.2}s{exp}  {note}",
        r.verdict.name(),
        entry.id,
        r.backend.name(),
        r.wall_s
    );
}

/// Prints the closing part of a human run: repro lines, then the summary.
pub fn print_summary(board: &Scoreboard, out: &Path) {
    let mut repros = Vec::new();
    for c in &board.cases {
        for r in &c.results {
            if !r.repro.is_empty() {
                repros.push(format!("  {}", r.repro));
            }
        }
    }
    if !repros.is_empty() {
        println!("\nrepro:");
        for r in repros {
            println!("{r}");
        }
    }
    println!("\nscoreboard: {}", out.join("scoreboard.json").display());
    println!("{}", board.summary.line());
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn progress_only_on_a_terminal_without_json_or_ci() {
        assert!(show_progress(false, false, true));
        assert!(!show_progress(true, false, true));
        assert!(!show_progress(false, true, true));
        assert!(!show_progress(false, false, false));
    }
}
