//! What an operation is: the row type of the operation table
//! ([`OpEntry`], `judge/ops/`), the backends and precisions it supports
//! ([`Support`]) and what it may read ([`OpCtx`]). An operation turns a
//! scene and parameters into named tensors, metrics and counters
//! ([`Outputs`]); assertions judge those. Operations that compute an
//! independent reference (a closed form, an f64 quadrature, a DDA referee)
//! are rows too, so the runner never re-implements math.

use std::path::{Path, PathBuf};

use serde::de::DeserializeOwned;
use serde::{Deserialize, Serialize};
use serde_yaml::Value;

use crate::budget::MemBudget;
use crate::error::{Error, Result};
use crate::real::Precision;
use crate::scene::{from_value, SceneDoc};
use crate::tensor::{Outputs, Tensor};

/// Where an operation runs.
#[derive(Clone, Copy, Debug, PartialEq, Eq, PartialOrd, Ord, Hash, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum BackendKind {
    Cpu,
    Gpu,
}

impl BackendKind {
    pub fn name(self) -> &'static str {
        match self {
            BackendKind::Cpu => "cpu",
            BackendKind::Gpu => "gpu",
        }
    }
}

/// Everything an operation may read. Built by the judge's worker (or by
/// `hpjudge render`) from the case, the scene and the command line.
pub struct OpCtx<'a> {
    /// The case id (or `render`).
    pub case_id: &'a str,
    /// The scene, after the case's and the command line's overrides.
    pub scene: Option<&'a SceneDoc>,
    /// The case's `params:` mapping (`Value::Null` when absent).
    pub params: &'a Value,
    pub backend: BackendKind,
    pub precision: Precision,
    /// Run seed (`--seed`), for operations that draw random numbers.
    pub seed: u32,
    pub budget: MemBudget,
    /// `--dump-failing` re-run: add per-ray tensors (rays, per-ray buffers).
    pub dump: bool,
    /// Rays to replay instead of camera rays (`render --rays FILE`).
    pub rays: Option<&'a Tensor>,
    /// Folder of the manifest or scene that named this run, for relative paths.
    pub root: &'a Path,
}

impl<'a> OpCtx<'a> {
    /// The scene, or an error saying this operation needs one.
    pub fn scene(&self) -> Result<&'a SceneDoc> {
        self.scene
            .ok_or_else(|| Error::invalid(self.case_id, "this operation needs a `scene:`"))
    }

    /// Parameter `key` of the case's `params:`, typed; `None` when absent.
    pub fn param<T: DeserializeOwned>(&self, key: &str) -> Result<Option<T>> {
        match self.params.get(key) {
            None | Some(Value::Null) => Ok(None),
            Some(v) => from_value(v, &format!("{} params.{key}", self.case_id)).map(Some),
        }
    }

    /// Parameter `key`, or `default` when absent.
    pub fn param_or<T: DeserializeOwned>(&self, key: &str, default: T) -> Result<T> {
        Ok(self.param(key)?.unwrap_or(default))
    }

    /// Parameter `key`, required.
    pub fn param_req<T: DeserializeOwned>(&self, key: &str) -> Result<T> {
        self.param(key)?.ok_or_else(|| {
            Error::invalid(
                format!("{} params", self.case_id),
                format!("missing `{key}`"),
            )
        })
    }

    /// `<case> params.<key>`: where a parameter error points.
    pub fn at(&self, key: &str) -> String {
        format!("{} params.{key}", self.case_id)
    }

    /// `params.<key>`, required: rays as `[ox, oy, oz, dx, dy, dz]`, each
    /// finite with |d| > 0.
    pub fn listed_rays(&self, key: &str) -> Result<Vec<[f64; 6]>> {
        let rays: Vec<[f64; 6]> = self.param_req(key)?;
        let bad = |r: &[f64; 6]| {
            r.iter().any(|x| !x.is_finite()) || (r[3] * r[3] + r[4] * r[4] + r[5] * r[5]) == 0.0
        };
        match rays.iter().position(bad) {
            Some(i) => Err(self.bad(&format!("{key}[{i}]"), "needs finite numbers and d != 0")),
            None => Ok(rays),
        }
    }

    /// An invalid-input error at parameter `key` of this case.
    pub fn bad(&self, key: &str, why: impl Into<String>) -> Error {
        Error::invalid(self.at(key), why)
    }

    /// A path relative to [`OpCtx::root`].
    pub fn resolve(&self, p: &str) -> PathBuf {
        self.root.join(p)
    }
}

/// The backends and precisions an operation runs in. The manifest loader
/// (and `hpjudge check`) refuses any other combination before anything runs;
/// [`OpEntry::call`] refuses it again for direct calls (`hpjudge render`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Support {
    /// The CPU, in f32 and f64 (no GPU kernel yet).
    Cpu,
    /// The CPU in f32 and f64, the GPU in f32.
    CpuGpuF32,
    /// The CPU in f32 only (a renderer with no f64 instance: the path tracer).
    CpuF32,
    /// The CPU and the GPU, f32 only.
    F32,
    /// The GPU in f32 only (a parity or bench operation that runs the CPU
    /// beside the GPU itself).
    GpuF32,
    /// Any backend and precision: the operation computes the same either
    /// way (a reference in f64 on the CPU, a table, a planted self-test).
    Any,
}

impl Support {
    /// Whether `backend` in `precision` is supported.
    pub fn allows(self, backend: BackendKind, precision: Precision) -> bool {
        match self {
            Support::Cpu => backend == BackendKind::Cpu,
            Support::CpuGpuF32 => backend == BackendKind::Cpu || precision == Precision::F32,
            Support::GpuF32 => backend == BackendKind::Gpu && precision == Precision::F32,
            Support::CpuF32 => backend == BackendKind::Cpu && precision == Precision::F32,
            Support::F32 => precision == Precision::F32,
            Support::Any => true,
        }
    }

    /// For messages and `hpjudge list --ops`.
    pub fn describe(self) -> &'static str {
        match self {
            Support::Cpu => "cpu f32/f64",
            Support::CpuGpuF32 => "cpu f32/f64, gpu f32",
            Support::GpuF32 => "gpu f32",
            Support::CpuF32 => "cpu f32",
            Support::F32 => "cpu f32, gpu f32",
            Support::Any => "any backend and precision",
        }
    }
}

/// One row of the table.
pub struct OpEntry {
    /// `renderer.operation`.
    pub name: &'static str,
    /// One line for `hpjudge list --ops`.
    pub doc: &'static str,
    /// Parameter keys the operation reads (unknown keys are refused on load).
    pub params: &'static [&'static str],
    /// Backends and precisions it runs in.
    pub support: Support,
    pub run: fn(&OpCtx) -> Result<Outputs>,
}

impl OpEntry {
    /// `None` when this operation runs on `backend` in `precision`, else why not.
    pub fn refuses(&self, backend: BackendKind, precision: Precision) -> Option<String> {
        (!self.support.allows(backend, precision)).then(|| {
            format!(
                "{} does not run on {} in {} (it runs: {})",
                self.name,
                backend.name(),
                precision.name(),
                self.support.describe()
            )
        })
    }

    /// `None` when this operation takes parameter `key`, else why not
    /// (naming the ones it takes).
    pub fn refuses_param(&self, key: &str) -> Option<String> {
        (!self.params.contains(&key)).then(|| {
            format!(
                "{} takes no parameter {key:?} (it takes {:?})",
                self.name, self.params
            )
        })
    }

    /// Runs the operation, refusing an unsupported backend or precision.
    pub fn call(&self, ctx: &OpCtx) -> Result<Outputs> {
        if let Some(why) = self.refuses(ctx.backend, ctx.precision) {
            return Err(Error::NotSupported(format!("{}: {why}", ctx.case_id)));
        }
        (self.run)(ctx)
    }
}
