//! Manifests: declarative cases, with `include:` of other manifests (paths
//! relative to the including file). Everything is validated on load, before
//! any case runs: ids, operations, parameter keys, assertion kinds,
//! threshold names, scene files and perf scenario names.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use serde_yaml::Value;
use sha2::{Digest, Sha256};

use super::asserts::Assertion;
use super::load::{find_line, load_yaml_typed, JudgeInputError};
use super::ops::{self, BackendKind};
use super::perf::PerfScenarios;
use super::thresholds::Thresholds;
use crate::real::Precision;

/// How big a case is.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum CaseSize {
    /// Small enough for CI; runs in every size profile.
    #[default]
    Ci,
    /// Runs only in the `full` size profile.
    Full,
}

/// A verdict a self-test case must get.
#[derive(Clone, Copy, Debug, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum Expect {
    Pass,
    Fail,
    Error,
    Timeout,
    Skip,
}

/// A further run of a case whose outputs assertions name as `<ref>.<tensor>`.
/// Keys left out inherit the case's values.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct RefSpec {
    pub op: Option<String>,
    pub scene: Option<String>,
    pub set: Option<BTreeMap<String, Value>>,
    pub params: Option<Value>,
    pub precision: Option<Precision>,
    pub backend: Option<BackendKind>,
    pub threads: Option<usize>,
}

/// One case as written.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Case {
    pub id: String,
    pub op: String,
    #[serde(default)]
    pub scene: Option<String>,
    #[serde(default)]
    pub set: BTreeMap<String, Value>,
    #[serde(default)]
    pub ci: BTreeMap<String, Value>,
    #[serde(default)]
    pub params: Value,
    #[serde(default = "cpu_only")]
    pub backends: Vec<BackendKind>,
    #[serde(default)]
    pub precision: Precision,
    #[serde(default)]
    pub size: CaseSize,
    #[serde(default = "default_timeout")]
    pub timeout: String,
    #[serde(default)]
    pub threads: usize,
    #[serde(default)]
    pub expect: Option<Expect>,
    /// A perf scenario whose warm-up and repeats apply to the main run;
    /// metrics are then medians.
    #[serde(default)]
    pub perf: Option<String>,
    #[serde(default)]
    pub refs: BTreeMap<String, RefSpec>,
    /// Assertions, each a one-key map `- kind: {args}`.
    #[serde(
        default,
        rename = "assert",
        with = "serde_yaml::with::singleton_map_recursive"
    )]
    pub asserts: Vec<Assertion>,
    /// One line on what the case proves.
    #[serde(default)]
    pub doc: String,
}

fn cpu_only() -> Vec<BackendKind> {
    vec![BackendKind::Cpu]
}
fn default_timeout() -> String {
    "default".into()
}

#[derive(Deserialize)]
#[serde(deny_unknown_fields)]
struct ManifestFile {
    #[serde(default)]
    include: Vec<String>,
    #[serde(default)]
    cases: Vec<Case>,
}

/// A case with where it came from.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct LoadedCase {
    pub case: Case,
    /// The manifest file that defines it.
    pub file: PathBuf,
    /// Its line there (of `id: ...`), when found.
    pub line: Option<usize>,
}

impl LoadedCase {
    /// The folder its relative paths are resolved against.
    pub fn dir(&self) -> &Path {
        self.file.parent().unwrap_or(Path::new("."))
    }

    /// `file:line` for messages.
    pub fn at(&self) -> String {
        match self.line {
            Some(l) => format!("{}:{l}", self.file.display()),
            None => self.file.display().to_string(),
        }
    }

    /// The scene path of the main run, resolved.
    pub fn scene_path(&self, scene: Option<&str>) -> Option<PathBuf> {
        scene.map(|s| self.dir().join(s))
    }

    /// Every scene file its runs read (main and refs), resolved.
    pub fn scene_paths(&self) -> BTreeSet<PathBuf> {
        let c = &self.case;
        let refs = c.refs.values().filter_map(|r| r.scene.as_ref());
        c.scene
            .iter()
            .chain(refs)
            .map(|s| self.dir().join(s))
            .collect()
    }
}

/// All cases of a manifest and its includes, in file order.
#[derive(Clone, Debug)]
pub struct Manifest {
    pub path: PathBuf,
    pub cases: Vec<LoadedCase>,
    /// SHA-256 over every file of the include tree (path and content, load order).
    pub tree_sha256: String,
    /// Files in the include tree.
    pub files: usize,
}

/// Largest include depth (cycles are caught separately).
const MAX_INCLUDE_DEPTH: usize = 16;

impl Manifest {
    /// Loads a manifest and everything it includes (no validation against
    /// thresholds; see [`Manifest::validate`]).
    pub fn load(path: &Path) -> Result<Manifest, JudgeInputError> {
        let mut cases = Vec::new();
        let mut stack = Vec::new();
        let mut tree = Vec::new();
        load_into(path, &mut cases, &mut stack, &mut tree)?;
        let mut seen: BTreeMap<String, String> = BTreeMap::new();
        for c in &cases {
            if let Some(first) = seen.insert(c.case.id.clone(), c.at()) {
                return Err(JudgeInputError::new(
                    &c.at(),
                    "id",
                    format!("{:?} is also defined at {first}", c.case.id),
                ));
            }
        }
        let mut h = Sha256::new();
        for line in &tree {
            h.update(line.as_bytes());
        }
        Ok(Manifest {
            path: path.to_path_buf(),
            cases,
            tree_sha256: format!("{:x}", h.finalize()),
            files: tree.len(),
        })
    }

    /// Checks every name a case uses against the op table, the thresholds
    /// and the perf scenarios, and that every scene file exists.
    pub fn validate(&self, th: &Thresholds, perf: &PerfScenarios) -> Result<(), JudgeInputError> {
        for lc in &self.cases {
            validate_case(lc, th, perf)?;
        }
        Ok(())
    }

    pub fn find(&self, id: &str) -> Option<&LoadedCase> {
        self.cases.iter().find(|c| c.case.id == id)
    }
}

fn load_into(
    path: &Path,
    out: &mut Vec<LoadedCase>,
    stack: &mut Vec<PathBuf>,
    tree: &mut Vec<String>,
) -> Result<(), JudgeInputError> {
    let at = path.display().to_string();
    let canon = path
        .canonicalize()
        .map_err(|e| JudgeInputError::new(&at, "", format!("cannot read: {e}")))?;
    if stack.contains(&canon) {
        return Err(JudgeInputError::new(&at, "include", "include cycle"));
    }
    if stack.len() >= MAX_INCLUDE_DEPTH {
        return Err(JudgeInputError::new(
            &at,
            "include",
            format!("includes nest deeper than {MAX_INCLUDE_DEPTH}"),
        ));
    }
    let (file, text): (ManifestFile, String) = load_yaml_typed(path)?;
    tree.push(format!(
        "{:x}  {}\n",
        Sha256::digest(text.as_bytes()),
        path.display()
    ));
    stack.push(canon);
    let dir = path.parent().unwrap_or(Path::new("."));
    for (i, inc) in file.include.iter().enumerate() {
        let p = dir.join(inc);
        if !p.is_file() {
            return Err(
                JudgeInputError::new(&at, &format!("include[{i}]"), not_a_file(&p))
                    .at_line(find_line(&text, inc)),
            );
        }
        load_into(&p, out, stack, tree)?;
    }
    stack.pop();
    for case in file.cases {
        let line = find_line(&text, &format!("id: {}", case.id));
        out.push(LoadedCase {
            case,
            file: path.to_path_buf(),
            line,
        });
    }
    Ok(())
}

/// Why `p` cannot be read as a file: "is a directory" or "does not exist".
pub fn not_a_file(p: &Path) -> String {
    if p.is_dir() {
        format!("{} is a directory, not a file", p.display())
    } else {
        format!("{} does not exist", p.display())
    }
}

/// Whether a case id is safe as a folder name: `[A-Za-z0-9_.-]+`, not `.`/`..`.
pub fn valid_id(id: &str) -> bool {
    !id.is_empty()
        && id.len() <= 128
        && id != "."
        && id != ".."
        && !id.starts_with('.')
        && id
            .chars()
            .all(|c| c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.'))
}

fn validate_case(
    lc: &LoadedCase,
    th: &Thresholds,
    perf: &PerfScenarios,
) -> Result<(), JudgeInputError> {
    let c = &lc.case;
    let at = lc.at();
    let err = |key: &str, what: String| {
        Err(JudgeInputError::new(
            &at,
            &format!("cases[{}].{key}", c.id),
            what,
        ))
    };
    if !valid_id(&c.id) {
        return err(
            "id",
            format!(
                "{:?} must match [A-Za-z0-9_.-]+ and not start with '.' (it names a folder)",
                c.id
            ),
        );
    }
    if c.backends.is_empty() {
        return err("backends", "empty".into());
    }
    if th.timeout(&c.timeout).is_none() {
        return err(
            "timeout",
            format!(
                "{:?} is not under `timeouts:` in {}",
                c.timeout,
                th.path.display()
            ),
        );
    }
    if let Some(p) = &c.perf {
        if perf.find(p).is_none() {
            return err(
                "perf",
                format!("{p:?} is not a scenario in perf_scenarios.yaml"),
            );
        }
    }
    // (key, op, scene, params, backends and precision it runs in)
    type Run<'a> = (
        String,
        String,
        Option<String>,
        &'a Value,
        Vec<BackendKind>,
        Precision,
    );
    let mut runs: Vec<Run> = vec![(
        "op".into(),
        c.op.clone(),
        c.scene.clone(),
        &c.params,
        c.backends.clone(),
        c.precision,
    )];
    for (name, r) in &c.refs {
        if !valid_id(name) || name.contains('.') {
            return err(
                &format!("refs.{name}"),
                "a ref name must match [A-Za-z0-9_-]+".into(),
            );
        }
        let op = r.op.clone().unwrap_or_else(|| c.op.clone());
        let scene = r.scene.clone().or_else(|| c.scene.clone());
        runs.push((
            format!("refs.{name}.op"),
            op,
            scene,
            r.params.as_ref().unwrap_or(&c.params),
            r.backend.map_or_else(|| c.backends.clone(), |b| vec![b]),
            r.precision.unwrap_or(c.precision),
        ));
    }
    for (key, op, scene, params, backends, precision) in runs {
        let Some(entry) = ops::find(&op) else {
            return err(
                &key,
                format!(
                    "unknown operation {op:?} (known: {})",
                    ops::names().join(", ")
                ),
            );
        };
        if let Some(why) = backends.iter().find_map(|&b| entry.refuses(b, precision)) {
            return err(&key, why);
        }
        if let Some(m) = params.as_mapping() {
            for k in m.keys() {
                let k = k.as_str().unwrap_or("?");
                if let Some(why) = entry.refuses_param(k) {
                    return err(&format!("params.{k}"), why);
                }
            }
        } else if !params.is_null() {
            return err("params", "must be a mapping".into());
        }
        if let Some(s) = scene {
            let p = lc.dir().join(&s);
            if !p.is_file() {
                return err("scene", not_a_file(&p));
            }
        }
    }
    let known: BTreeSet<&str> = c.refs.keys().map(String::as_str).collect();
    for (i, a) in c.asserts.iter().enumerate() {
        a.validate(th, &known)
            .or_else(|what| err(&format!("assert[{i}].{}", a.kind()), what))?;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ids_that_would_escape_the_out_dir_are_invalid() {
        assert!(valid_id("rays_pinhole.f32-1"));
        for bad in ["", ".", "..", "../x", "a/b", ".hidden", "a b", "x\\y"] {
            assert!(!valid_id(bad), "{bad}");
        }
    }
}
