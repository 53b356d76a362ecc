//! What the judge hands a worker, and the worker process that runs it. The
//! judge resolves everything (the case as loaded, thresholds with the profile
//! applied, perf scenarios, the text of the case's scene files as hashed on
//! the scoreboard) and writes it to the worker's stdin as YAML: a worker never
//! re-reads the manifest, thresholds or scenes, so an edit during a run cannot
//! change a verdict, and no case id or path ever passes through argument parsing.
//! Workers die with the judge (parent-death signal) and end themselves at
//! their own deadline.

use std::collections::BTreeMap;
use std::io::{Read, Write};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use serde::{Deserialize, Serialize};

use super::manifest::LoadedCase;
use super::ops::BackendKind;
use super::perf::PerfScenarios;
use super::thresholds::Thresholds;

/// What one worker runs.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(tag = "type", rename_all = "snake_case")]
pub enum Task {
    /// One case on one backend.
    Case {
        case: Box<LoadedCase>,
        backend: BackendKind,
    },
    /// One perf scenario of `Job::perf`.
    Scenario { id: String },
}

/// Everything a worker needs, resolved by the judge.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Job {
    pub task: Task,
    /// Text of each scene file the case reads, as the judge read it at load.
    pub scenes: BTreeMap<PathBuf, String>,
    pub thresholds: Thresholds,
    pub perf: PerfScenarios,
    /// The run's output folder (artifacts go to `<out>/<case>/<backend>/`).
    pub out: PathBuf,
    /// GOLDENS/ of the project.
    pub goldens: PathBuf,
    pub seed: u32,
    /// Rayon threads (0 = one per logical CPU).
    pub threads: usize,
    pub mem_limit: Option<u64>,
    pub dump: bool,
    pub bless: bool,
    /// Seconds after which the worker ends itself (exit 124), whatever the
    /// judge does: the judge's own limit plus a grace.
    pub deadline_s: f64,
}

/// Extra seconds a worker gives itself past the judge's limit.
pub const DEADLINE_GRACE_S: f64 = 5.0;

/// How a child worker ended.
pub enum ChildEnd {
    /// Exited 0 and wrote its result file (its text).
    Done(String),
    /// Killed at the time limit.
    TimedOut,
    /// Anything else, described.
    Failed(String),
}

/// Runs `job` in `hpjudge worker --result FILE` (job on stdin, stderr to
/// `log`), killing it after `limit` seconds.
pub fn run_child(job: &Job, limit: f64, log_path: &Path, result_path: &Path) -> ChildEnd {
    let _ = std::fs::remove_file(result_path);
    let text = match serde_yaml::to_string(job) {
        Ok(t) => t,
        Err(e) => return ChildEnd::Failed(format!("cannot serialise the job: {e}")),
    };
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
        .arg("--result")
        .arg(result_path)
        .stdin(Stdio::piped())
        .stdout(Stdio::null())
        .stderr(log);
    die_with_parent(&mut cmd);
    let started = Instant::now();
    let mut child = match cmd.spawn() {
        Ok(c) => c,
        Err(e) => return ChildEnd::Failed(format!("cannot start a worker: {e}")),
    };
    if let Some(mut stdin) = child.stdin.take() {
        // A worker that dies before reading is reported by its exit status.
        let _ = stdin.write_all(text.as_bytes());
    }
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

/// The child gets SIGKILL when the judge dies, even by kill -9 (Linux
/// `PR_SET_PDEATHSIG`; the death signal follows the spawning thread, and the
/// judge spawns every worker from its main thread).
#[cfg(target_os = "linux")]
fn die_with_parent(cmd: &mut Command) {
    use std::os::unix::process::CommandExt;
    // SAFETY: getpid before fork; in the child only async-signal-safe calls.
    let parent = unsafe { libc::getpid() };
    unsafe {
        cmd.pre_exec(move || {
            if libc::prctl(libc::PR_SET_PDEATHSIG, libc::SIGKILL) != 0 {
                return Err(std::io::Error::last_os_error());
            }
            // The judge may have died between fork and prctl.
            if libc::getppid() != parent {
                libc::_exit(137);
            }
            Ok(())
        });
    }
}

#[cfg(not(target_os = "linux"))]
fn die_with_parent(_: &mut Command) {}

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
        (Some(124), _) => "ran past its own deadline (exit 124)".into(),
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

/// Reads a job from `input` (the worker's stdin).
pub fn read_job(mut input: impl Read) -> Result<Job, String> {
    let mut text = String::new();
    input
        .read_to_string(&mut text)
        .map_err(|e| format!("cannot read the job on stdin: {e}"))?;
    serde_yaml::from_str(&text).map_err(|e| format!("unreadable job on stdin: {e}"))
}

/// Ends this process with exit 124 once `seconds` have passed.
pub fn start_deadline(seconds: f64) {
    let d = if seconds.is_finite() && seconds > 0.0 {
        Duration::from_secs_f64(seconds.min(1e9))
    } else {
        Duration::from_secs(1)
    };
    std::thread::spawn(move || {
        std::thread::sleep(d);
        eprintln!(
            "hpjudge worker: past its own deadline of {:.1} s; ending",
            d.as_secs_f64()
        );
        std::process::exit(124);
    });
}
