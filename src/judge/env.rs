//! The environment a run is recorded with: CPU, threads, OS, GPU adapter,
//! git revision.

use serde_json::{json, Value};

/// The git revision this binary was built from (build.rs), or "unknown".
pub const GIT_REVISION: &str = match option_env!("HOTPATH_GIT_REVISION") {
    Some(r) => r,
    None => "unknown",
};

/// `hpjudge --version`: package version and git revision (build.rs sets
/// `HOTPATH_VERSION_LINE`; "unknown" revision outside a git checkout).
pub const VERSION: &str = match option_env!("HOTPATH_VERSION_LINE") {
    Some(v) => v,
    None => env!("CARGO_PKG_VERSION"),
};

/// The CPU model name from /proc/cpuinfo.
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("model name"))
                .and_then(|l| l.split(':').nth(1))
                .map(|s| s.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

/// The OS name from /etc/os-release, else the target OS.
pub fn os_name() -> String {
    std::fs::read_to_string("/etc/os-release")
        .ok()
        .and_then(|s| {
            s.lines()
                .find(|l| l.starts_with("PRETTY_NAME="))
                .map(|l| l["PRETTY_NAME=".len()..].trim_matches('"').to_string())
        })
        .unwrap_or_else(|| std::env::consts::OS.to_string())
}

/// Logical CPUs the process may use.
pub fn logical_cpus() -> usize {
    std::thread::available_parallelism()
        .map(|n| n.get())
        .unwrap_or(1)
}

/// The environment block of the scoreboard and perf.json.
pub fn describe(
    threads: usize,
    seed: u32,
    profile: &str,
    size: &str,
    thresholds_sha256: &str,
    gpu: Option<Value>,
) -> Value {
    json!({
        "cpu": cpu_model(),
        "logical_cpus": logical_cpus(),
        "threads": threads,
        "os": os_name(),
        "arch": std::env::consts::ARCH,
        "git_revision": GIT_REVISION,
        "seed": seed,
        "profile": profile,
        "size": size,
        "thresholds_sha256": thresholds_sha256,
        "gpu": gpu,
    })
}
