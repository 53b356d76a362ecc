//! hpjudge: manifests, thresholds, assertions, verdicts, scoreboard,
//! artifacts and perf triage.

pub mod ops;
