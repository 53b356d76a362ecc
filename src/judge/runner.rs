//! The runner: loads and validates every input, then runs each case on each
//! backend in a worker process (`hpjudge` re-executing itself), with a time
//! limit, and writes the scoreboard atomically after every case.

use std::collections::{BTreeMap, BTreeSet};
use std::io::Write;
use std::path::{Path, PathBuf};
use std::time::Instant;

use super::env;
use super::job::{run_child, ChildEnd, Job, Task, DEADLINE_GRACE_S};
use super::junit::to_junit;
use super::load::JudgeInputError;
use super::manifest::not_a_file;
use super::manifest::{LoadedCase, Manifest};
use super::ops::BackendKind;
use super::outlock::lock_out_dir;
use super::partition::Partition;
use super::perf::PerfScenarios;
use super::scoreboard::InputHashes;
use super::scoreboard::{BackendResult, CaseEntry, Scoreboard, Summary, Verdict, SCHEMA_VERSION};
use super::thresholds::{pick_profile, Thresholds, ThresholdsFile};
use super::worker::{case_dir, sets_for, PERF_NOT_ENFORCED};
use crate::scene::{self, SceneDoc};
use sha2::{Digest, Sha256};

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
    /// Workers write goldens instead of judging (`hpjudge bless`).
    pub bless: bool,
    /// Run only this shard's cases (`--partition K/N`).
    pub partition: Option<Partition>,
}

/// The judge's inputs, loaded and cross-checked.
pub struct Inputs {
    pub manifest: Manifest,
    pub thresholds: Thresholds,
    pub perf: PerfScenarios,
    /// Folder of thresholds.yaml: the project root (GOLDENS/ lives there).
    pub root: PathBuf,
    pub profile_reason: String,
    /// Every scene file the cases name, as read at load time.
    pub scenes: BTreeMap<PathBuf, SceneFile>,
}

/// A scene file as the judge read it: workers get this text, never the file.
pub struct SceneFile {
    pub text: String,
    pub sha256: String,
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
        return Err(JudgeInputError::new(&at, "", not_a_file(manifest)));
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
    let mut scenes = BTreeMap::new();
    for lc in &m.cases {
        validate_scenes(lc, &mut scenes)?;
    }
    Ok(Inputs {
        manifest: m,
        thresholds: th,
        perf,
        root,
        profile_reason: reason,
        scenes,
    })
}

/// Loads and validates every scene a case's runs use, as `run` would:
/// with the case's `set:`, with its `ci:` overrides on top, and each ref's
/// scene with its own `set:`. Keeps each scene file's text and SHA-256.
fn validate_scenes(
    lc: &LoadedCase,
    files: &mut BTreeMap<PathBuf, SceneFile>,
) -> Result<(), JudgeInputError> {
    let c = &lc.case;
    type Sets = BTreeMap<String, serde_yaml::Value>;
    let mut runs: Vec<(String, Option<&String>, Option<&Sets>)> =
        vec![(format!("cases[{}]", c.id), c.scene.as_ref(), None)];
    for (name, r) in &c.refs {
        runs.push((
            format!("cases[{}].refs.{name}", c.id),
            r.scene.as_ref().or(c.scene.as_ref()),
            r.set.as_ref(),
        ));
    }
    if !c.ci.is_empty() && runs.iter().all(|r| r.1.is_none()) {
        return Err(JudgeInputError::new(
            &lc.at(),
            &format!("cases[{}].ci", c.id),
            "`ci:` overrides scene keys, but the case has no scene",
        ));
    }
    for (key, scene, extra) in runs {
        let Some(s) = scene else { continue };
        let path = lc.dir().join(s);
        if !files.contains_key(&path) {
            let text = scene::read_yaml_text(&path)
                .map_err(|e| JudgeInputError::new(&lc.at(), &key, e.to_string()))?;
            let sha256 = format!("{:x}", Sha256::digest(text.as_bytes()));
            files.insert(path.clone(), SceneFile { text, sha256 });
        }
        let text = &files[&path].text;
        let profiles: &[Option<&Sets>] = if c.ci.is_empty() {
            &[None]
        } else {
            &[None, Some(&c.ci)]
        };
        for ci in profiles {
            let at_key = if ci.is_some() {
                format!("{key}.ci")
            } else {
                format!("{key}.scene")
            };
            let doc = SceneDoc::load_text(&path, text, &sets_for(&c.set, *ci, extra))
                .map_err(|e| JudgeInputError::new(&lc.at(), &at_key, e.to_string()))?;
            scene::validate(&doc)
                .map_err(|e| JudgeInputError::new(&lc.at(), &at_key, e.to_string()))?;
        }
    }
    Ok(())
}

/// One SHA-256 over `(hash, path)` lines of files.
fn combined_sha256(files: &BTreeMap<PathBuf, SceneFile>) -> String {
    let mut h = Sha256::new();
    for (p, f) in files {
        h.update(format!("{}  {}\n", f.sha256, p.display()).as_bytes());
    }
    format!("{:x}", h.finalize())
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

/// Quotes `s` for a POSIX shell when it holds anything but `[A-Za-z0-9_./=:,+-]`.
pub fn shell_quote(s: &str) -> String {
    let plain = !s.is_empty()
        && s.chars()
            .all(|c| c.is_ascii_alphanumeric() || "_./=:,+-".contains(c));
    if plain {
        s.to_string()
    } else {
        format!("'{}'", s.replace('\'', r"'\''"))
    }
}

/// The command that reruns one case on one backend, shell-quoted, writing
/// to its own output folder (`<out>/repro/<case>-<backend>`), never over the
/// suite's scoreboard. Values go as `--key=value`, safe when they start with `-`.
pub fn repro(opts: &RunOptions, profile: &str, id: &str, b: BackendKind) -> String {
    let out = opts.out.join("repro").join(format!("{id}-{}", b.name()));
    let q = |p: &Path| shell_quote(&p.display().to_string());
    format!(
        "hpjudge run {} --filter={} --backend={} --profile={} --seed={} --out={} --dump-failing",
        q(&opts.manifest),
        shell_quote(id),
        b.name(),
        shell_quote(profile),
        opts.seed,
        q(&out)
    )
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
    let limit = inputs.thresholds.timeout(&lc.case.timeout).unwrap_or(120.0);
    let job = Job {
        task: Task::Case {
            case: Box::new(lc.clone()),
            backend: b,
        },
        scenes: lc
            .scene_paths()
            .into_iter()
            .filter_map(|p| Some((p.clone(), inputs.scenes.get(&p)?.text.clone())))
            .collect(),
        thresholds: inputs.thresholds.clone(),
        perf: inputs.perf.clone(),
        out: opts.out.clone(),
        goldens: inputs.root.join("GOLDENS"),
        seed: opts.seed,
        threads: opts.threads,
        mem_limit: opts.mem_limit,
        dump,
        bless: opts.bless,
        deadline_s: limit + DEADLINE_GRACE_S,
    };
    let end = run_child(
        &job,
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

/// Most `--threads` accepted: more only costs time spawning them.
pub const MAX_THREADS: usize = 1024;

/// Parses `--threads` (0 = one per logical CPU, at most [`MAX_THREADS`]).
pub fn parse_threads(s: &str) -> Result<usize, String> {
    let n: usize = s
        .trim()
        .parse()
        .map_err(|_| format!("{s:?} is not a thread count"))?;
    if n > MAX_THREADS {
        return Err(format!(
            "{n} threads is over the limit of {MAX_THREADS} (0 = one per logical CPU)"
        ));
    }
    Ok(n)
}

/// Writes one line to stdout; false once stdout is closed (a reader such as
/// `head` went away), so the run can stop quietly.
pub fn emit(line: &str) -> bool {
    let mut o = std::io::stdout().lock();
    writeln!(o, "{line}").and_then(|_| o.flush()).is_ok()
}

/// `hpjudge run`: the whole suite. Returns the finished scoreboard, whose
/// `complete` is false when the run stopped early (stdout closed).
pub fn run(opts: &RunOptions) -> Result<Scoreboard, JudgeInputError> {
    if opts.threads > MAX_THREADS {
        return Err(JudgeInputError::new(
            "--threads",
            "",
            format!("{} is over the limit of {MAX_THREADS}", opts.threads),
        ));
    }
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
    let out_at = out.display().to_string();
    if out.exists() && !out.is_dir() {
        return Err(JudgeInputError::new(
            &out_at,
            "",
            "exists and is not a directory",
        ));
    }
    std::fs::create_dir_all(out)
        .map_err(|e| JudgeInputError::new(&out_at, "", format!("cannot create: {e}")))?;
    let _lock = lock_out_dir(out, &format!("run {}", opts.manifest.display()))?;
    let threads = if opts.threads > 0 {
        opts.threads
    } else {
        env::logical_cpus()
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
        .filter(|c| !opts.bless || c.case.asserts.iter().any(|a| !a.goldens().is_empty()))
        .filter(|c| opts.partition.is_none_or(|p| p.contains(&c.case.id)))
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
    let mut board = Scoreboard {
        schema_version: SCHEMA_VERSION,
        hpjudge_version: env::VERSION.to_string(),
        manifest: opts.manifest.display().to_string(),
        complete: false,
        cases_total: total,
        cases_done: 0,
        stopped: None,
        partition: opts.partition,
        inputs: InputHashes {
            manifest_tree_sha256: inputs.manifest.tree_sha256.clone(),
            thresholds_sha256: th.sha256.clone(),
            scenes_sha256: combined_sha256(&inputs.scenes),
            manifest_files: inputs.manifest.files,
            scene_files: inputs.scenes.len(),
        },
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
    let bar = super::progress::bar(total, opts.json);
    let board_path = out.join("scoreboard.json");
    save(&mut board, &board_path)?;
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
                && !r.reason.starts_with(PERF_NOT_ENFORCED)
            {
                r.verdict = Verdict::Fail;
                r.reason = format!("--require-gpu: {}", r.reason);
            }
            let bad = matches!(r.verdict, Verdict::Fail | Verdict::Error | Verdict::Timeout);
            let unexpected = c.expect.is_some_and(|e| !r.verdict.matches(e));
            if !opts.bless && ((bad && c.expect.is_none()) || unexpected) {
                r.repro = repro(opts, &th.profile_name, &c.id, b);
                if opts.dump_failing && r.verdict != Verdict::Timeout {
                    let d = spawn_worker(&inputs, opts, lc, b, true);
                    r.artifacts = d.artifacts;
                }
            }
            let printed = opts.json || bar.suspend(|| print_row(&entry, &r));
            entry.results.push(r);
            bar.inc(1);
            if !printed {
                board.stopped = Some("stdout was closed (EPIPE); the run stopped".into());
                break;
            }
        }
        if !entry.results.is_empty() {
            board.cases.push(entry);
        }
        save(&mut board, &board_path)?;
        if board.stopped.is_some() {
            break;
        }
    }
    bar.finish_and_clear();
    board.complete = board.stopped.is_none();
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

/// Prints one result row; false when stdout is closed.
fn print_row(entry: &CaseEntry, r: &BackendResult) -> bool {
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
    emit(&format!(
        "{:<7} {:<44} {:<4} {:>7.2}s{exp}  {note}",
        r.verdict.name(),
        entry.id,
        r.backend.name(),
        r.wall_s
    ))
}

/// Prints the closing part of a human run: repro lines, then the summary
/// (and that the run is incomplete, when it is). Quiet once stdout is closed.
pub fn print_summary(board: &Scoreboard, out: &Path) {
    let mut lines = Vec::new();
    let repros: Vec<String> = board
        .cases
        .iter()
        .flat_map(|c| c.results.iter())
        .filter(|r| !r.repro.is_empty())
        .map(|r| format!("  {}", r.repro))
        .collect();
    if !repros.is_empty() {
        lines.push("\nrepro:".to_string());
        lines.extend(repros);
    }
    lines.push(format!(
        "\nscoreboard: {}",
        out.join("scoreboard.json").display()
    ));
    if !board.complete {
        lines.push(format!(
            "INCOMPLETE: {} of {} results ({})",
            board.cases_done,
            board.cases_total,
            board.stopped.as_deref().unwrap_or("stopped early")
        ));
    }
    lines.push(board.summary.line());
    for l in lines {
        if !emit(&l) {
            return;
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn repro_commands_quote_and_use_their_own_out_folder() {
        assert_eq!(shell_quote("a_b-1.x"), "a_b-1.x");
        assert_eq!(shell_quote("it's here"), r"'it'\''s here'");
        assert_eq!(shell_quote(""), "''");
        let opts = RunOptions {
            manifest: PathBuf::from("my tests/m.yaml"),
            out: PathBuf::from("out"),
            filter: None,
            backend: BackendFilter::All,
            threads: 0,
            seed: 3,
            json: false,
            junit: None,
            dump_failing: false,
            require_gpu: false,
            profile: None,
            thresholds: None,
            mem_limit: None,
            bless: false,
            partition: None,
        };
        let r = repro(&opts, "ci", "-odd", BackendKind::Gpu);
        assert_eq!(
            r,
            "hpjudge run 'my tests/m.yaml' --filter=-odd --backend=gpu --profile=ci --seed=3 --out=out/repro/-odd-gpu --dump-failing"
        );
    }

    #[test]
    fn thread_counts_over_the_limit_are_refused() {
        assert_eq!(parse_threads("0"), Ok(0));
        assert_eq!(parse_threads("1024"), Ok(1024));
        assert!(parse_threads("100000")
            .unwrap_err()
            .contains("over the limit"));
        assert!(parse_threads("-1").is_err());
    }

    #[test]
    fn progress_only_on_a_terminal_without_json_or_ci() {
        assert!(show_progress(false, false, true));
        assert!(!show_progress(true, false, true));
        assert!(!show_progress(false, true, true));
        assert!(!show_progress(false, false, false));
    }
}
