//! The worker: runs one case on one backend inside this process, evaluates
//! its assertions and writes artifacts. The runner re-executes `hpjudge` as a
//! worker per case, so a panic, abort or hang here costs one case, not the run.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_yaml::Value;

use super::artifacts::write_tensor;
use super::asserts::Evidence;
use super::job::{read_job, start_deadline, Task};
use super::manifest::{CaseSize, LoadedCase};
use super::ops::{self, BackendKind, OpCtx, OpEntry};
use super::perf::{MetricStats, PerfScenarios, Scenario, ScenarioResult};
use super::scoreboard::{BackendResult, Verdict};
use super::thresholds::{SizeProfile, Thresholds};
use crate::budget::MemBudget;
use crate::error::Error;
use crate::parallel::with_threads;
use crate::real::Precision;
use crate::scene::SceneDoc;
use crate::tensor::{Outputs, Tensor, TensorInfo};

/// How the reason of a case whose only checks are perf gates outside a perf
/// profile starts (a SKIP that `--require-gpu` leaves alone).
pub const PERF_NOT_ENFORCED: &str = "perf gates not enforced in profile";

/// What the worker needs besides the case.
pub struct WorkerEnv<'a> {
    pub thresholds: &'a Thresholds,
    /// The case's scene files as the judge read them ([`super::job::Job::scenes`]).
    pub scenes: &'a BTreeMap<PathBuf, String>,
    pub perf: &'a PerfScenarios,
    /// The run's output folder (artifacts go to `<out>/<case>/<backend>/`).
    pub out: &'a Path,
    /// GOLDENS/ of the project.
    pub goldens: &'a Path,
    pub seed: u32,
    pub budget: MemBudget,
    pub dump: bool,
    pub bless: bool,
}

/// One run (main or ref) fully resolved.
struct RunSpec {
    prefix: String,
    op: &'static OpEntry,
    scene: Option<SceneDoc>,
    params: Value,
    precision: Precision,
    backend: BackendKind,
    threads: usize,
}

/// The scene overrides of one run: the case's `set:`, then its `ci:`
/// overrides (ci size profile), then a ref's own `set:`.
pub fn sets_for(
    case_set: &BTreeMap<String, Value>,
    ci: Option<&BTreeMap<String, Value>>,
    extra: Option<&BTreeMap<String, Value>>,
) -> Vec<(String, Value)> {
    let mut v: Vec<(String, Value)> = case_set
        .iter()
        .map(|(k, x)| (k.clone(), x.clone()))
        .collect();
    v.extend(
        ci.into_iter()
            .flatten()
            .map(|(k, x)| (k.clone(), x.clone())),
    );
    v.extend(
        extra
            .into_iter()
            .flatten()
            .map(|(k, x)| (k.clone(), x.clone())),
    );
    v
}

/// The runs of a case, their scenes parsed from the judge's snapshot
/// (`scenes`), never from the files, which may have changed since.
fn resolve_runs(
    lc: &LoadedCase,
    backend: BackendKind,
    size: SizeProfile,
    scenes: &BTreeMap<PathBuf, String>,
) -> Result<Vec<RunSpec>, String> {
    let c = &lc.case;
    let ci = (size == SizeProfile::Ci).then_some(&c.ci);
    let load = |scene: &Option<String>,
                extra: Option<&BTreeMap<String, Value>>|
     -> Result<Option<SceneDoc>, String> {
        let Some(s) = scene else { return Ok(None) };
        let path = lc.dir().join(s);
        let text = scenes
            .get(&path)
            .ok_or_else(|| format!("{}: not in the judge's snapshot", path.display()))?;
        SceneDoc::load_text(&path, text, &sets_for(&c.set, ci, extra))
            .map(Some)
            .map_err(|e| e.to_string())
    };
    let find = |op: &str| ops::find(op).ok_or_else(|| format!("unknown operation {op:?}"));
    let mut runs = vec![RunSpec {
        prefix: String::new(),
        op: find(&c.op)?,
        scene: load(&c.scene, None)?,
        params: c.params.clone(),
        precision: c.precision,
        backend,
        threads: c.threads,
    }];
    for (name, r) in &c.refs {
        let scene = r.scene.clone().or_else(|| c.scene.clone());
        runs.push(RunSpec {
            prefix: format!("{name}."),
            op: find(r.op.as_deref().unwrap_or(&c.op))?,
            scene: load(&scene, r.set.as_ref())?,
            params: r.params.clone().unwrap_or_else(|| c.params.clone()),
            precision: r.precision.unwrap_or(c.precision),
            backend: r.backend.unwrap_or(backend),
            threads: r.threads.unwrap_or(c.threads),
        });
    }
    Ok(runs)
}

/// Runs one op once (in a pool of `threads` when non-zero); adds `wall_s`.
fn run_once(spec: &RunSpec, env: &WorkerEnv, case_id: &str, root: &Path) -> Result<Outputs, Error> {
    let ctx = OpCtx {
        case_id,
        scene: spec.scene.as_ref(),
        params: &spec.params,
        backend: spec.backend,
        precision: spec.precision,
        seed: env.seed,
        budget: env.budget,
        dump: env.dump,
        rays: None,
        root,
    };
    let t = Instant::now();
    let mut out = if spec.threads > 0 {
        with_threads(spec.threads, || spec.op.call(&ctx))
    } else {
        spec.op.call(&ctx)
    }?;
    out.metrics
        .insert("wall_s".into(), t.elapsed().as_secs_f64());
    Ok(out)
}

/// Runs `spec` `warmup + repeats` times and keeps the last outputs with
/// every metric replaced by its median over the repeats.
fn run_repeated(
    spec: &RunSpec,
    env: &WorkerEnv,
    id: &str,
    root: &Path,
    warmup: usize,
    repeats: usize,
) -> Result<(Outputs, BTreeMap<String, MetricStats>), Error> {
    for _ in 0..warmup {
        run_once(spec, env, id, root)?;
    }
    let mut samples: BTreeMap<String, Vec<f64>> = BTreeMap::new();
    let mut last = Outputs::default();
    for _ in 0..repeats.max(1) {
        last = run_once(spec, env, id, root)?;
        for (k, v) in &last.metrics {
            samples.entry(k.clone()).or_default().push(*v);
        }
    }
    let stats: BTreeMap<String, MetricStats> = samples
        .into_iter()
        .map(|(k, v)| (k, MetricStats::of(v)))
        .collect();
    for (k, s) in &stats {
        last.metrics.insert(k.clone(), s.median);
    }
    Ok((last, stats))
}

fn skip_or_error(e: &Error) -> Verdict {
    match e {
        Error::NotSupported(_) => Verdict::Skip,
        _ => Verdict::Error,
    }
}

/// Runs one case on one backend and judges it.
pub fn run_case(lc: &LoadedCase, backend: BackendKind, env: &WorkerEnv) -> BackendResult {
    let c = &lc.case;
    let mut res = BackendResult {
        backend,
        verdict: Verdict::Pass,
        reason: String::new(),
        checks: vec![],
        metrics: BTreeMap::new(),
        counters: BTreeMap::new(),
        tensors: BTreeMap::new(),
        artifacts: vec![],
        wall_s: 0.0,
        repro: String::new(),
    };
    let size = env.thresholds.profile.size;
    if c.size == CaseSize::Full && size == SizeProfile::Ci {
        res.verdict = Verdict::Skip;
        res.reason = format!(
            "size full: runs in a full-size profile, not {}",
            env.thresholds.profile_name
        );
        return res;
    }
    let runs = match resolve_runs(lc, backend, size, env.scenes) {
        Ok(r) => r,
        Err(e) => return errored(res, format!("cannot prepare the case: {e}")),
    };
    let root = lc.dir().to_path_buf();
    let mut tensors: BTreeMap<String, Tensor> = BTreeMap::new();
    let mut metrics: BTreeMap<String, f64> = BTreeMap::new();
    for spec in &runs {
        let r = match (&c.perf, spec.prefix.is_empty()) {
            (Some(p), true) => match env.perf.find(p) {
                Some(s) => run_repeated(spec, env, &c.id, &root, s.warmup, s.repeats).map(|x| x.0),
                None => return errored(res, format!("no perf scenario {p:?}")),
            },
            _ => run_once(spec, env, &c.id, &root),
        };
        let out = match r {
            Ok(o) => o,
            Err(e) => {
                let who = if spec.prefix.is_empty() {
                    "op".to_string()
                } else {
                    format!("ref {}", spec.prefix.trim_end_matches('.'))
                };
                res.verdict = skip_or_error(&e);
                res.reason = format!("{who} {}: {e}", spec.op.name);
                return res;
            }
        };
        if spec.prefix.is_empty() {
            res.counters = out.counters.clone();
            res.tensors = out
                .tensors
                .iter()
                .map(|(k, t)| (k.clone(), TensorInfo::from(t)))
                .collect();
        }
        for (k, v) in out.metrics {
            metrics.insert(format!("{}{k}", spec.prefix), v);
        }
        for (k, v) in out.counters {
            metrics.insert(format!("{}{k}", spec.prefix), v as f64);
        }
        for (k, t) in out.tensors {
            tensors.insert(format!("{}{k}", spec.prefix), t);
        }
    }
    res.metrics = metrics.clone();
    let dir = env.out.join(&c.id).join(backend.name());
    if let Err(e) = std::fs::create_dir_all(&dir) {
        return errored(res, format!("cannot create {}: {e}", dir.display()));
    }
    if env.bless {
        return bless(res, c, &tensors, env.goldens);
    }
    if env.dump {
        for spec in runs.iter().filter(|s| s.scene.is_some()) {
            let p = dir.join(format!("{}scene.yaml", spec.prefix));
            let text = spec
                .scene
                .as_ref()
                .map(|d| serde_yaml::to_string(&d.value).unwrap_or_default())
                .unwrap_or_default();
            match std::fs::write(&p, text) {
                Ok(()) => res.artifacts.push(rel(env.out, &p)),
                Err(e) => return errored(res, format!("cannot write {}: {e}", p.display())),
            }
        }
    }
    let ev = Evidence {
        tensors: &tensors,
        metrics: &metrics,
        goldens: env.goldens,
        thresholds: env.thresholds,
    };
    for (i, a) in c.asserts.iter().enumerate() {
        match a.evaluate(&ev, env.thresholds.profile.enforce_perf) {
            Ok(ch) => {
                if !ch.passed {
                    res.verdict = Verdict::Fail;
                }
                res.checks.push(ch);
            }
            Err(e) => return errored(res, format!("assert[{i}] ({}): {e}", a.kind())),
        }
    }
    let unenforced: Vec<String> = res
        .checks
        .iter()
        .filter(|k| !k.enforced)
        .map(|k| k.message.clone())
        .collect();
    if res.verdict == Verdict::Pass
        && !unenforced.is_empty()
        && unenforced.len() == res.checks.len()
    {
        res.verdict = Verdict::Skip;
        res.reason = format!(
            "{PERF_NOT_ENFORCED} {}: {}",
            env.thresholds.profile_name,
            unenforced.join("; ")
        );
    }
    let keep_refs = env.dump || res.verdict != Verdict::Pass;
    for (name, t) in &tensors {
        if name.contains('.') && !keep_refs {
            continue;
        }
        match write_tensor(&dir, name, t) {
            Ok(paths) => res.artifacts.extend(paths.iter().map(|p| rel(env.out, p))),
            Err(e) => return errored(res, format!("artifact {name}: {e}")),
        }
    }
    res
}

fn rel(base: &Path, p: &Path) -> String {
    p.strip_prefix(base).unwrap_or(p).display().to_string()
}

fn errored(mut res: BackendResult, msg: String) -> BackendResult {
    res.verdict = Verdict::Error;
    res.reason = msg;
    res
}

/// `hpjudge bless`: writes the `a` side of every golden comparison, each to
/// a `.part` file first, then renames them all: a case that dies part way
/// leaves its old goldens whole.
fn bless(
    mut res: BackendResult,
    c: &super::manifest::Case,
    tensors: &BTreeMap<String, Tensor>,
    goldens: &Path,
) -> BackendResult {
    let mut parts = vec![];
    for a in &c.asserts {
        for (name, path) in a.goldens() {
            let Some(t) = tensors.get(&name) else {
                return errored(res, format!("bless: no output {name:?}"));
            };
            let p = goldens.join(&path);
            let part = p.with_extension("npy.part");
            if let Some(parent) = p.parent() {
                if let Err(e) = std::fs::create_dir_all(parent) {
                    return errored(res, format!("bless: {}: {e}", parent.display()));
                }
            }
            if let Err(e) = t.write_npy(&part) {
                return errored(res, format!("bless: {e}"));
            }
            parts.push((part, p));
        }
    }
    for (part, p) in parts {
        if let Err(e) = std::fs::rename(&part, &p) {
            return errored(res, format!("bless: {}: {e}", p.display()));
        }
        res.artifacts.push(p.display().to_string());
    }
    res
}

/// Runs one perf scenario (warm-up discarded) and summarises its metrics.
pub fn run_scenario(s: &Scenario, perf: &PerfScenarios, env: &WorkerEnv) -> ScenarioResult {
    let mut r = ScenarioResult {
        id: s.id.clone(),
        op: s.op.clone(),
        backend: s.backend,
        precision: s.precision,
        metrics: BTreeMap::new(),
        error: None,
    };
    let spec = (|| -> Result<RunSpec, String> {
        let op = ops::find(&s.op).ok_or_else(|| format!("unknown operation {:?}", s.op))?;
        let sets: Vec<(String, Value)> =
            s.set.iter().map(|(k, v)| (k.clone(), v.clone())).collect();
        let scene = match &s.scene {
            Some(p) => {
                Some(SceneDoc::load_values(&perf.dir().join(p), &sets).map_err(|e| e.to_string())?)
            }
            None => None,
        };
        Ok(RunSpec {
            prefix: String::new(),
            op,
            scene,
            params: s.params.clone(),
            precision: s.precision,
            backend: s.backend,
            threads: 0,
        })
    })();
    match spec.and_then(|sp| {
        run_repeated(&sp, env, &s.id, perf.dir(), s.warmup, s.repeats).map_err(|e| e.to_string())
    }) {
        Ok((_, stats)) => {
            r.metrics = stats
                .into_iter()
                .filter(|(k, _)| s.metrics.is_empty() || s.metrics.contains(k) || k == "wall_s")
                .collect();
        }
        Err(e) => r.error = Some(e),
    }
    r
}

/// `hpjudge worker`: reads the job on stdin, ends itself at the job's
/// deadline, runs the case or scenario and writes the result to `result`.
pub fn serve(result: &Path) -> Result<(), String> {
    let job = read_job(std::io::stdin().lock())?;
    start_deadline(job.deadline_s);
    if job.threads > 0 {
        // Only fails if a pool exists already, which then keeps its size.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(job.threads)
            .build_global();
    }
    let wenv = WorkerEnv {
        thresholds: &job.thresholds,
        scenes: &job.scenes,
        perf: &job.perf,
        out: &job.out,
        goldens: &job.goldens,
        seed: job.seed,
        budget: job
            .mem_limit
            .map_or_else(MemBudget::from_machine, MemBudget::fixed),
        dump: job.dump,
        bless: job.bless,
    };
    let text = match &job.task {
        Task::Case { case, backend } => serde_json::to_string(&run_case(case, *backend, &wenv)),
        Task::Scenario { id } => {
            let s = job
                .perf
                .find(id)
                .ok_or_else(|| format!("no perf scenario {id:?}"))?;
            serde_json::to_string(&run_scenario(s, &job.perf, &wenv))
        }
    }
    .map_err(|e| format!("cannot serialise the result: {e}"))?;
    std::fs::write(result, text).map_err(|e| format!("writing {}: {e}", result.display()))
}

/// The output folder of a case on a backend.
pub fn case_dir(out: &Path, id: &str, backend: BackendKind) -> PathBuf {
    out.join(id).join(backend.name())
}
