//! hpjudge: manifests, thresholds, assertions, verdicts, scoreboard,
//! artifacts and perf triage.
//!
//! | file | job |
//! | --- | --- |
//! | `manifest.rs` | cases, includes, validation on load |
//! | `thresholds.rs` | tolerances, gates, time limits, device profiles |
//! | `perf.rs` | perf scenarios, noise-aware `compare` |
//! | `perf_run.rs` | `hpjudge perf`: scenarios in workers, perf.json |
//! | `render.rs` | `hpjudge render`: one scene, outside a manifest |
//! | `frames.rs` | `hpjudge render --all-frames`: every frame of a NeRF camera file |
//! | `asserts/` | the closed set of assertions: one file per kind with its tests |
//! | `op.rs`, `ops/` | what an operation is; the table of operations cases name (wiring only) |
//! | `worker.rs` | one case on one backend, in a child process |
//! | `job.rs` | what the judge hands a worker (stdin), the child process, its deadline |
//! | `outlock.rs` | the exclusive lock on a run's output folder |
//! | `runner.rs` | the run: workers, time limits, scoreboard, summary |
//! | `scoreboard.rs`, `junit.rs`, `artifacts.rs` | what a run writes |
//! | `measure/` | wall and CPU seconds; per-renderer timing harnesses |
//! | `progress.rs` | progress bars on a terminal only |
//! | `partition.rs`, `merge.rs` | sharded runs (`--partition K/N`) and `hpjudge merge` |
//! | `plot.rs` | every plot the judge draws |
//! | `report/` | `hpjudge report`: the run as one static HTML page |
//!
//! Statistics (Šidák, KS, chi-square, medians, slopes) are `crate::stats`,
//! named here as `stats` for the assertions.

pub mod artifacts;
pub mod asserts;
pub mod env;
pub mod frames;
#[cfg(test)]
mod fuzz_tests;
pub mod job;
pub mod junit;
pub mod load;
pub mod manifest;
pub mod measure;
pub mod merge;
pub mod op;
#[cfg(test)]
mod op_tests;
pub mod ops;
pub mod outlock;
pub mod partition;
pub mod perf;
pub mod perf_run;
pub mod plants;
pub mod plot;
pub mod progress;
pub mod render;
pub mod report;
pub mod runner;
pub mod scoreboard;
pub mod thresholds;
pub mod worker;

use crate::stats;
