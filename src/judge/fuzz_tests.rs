//! Fuzzing in `cargo test`: seeded byte mutations and structure-aware (YAML
//! tree, `.npy` header) mutations of every committed manifest, thresholds
//! file, perf scenario file, scene and `.npy`. Each input must load or be
//! refused with an error: no panic, no abort, none over 1 s. YAML inputs go
//! through exactly `hpjudge check`'s path ([`load_inputs`], the function
//! `check` calls, profile `ci`); `.npy` inputs through the run's reader. A
//! deterministic counter-based mutator (`rng::rand_u32`), no cargo-fuzz.

use std::path::{Path, PathBuf};
use std::time::Instant;

use serde_yaml::Value;

use super::runner::load_inputs;
use crate::budget::MemBudget;
use crate::rng::rand_u32;
use crate::tensor::Tensor;

/// Inputs generated in all (CI included).
const INPUTS: u32 = 20_000;
/// Slowest refusal accepted per input (a loaded input: 3x its original).
const MAX_SECONDS: f64 = 1.0;

#[derive(Clone, Copy, PartialEq, Eq, Debug)]
enum Kind {
    Manifest,
    Thresholds,
    Perf,
    Scene,
    Npy,
}

fn corpus() -> Vec<(Kind, PathBuf)> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut v = vec![
        (Kind::Thresholds, root.join("thresholds.yaml")),
        (Kind::Perf, root.join("perf_scenarios.yaml")),
    ];
    let mut stack = vec![root.join("TESTS"), root.join("GOLDENS")];
    while let Some(d) = stack.pop() {
        let mut entries: Vec<PathBuf> = std::fs::read_dir(&d)
            .into_iter()
            .flatten()
            .flatten()
            .map(|e| e.path())
            .collect();
        entries.sort();
        for p in entries {
            if p.is_dir() {
                stack.push(p);
            } else if p.extension().is_some_and(|x| x == "npy") {
                v.push((Kind::Npy, p));
            } else if p.file_name().is_some_and(|n| n == "manifest.yaml") {
                v.push((Kind::Manifest, p));
            } else if p.extension().is_some_and(|x| x == "yaml") {
                v.push((Kind::Scene, p));
            }
        }
    }
    v
}

/// A counter-based stream of random words for one input.
struct Rng {
    seed: u32,
    input: u32,
    n: u32,
}

impl Rng {
    fn next(&mut self) -> u32 {
        self.n += 1;
        rand_u32(self.seed, self.input, self.n, 0)
    }
    fn below(&mut self, n: usize) -> usize {
        if n == 0 {
            0
        } else {
            self.next() as usize % n
        }
    }
}

const TOKENS: &[&str] = &[
    "[",
    "]",
    "{",
    "}",
    ":",
    "- ",
    "\n",
    "  ",
    "*a",
    "&a ",
    ".inf",
    "-.inf",
    ".nan",
    "-1",
    "0",
    "1e308",
    "4294967295",
    "18446744073709551616",
    "~",
    "'",
    "\"",
    "\0",
    "#",
    "!!binary",
    ",",
    "..",
    "/",
    "-",
];

/// One byte-level mutation: flip, insert, delete, duplicate, truncate, token.
fn mutate_bytes(b: &mut Vec<u8>, r: &mut Rng) {
    let len = b.len();
    match r.below(6) {
        0 if len > 0 => {
            let i = r.below(len);
            b[i] ^= 1 << r.below(8);
        }
        1 => {
            let i = r.below(len + 1);
            b.insert(i, r.next() as u8);
        }
        2 if len > 0 => {
            let i = r.below(len);
            let n = 1 + r.below(16.min(len - i));
            b.drain(i..i + n);
        }
        3 if len > 0 => {
            let i = r.below(len);
            let n = 1 + r.below(64.min(len - i));
            let piece: Vec<u8> = b[i..i + n].to_vec();
            let at = r.below(len + 1);
            b.splice(at..at, piece);
        }
        4 => b.truncate(r.below(len + 1)),
        _ => {
            let t = TOKENS[r.below(TOKENS.len())].as_bytes();
            let i = r.below(len + 1);
            b.splice(i..i, t.iter().copied());
        }
    }
}

fn interesting(r: &mut Rng) -> Value {
    let pick = [
        "-1",
        "0",
        "1",
        "1e308",
        "-1e308",
        ".nan",
        ".inf",
        "4294967295",
        "18446744073709551615",
        "\"\"",
        "[]",
        "{}",
        "[1, 2, 3]",
        "{a: 1}",
        "true",
        "~",
        "-x",
        "\"../../etc\"",
        "[[[[1]]]]",
        "[100000, 100000, 100000]",
    ];
    serde_yaml::from_str(pick[r.below(pick.len())]).unwrap_or(Value::Null)
}

/// Replaces, deletes or duplicates one node of a YAML tree.
fn mutate_tree(v: &mut Value, r: &mut Rng, depth: usize) {
    let children = match v {
        Value::Mapping(m) => m.len(),
        Value::Sequence(s) => s.len(),
        _ => 0,
    };
    if children == 0 || depth > 8 || r.below(4) == 0 {
        *v = interesting(r);
        return;
    }
    let i = r.below(children);
    match v {
        Value::Mapping(m) => {
            let key = m.keys().nth(i).cloned().unwrap_or(Value::Null);
            match r.below(5) {
                0 => {
                    m.remove(&key);
                }
                1 => {
                    let extra = Value::String(format!("fuzz_{}", r.below(3)));
                    m.insert(extra, interesting(r));
                }
                _ => {
                    if let Some(c) = m.get_mut(&key) {
                        mutate_tree(c, r, depth + 1);
                    }
                }
            }
        }
        Value::Sequence(s) => match r.below(4) {
            0 => {
                s.remove(i);
            }
            1 => {
                let c = s[i].clone();
                s.push(c);
            }
            _ => mutate_tree(&mut s[i], r, depth + 1),
        },
        _ => {}
    }
}

/// Rewrites one number of the `.npy` header's shape or its descr.
fn mutate_npy_header(b: &mut Vec<u8>, r: &mut Rng) {
    let end = b.len().min(256);
    let Ok(text) = std::str::from_utf8(&b[10.min(end)..end]) else {
        return mutate_bytes(b, r);
    };
    let repl = [
        ("'shape': (", "'shape': (3000, 3000, 3000, "),
        ("'shape': (", "'shape': (18446744073709551615, "),
        ("'shape': (", "'shape': (0, "),
        ("'shape': (", "'shape': (-1, "),
        ("<f4", ">f4"),
        ("<f4", "<f8"),
        ("<u4", "<i8"),
        ("False", "True"),
        ("'descr'", "'dtype'"),
    ];
    let (from, to) = repl[r.below(repl.len())];
    if let Some(i) = text.find(from) {
        let i = i + 10;
        b.splice(i..i + from.len(), to.bytes());
    } else {
        mutate_bytes(b, r);
    }
}

/// Loads `path` as `kind` the way `hpjudge check` would: a manifest against
/// the project's thresholds; thresholds, a perf file or a scene through
/// `check.yaml` (one case naming `scene.yaml`) in `dir`, with `dir`'s
/// thresholds and perf file. Ok or Err are both fine, a panic is not.
fn load(kind: Kind, path: &Path, dir: &Path) -> Result<(), String> {
    let project_th = Path::new(env!("CARGO_MANIFEST_DIR")).join("thresholds.yaml");
    let check = |manifest: &Path, th: &Path| {
        load_inputs(manifest, Some(th), Some("ci"))
            .map(drop)
            .map_err(|e| e.to_string())
    };
    match kind {
        Kind::Manifest => check(path, &project_th),
        Kind::Thresholds | Kind::Perf | Kind::Scene => {
            check(&dir.join("check.yaml"), &dir.join("thresholds.yaml"))
        }
        Kind::Npy => Tensor::read_npy_within(path, MemBudget::fixed(1 << 30))
            .map(drop)
            .map_err(|e| e.to_string()),
    }
}

#[test]
fn twenty_thousand_mutated_inputs_are_refused_within_a_second_or_load_no_slower_than_their_original(
) {
    let files = corpus();
    assert!(files.len() >= 30, "corpus of {} files", files.len());
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    // A TESTS/ of links to the real folders, so that mutated manifests find
    // the scenes and includes their originals name (and get validated past them).
    let dir = std::env::temp_dir().join(format!("hp-fuzz-{}", std::process::id()));
    let tests = dir.join("TESTS");
    std::fs::create_dir_all(tests.join("fuzz")).unwrap();
    std::fs::copy(root.join("thresholds.yaml"), dir.join("thresholds.yaml")).unwrap();
    std::fs::copy(
        root.join("perf_scenarios.yaml"),
        dir.join("perf_scenarios.yaml"),
    )
    .unwrap();
    // Scenes sit where the files they name (grids/, hash/, nerf/) resolve.
    std::fs::copy(
        root.join("TESTS/scenes/rays_pinhole.yaml"),
        dir.join("scene.yaml"),
    )
    .unwrap();
    for e in std::fs::read_dir(root.join("TESTS/scenes"))
        .unwrap()
        .flatten()
    {
        if e.path().is_dir() {
            #[cfg(unix)]
            let _ = std::os::unix::fs::symlink(e.path(), dir.join(e.file_name()));
        }
    }
    std::fs::write(
        dir.join("check.yaml"),
        "cases:\n  - id: s\n    op: selftest.good\n    scene: scene.yaml\n",
    )
    .unwrap();
    for e in std::fs::read_dir(root.join("TESTS")).unwrap().flatten() {
        if e.path().is_dir() {
            #[cfg(unix)]
            let _ = std::os::unix::fs::symlink(e.path(), tests.join(e.file_name()));
        }
    }
    let per_file = INPUTS.div_ceil(files.len() as u32);
    let mut problems = Vec::new();
    let (mut loaded, mut refused, mut slowest) = (0u32, 0u32, 0.0f64);
    for (fi, (kind, src)) in files.iter().enumerate() {
        let original = std::fs::read(src).unwrap();
        let tree: Option<Value> = (*kind != Kind::Npy)
            .then(|| serde_yaml::from_slice(&original).ok())
            .flatten();
        // Mutated manifests sit where their includes and scenes resolve.
        let target = match kind {
            Kind::Manifest if src.parent() == Some(&root.join("TESTS")) => {
                tests.join("manifest.yaml")
            }
            Kind::Manifest => tests.join("fuzz/manifest.yaml"),
            Kind::Thresholds => dir.join("thresholds.yaml"),
            Kind::Perf => dir.join("perf_scenarios.yaml"),
            Kind::Scene => dir.join("scene.yaml"),
            Kind::Npy => dir.join(src.file_name().unwrap()),
        };
        // A mutant that loads may do the original's real work (a mesh scene
        // voxelises its mesh): it is held to 3x the original's own load time
        // under the same machine load; a refusal is held to MAX_SECONDS.
        std::fs::write(&target, &original).unwrap();
        let t = Instant::now();
        let _ = load(*kind, &target, &dir);
        let loaded_limit = MAX_SECONDS.max(3.0 * t.elapsed().as_secs_f64());
        for k in 0..per_file {
            let mut r = Rng {
                seed: 0x11,
                input: fi as u32 * 1_000_000 + k,
                n: 0,
            };
            let bytes = match (kind, &tree, k % 2) {
                (Kind::Npy, _, 0) => {
                    let mut b = original.clone();
                    mutate_npy_header(&mut b, &mut r);
                    b
                }
                (_, Some(t), 0) => {
                    let mut t = t.clone();
                    for _ in 0..1 + r.below(3) {
                        mutate_tree(&mut t, &mut r, 0);
                    }
                    serde_yaml::to_string(&t).unwrap_or_default().into_bytes()
                }
                _ => {
                    let mut b = original.clone();
                    for _ in 0..1 + r.below(4) {
                        mutate_bytes(&mut b, &mut r);
                    }
                    b
                }
            };
            std::fs::write(&target, &bytes).unwrap();
            let t = Instant::now();
            let res = std::panic::catch_unwind(|| load(*kind, &target, &dir));
            let secs = t.elapsed().as_secs_f64();
            slowest = slowest.max(secs);
            let limit = match res {
                Ok(Ok(())) => {
                    loaded += 1;
                    loaded_limit
                }
                Ok(Err(_)) => {
                    refused += 1;
                    MAX_SECONDS
                }
                Err(_) => {
                    problems.push(format!("{} input {k}: panicked", src.display()));
                    MAX_SECONDS
                }
            };
            if secs > limit {
                problems.push(format!("{} input {k}: took {secs:.2} s", src.display()));
            }
        }
        // The next file is checked against this one's original.
        std::fs::write(&target, &original).unwrap();
    }
    let _ = std::fs::remove_dir_all(&dir);
    eprintln!(
        "fuzz: {} files, {} inputs: {loaded} loaded, {refused} refused, slowest {slowest:.3} s",
        files.len(),
        loaded + refused
    );
    assert!(loaded + refused >= INPUTS, "{loaded} + {refused}");
    assert!(
        problems.is_empty(),
        "{}",
        problems[..problems.len().min(10)].join("\n")
    );
}
