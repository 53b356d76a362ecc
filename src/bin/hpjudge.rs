//! hpjudge: the online-judge CLI of hotpath. Results go to stdout, logs to
//! stderr. Exit codes: 0 all passed, 1 a case failed, errored or timed out
//! (or a perf regression), 2 unusable input.

use std::path::PathBuf;
use std::process::ExitCode;

use anyhow::{bail, Context};
use clap::{Parser, Subcommand};

use hotpath::budget::{parse_size, MemBudget};
use hotpath::error::Error;
use hotpath::judge::artifacts::{write_png, write_tensor};
use hotpath::judge::junit::to_junit;
use hotpath::judge::load::JudgeInputError;
use hotpath::judge::manifest::Manifest;
use hotpath::judge::ops::{self, BackendKind};
use hotpath::judge::partition::{parse_partition, Partition};
use hotpath::judge::perf::{
    compare, missing_or_errored, read_pair, validate_compare_args, Change, ScenarioResult,
};
use hotpath::judge::render::{self, RenderRequest};
use hotpath::judge::runner::{self, load_inputs, print_summary, BackendFilter, RunOptions};
use hotpath::judge::scoreboard::Verdict;
use hotpath::judge::worker;
use hotpath::judge::{env, perf_run};
use hotpath::judge::{frames, merge, plot, progress, report};
use hotpath::real::Precision;

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
    Run(RunArgs),
    /// Render one scene and write its output files (SCENES.md names).
    Render(RenderArgs),
    /// List a manifest's cases (or the operation table with --ops).
    List(ListArgs),
    /// Validate a manifest, its includes, scenes, thresholds and perf scenarios without running.
    Check(CheckArgs),
    /// Describe this machine: CPU, threads, OS, GPU adapters.
    Info(InfoArgs),
    /// Run perf_scenarios.yaml and write perf.json (medians and spreads).
    Perf(PerfArgs),
    /// Compare two perf.json or scoreboard.json files; exit 1 on a regression past the noise.
    Compare(CompareArgs),
    /// Rewrite the goldens (GOLDENS/) of the selected cases from their outputs. Refused when CI is set.
    Bless(BlessArgs),
    /// Merge the scoreboards of a sharded run (`run --partition K/N`) into one.
    Merge(MergeArgs),
    /// Write OUT_DIR/report.html: one static page of a run's verdicts, images and plots.
    Report(ReportArgs),
    /// Draw a chart (YAML or JSON: title, x_label, y_label, log_x, log_y, series) as PNG or SVG.
    Plot(PlotArgs),
    /// (internal) Run one case or perf scenario; used by `run` and `perf`.
    #[command(hide = true)]
    Worker(WorkerArgs),
}

#[derive(clap::Args, Debug)]
struct RunArgs {
    /// The manifest (default ./manifest.yaml).
    #[arg(default_value = "manifest.yaml")]
    manifest: PathBuf,
    /// Output folder.
    #[arg(long, default_value = "out")]
    out: PathBuf,
    /// Only cases whose id contains this.
    #[arg(long, allow_hyphen_values = true)]
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
    /// Run only shard K of N (cases assigned by a hash of their id; see `merge`).
    #[arg(long, value_name = "K/N", value_parser = parse_partition)]
    partition: Option<Partition>,
}

#[derive(clap::Args, Debug)]
struct MergeArgs {
    /// The shards' scoreboard.json files, one per shard.
    #[arg(required = true)]
    boards: Vec<PathBuf>,
    /// Where to write the merged scoreboard.
    #[arg(short = 'o', long)]
    out: PathBuf,
    /// Also write JUnit XML here.
    #[arg(long)]
    junit: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct ReportArgs {
    /// A run's output folder (holding scoreboard.json).
    out_dir: PathBuf,
    /// Where to write the page (default OUT_DIR/report.html).
    #[arg(short = 'o', long)]
    output: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct PlotArgs {
    /// The chart, YAML or JSON.
    chart: PathBuf,
    /// The file to write: `.svg` or `.png`.
    #[arg(short = 'o', long)]
    out: PathBuf,
}

#[derive(clap::Args, Debug)]
struct RenderArgs {
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
    /// A parameter of the renderer's `render` operation, as in a manifest case's
    /// `params:`: key=value (`hpjudge list --ops` names them; e.g. voxels `cast=lanes`, `beam=true`).
    #[arg(long = "param", value_name = "KEY=VALUE")]
    param: Vec<String>,
    /// Replay rays from a (N, 9) .npy written by --dump-failing.
    #[arg(long)]
    rays: Option<PathBuf>,
    /// dL/d rgb (H, W, 3) for renderers with gradients.
    #[arg(long)]
    grad_from: Option<PathBuf>,
    /// Render every frame of the scene's NeRF camera file (`camera: {type: nerf}`) into OUT/frame_IIII/.
    #[arg(long)]
    all_frames: bool,
    #[command(flatten)]
    common: Common,
}

#[derive(clap::Args, Debug)]
struct ListArgs {
    #[arg(default_value = "manifest.yaml")]
    manifest: PathBuf,
    #[arg(long)]
    ops: bool,
}

#[derive(clap::Args, Debug)]
struct CheckArgs {
    #[arg(default_value = "manifest.yaml")]
    manifest: PathBuf,
    #[arg(long)]
    profile: Option<String>,
    #[arg(long)]
    thresholds: Option<PathBuf>,
}

#[derive(clap::Args, Debug)]
struct InfoArgs {
    #[arg(long)]
    json: bool,
}

#[derive(clap::Args, Debug)]
struct PerfArgs {
    #[arg(default_value = "perf_scenarios.yaml")]
    scenarios: PathBuf,
    #[arg(long, default_value = "out")]
    out: PathBuf,
    #[arg(long, allow_hyphen_values = true)]
    filter: Option<String>,
    #[arg(long)]
    json: bool,
    #[command(flatten)]
    common: Common,
}

#[derive(clap::Args, Debug)]
struct CompareArgs {
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
}

#[derive(clap::Args, Debug)]
struct BlessArgs {
    #[arg(default_value = "manifest.yaml")]
    manifest: PathBuf,
    #[arg(long, allow_hyphen_values = true)]
    filter: Option<String>,
    #[arg(long)]
    profile: Option<String>,
}

#[derive(clap::Args, Debug)]
struct WorkerArgs {
    /// Where the worker writes its result (the job comes on stdin).
    #[arg(long)]
    result: PathBuf,
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
        Cmd::Run(a) => cmd_run(a),
        Cmd::Render(a) => cmd_render(&a),
        Cmd::List(a) => cmd_list(&a),
        Cmd::Check(a) => cmd_check(&a),
        Cmd::Info(a) => cmd_info(&a),
        Cmd::Perf(a) => cmd_perf(&a),
        Cmd::Compare(a) => cmd_compare(&a),
        Cmd::Bless(a) => cmd_bless(&a),
        Cmd::Merge(a) => cmd_merge(&a),
        Cmd::Report(a) => cmd_report(&a),
        Cmd::Plot(a) => cmd_plot(&a),
        Cmd::Worker(a) => cmd_worker(&a),
    }
}

/// `hpjudge run`: the suite, its table (or JSON) and the summary line.
fn cmd_run(a: RunArgs) -> anyhow::Result<Outcome> {
    init_threads(a.common.threads);
    let opts = RunOptions {
        manifest: a.manifest,
        out: a.out,
        filter: a.filter,
        backend: a.backend,
        threads: a.common.threads,
        seed: a.common.seed,
        json: a.json,
        junit: a.junit,
        dump_failing: a.dump_failing,
        require_gpu: a.require_gpu,
        profile: a.profile,
        thresholds: a.thresholds,
        mem_limit: a.common.mem_limit,
        bless: false,
        partition: a.partition,
    };
    let board = runner::run(&opts)?;
    if opts.json {
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

/// `hpjudge render`: one scene through its renderer's `render` operation;
/// prints the files written, metrics on stderr.
fn cmd_render(a: &RenderArgs) -> anyhow::Result<Outcome> {
    init_threads(a.common.threads);
    let req = RenderRequest {
        scene: &a.scene,
        backend: a.backend.into(),
        precision: a.precision.into(),
        set: &a.set,
        params: &a.param,
        rays: a.rays.as_deref(),
        grad_from: a.grad_from.as_deref(),
        seed: a.common.seed,
        budget: budget(&a.common),
    };
    let out = &a.out;
    std::fs::create_dir_all(out).with_context(|| format!("creating {}", out.display()))?;
    if a.all_frames {
        let n = frames::render_all(&req, out, |p| println!("{}", p.display()))?;
        eprintln!("{n} frames rendered");
        return Ok(Outcome::Ok);
    }
    let follower = progress::follow(&format!("rendering {}", a.scene.display()), false);
    let outputs = render::render(&req);
    drop(follower);
    let outputs = outputs?;
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

/// `hpjudge list`: a manifest's cases, or the operation table.
fn cmd_list(a: &ListArgs) -> anyhow::Result<Outcome> {
    if a.ops {
        for e in ops::table() {
            println!("{:<32} {:<22} {}", e.name, e.support.describe(), e.doc);
        }
        return Ok(Outcome::Ok);
    }
    let m = Manifest::load(&a.manifest)?;
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

/// `hpjudge check`: loads and validates everything a run would, runs nothing.
fn cmd_check(a: &CheckArgs) -> anyhow::Result<Outcome> {
    let i = load_inputs(&a.manifest, a.thresholds.as_deref(), a.profile.as_deref())?;
    println!(
        "ok: {} cases, {} perf scenarios, profile {}, thresholds sha256 {}",
        i.manifest.cases.len(),
        i.perf.scenarios.len(),
        i.thresholds.profile_name,
        &i.thresholds.sha256[..16]
    );
    Ok(Outcome::Ok)
}

/// `hpjudge info`: CPU, threads, OS and GPU adapters.
fn cmd_info(a: &InfoArgs) -> anyhow::Result<Outcome> {
    let gpu = hotpath::gpu::describe();
    let v = env::describe(
        rayon::current_num_threads(),
        0,
        "-",
        "-",
        "-",
        Some(gpu.clone()),
    );
    if a.json {
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
    if let Some(f) = gpu["shader_f64"].as_bool() {
        println!("gpu f64:  {f} (the voxel beam pre-pass needs it)");
    }
    if let Some(e) = gpu["error"].as_str() {
        println!("gpu error: {e}");
    }
    Ok(Outcome::Ok)
}

/// `hpjudge perf`: every scenario in a worker, perf.json written.
fn cmd_perf(a: &PerfArgs) -> anyhow::Result<Outcome> {
    let (report, path) = perf_run::run_scenarios(
        &a.scenarios,
        &a.out,
        a.filter.as_deref(),
        a.common.threads,
        a.common.seed,
        a.common.mem_limit,
        a.json,
        |r| {
            if !a.json {
                print_scenario(r);
            }
        },
    )
    .map_err(|e| match e {
        // Unusable input keeps its type: exit code 2.
        perf_run::PerfRunError::Input(i) => anyhow::Error::new(i),
        e => anyhow::Error::new(e),
    })?;
    if a.json {
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

fn print_scenario(r: &ScenarioResult) {
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

/// `hpjudge compare`: each metric's change; exit 1 on a regression.
fn cmd_compare(a: &CompareArgs) -> anyhow::Result<Outcome> {
    let (threshold, noise_k) = (a.threshold, a.noise_k);
    validate_compare_args(threshold, noise_k)?;
    let (b, n) = read_pair(&a.base, &a.new)?;
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
            a.base.display(),
            a.new.display()
        );
    }
    if a.json {
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

/// `hpjudge bless`: rewrites the selected cases' goldens (refused under CI).
fn cmd_bless(a: &BlessArgs) -> anyhow::Result<Outcome> {
    if std::env::var_os("CI").is_some() {
        bail!("bless refuses to run when CI is set: goldens change only on request, reviewed");
    }
    // Each case runs in a worker, under the same limits as `run`.
    let opts = RunOptions {
        manifest: a.manifest.clone(),
        out: std::env::temp_dir().join(format!("hpjudge-bless-{}", std::process::id())),
        filter: a.filter.clone(),
        backend: BackendFilter::Cpu,
        threads: 0,
        seed: 0,
        json: true,
        junit: None,
        dump_failing: false,
        require_gpu: false,
        profile: a.profile.clone(),
        thresholds: None,
        mem_limit: None,
        bless: true,
        partition: None,
    };
    let board = runner::run(&opts)?;
    let _ = std::fs::remove_dir_all(&opts.out);
    let (mut wrote, mut failed) = (0, vec![]);
    for c in &board.cases {
        for r in &c.results {
            if r.verdict != Verdict::Pass {
                failed.push(format!("{}: {} {}", c.id, r.verdict.name(), r.reason));
            }
            for f in &r.artifacts {
                println!("blessed {f}");
                wrote += 1;
            }
        }
    }
    println!("{wrote} golden files written; review them with git diff before committing");
    if !failed.is_empty() {
        bail!(
            "{} cases wrote no goldens (their old goldens are untouched):\n{}",
            failed.len(),
            failed.join("\n")
        );
    }
    Ok(Outcome::Ok)
}

/// `hpjudge merge`: the shards' boards as one; exit 1 when a case failed.
fn cmd_merge(a: &MergeArgs) -> anyhow::Result<Outcome> {
    let boards = a
        .boards
        .iter()
        .map(|p| Ok((p.display().to_string(), merge::read_board(p)?)))
        .collect::<Result<Vec<_>, JudgeInputError>>()?;
    let board = merge::merge(&boards)?;
    board
        .write_atomic(&a.out)
        .with_context(|| format!("writing {}", a.out.display()))?;
    if let Some(j) = &a.junit {
        std::fs::write(j, to_junit(&board)).with_context(|| format!("writing {}", j.display()))?;
    }
    println!("merged {} shards: {}", boards.len(), a.out.display());
    println!("{}", board.summary.line());
    Ok(if board.all_good() {
        Outcome::Ok
    } else {
        Outcome::Failed
    })
}

/// `hpjudge report`: the run's static HTML page.
fn cmd_report(a: &ReportArgs) -> anyhow::Result<Outcome> {
    let out = a
        .output
        .clone()
        .unwrap_or_else(|| a.out_dir.join("report.html"));
    let html = report::build(&a.out_dir)?;
    std::fs::write(&out, html).with_context(|| format!("writing {}", out.display()))?;
    println!("{}", out.display());
    Ok(Outcome::Ok)
}

/// `hpjudge plot`: one chart file drawn with axes and a legend.
fn cmd_plot(a: &PlotArgs) -> anyhow::Result<Outcome> {
    let chart = plot::load_chart(&a.chart)?;
    match a.out.extension().and_then(|e| e.to_str()) {
        Some("svg") => std::fs::write(&a.out, plot::render_svg(&chart)?)
            .with_context(|| format!("writing {}", a.out.display()))?,
        Some("png") => {
            let t = plot::render(&chart)?;
            let s = t.shape();
            write_png(&a.out, s[0], s[1], &t.to_f64_vec())?;
        }
        _ => bail!("{}: the output must end in .svg or .png", a.out.display()),
    }
    println!("{}", a.out.display());
    Ok(Outcome::Ok)
}

/// `hpjudge worker` (internal): one case or scenario, its result as JSON in `--result`.
fn cmd_worker(a: &WorkerArgs) -> anyhow::Result<Outcome> {
    worker::serve(&a.result).map_err(anyhow::Error::msg)?;
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
