//! Assertions: a closed enum, generic over named output tensors, with
//! tolerances and gates read from thresholds.yaml by name. Each evaluation
//! returns a [`Check`] (`metric`, `value`, `limit`, `worst_index`,
//! `message`). A problem with the evidence itself (a missing tensor, shapes
//! that do not match) is a judge error, never a failed check.

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
            } => {
                let t = ev.tensor(tensor)?;
                let tol = ev.tol(tol)?;
                let shape = t.shape().to_vec();
                let k = *shape
                    .last()
                    .ok_or("norm_eq needs a tensor with a last axis")?;
                let v = t.to_f64_vec();
                let m = ev.mask(mask.as_ref(), &shape[..shape.len() - 1])?;
                let limit = tol.atol + tol.rtol * value.abs();
                let (mut worst, mut wi, mut bad) = (0.0f64, None, 0usize);
                for (i, vec) in v.chunks(k.max(1)).enumerate() {
                    if m.as_ref().is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let n = vec.iter().map(|x| x * x).sum::<f64>().sqrt();
                    let dev = (n - value).abs();
                    if !(dev <= limit) {
                        bad += 1;
                    }
                    if dev.is_nan() || dev > worst {
                        worst = if dev.is_nan() { f64::INFINITY } else { dev };
                        wi = Some(i * k);
                    }
                }
                let msg = format!(
                    "{bad} vectors of {tensor} have |norm - {value}| > {limit:e}; worst {worst:e}"
                );
                Ok(check(kind, "max_norm_dev", worst, limit, wi, bad == 0, msg))
            }
            Assertion::Gt { a, b, mask } | Assertion::Ge { a, b, mask } => {
                let strict = matches!(self, Assertion::Gt { .. });
                let at = ev.tensor(a)?;
                let av = at.to_f64_vec();
                let bv = ev.vals(b)?;
                let p = pairs(&av, at.shape(), &bv, a)?;
                let m = ev.mask(mask.as_ref(), at.shape())?;
                let mut bad = 0usize;
                let mut first = None;
                for (i, (x, y)) in p.iter().enumerate() {
                    if m.as_ref().is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let ok = if strict { x > y } else { x >= y };
                    if !ok {
                        bad += 1;
                        first.get_or_insert(i);
                    }
                }
                let rel = if strict { ">" } else { ">=" };
                let msg = match first {
                    Some(i) => format!(
                        "{bad} elements fail {a} {rel} {}; first at {i}: {} vs {}",
                        op_name(b),
                        p[i].0,
                        p[i].1
                    ),
                    None => format!("{a} {rel} {} everywhere checked", op_name(b)),
                };
                Ok(check(
                    kind,
                    "violations",
                    bad as f64,
                    0.0,
                    first,
                    bad == 0,
                    msg,
                ))
            }
            Assertion::MonotoneT { t, off } => {
                let tv = ev.tensor(t)?.to_f64_vec();
                let ov = ev.tensor(off)?.to_f64_vec();
                let mut bad = 0usize;
                let mut first = None;
                for w in ov.windows(2) {
                    let (s, e) = (w[0] as usize, (w[1] as usize).min(tv.len()));
                    for i in s + 1..e.max(s + 1) {
                        if !(tv[i] > tv[i - 1]) {
                            bad += 1;
                            first.get_or_insert(i);
                        }
                    }
                }
                let msg = format!("{bad} samples where {t} does not increase within its ray");
                Ok(check(
                    kind,
                    "violations",
                    bad as f64,
                    0.0,
                    first,
                    bad == 0,
                    msg,
                ))
            }
            Assertion::OffWellFormed { off, m } => {
                let ov = ev.tensor(off)?.to_f64_vec();
                let total = match m {
                    Some(n) => Some(ev.tensor(n)?.shape().first().copied().unwrap_or(0) as f64),
                    None => None,
                };
                let mut problems = Vec::new();
                let mut first = None;
                if ov.first() != Some(&0.0) {
                    problems.push(format!("off[0] = {:?}, not 0", ov.first()));
                    first = Some(0);
                }
                if let Some(i) = ov.windows(2).position(|w| w[1] < w[0]) {
                    problems.push(format!(
                        "off decreases at {}: {} -> {}",
                        i + 1,
                        ov[i],
                        ov[i + 1]
                    ));
                    first.get_or_insert(i + 1);
                }
                if let (Some(t), Some(&last)) = (total, ov.last()) {
                    if last != t {
                        problems.push(format!("off[n] = {last}, but M = {t}"));
                        first.get_or_insert(ov.len() - 1);
                    }
                }
                let msg = if problems.is_empty() {
                    "off[0] = 0, monotone, off[n] = M".into()
                } else {
                    problems.join("; ")
                };
                Ok(check(
                    kind,
                    "problems",
                    problems.len() as f64,
                    0.0,
                    first,
                    problems.is_empty(),
                    msg,
                ))
            }
            Assertion::OobPolicy {
                value,
                inside,
                policy,
                clamped,
            } => {
                let vt = ev.tensor(value)?;
                let v = vt.to_f64_vec();
                let ins = ev.tensor(inside)?;
                same_shape(vt.shape(), ins.shape(), value, inside)?;
                let ins = ins.to_f64_vec();
                let cv = match (policy, clamped) {
                    (OobKind::Clamp, Some(c)) => Some(ev.tensor(c)?.to_f64_vec()),
                    (OobKind::Clamp, None) => return Err("oob_policy clamp needs `clamped`".into()),
                    (OobKind::Zero, _) => None,
                };
                let mut bad = 0usize;
                let mut first = None;
                for i in 0..v.len() {
                    if ins[i] != 0.0 {
                        continue;
                    }
                    let want = cv.as_ref().map_or(0.0, |c| c[i]);
                    if v[i] != want {
                        bad += 1;
                        first.get_or_insert(i);
                    }
                }
                let msg = format!("{bad} outside samples of {value} break the {policy:?} policy");
                Ok(check(
                    kind,
                    "violations",
                    bad as f64,
                    0.0,
                    first,
                    bad == 0,
                    msg,
                ))
            }
            Assertion::MaxAbs { a, b, tol, mask } => {
                let tol = ev.tol(tol)?;
                let at = ev.tensor(a)?;
                let p = pairs(&at.to_f64_vec(), at.shape(), &ev.vals(b)?, a)?;
                let m = ev.mask(mask.as_ref(), at.shape())?;
                let (mut worst, mut wi, mut bad, mut wlim) = (0.0f64, None, 0usize, tol.atol);
                let mut worst_ratio = -1.0f64;
                for (i, &(x, y)) in p.iter().enumerate() {
                    if m.as_ref().is_some_and(|m| !m[i]) {
                        continue;
                    }
                    let close = tol.close(x, y);
                    let d = if x == y { 0.0 } else { (x - y).abs() };
                    let lim = tol.atol + tol.rtol * y.abs();
                    let ratio = if d.is_nan() {
                        f64::INFINITY
                    } else if lim > 0.0 {
                        d / lim
                    } else if d > 0.0 {
                        f64::INFINITY
                    } else {
                        0.0
                    };
                    if !close {
                        bad += 1;
                    }
                    if ratio > worst_ratio {
                        (worst_ratio, worst, wi, wlim) = (
                            ratio,
                            if d.is_nan() { f64::INFINITY } else { d },
                            Some(i),
                            lim,
                        );
                    }
                }
                let msg = match wi {
                    Some(i) => format!(
                        "{bad} elements out of tolerance; worst at {i}: {a} = {}, {} = {}",
                        p[i].0,
                        op_name(b),
                        p[i].1
                    ),
                    None => "no elements compared".into(),
                };
                Ok(check(kind, "max_abs_diff", worst, wlim, wi, bad == 0, msg))
            }
            Assertion::RelErr { a, b, tol, mask } => {
                let bv = ev.vals(b)?;
                rel_err(kind, ev, a, &op_name(b), bv, tol, mask.as_ref())
            }
            Assertion::FdRelErr { a, b, tol, mask } => {
                let bv = ev.vals(&Operand::Name(b.clone()))?;
                rel_err(kind, ev, a, b, bv, tol, mask.as_ref())
            }
            Assertion::MemcmpSame { a, b } => {
                let (x, y) = (ev.tensor(a)?, ev.tensor(b)?);
                if x.dtype() != y.dtype() || x.shape() != y.shape() {
                    let msg = format!(
                        "{a} is {} {:?}, {b} is {} {:?}",
                        x.dtype(),
                        x.shape(),
                        y.dtype(),
                        y.shape()
                    );
                    return Ok(check(
                        kind,
                        "differing_elements",
                        f64::INFINITY,
                        0.0,
                        None,
                        false,
                        msg,
                    ));
                }
                let (xb, yb) = (x.to_bytes(), y.to_bytes());
                let es = x.elem_size();
                let diff: Vec<usize> = xb
                    .chunks(es)
                    .zip(yb.chunks(es))
                    .enumerate()
                    .filter(|(_, (p, q))| p != q)
                    .map(|(i, _)| i)
                    .collect();
                let msg = match diff.first() {
                    Some(i) => format!(
                        "{} of {} elements differ; first at {i}",
                        diff.len(),
                        x.len()
                    ),
                    None => format!("{} elements bit-identical", x.len()),
                };
                Ok(check(
                    kind,
                    "differing_elements",
                    diff.len() as f64,
                    0.0,
                    diff.first().copied(),
                    diff.is_empty(),
                    msg,
                ))
            }
            Assertion::NoNanInf { tensors } => {
                let names: Vec<String> = match tensors {
                    Some(t) => t.clone(),
                    None => ev
                        .tensors
                        .iter()
                        .filter(|(k, t)| !k.contains('.') && t.is_float())
                        .map(|(k, _)| k.clone())
                        .collect(),
                };
                let mut bad = 0usize;
                let mut first: Option<(String, usize)> = None;
                for n in &names {
                    let v = ev.tensor(n)?.to_f64_vec();
                    for (i, x) in v.iter().enumerate() {
                        if !x.is_finite() {
                            bad += 1;
                            if first.is_none() {
                                first = Some((n.clone(), i));
                            }
                        }
                    }
                }
                let msg = match &first {
                    Some((n, i)) => format!("{bad} non-finite values; first in {n} at {i}"),
                    None => format!("all finite in {names:?}"),
                };
                Ok(check(
                    kind,
                    "non_finite",
                    bad as f64,
                    0.0,
                    first.map(|f| f.1),
                    bad == 0,
                    msg,
                ))
            }
            Assertion::Range {
                tensor,
                min,
                max,
                mask,
            } => {
                let t = ev.tensor(tensor)?;
                let v = t.to_f64_vec();
                let m = ev.mask(mask.as_ref(), t.shape())?;
                let mut bad = 0usize;
                let mut first = None;
                let (mut lo, mut hi) = (f64::INFINITY, f64::NEG_INFINITY);
                for (i, &x) in v.iter().enumerate() {
                    if m.as_ref().is_some_and(|m| !m[i]) {
                        continue;
                    }
                    lo = lo.min(x);
                    hi = hi.max(x);
                    if !(x >= *min && x <= *max) {
                        bad += 1;
                        first.get_or_insert(i);
                    }
                }
                let msg =
                    format!("{bad} values of {tensor} outside [{min}, {max}]; seen [{lo}, {hi}]");
                let value = if bad == 0 { 0.0 } else { bad as f64 };
                Ok(check(
                    kind,
                    "out_of_range",
                    value,
                    0.0,
                    first,
                    bad == 0,
                    msg,
                ))
            }
            Assertion::EqualCount { a, b, max } => {
                let (x, y) = (ev.tensor(a)?, ev.tensor(b)?);
                same_shape(x.shape(), y.shape(), a, b)?;
                let (xv, yv) = (x.to_f64_vec(), y.to_f64_vec());
                let diff: Vec<usize> = (0..xv.len()).filter(|&i| xv[i] != yv[i]).collect();
                let msg = format!(
                    "{} of {} elements differ (allowed {max})",
                    diff.len(),
                    xv.len()
                );
                Ok(check(
                    kind,
                    "differing_elements",
                    diff.len() as f64,
                    *max as f64,
                    diff.first().copied(),
                    diff.len() as u64 <= *max,
                    msg,
                ))
            }
            Assertion::KsUniform { tensors, alpha } => {
                let fam = ev.gate(alpha)?;
                let each = sidak(fam, tensors.len());
                let mut minp = 1.0f64;
                let mut worst = None;
                let mut parts = Vec::new();
                for (i, n) in tensors.iter().enumerate() {
                    let v = ev.tensor(n)?.to_f64_vec();
                    if v.is_empty() {
                        return Err(format!("{n} is empty"));
                    }
                    let p = ks_uniform_p(&v);
                    parts.push(format!("{n}: p = {p:.4} (n = {})", v.len()));
                    if p < minp || worst.is_none() {
                        minp = p.min(minp);
                        worst = Some(i);
                    }
                }
                let msg = format!(
                    "{}; Šidák alpha per test {each:.4} (family {fam})",
                    parts.join(", ")
                );
                Ok(check(
                    kind,
                    "min_p_value",
                    minp,
                    each,
                    worst,
                    minp >= each,
                    msg,
                ))
            }
            Assertion::ThroughputGe { metric, gate } => {
                let v = ev.metric(metric)?;
                let g = ev.gate(gate)?;
                Ok(perf_check(kind, metric, v, g, enforce_perf))
            }
            Assertion::SpeedupGe { num, den, gate } => {
                let (n, d) = (ev.metric(num)?, ev.metric(den)?);
                let g = ev.gate(gate)?;
                let v = if d > 0.0 { n / d } else { f64::INFINITY };
                let mut c = perf_check(kind, &format!("{num}/{den}"), v, g, enforce_perf);
                c.message = format!("{num} = {n:.4e}, {den} = {d:.4e}; {}", c.message);
                Ok(c)
            }
        }
    }
}

fn perf_check(kind: &str, metric: &str, v: f64, g: f64, enforce: bool) -> Check {
    let ok = v >= g;
    let mut c = check(
        kind,
        metric,
        v,
        g,
        None,
        ok || !enforce,
        format!("{metric} = {v:.4e}, gate {g:.4e}"),
    );
    c.enforced = enforce;
    if !enforce {
        c.message += if ok {
            " (reported; met)"
        } else {
            " (reported; below gate, not enforced in this profile)"
        };
    }
    c
}

fn rel_err(
    kind: &str,
    ev: &Evidence,
    a: &str,
    bn: &str,
    b: Vals,
    tol: &str,
    mask: Option<&String>,
) -> Result<Check, String> {
    let tol = ev.tol(tol)?;
    let at = ev.tensor(a)?;
    let p = pairs(&at.to_f64_vec(), at.shape(), &b, a)?;
    let m = ev.mask(mask, at.shape())?;
    let keep = |i: usize| m.as_ref().is_none_or(|m| m[i]);
    let bmax = p
        .iter()
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, q)| q.1.abs())
        .fold(0.0, f64::max);
    let floor = tol.floor.max(tol.floor_rel * bmax);
    let (mut worst, mut wi) = (0.0f64, None);
    for (i, &(x, y)) in p.iter().enumerate() {
        if !keep(i) {
            continue;
        }
        let den = y.abs().max(floor);
        let e = if x == y {
            0.0
        } else if den > 0.0 {
            (x - y).abs() / den
        } else {
            f64::INFINITY
        };
        let e = if e.is_nan() { f64::INFINITY } else { e };
        if e > worst || wi.is_none() {
            worst = e.max(worst);
            wi = Some(i);
        }
    }
    let msg = match wi {
        Some(i) => format!(
            "max rel err {worst:.3e} at {i} ({a} = {:.6e}, {bn} = {:.6e}); floor {floor:.3e}",
            p[i].0, p[i].1
        ),
        None => "no elements compared".into(),
    };
    Ok(check(
        kind,
        "max_rel_err",
        worst,
        tol.rtol,
        wi,
        worst <= tol.rtol,
        msg,
    ))
}
