//! `hpjudge bless`: rewrites goldens from the selected cases' CPU outputs.
//! Goldens change only on request, reviewed; the binary refuses it under CI.

use std::path::Path;

use crate::budget::MemBudget;
use crate::judge::load::JudgeInputError;
use crate::judge::ops::BackendKind;
use crate::judge::runner::load_inputs;
use crate::judge::scoreboard::{BackendResult, Verdict};
use crate::judge::worker::{run_case, WorkerEnv};

/// Why blessing stopped.
#[derive(Debug, thiserror::Error)]
pub enum BlessError {
    #[error(transparent)]
    Input(#[from] JudgeInputError),
    /// A case errored instead of producing its outputs: `case: reason`.
    #[error("{0}: {1}")]
    Case(String, String),
}

/// Runs every case with goldens whose id contains `filter` on the CPU in bless
/// mode; calls `wrote` with each golden file written; returns their number.
pub fn bless(
    manifest: &Path,
    filter: Option<&str>,
    profile: Option<&str>,
    mut wrote: impl FnMut(&str),
) -> Result<usize, BlessError> {
    let inputs = load_inputs(manifest, None, profile)?;
    let goldens = inputs.root.join("GOLDENS");
    let out = std::env::temp_dir().join(format!("hpjudge-bless-{}", std::process::id()));
    let mut n = 0;
    for lc in inputs
        .manifest
        .cases
        .iter()
        .filter(|c| filter.is_none_or(|f| c.case.id.contains(f)))
    {
        if lc.case.asserts.iter().all(|a| a.goldens().is_empty()) {
            continue;
        }
        let wenv = WorkerEnv {
            thresholds: &inputs.thresholds,
            perf: &inputs.perf,
            out: &out,
            goldens: &goldens,
            seed: 0,
            budget: MemBudget::from_machine(),
            dump: false,
            bless: true,
        };
        let r: BackendResult = run_case(lc, BackendKind::Cpu, &wenv);
        if r.verdict == Verdict::Error {
            return Err(BlessError::Case(lc.case.id.clone(), r.reason));
        }
        for a in &r.artifacts {
            wrote(a);
            n += 1;
        }
    }
    Ok(n)
}
