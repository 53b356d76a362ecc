//! Assertions: a closed enum, generic over named output tensors, with
//! tolerances and gates read from thresholds.yaml by name. Each evaluation
//! returns a [`Check`] (`metric`, `value`, `limit`, `worst_index`,
//! `message`). A problem with the evidence itself (a missing tensor, shapes
//! that do not match) is a judge error, never a failed check.

mod equal_count;
mod ks_uniform;
mod max_abs;
mod memcmp_same;
mod monotone_t;
mod no_nan_inf;
mod norm_eq;
mod off_well_formed;
mod oob_policy;
mod order;
mod perf;
mod range;
mod rel_err;
#[cfg(test)]
mod test_fixture;

use std::collections::{BTreeMap, BTreeSet};
use std::path::Path;

use serde::{Deserialize, Serialize};

use super::stats::{ks_uniform_p, sidak};
use super::thresholds::{Thresholds, Tol};
use crate::tensor::Tensor;

/// A tensor name or a number.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
#[serde(untagged)]
pub enum Operand {
    Number(f64),
    Name(String),
}

/// Out-of-box policy an `oob_policy` check enforces.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum OobKind {
    Zero,
    Clamp,
}

/// One assertion as written in a manifest (see docs/manifest.md).
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(rename_all = "snake_case", deny_unknown_fields)]
pub enum Assertion {
    NormEq {
        tensor: String,
        tol: String,
        #[serde(default = "one")]
        value: f64,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    Gt {
        a: String,
        b: Operand,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    Ge {
        a: String,
        b: Operand,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    MonotoneT {
        t: String,
        off: String,
    },
    OffWellFormed {
        off: String,
        #[serde(default)]
        m: Option<String>,
    },
    OobPolicy {
        value: String,
        inside: String,
        policy: OobKind,
        #[serde(default)]
        clamped: Option<String>,
    },
    MaxAbs {
        a: String,
        b: Operand,
        tol: String,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    RelErr {
        a: String,
        b: Operand,
        tol: String,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    FdRelErr {
        a: String,
        b: String,
        tol: String,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    MemcmpSame {
        a: String,
        b: String,
    },
    NoNanInf {
        #[serde(default)]
        tensors: Option<Vec<String>>,
    },
    Range {
        tensor: String,
        min: f64,
        max: f64,
        #[serde(default, rename = "where")]
        mask: Option<String>,
    },
    EqualCount {
        a: String,
        b: String,
        #[serde(default)]
        max: u64,
    },
    KsUniform {
        tensors: Vec<String>,
        alpha: String,
    },
    ThroughputGe {
        metric: String,
        gate: String,
    },
    SpeedupGe {
        num: String,
        den: String,
        gate: String,
    },
}

fn one() -> f64 {
    1.0
}

/// The result of one assertion.
#[derive(Clone, Debug, Deserialize, Serialize, PartialEq)]
pub struct Check {
    /// The assertion kind (`max_abs`, ...).
    pub assertion: String,
    /// What was measured (`max_abs_diff`, `violations`, `p_value`, ...).
    pub metric: String,
    pub value: Option<f64>,
    pub limit: Option<f64>,
    /// Flat row-major index of the worst element, when there is one.
    pub worst_index: Option<usize>,
    pub passed: bool,
    /// False for perf gates outside perf profiles: reported, not enforced.
    pub enforced: bool,
    pub message: String,
}

/// What assertions read: tensors and metrics of the main run (`x`) and of
/// refs (`ref.x`), goldens, and the thresholds.
pub struct Evidence<'a> {
    pub tensors: &'a BTreeMap<String, Tensor>,
    pub metrics: &'a BTreeMap<String, f64>,
    pub goldens: &'a Path,
    pub thresholds: &'a Thresholds,
}

/// Prefix naming a committed golden file under GOLDENS/.
pub const GOLDEN: &str = "golden:";

enum Vals {
    Arr { v: Vec<f64>, shape: Vec<usize> },
    Scalar(f64),
}

impl<'a> Evidence<'a> {
    fn tensor(&self, name: &str) -> Result<Tensor, String> {
        if let Some(path) = name.strip_prefix(GOLDEN) {
            let p = self.goldens.join(path);
            return Tensor::read_npy(&p)
                .map_err(|e| format!("golden {name}: {e} (create it with `hpjudge bless`)"));
        }
        self.tensors.get(name).cloned().ok_or_else(|| {
            let have: Vec<&String> = self.tensors.keys().collect();
            format!("no output tensor {name:?} (outputs: {have:?})")
        })
    }

    fn vals(&self, o: &Operand) -> Result<Vals, String> {
        match o {
            Operand::Number(x) => Ok(Vals::Scalar(*x)),
            Operand::Name(n) => {
                let t = self.tensor(n)?;
                if t.shape().is_empty() {
                    return Ok(Vals::Scalar(t.to_f64_vec()[0]));
                }
                Ok(Vals::Arr {
                    v: t.to_f64_vec(),
                    shape: t.shape().to_vec(),
                })
            }
        }
    }

    fn metric(&self, name: &str) -> Result<f64, String> {
        self.metrics.get(name).copied().ok_or_else(|| {
            let have: Vec<&String> = self.metrics.keys().collect();
            format!("no metric {name:?} (metrics: {have:?})")
        })
    }

    fn tol(&self, name: &str) -> Result<Tol, String> {
        self.thresholds
            .tol(name)
            .ok_or_else(|| format!("no tolerance {name:?}"))
    }

    fn gate(&self, name: &str) -> Result<f64, String> {
        self.thresholds
            .gate(name)
            .ok_or_else(|| format!("no gate {name:?}"))
    }

    /// A mask over `shape`: `None` = everything. The mask's shape must equal
    /// `shape` or be a leading part of it (a (H, W) mask over (H, W, 3)).
    fn mask(&self, name: Option<&String>, shape: &[usize]) -> Result<Option<Vec<bool>>, String> {
        let Some(n) = name else { return Ok(None) };
        let m = self.tensor(n)?;
        let ms = m.shape();
        if ms.len() > shape.len() || ms != &shape[..ms.len()] {
            return Err(format!(
                "mask {n:?} of shape {ms:?} does not fit shape {shape:?}"
            ));
        }
        let rep: usize = shape[ms.len()..].iter().product();
        let mv = m.to_f64_vec();
        if rep == 0 || mv.iter().all(|&x| x == 0.0) {
            return Err(format!(
                "mask {n:?} selects no elements of shape {shape:?}: the check would compare nothing"
            ));
        }
        Ok(Some(
            mv.iter()
                .flat_map(|&x| std::iter::repeat_n(x != 0.0, rep))
                .collect(),
        ))
    }
}

fn same_shape(a: &[usize], b: &[usize], an: &str, bn: &str) -> Result<(), String> {
    if a == b {
        Ok(())
    } else {
        Err(format!("{an} has shape {a:?} but {bn} has shape {b:?}"))
    }
}

fn check(
    assertion: &str,
    metric: &str,
    value: f64,
    limit: f64,
    worst: Option<usize>,
    passed: bool,
    msg: String,
) -> Check {
    let fin = |x: f64| if x.is_finite() { Some(x) } else { None };
    Check {
        assertion: assertion.into(),
        metric: metric.into(),
        value: fin(value),
        limit: fin(limit),
        worst_index: worst,
        passed,
        enforced: true,
        message: msg,
    }
}

/// Pairs `(a, b)` of an element-wise comparison, with a scalar `b` broadcast.
fn pairs(a: &[f64], ashape: &[usize], b: &Vals, an: &str) -> Result<Vec<(f64, f64)>, String> {
    if a.is_empty() {
        return Err(format!(
            "{an} of shape {ashape:?} has no elements: the check would compare nothing"
        ));
    }
    match b {
        Vals::Scalar(x) => Ok(a.iter().map(|&v| (v, *x)).collect()),
        Vals::Arr { v, shape } => {
            same_shape(ashape, shape, an, "b")?;
            Ok(a.iter().copied().zip(v.iter().copied()).collect())
        }
    }
}

fn op_name(o: &Operand) -> String {
    match o {
        Operand::Number(x) => x.to_string(),
        Operand::Name(n) => n.clone(),
    }
}

impl Assertion {
    /// The assertion's kind as written.
    pub fn kind(&self) -> &'static str {
        match self {
            Assertion::NormEq { .. } => "norm_eq",
            Assertion::Gt { .. } => "gt",
            Assertion::Ge { .. } => "ge",
            Assertion::MonotoneT { .. } => "monotone_t",
            Assertion::OffWellFormed { .. } => "off_well_formed",
            Assertion::OobPolicy { .. } => "oob_policy",
            Assertion::MaxAbs { .. } => "max_abs",
            Assertion::RelErr { .. } => "rel_err",
            Assertion::FdRelErr { .. } => "fd_rel_err",
            Assertion::MemcmpSame { .. } => "memcmp_same",
            Assertion::NoNanInf { .. } => "no_nan_inf",
            Assertion::Range { .. } => "range",
            Assertion::EqualCount { .. } => "equal_count",
            Assertion::KsUniform { .. } => "ks_uniform",
            Assertion::ThroughputGe { .. } => "throughput_ge",
            Assertion::SpeedupGe { .. } => "speedup_ge",
        }
    }

    fn names(&self) -> Vec<&str> {
        fn o(x: &Operand) -> Option<&str> {
            match x {
                Operand::Name(n) => Some(n.as_str()),
                Operand::Number(_) => None,
            }
        }
        match self {
            Assertion::NormEq { tensor, mask, .. } | Assertion::Range { tensor, mask, .. } => {
                [Some(tensor.as_str()), mask.as_deref()]
                    .into_iter()
                    .flatten()
                    .collect()
            }
            Assertion::Gt { a, b, mask } | Assertion::Ge { a, b, mask } => {
                [Some(a.as_str()), o(b), mask.as_deref()]
                    .into_iter()
                    .flatten()
                    .collect()
            }
            Assertion::MaxAbs { a, b, mask, .. } | Assertion::RelErr { a, b, mask, .. } => {
                [Some(a.as_str()), o(b), mask.as_deref()]
                    .into_iter()
                    .flatten()
                    .collect()
            }
            Assertion::FdRelErr { a, b, mask, .. } => {
                [Some(a.as_str()), Some(b.as_str()), mask.as_deref()]
                    .into_iter()
                    .flatten()
                    .collect()
            }
            Assertion::MonotoneT { t, off } => vec![t, off],
            Assertion::OffWellFormed { off, m } => [Some(off.as_str()), m.as_deref()]
                .into_iter()
                .flatten()
                .collect(),
            Assertion::OobPolicy {
                value,
                inside,
                clamped,
                ..
            } => [
                Some(value.as_str()),
                Some(inside.as_str()),
                clamped.as_deref(),
            ]
            .into_iter()
            .flatten()
            .collect(),
            Assertion::MemcmpSame { a, b } | Assertion::EqualCount { a, b, .. } => vec![a, b],
            Assertion::NoNanInf { tensors } => {
                tensors.iter().flatten().map(String::as_str).collect()
            }
            Assertion::KsUniform { tensors, .. } => tensors.iter().map(String::as_str).collect(),
            Assertion::ThroughputGe { metric, .. } => vec![metric],
            Assertion::SpeedupGe { num, den, .. } => vec![num, den],
        }
    }

    /// Checks names before anything runs: tolerance and gate names exist,
    /// `x.y` names a declared ref, goldens are relative paths inside GOLDENS/.
    pub fn validate(&self, th: &Thresholds, refs: &BTreeSet<&str>) -> Result<(), String> {
        let tol = |n: &str| {
            th.tol(n)
                .map(drop)
                .ok_or_else(|| format!("no tolerance {n:?} in {}", th.path.display()))
        };
        let gate = |n: &str| {
            th.gate(n)
                .map(drop)
                .ok_or_else(|| format!("no gate {n:?} in {}", th.path.display()))
        };
        match self {
            Assertion::NormEq { tol: t, .. }
            | Assertion::MaxAbs { tol: t, .. }
            | Assertion::RelErr { tol: t, .. }
            | Assertion::FdRelErr { tol: t, .. } => tol(t)?,
            Assertion::KsUniform { alpha, .. } => gate(alpha)?,
            Assertion::ThroughputGe { gate: g, .. } | Assertion::SpeedupGe { gate: g, .. } => {
                gate(g)?
            }
            Assertion::Range { min, max, .. } if min > max => {
                return Err(format!("min {min} > max {max}"))
            }
            _ => {}
        }
        for n in self.names() {
            if let Some(p) = n.strip_prefix(GOLDEN) {
                let bad =
                    p.is_empty() || Path::new(p).is_absolute() || p.split('/').any(|c| c == "..");
                if bad {
                    return Err(format!(
                        "golden path {p:?} must be relative, inside GOLDENS/"
                    ));
                }
            } else if let Some((r, _)) = n.split_once('.') {
                if !refs.contains(r) {
                    return Err(format!(
                        "{n:?} names ref {r:?}, which the case does not declare under `refs:`"
                    ));
                }
            }
        }
        Ok(())
    }

    /// `(tensor, golden path)` pairs this assertion compares: what `bless` writes.
    pub fn goldens(&self) -> Vec<(String, String)> {
        let (a, b) = match self {
            Assertion::MaxAbs {
                a,
                b: Operand::Name(b),
                ..
            }
            | Assertion::RelErr {
                a,
                b: Operand::Name(b),
                ..
            } => (a, b),
            Assertion::MemcmpSame { a, b } | Assertion::EqualCount { a, b, .. } => (a, b),
            _ => return vec![],
        };
        b.strip_prefix(GOLDEN)
            .map(|p| vec![(a.clone(), p.to_string())])
            .unwrap_or_default()
    }

    /// Evaluates the assertion. `Err` means the evidence is unusable (a judge
    /// or manifest problem: ERROR), never that the output is wrong.
    pub fn evaluate(&self, ev: &Evidence, enforce_perf: bool) -> Result<Check, String> {
        let kind = self.kind();
        match self {
            Assertion::NormEq {
                tensor,
                tol,
                value,
                mask,
            } => norm_eq::eval(kind, ev, tensor, tol, value, mask),
            Assertion::Gt { a, b, mask } => order::eval(kind, ev, true, a, b, mask),
            Assertion::Ge { a, b, mask } => order::eval(kind, ev, false, a, b, mask),
            Assertion::MonotoneT { t, off } => monotone_t::eval(kind, ev, t, off),
            Assertion::OffWellFormed { off, m } => off_well_formed::eval(kind, ev, off, m),
            Assertion::OobPolicy {
                value,
                inside,
                policy,
                clamped,
            } => oob_policy::eval(kind, ev, value, inside, policy, clamped),
            Assertion::MaxAbs { a, b, tol, mask } => max_abs::eval(kind, ev, a, b, tol, mask),
            Assertion::RelErr { a, b, tol, mask } => {
                let bv = ev.vals(b)?;
                rel_err::rel_err(kind, ev, a, &op_name(b), bv, tol, mask.as_ref())
            }
            Assertion::FdRelErr { a, b, tol, mask } => {
                let bv = ev.vals(&Operand::Name(b.clone()))?;
                rel_err::rel_err(kind, ev, a, b, bv, tol, mask.as_ref())
            }
            Assertion::MemcmpSame { a, b } => memcmp_same::eval(kind, ev, a, b),
            Assertion::NoNanInf { tensors } => no_nan_inf::eval(kind, ev, tensors),
            Assertion::Range {
                tensor,
                min,
                max,
                mask,
            } => range::eval(kind, ev, tensor, min, max, mask),
            Assertion::EqualCount { a, b, max } => equal_count::eval(kind, ev, a, b, max),
            Assertion::KsUniform { tensors, alpha } => ks_uniform::eval(kind, ev, tensors, alpha),
            Assertion::ThroughputGe { metric, gate } => {
                perf::throughput(kind, ev, metric, gate, enforce_perf)
            }
            Assertion::SpeedupGe { num, den, gate } => {
                perf::speedup(kind, ev, (num, den), gate, enforce_perf)
            }
        }
    }
}
