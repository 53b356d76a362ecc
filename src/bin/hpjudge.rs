//! hpjudge: the online-judge CLI of hotpath. Results go to stdout, logs to
//! stderr. Exit codes: 0 all passed, 1 a case failed, errored or timed out
//! (or a perf regression), 2 unusable input.

use std::path::{Path, PathBuf};
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};

use hotpath::budget::{parse_size, MemBudget};
use hotpath::error::Error;
use hotpath::judge::artifacts::write_tensor;
use hotpath::judge::env;
use hotpath::judge::job::{run_child, ChildEnd, Job, Task, DEADLINE_GRACE_S};
use hotpath::judge::load::JudgeInputError;
use hotpath::judge::ops::{self, BackendKind, OpCtx};
use hotpath::judge::perf::{
    compare, missing_or_errored, read_pair, validate_compare_args, Change, PerfReport,
    PerfScenarios,
};
use hotpath::judge::runner::{self, load_inputs, print_summary, BackendFilter, RunOptions};
use hotpath::judge::scoreboard::Verdict;
use hotpath::judge::thresholds::Thresholds;
use hotpath::judge::worker;
use hotpath::real::Precision;
use hotpath::scene::SceneDoc;
use hotpath::tensor::Tensor;

/// hpjudge: runs hotpath's renderers on declarative cases and judges them.
#[derive(Parser, Debug)]
#[command(name = "hpjudge", version = env::VERSION, about, long_about = None)]
pub struct Cli {
    #[command(subcommand)]
    command: Cmd,
}

#[derive(clap::Args, Debug, Clone)]
struct Common {
    /// Rayon threads (0 = one per logical CPU; at most 1024).
    #[arg(long, default_value_t = 0, value_parser = runner::parse_threads)]
    threads: usize,
    /// Seed for every stochastic choice.
    #[arg(long, default_value_t = 0)]
    seed: u32,
    /// Memory budget per plan, e.g. 2G (default: 3/4 of available memory).
    #[arg(long, value_parser = parse_size)]
    mem_limit: Option<u64>,
}

#[derive(Subcommand, Debug)]
enum Cmd {
    /// Run a manifest's cases and write scoreboard.json and artifacts.
    Run {
        /// The manifest (default ./manifest.yaml).
        #[arg(default_value = "manifest.yaml")]
        manifest: PathBuf,
        /// Output folder.
        #[arg(long, default_value = "out")]
        out: PathBuf,
        /// Only cases whose id contains this.
        #[arg(long)]
        filter: Option<String>,
        /// Backends to run.
        #[arg(long, value_enum, default_value = "all")]
        backend: BackendFilter,
        #[command(flatten)]
        common: Common,
        /// Print the scoreboard as JSON on stdout instead of the table.
        #[arg(long)]
        json: bool,
        /// Also write JUnit XML here.
        #[arg(long)]
        junit: Option<PathBuf>,
        /// Re-run failing cases writing their inputs and per-ray tensors.
        #[arg(long)]
        dump_failing: bool,
        /// A GPU case that cannot run (no adapter) fails instead of skipping.
        #[arg(long)]
        require_gpu: bool,
        /// Device profile of thresholds.yaml (default: `ci` when CI is set, else `default`).
        #[arg(long)]
        profile: Option<String>,
        /// thresholds.yaml (default: found in the manifest's folder or above).
        #[arg(long)]
        thresholds: Option<PathBuf>,
    },
    /// Render one scene and write its output files (SCENES.md names).
    Render {
        scene: PathBuf,
        #[arg(long)]
        out: PathBuf,
        #[arg(long, value_enum, default_value = "cpu")]
        backend: BackendArg,
        #[arg(long, value_enum, default_value = "f32")]
        precision: PrecisionArg,
        /// Override a scene parameter: key=value (dotted paths allowed).
        #[arg(long = "set", value_name = "KEY=VALUE")]
        set: Vec<String>,
        /// Replay rays from a (N, 9) .npy written by --dump-failing.
        #[arg(long)]
        rays: Option<PathBuf>,
        /// dL/d rgb (H, W, 3) for renderers with gradients.
        #[arg(long)]
        grad_from: Option<PathBuf>,
        #[command(flatten)]
        common: Common,
    },
    /// List a manifest's cases (or the operation table with --ops).
    List {
        #[arg(default_value = "manifest.yaml")]
        manifest: PathBuf,
        #[arg(long)]
        ops: bool,
    },
    /// Validate a manifest, its includes, scenes, thresholds and perf scenarios without running.
    Check {
        #[arg(default_value = "manifest.yaml")]
        manifest: PathBuf,
        #[arg(long)]
        profile: Option<String>,
        #[arg(long)]
        thresholds: Option<PathBuf>,
    },
    /// Describe this machine: CPU, threads, OS, GPU adapters.
    Info {
        #[arg(long)]
        json: bool,
    },
    /// Run perf_scenarios.yaml and write perf.json (medians and spreads).
    Perf {
        #[arg(default_value = "perf_scenarios.yaml")]
        scenarios: PathBuf,
        #[arg(long, default_value = "out")]
        out: PathBuf,
        #[arg(long)]
        filter: Option<String>,
        #[arg(long)]
        json: bool,
        #[command(flatten)]
        common: Common,
    },
    /// Compare two perf.json or scoreboard.json files; exit 1 on a regression past the noise.
    Compare {
        base: PathBuf,
        new: PathBuf,
        /// Smallest relative change that can count.
        #[arg(long, default_value_t = 0.10)]
        threshold: f64,
        /// A change must also exceed this many times the relative spread.
        #[arg(long, default_value_t = 2.0)]
        noise_k: f64,
        #[arg(long)]
        json: bool,
    },
    /// Rewrite the goldens (GOLDENS/) of the selected cases from their outputs. Refused when CI is set.
    Bless {
        #[arg(default_value = "manifest.yaml")]
        manifest: PathBuf,
        #[arg(long)]
        filter: Option<String>,
        #[arg(long)]
        profile: Option<String>,
    },
    /// (internal) Run the job on stdin (one case or perf scenario, resolved
    /// by `run`, `perf` or `bless`) and write its result.
    #[command(hide = true)]
    Worker {
        #[arg(long)]
        result: PathBuf,
    },
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum BackendArg {
    Cpu,
    Gpu,
}

impl From<BackendArg> for BackendKind {
    fn from(b: BackendArg) -> Self {
        match b {
            BackendArg::Cpu => BackendKind::Cpu,
            BackendArg::Gpu => BackendKind::Gpu,
        }
    }
}

#[derive(Clone, Copy, Debug, clap::ValueEnum)]
enum PrecisionArg {
    F32,
    F64,
}

impl From<PrecisionArg> for Precision {
    fn from(p: PrecisionArg) -> Self {
        match p {
            PrecisionArg::F32 => Precision::F32,
            PrecisionArg::F64 => Precision::F64,
        }
    }
}

/// How a command ended, mapped to the exit code in one place.
enum Outcome {
    /// Everything passed.
    Ok,
    /// A case failed, errored or timed out; a regression; a render that failed at run time.
    Failed,
    /// Unusable input: bad YAML, missing file, unknown names.
    BadInput,
}

fn exit_code(o: Outcome) -> ExitCode {
    match o {
        Outcome::Ok => ExitCode::from(0),
        Outcome::Failed => ExitCode::from(1),
        Outcome::BadInput => ExitCode::from(2),
    }
}

fn budget(c: &Common) -> MemBudget {
    c.mem_limit
        .map_or_else(MemBudget::from_machine, MemBudget::fixed)
}

fn init_threads(n: usize) {
    if n > 0 {
        // Only fails if a pool exists already, which then keeps its size.
        let _ = rayon::ThreadPoolBuilder::new()
            .num_threads(n)
            .build_global();
    }
}

/// Mesa's Vulkan drivers print an error on every process start when
/// `XDG_RUNTIME_DIR` is unset; give them a private folder. Runs before any
/// thread exists.
fn quiet_mesa() {
    if std::env::var_os("XDG_RUNTIME_DIR").is_none() {
        #[cfg(unix)]
        let uid = {
            use std::os::unix::fs::MetadataExt;
            std::fs::metadata("/proc/self").map_or(0, |m| m.uid())
        };
        #[cfg(not(unix))]
        let uid = 0;
        let dir = std::env::temp_dir().join(format!("hpjudge-xdg-{uid}"));
        if std::fs::create_dir_all(&dir).is_ok() {
            #[cfg(unix)]
            {
                use std::os::unix::fs::PermissionsExt;
                let _ = std::fs::set_permissions(&dir, std::fs::Permissions::from_mode(0o700));
            }
            std::env::set_var("XDG_RUNTIME_DIR", &dir);
        }
    }
}

fn main() -> ExitCode {
    quiet_mesa();
    let filter = tracing_subscriber::EnvFilter::try_from_env("HPJUDGE_LOG")
        .unwrap_or_else(|_| tracing_subscriber::EnvFilter::new("warn"));
    tracing_subscriber::fmt()
        .with_env_filter(filter)
        .with_writer(std::io::stderr)
        .init();
    let cli = Cli::parse();
    match dispatch(cli) {
        Ok(o) => exit_code(o),
        Err(e) => {
            eprintln!("hpjudge: error: {e:#}");
            let bad_input = e.downcast_ref::<JudgeInputError>().is_some()
                || matches!(
                    e.downcast_ref::<Error>(),
                    Some(Error::InvalidInput { .. } | Error::Io { .. } | Error::OutOfMemory { .. })
                );
            exit_code(if bad_input {
                Outcome::BadInput
            } else {
                Outcome::Failed
            })
        }
    }
}

fn dispatch(cli: Cli) -> anyhow::Result<Outcome> {
    match cli.command {
        Cmd::Run {
            manifest,
            out,
            filter,
            backend,
            common,
            json,
            junit,
            dump_failing,
            require_gpu,
            profile,
            thresholds,
        } => {
            init_threads(common.threads);
            let opts = RunOptions {
                manifest,
                out,
                filter,
                backend,
                threads: common.threads,
                seed: common.seed,
                json,
                junit,
                dump_failing,
                require_gpu,
                profile,
                thresholds,
                mem_limit: common.mem_limit,
                bless: false,
            };
            let board = runner::run(&opts)?;
            if json {
                runner::emit(&serde_json::to_string_pretty(&board)?);
            } else {
                print_summary(&board, &opts.out);
            }
            Ok(if board.all_good() {
                Outcome::Ok
            } else {
                Outcome::Failed
            })
        }
        Cmd::Render {
            scene,
            out,
            backend,
            precision,
            set,
            rays,
            grad_from,
            common,
        } => {
            init_threads(common.threads);
            render(
                &scene,
                &out,
                backend.into(),
                precision.into(),
                &set,
                rays.as_deref(),
                grad_from.as_deref(),
                &common,
            )
        }
        Cmd::List { manifest, ops } => {
            if ops {
                for e in ops::table() {
                    println!("{:<32} {}", e.name, e.doc);
                }
                return Ok(Outcome::Ok);
            }
            let m = hotpath::judge::manifest::Manifest::load(&manifest)?;
            for c in &m.cases {
                let b: Vec<&str> = c.case.backends.iter().map(|b| b.name()).collect();
                println!(
                    "{:<44} {:<28} {:<8} {:?}  {}",
                    c.case.id,
                    c.case.op,
                    b.join(","),
                    c.case.size,
                    c.at()
                );
            }
            Ok(Outcome::Ok)
        }
        Cmd::Check {
            manifest,
            profile,
            thresholds,
        } => {
            let i = load_inputs(&manifest, thresholds.as_deref(), profile.as_deref())?;
            println!(
                "ok: {} cases, {} perf scenarios, profile {}, thresholds sha256 {}",
                i.manifest.cases.len(),
                i.perf.scenarios.len(),
                i.thresholds.profile_name,
                &i.thresholds.sha256[..16]
            );
            Ok(Outcome::Ok)
        }
        Cmd::Info { json } => {
            let gpu = hotpath::gpu::describe();
            let v = env::describe(
                rayon::current_num_threads(),
                0,
                "-",
                "-",
                "-",
                Some(gpu.clone()),
            );
            if json {
                println!("{}", serde_json::to_string_pretty(&v)?);
                return Ok(Outcome::Ok);
            }
            println!("hpjudge {}", env::VERSION);
            println!(
                "cpu:      {} ({} logical CPUs)",
                env::cpu_model(),
                env::logical_cpus()
            );
            println!("os:       {} {}", env::os_name(), std::env::consts::ARCH);
            println!(
                "backends: {} (WGPU_BACKEND)",
                gpu["backends"].as_str().unwrap_or("?")
            );
            let adapters = hotpath::gpu::adapters();
            if adapters.is_empty() {
                println!("gpu:      no adapter on these backends (install a Vulkan driver, e.g. mesa-vulkan-drivers)");
            }
            for a in &adapters {
                println!(
                    "gpu:      {} [{}, {}] driver {} {}",
                    a.name, a.backend, a.device_type, a.driver, a.driver_info
                );
            }
            if let Some(e) = gpu["error"].as_str() {
                println!("gpu error: {e}");
            }
            Ok(Outcome::Ok)
        }
        Cmd::Perf {
            scenarios,
            out,
            filter,
            json,
            common,
        } => perf(&scenarios, &out, filter.as_deref(), json, &common),
        Cmd::Compare {
            base,
            new,
            threshold,
            noise_k,
            json,
        } => {
            validate_compare_args(threshold, noise_k)?;
            let (b, n) = read_pair(&base, &new)?;
            let rows = compare(&b.metrics, &n.metrics, threshold, noise_k);
            let missing = missing_or_errored(&b, &n);
            let regressions = rows
                .iter()
                .filter(|r| r.verdict == Change::Regression)
                .count()
                + missing.len();
            if rows.is_empty() && missing.is_empty() {
                bail!(
                    "no metric of {} is in {}: nothing was compared",
                    base.display(),
                    new.display()
                );
            }
            if json {
                let v = serde_json::json!({"metrics": rows, "missing_or_errored": missing});
                println!("{}", serde_json::to_string_pretty(&v)?);
            } else {
                for m in &missing {
                    println!("{:<52} Regression: {}", m.id, m.why);
                }
                println!(
                    "{:<52} {:>12} {:>12} {:>8} {:>7}  verdict",
                    "metric", "base", "new", "change", "noise"
                );
                for r in &rows {
                    println!(
                        "{:<52} {:>12.4e} {:>12.4e} {:>7.1}% {:>6.1}%  {:?}",
                        r.key,
                        r.base,
                        r.new,
                        100.0 * r.change,
                        100.0 * r.noise,
                        r.verdict
                    );
                }
                println!("{} metrics compared, {regressions} regressions (threshold {threshold}, noise x{noise_k})", rows.len());
            }
            Ok(if regressions == 0 {
                Outcome::Ok
            } else {
                Outcome::Failed
            })
        }
        Cmd::Bless {
            manifest,
            filter,
            profile,
        } => bless(&manifest, filter.as_deref(), profile.as_deref()),
        Cmd::Worker { result } => {
            worker::serve(&result).map_err(anyhow::Error::msg)?;
            Ok(Outcome::Ok)
        }
    }
}

#[allow(clippy::too_many_arguments)]
fn render(
    scene: &Path,
    out: &Path,
    backend: BackendKind,
    precision: Precision,
    set: &[String],
    rays: Option<&Path>,
    grad_from: Option<&Path>,
    common: &Common,
) -> anyhow::Result<Outcome> {
    let doc = SceneDoc::load(scene, set)?;
    let renderer = doc.renderer()?.to_string();
    let name = format!("{renderer}.render");
    let op = ops::find(&name).ok_or_else(|| {
        Error::NotSupported(format!("renderer {renderer:?} has no `render` operation"))
    })?;
    let rays_t = rays
        .map(|p| Tensor::read_npy_within(p, budget(common)))
        .transpose()?;
    let mut params = serde_yaml::Mapping::new();
    if let Some(g) = grad_from {
        params.insert("grad_from".into(), g.display().to_string().into());
    }
    let params = serde_yaml::Value::Mapping(params);
    let root = scene.parent().unwrap_or(Path::new(".")).to_path_buf();
    let ctx = OpCtx {
        case_id: "render",
        scene: Some(&doc),
        params: &params,
        backend,
        precision,
        seed: common.seed,
        budget: budget(common),
        dump: false,
        rays: rays_t.as_ref(),
        root: &root,
    };
    let outputs = (op.run)(&ctx)?;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    for (n, t) in &outputs.tensors {
        for p in write_tensor(out, n, t)? {
            println!("{}", p.display());
        }
    }
    for (k, v) in &outputs.metrics {
        eprintln!("{k}: {v:.6e}");
    }
    Ok(Outcome::Ok)
}

fn perf(
    scenarios: &Path,
    out: &Path,
    filter: Option<&str>,
    json: bool,
    common: &Common,
) -> anyhow::Result<Outcome> {
    let perf = PerfScenarios::load(scenarios)?;
    let root = scenarios.parent().unwrap_or(Path::new("."));
    let root = if root.as_os_str().is_empty() {
        Path::new(".")
    } else {
        root
    };
    let th_path = root.join("thresholds.yaml");
    let (tf, _): (hotpath::judge::thresholds::ThresholdsFile, String) =
        hotpath::judge::load::load_yaml_typed(&th_path)?;
    let (profile, _) =
        hotpath::judge::thresholds::pick_profile(&tf, std::env::var_os("CI").is_some(), None);
    let th = Thresholds::load(&th_path, &profile)?;
    std::fs::create_dir_all(out)?;
    let mut results = Vec::new();
    for s in perf
        .scenarios
        .iter()
        .filter(|s| filter.is_none_or(|f| s.id.contains(f)))
    {
        let dir = out.join("perf").join(&s.id);
        std::fs::create_dir_all(&dir)?;
        let limit = th
            .timeout("perf")
            .or_else(|| th.timeout("default"))
            .unwrap_or(600.0);
        let job = Job {
            task: Task::Scenario { id: s.id.clone() },
            thresholds: th.clone(),
            perf: perf.clone(),
            out: out.to_path_buf(),
            goldens: root.join("GOLDENS"),
            seed: common.seed,
            threads: common.threads,
            mem_limit: common.mem_limit,
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
        if !json {
            print_scenario(&r);
        }
        results.push(r);
    }
    let threads = if common.threads > 0 {
        common.threads
    } else {
        env::logical_cpus()
    };
    let report = PerfReport {
        schema_version: 1,
        environment: env::describe(threads, common.seed, &profile, "-", &th.sha256, None),
        scenarios: results,
    };
    let path = out.join("perf.json");
    std::fs::write(&path, serde_json::to_string_pretty(&report)? + "\n")?;
    if json {
        println!("{}", serde_json::to_string_pretty(&report)?);
    } else {
        println!("perf report: {}", path.display());
    }
    let errors = report
        .scenarios
        .iter()
        .filter(|s| s.error.is_some())
        .count();
    Ok(if errors == 0 {
        Outcome::Ok
    } else {
        Outcome::Failed
    })
}

fn failed_scenario(
    s: &hotpath::judge::perf::Scenario,
    e: String,
) -> hotpath::judge::perf::ScenarioResult {
    hotpath::judge::perf::ScenarioResult {
        id: s.id.clone(),
        op: s.op.clone(),
        backend: s.backend,
        precision: s.precision,
        metrics: Default::default(),
        error: Some(e),
    }
}

fn print_scenario(r: &hotpath::judge::perf::ScenarioResult) {
    if let Some(e) = &r.error {
        println!("{:<32} ERROR {e}", r.id);
        return;
    }
    for (k, m) in &r.metrics {
        println!(
            "{:<32} {:<28} median {:>12.4e}  spread {:>5.1}%  n={}",
            r.id,
            k,
            m.median,
            100.0 * m.spread_rel,
            m.samples.len()
        );
    }
}

fn bless(manifest: &Path, filter: Option<&str>, profile: Option<&str>) -> anyhow::Result<Outcome> {
    if std::env::var_os("CI").is_some() {
        bail!("bless refuses to run when CI is set: goldens change only on request, reviewed");
    }
    // Each case runs in a worker, under the same limits as `run`.
    let opts = RunOptions {
        manifest: manifest.to_path_buf(),
        out: std::env::temp_dir().join(format!("hpjudge-bless-{}", std::process::id())),
        filter: filter.map(str::to_string),
        backend: BackendFilter::Cpu,
        threads: 0,
        seed: 0,
        json: true,
        junit: None,
        dump_failing: false,
        require_gpu: false,
        profile: profile.map(str::to_string),
        thresholds: None,
        mem_limit: None,
        bless: true,
    };
    let board = runner::run(&opts)?;
    let mut wrote = 0;
    for c in &board.cases {
        for r in &c.results {
            if r.verdict != Verdict::Pass {
                bail!("{}: {} {}", c.id, r.verdict.name(), r.reason);
            }
            for a in &r.artifacts {
                println!("blessed {a}");
                wrote += 1;
            }
        }
    }
    println!("{wrote} golden files written; review them with git diff before committing");
    Ok(Outcome::Ok)
}

#[cfg(test)]
mod tests {
    use super::*;
    use clap::CommandFactory;

    #[test]
    fn cli_definition_is_consistent() {
        Cli::command().debug_assert();
    }
}
