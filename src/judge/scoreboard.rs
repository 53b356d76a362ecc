//! `scoreboard.json`: versioned (`schema_version` first), snake_case keys,
//! cases sorted by id, environment recorded. Written atomically (temp file +
//! rename) after every case, so a crash never loses the board. Documented in
//! docs/scoreboard.md.

use std::collections::BTreeMap;
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::asserts::Check;
use super::manifest::Expect;
use super::ops::BackendKind;
use super::partition::Partition;
use crate::tensor::TensorInfo;

/// The scoreboard's schema version (2: `complete`, `cases_total`,
/// `cases_done`, `stopped`, `inputs`).
pub const SCHEMA_VERSION: u32 = 2;

/// Scoreboard schema versions `compare` reads.
pub const KNOWN_SCHEMA_VERSIONS: [u32; 2] = [1, 2];

/// SHA-256 of what decided the verdicts.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
pub struct InputHashes {
    /// Over every manifest file of the include tree (path and content, in load order).
    pub manifest_tree_sha256: String,
    pub thresholds_sha256: String,
    /// Over every scene file the selected cases name (path and content, sorted by path).
    pub scenes_sha256: String,
    pub manifest_files: usize,
    pub scene_files: usize,
}

/// What happened to one case on one backend. A judge bug is never a FAIL.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq, PartialOrd, Ord)]
#[serde(rename_all = "UPPERCASE")]
pub enum Verdict {
    /// Every check passed.
    Pass,
    /// A check failed: the output is wrong.
    Fail,
    /// The case could not be judged: bad case input, a crash, a panic.
    Error,
    /// The worker ran past the time limit and was killed.
    Timeout,
    /// Not run, with a reason (no GPU, size profile).
    Skip,
}

impl Verdict {
    pub fn name(self) -> &'static str {
        match self {
            Verdict::Pass => "PASS",
            Verdict::Fail => "FAIL",
            Verdict::Error => "ERROR",
            Verdict::Timeout => "TIMEOUT",
            Verdict::Skip => "SKIP",
        }
    }

    /// Whether this verdict is what a self-test case expects.
    pub fn matches(self, e: Expect) -> bool {
        matches!(
            (self, e),
            (Verdict::Pass, Expect::Pass)
                | (Verdict::Fail, Expect::Fail)
                | (Verdict::Error, Expect::Error)
                | (Verdict::Timeout, Expect::Timeout)
                | (Verdict::Skip, Expect::Skip)
        )
    }
}

/// One case on one backend.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct BackendResult {
    pub backend: BackendKind,
    pub verdict: Verdict,
    /// Why it was skipped, errored or timed out; empty on PASS/FAIL.
    #[serde(default)]
    pub reason: String,
    #[serde(default)]
    pub checks: Vec<Check>,
    #[serde(default)]
    pub metrics: BTreeMap<String, f64>,
    #[serde(default)]
    pub counters: BTreeMap<String, u64>,
    /// Output tensors of the main run (dtype, shape).
    #[serde(default)]
    pub tensors: BTreeMap<String, TensorInfo>,
    /// Artifact files, relative to the output folder.
    #[serde(default)]
    pub artifacts: Vec<String>,
    /// Seconds the worker ran (process start to exit).
    #[serde(default)]
    pub wall_s: f64,
    /// A command that reruns just this.
    #[serde(default)]
    pub repro: String,
}

/// One case, all backends.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct CaseEntry {
    pub id: String,
    pub op: String,
    #[serde(default)]
    pub scene: Option<String>,
    /// `file:line` of the case in its manifest.
    pub defined_at: String,
    #[serde(default)]
    pub expect: Option<Expect>,
    pub results: Vec<BackendResult>,
}

/// Counts over every (case, backend) result.
#[derive(Clone, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
pub struct Summary {
    pub passed: u64,
    pub failed: u64,
    pub errored: u64,
    pub timed_out: u64,
    pub skipped: u64,
}

impl Summary {
    /// Counts a result. A self-test case whose verdict is the one it expects
    /// counts as passed; any other verdict of it counts as failed.
    pub fn add(&mut self, v: Verdict, expect: Option<Expect>) {
        if let Some(e) = expect {
            if v.matches(e) {
                self.passed += 1;
            } else {
                self.failed += 1;
            }
            return;
        }
        match v {
            Verdict::Pass => self.passed += 1,
            Verdict::Fail => self.failed += 1,
            Verdict::Error => self.errored += 1,
            Verdict::Timeout => self.timed_out += 1,
            Verdict::Skip => self.skipped += 1,
        }
    }

    /// The plain closing line: `N passed, N failed, N skipped` (errors and
    /// timeouts count as failed).
    pub fn line(&self) -> String {
        format!(
            "{} passed, {} failed, {} skipped",
            self.passed,
            self.failed + self.errored + self.timed_out,
            self.skipped
        )
    }

    pub fn all_good(&self) -> bool {
        self.failed == 0 && self.errored == 0 && self.timed_out == 0
    }
}

/// The whole file.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Scoreboard {
    pub schema_version: u32,
    pub hpjudge_version: String,
    pub manifest: String,
    /// True only once every selected (case, backend) has a result; a run
    /// stopped by a closed stdout, a signal or kill -9 leaves `false`.
    #[serde(default)]
    pub complete: bool,
    /// (case, backend) results the run selected.
    #[serde(default)]
    pub cases_total: u64,
    /// (case, backend) results written so far.
    #[serde(default)]
    pub cases_done: u64,
    /// Why the run stopped before the end, when it did.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub stopped: Option<String>,
    /// The shard this run covered (`run --partition K/N`); absent for a
    /// whole run and for a merged board.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub partition: Option<Partition>,
    #[serde(default)]
    pub inputs: InputHashes,
    pub environment: serde_json::Value,
    pub summary: Summary,
    pub cases: Vec<CaseEntry>,
}

impl Scoreboard {
    /// Recomputes the summary and sorts cases by id.
    pub fn finish(&mut self) {
        self.cases.sort_by(|a, b| a.id.cmp(&b.id));
        let mut s = Summary::default();
        let mut done = 0;
        for c in &self.cases {
            for r in &c.results {
                s.add(r.verdict, c.expect);
                done += 1;
            }
        }
        self.summary = s;
        self.cases_done = done;
    }

    /// Whether the run is complete and nothing failed, errored or timed out.
    pub fn all_good(&self) -> bool {
        self.complete && self.summary.all_good()
    }

    /// Writes the board atomically: a temp file beside it, then rename.
    pub fn write_atomic(&self, path: &Path) -> std::io::Result<()> {
        let tmp = path.with_extension(format!("json.tmp{}", std::process::id()));
        let text = serde_json::to_string_pretty(self).map_err(std::io::Error::other)?;
        std::fs::write(&tmp, text + "\n")?;
        std::fs::rename(&tmp, path)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn summary_counts_expected_verdicts_as_passed() {
        let mut s = Summary::default();
        s.add(Verdict::Fail, Some(Expect::Fail));
        s.add(Verdict::Pass, Some(Expect::Fail));
        s.add(Verdict::Timeout, None);
        s.add(Verdict::Skip, None);
        assert_eq!(s.line(), "1 passed, 2 failed, 1 skipped");
        assert!(!s.all_good());
    }
}
