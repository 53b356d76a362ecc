//! The one integration-test binary: drives the `hpjudge` executable on the
//! judge's self-test and on bad inputs, each of which must get a clear
//! error naming what was wrong and exit code 2.

mod common;

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

use common::{exe, hpjudge, run_cmd, run_out, text};

fn tmp(name: &str) -> common::TmpDir {
    common::tmp_in("it", name)
}

/// Writes a manifest (with a copy of the project's thresholds beside it).
fn manifest(dir: &Path, body: &str) -> PathBuf {
    std::fs::copy(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("thresholds.yaml"),
        dir.join("thresholds.yaml"),
    )
    .unwrap();
    let scenes = Path::new(env!("CARGO_MANIFEST_DIR")).join("TESTS/scenes");
    let body = body.replace("SCENES", &scenes.display().to_string());
    let p = dir.join("manifest.yaml");
    std::fs::write(&p, body).unwrap();
    p
}

fn bad_input(body: &str, expect: &[&str]) {
    let d = tmp("bad");
    let m = manifest(&d, body);
    let o = run_out(&m, &d.join("out"), &[]);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(2), "{t}");
    for e in expect {
        assert!(t.contains(e), "expected {e:?} in: {t}");
    }
    assert!(
        !d.join("out/scoreboard.json").exists(),
        "nothing may run on bad input"
    );
}

#[test]
fn judge_self_test_gets_every_expected_verdict() {
    let d = tmp("selftest");
    let o = run_out("TESTS/selftest/manifest.yaml", &d, &["--json"]);
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let cases = b["cases"].as_array().unwrap();
    assert!(cases.len() >= 12);
    for c in cases {
        let expect = c["expect"].as_str().unwrap().to_uppercase();
        let got = c["results"][0]["verdict"].as_str().unwrap();
        assert_eq!(got, expect, "case {}", c["id"]);
    }
    assert_eq!(b["schema_version"], 2);
    let ids: Vec<&str> = cases.iter().map(|c| c["id"].as_str().unwrap()).collect();
    let mut sorted = ids.clone();
    sorted.sort();
    assert_eq!(ids, sorted, "cases sorted by id");
}

#[test]
fn plain_run_ends_with_the_summary_line_and_writes_junit() {
    let d = tmp("summary");
    let o = run_cmd("TESTS/rays/manifest.yaml", &d, &["--filter", "rays_clip"])
        .arg("--junit")
        .arg(d.join("junit.xml"))
        .output()
        .unwrap();
    let out = String::from_utf8_lossy(&o.stdout);
    assert_eq!(
        out.lines().last(),
        Some("2 passed, 0 failed, 0 skipped"),
        "{out}"
    );
    let j = std::fs::read_to_string(d.join("junit.xml")).unwrap();
    assert!(
        j.contains("tests=\"2\"") && j.contains("rays_clip_exact_f64 [cpu]"),
        "{j}"
    );
}

#[test]
fn malformed_yaml_names_file_and_line() {
    bad_input(
        "cases:\n  - id: a\n    op: [unclosed\n",
        &["manifest.yaml:", "line"],
    );
}

#[test]
fn unknown_key_is_refused_with_its_path() {
    bad_input(
        "cases:\n  - id: a\n    op: selftest.good\n    colour: red\n",
        &["unknown field `colour`", "cases[0]"],
    );
}

#[test]
fn unknown_operation_and_assertion_are_refused() {
    bad_input(
        "cases:\n  - id: a\n    op: volume.nope\n",
        &["unknown operation \"volume.nope\""],
    );
    bad_input(
        "cases:\n  - id: a\n    op: selftest.good\n    assert:\n      - looks_fine: {}\n",
        &["looks_fine"],
    );
}

#[test]
fn missing_threshold_name_is_refused() {
    bad_input(
        "cases:\n  - id: a\n    op: selftest.gradient\n    assert:\n      - fd_rel_err: {a: grad, b: fd, tol: no_such_tol}\n",
        &["no tolerance \"no_such_tol\"", "manifest.yaml:2"],
    );
}

#[test]
fn missing_scene_and_include_files_are_refused() {
    bad_input(
        "cases:\n  - id: a\n    op: rays.generate\n    scene: nowhere.yaml\n",
        &["nowhere.yaml does not exist"],
    );
    bad_input("include: [gone.yaml]\n", &["gone.yaml does not exist"]);
}

#[test]
fn case_id_escaping_the_out_dir_is_refused() {
    bad_input(
        "cases:\n  - id: ../../etc\n    op: selftest.good\n",
        &["must match"],
    );
}

#[test]
fn include_cycles_and_alias_bombs_are_refused() {
    let d = tmp("cycle");
    let m = manifest(&d, "include: [manifest.yaml]\n");
    let o = hpjudge().arg("check").arg(&m).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("include cycle"), "{}", text(&o));
    let mut bomb = String::from("a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n");
    for i in 1..10 {
        let p = i - 1;
        bomb += &format!(
            "a{i}: &a{i} [*a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}, *a{p}]\n"
        );
    }
    bomb += "cases: []\n";
    bad_input(&bomb, &["manifest.yaml"]);
}

#[test]
fn zero_and_absurd_image_sizes_are_refused_before_allocating() {
    let d = tmp("sizes");
    let o = hpjudge()
        .args([
            "render",
            "TESTS/scenes/rays_pinhole.yaml",
            "--set",
            "width=0",
            "--out",
        ])
        .arg(&d)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(text(&o).contains("width: 0 is not in"), "{}", text(&o));
    let o = hpjudge()
        .args([
            "render",
            "TESTS/scenes/rays_pinhole.yaml",
            "--set",
            "width=60000",
            "--set",
            "height=60000",
        ])
        .args(["--mem-limit", "1G", "--out"])
        .arg(&d)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o).contains("out of memory: f_ray rays needs"),
        "{}",
        text(&o)
    );
}

#[test]
fn wrong_npy_dtype_or_shape_is_refused() {
    let d = tmp("npy");
    let bad = d.join("rays.npy");
    let t = hotpath::tensor::Tensor::from_shape_vec(&[4, 9], vec![0i32; 36]).unwrap();
    t.write_npy(&bad).unwrap();
    let o = hpjudge()
        .args(["render", "TESTS/scenes/rays_pinhole.yaml", "--rays"])
        .arg(&bad)
        .arg("--out")
        .arg(&d)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    assert!(
        text(&o).contains("rays must be float (N, 9), got int32"),
        "{}",
        text(&o)
    );
    let t = hotpath::tensor::Tensor::from_shape_vec(&[4, 8], vec![0.0f64; 32]).unwrap();
    t.write_npy(&bad).unwrap();
    let o = hpjudge()
        .args(["render", "TESTS/scenes/rays_pinhole.yaml", "--rays"])
        .arg(&bad)
        .arg("--out")
        .arg(&d)
        .output()
        .unwrap();
    assert!(text(&o).contains("[4, 8]"), "{}", text(&o));
    std::fs::write(&bad, b"not a numpy file").unwrap();
    let o = hpjudge()
        .args(["render", "TESTS/scenes/rays_pinhole.yaml", "--rays"])
        .arg(&bad)
        .arg("--out")
        .arg(&d)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}

#[test]
fn dump_failing_writes_rays_that_render_replays() {
    let d = tmp("dump");
    let m = manifest(
        &d,
        "cases:\n  - id: planted_fail\n    op: rays.generate\n    scene: SCENES/rays_pinhole.yaml\n    set: {width: 8, height: 8}\n    assert:\n      - range: {tensor: t0, min: 100, max: 200}\n",
    );
    let o = run_out(&m, &d.join("out"), &["--dump-failing"]);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(1), "{t}");
    assert!(
        t.contains("hpjudge run")
            && t.contains("--filter=planted_fail")
            && t.contains("repro/planted_fail-cpu"),
        "repro line missing: {t}"
    );
    let case = d.join("out/planted_fail/cpu");
    assert!(case.join("rays.npy").is_file() && case.join("scene.yaml").is_file());
    let o = hpjudge()
        .arg("render")
        .arg(case.join("scene.yaml"))
        .arg("--rays")
        .arg(case.join("rays.npy"))
        .arg("--out")
        .arg(d.join("replay"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let a = hotpath::tensor::Tensor::read_npy(&case.join("t1.npy")).unwrap();
    let b = hotpath::tensor::Tensor::read_npy(&d.join("replay/t1.npy")).unwrap();
    assert_eq!(a.to_f64_vec(), b.to_f64_vec());
}

fn perf_json(path: &Path, center: f64, rel: f64) {
    let samples: Vec<f64> = (0..9)
        .map(|i| center * (1.0 + rel * (i as f64 - 4.0) / 4.0))
        .collect();
    let m = hotpath::judge::perf::MetricStats::of(samples);
    let v = serde_json::json!({"schema_version": 1, "environment": {}, "scenarios": [
        {"id": "s", "op": "rays.generate", "backend": "cpu", "precision": "f32", "metrics": {"samples_per_s": m}}]});
    std::fs::write(path, v.to_string()).unwrap();
}

#[test]
fn compare_flags_a_planted_30_percent_drop_and_ignores_noise() {
    let d = tmp("compare");
    perf_json(&d.join("base.json"), 100.0, 0.04);
    perf_json(&d.join("drop.json"), 70.0, 0.04);
    perf_json(&d.join("noise.json"), 97.0, 0.04);
    let o = hpjudge()
        .arg("compare")
        .arg(d.join("base.json"))
        .arg(d.join("drop.json"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(1), "{}", text(&o));
    assert!(text(&o).contains("Regression"));
    let o = hpjudge()
        .arg("compare")
        .arg(d.join("base.json"))
        .arg(d.join("noise.json"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
}

#[test]
fn bless_refuses_under_ci() {
    let o = hpjudge()
        .args(["bless", "TESTS/rays/manifest.yaml"])
        .env("CI", "true")
        .output()
        .unwrap();
    assert_ne!(o.status.code(), Some(0));
    assert!(
        text(&o).contains("refuses to run when CI is set"),
        "{}",
        text(&o)
    );
}

#[test]
fn version_names_the_git_revision() {
    let o = hpjudge().arg("--version").output().unwrap();
    let t = text(&o);
    assert!(t.starts_with("hpjudge ") && t.contains('('), "{t}");
}

/// A 192-byte `.npy` whose header claims (3000, 3000, 3000) float32.
fn huge_header_npy(path: &Path) {
    let mut h =
        "{'descr': '<f4', 'fortran_order': False, 'shape': (3000, 3000, 3000), }".to_string();
    while !(10 + h.len() + 1).is_multiple_of(64) {
        h.push(' ');
    }
    h.push('\n');
    let mut b = b"\x93NUMPY\x01\x00".to_vec();
    b.extend((h.len() as u16).to_le_bytes());
    b.extend(h.as_bytes());
    b.resize(192, 0);
    std::fs::write(path, b).unwrap();
}

#[test]
fn a_npy_header_claiming_108_gb_is_refused_on_every_load_path() {
    let d = tmp("hugenpy");
    huge_header_npy(&d.join("huge.npy"));
    std::fs::write(
        d.join("scene.yaml"),
        "renderer: volume\ncamera: {type: ortho, position: [0,0,3], target: [0,0,0]}\nwidth: 8\nheight: 8\nfield: {type: grid, file: huge.npy}\n",
    )
    .unwrap();
    let m = manifest(
        &d,
        "cases:\n  - id: a\n    op: volume.render\n    scene: scene.yaml\n",
    );
    let claim = "108000000000 bytes";
    let o = hpjudge().arg("check").arg(&m).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "check: {}", text(&o));
    assert!(text(&o).contains(claim), "check: {}", text(&o));
    let o = hpjudge()
        .arg("render")
        .arg(d.join("scene.yaml"))
        .arg("--out")
        .arg(d.join("r"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "render grid: {}", text(&o));
    let o = hpjudge()
        .args(["render", "TESTS/scenes/rays_pinhole.yaml", "--rays"])
        .arg(d.join("huge.npy"))
        .arg("--out")
        .arg(d.join("r"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "--rays: {}", text(&o));
    assert!(text(&o).contains(claim), "--rays: {}", text(&o));
    let o = hpjudge()
        .args(["render", "TESTS/scenes/vol_constant.yaml", "--grad-from"])
        .arg(d.join("huge.npy"))
        .arg("--out")
        .arg(d.join("r"))
        .output()
        .unwrap();
    assert!(
        matches!(o.status.code(), Some(1 | 2)),
        "--grad-from: {}",
        text(&o)
    );
    assert!(text(&o).contains("3000"), "--grad-from: {}", text(&o));
    std::fs::create_dir_all(d.join("GOLDENS")).unwrap();
    huge_header_npy(&d.join("GOLDENS/huge.npy"));
    let m = manifest(
        &d,
        "cases:\n  - id: g\n    op: selftest.good\n    assert:\n      - max_abs: {a: rgb, b: \"golden:huge.npy\", tol: exact}\n",
    );
    let o = run_out(&m, &d.join("out"), &["--json"]);
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap_or_default();
    let r = &b["cases"][0]["results"][0];
    assert_eq!(r["verdict"], "ERROR", "golden: {}", text(&o));
    assert!(
        r["reason"].as_str().unwrap_or("").contains(claim),
        "golden: {r}"
    );
}

/// Waits up to `secs` for a child; kills it and returns None past that.
fn wait_for(child: &mut std::process::Child, secs: f64) -> Option<std::process::ExitStatus> {
    let t = std::time::Instant::now();
    while t.elapsed().as_secs_f64() < secs {
        if let Ok(Some(s)) = child.try_wait() {
            return Some(s);
        }
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let _ = child.kill();
    let _ = child.wait();
    None
}

/// Pids whose parent is `pid` (from /proc).
fn children_of(pid: u32) -> Vec<u32> {
    let mut v = Vec::new();
    for e in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(p) = e.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(format!("/proc/{p}/stat")) else {
            continue;
        };
        let after = stat.rsplit(')').next().unwrap_or("");
        let ppid: u32 = after
            .split_whitespace()
            .nth(1)
            .and_then(|x| x.parse().ok())
            .unwrap_or(0);
        if ppid == pid {
            v.push(p);
        }
    }
    v
}

/// Whether `pid` is alive (not gone, not a zombie).
fn alive(pid: u32) -> bool {
    std::fs::read_to_string(format!("/proc/{pid}/stat"))
        .map(|s| {
            let state = s.rsplit(')').next().unwrap_or("").split_whitespace().next();
            state != Some("Z")
        })
        .unwrap_or(false)
}

/// Starts `hpjudge run` on one hanging case into `<d>/out` and waits (up to
/// 20 s) for its worker; returns the judge and the worker pids.
fn start_hanging_run(d: &Path) -> (std::process::Child, Vec<u32>) {
    let m = manifest(d, "cases:\n  - id: hang\n    op: selftest.hang\n");
    let judge = run_cmd(&m, &d.join("out"), &[])
        .stdout(std::process::Stdio::null())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let t = std::time::Instant::now();
    let mut workers = vec![];
    while workers.is_empty() && t.elapsed().as_secs() < 20 {
        std::thread::sleep(std::time::Duration::from_millis(20));
        workers = children_of(judge.id());
    }
    (judge, workers)
}

#[test]
fn a_second_run_into_the_same_out_folder_is_refused_naming_the_holder() {
    let d = tmp("lock");
    let (mut first, _) = start_hanging_run(&d);
    let o = run_out("TESTS/selftest/manifest.yaml", &d.join("out"), &[]);
    let _ = first.kill();
    let _ = first.wait();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains(&format!("in use by hpjudge pid {}", first.id())),
        "{}",
        text(&o)
    );
}

#[test]
fn killing_the_judge_with_sigkill_kills_its_worker() {
    let d = tmp("kill9");
    let (mut judge, workers) = start_hanging_run(&d);
    assert_eq!(workers.len(), 1, "no worker started");
    judge.kill().unwrap();
    judge.wait().unwrap();
    let t = std::time::Instant::now();
    while alive(workers[0]) && t.elapsed().as_secs_f64() < 3.0 {
        std::thread::sleep(std::time::Duration::from_millis(20));
    }
    let survived = alive(workers[0]);
    if survived {
        let _ = Command::new("kill")
            .arg("-9")
            .arg(workers[0].to_string())
            .status();
    }
    assert!(!survived, "worker {} outlived the judge by 3 s", workers[0]);
}

#[test]
fn a_worker_ends_itself_at_its_own_deadline() {
    use hotpath::judge::job::{Job, Task};
    let d = tmp("deadline");
    let m = manifest(&d, "cases:\n  - id: hang\n    op: selftest.hang\n");
    let man = hotpath::judge::manifest::Manifest::load(&m).unwrap();
    let th = hotpath::judge::thresholds::Thresholds::load(&d.join("thresholds.yaml"), "default")
        .unwrap();
    let job = Job {
        task: Task::Case {
            case: Box::new(man.cases[0].clone()),
            backend: hotpath::judge::ops::BackendKind::Cpu,
        },
        scenes: Default::default(),
        thresholds: th,
        perf: Default::default(),
        out: d.join("out"),
        goldens: d.join("GOLDENS"),
        seed: 0,
        threads: 1,
        mem_limit: None,
        dump: false,
        bless: false,
        deadline_s: 1.0,
    };
    let mut w = hpjudge()
        .arg("worker")
        .arg("--result")
        .arg(d.join("r.json"))
        .stdin(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    use std::io::Write;
    let _ = w
        .stdin
        .take()
        .unwrap()
        .write_all(serde_yaml::to_string(&job).unwrap().as_bytes());
    let s = wait_for(&mut w, 10.0).expect("worker still running 10 s after a 1 s deadline");
    assert_eq!(s.code(), Some(124));
}

#[test]
fn a_closed_stdout_ends_the_run_quietly_with_an_incomplete_scoreboard() {
    use std::io::BufRead;
    let d = tmp("epipe");
    let mut judge = run_cmd("TESTS/selftest/manifest.yaml", &d.join("out"), &[])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let mut lines = std::io::BufReader::new(judge.stdout.take().unwrap()).lines();
    for _ in 0..3 {
        lines.next().unwrap().unwrap();
    }
    drop(lines);
    let status = wait_for(&mut judge, 60.0).expect("judge did not end");
    let mut err = String::new();
    std::io::Read::read_to_string(&mut judge.stderr.take().unwrap(), &mut err).unwrap();
    assert!(!err.contains("panicked"), "{err}");
    assert_eq!(status.code(), Some(1), "{err}");
    let b: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("out/scoreboard.json")).unwrap())
            .unwrap();
    assert_eq!(b["complete"], false, "{b}");
    assert!(
        b["cases_done"].as_u64().unwrap() < b["cases_total"].as_u64().unwrap(),
        "{b}"
    );
}

#[test]
fn a_complete_run_records_counts_and_input_hashes() {
    let d = tmp("hashes");
    let o = run_out(
        "TESTS/rays/manifest.yaml",
        &d,
        &["--filter", "rays_clip", "--json"],
    );
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    assert_eq!(b["complete"], true, "{}", text(&o));
    assert_eq!(b["cases_total"], 2);
    assert_eq!(b["cases_done"], 2);
    for k in ["manifest_tree_sha256", "thresholds_sha256", "scenes_sha256"] {
        assert_eq!(
            b["inputs"][k].as_str().unwrap_or("").len(),
            64,
            "{k}: {}",
            b["inputs"]
        );
    }
}

fn thresholds_with(dir: &Path, from: &str, to: &str) -> PathBuf {
    let t = std::fs::read_to_string(Path::new(env!("CARGO_MANIFEST_DIR")).join("thresholds.yaml"))
        .unwrap();
    assert!(t.contains(from), "{from}");
    let p = dir.join("th.yaml");
    std::fs::write(&p, t.replacen(from, to, 1)).unwrap();
    p
}

#[test]
fn infinite_tolerances_and_nan_time_limits_are_refused_on_load() {
    let d = tmp("thvals");
    for (from, to, key) in [
        (
            "  exact: {}",
            "  exact: {atol: .inf}",
            "tolerances.exact.atol",
        ),
        ("  default: 120", "  default: .nan", "timeouts.default"),
        (
            "  selftest_short: 3",
            "  selftest_short: -3",
            "timeouts.selftest_short",
        ),
    ] {
        let th = thresholds_with(&d, from, to);
        let o = hpjudge()
            .args(["check", "TESTS/selftest/manifest.yaml", "--thresholds"])
            .arg(&th)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(2), "{to}: {}", text(&o));
        assert!(text(&o).contains(key), "{to}: {}", text(&o));
    }
}

#[test]
fn deeply_nested_yaml_is_refused_in_under_a_second() {
    let d = tmp("nest");
    let m = manifest(
        &d,
        &("cases: ".to_string() + &"[".repeat(100_000) + &"]".repeat(100_000)),
    );
    let t = std::time::Instant::now();
    let o = hpjudge().arg("check").arg(&m).output().unwrap();
    assert!(t.elapsed().as_secs_f64() < 1.0, "{:?}", t.elapsed());
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("nests deeper than"), "{}", text(&o));
}

#[test]
fn absurd_thread_counts_are_refused() {
    let d = tmp("threads");
    let mut c = run_cmd("TESTS/selftest/manifest.yaml", &d, &["--threads", "100000"])
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let s = wait_for(&mut c, 10.0).expect("still running after 10 s");
    let o = c.wait_with_output().unwrap();
    assert_eq!(s.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("over the limit of 1024"), "{}", text(&o));
}

#[test]
fn a_directory_given_as_a_file_is_called_a_directory() {
    let d = tmp("isdir");
    let o = hpjudge().arg("check").arg(&d).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("is a directory"), "{}", text(&o));
    std::fs::create_dir_all(d.join("scene.yaml")).unwrap();
    bad_input(
        &format!(
            "cases:\n  - id: a\n    op: rays.generate\n    scene: {}\n",
            d.join("scene.yaml").display()
        ),
        &["is a directory"],
    );
}

#[test]
fn ci_overrides_and_ref_sets_are_validated_by_check() {
    let d = tmp("ciset");
    let m = manifest(
        &d,
        "cases:\n  - id: a\n    op: rays.generate\n    scene: SCENES/rays_pinhole.yaml\n    ci: {width: 0}\n",
    );
    let o = hpjudge().arg("check").arg(&m).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "ci: {}", text(&o));
    assert!(text(&o).contains("cases[a].ci"), "ci: {}", text(&o));
    let m = manifest(
        &d,
        "cases:\n  - id: a\n    op: rays.generate\n    scene: SCENES/rays_pinhole.yaml\n    refs:\n      r: {set: {height: -4}}\n",
    );
    let o = hpjudge().arg("check").arg(&m).output().unwrap();
    assert_eq!(o.status.code(), Some(2), "ref set: {}", text(&o));
    assert!(text(&o).contains("refs.r"), "ref set: {}", text(&o));
}

#[test]
fn perf_gates_outside_a_perf_profile_are_a_skip_with_the_measured_value() {
    let d = tmp("perfskip");
    let o = hpjudge()
        .args([
            "run",
            "TESTS/rays/manifest.yaml",
            "--filter",
            "rays_throughput_1024",
            "--profile",
            "default",
            "--json",
            "--out",
        ])
        .arg(&d)
        .output()
        .unwrap();
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let r = &b["cases"][0]["results"][0];
    assert_eq!(r["verdict"], "SKIP", "{r}");
    assert!(
        r["reason"].as_str().unwrap().contains("mrays_per_s = "),
        "{r}"
    );
}

#[test]
fn compare_refuses_mixed_kinds_unknown_versions_and_bad_thresholds() {
    let d = tmp("compare2");
    perf_json(&d.join("base.json"), 100.0, 0.04);
    let board = serde_json::json!({"schema_version": 2, "cases": []});
    std::fs::write(d.join("board.json"), board.to_string()).unwrap();
    let o = hpjudge()
        .arg("compare")
        .arg(d.join("base.json"))
        .arg(d.join("board.json"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "mixed: {}", text(&o));
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("base.json")).unwrap()).unwrap();
    v["schema_version"] = 99.into();
    std::fs::write(d.join("v99.json"), v.to_string()).unwrap();
    let o = hpjudge()
        .arg("compare")
        .arg(d.join("base.json"))
        .arg(d.join("v99.json"))
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "version: {}", text(&o));
    let o = hpjudge()
        .arg("compare")
        .arg(d.join("base.json"))
        .arg(d.join("base.json"))
        .args(["--threshold", "NaN"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "NaN: {}", text(&o));
}

#[test]
fn compare_counts_a_renamed_or_errored_scenario_as_a_regression() {
    let d = tmp("compare3");
    perf_json(&d.join("base.json"), 100.0, 0.04);
    let mut v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(d.join("base.json")).unwrap()).unwrap();
    v["scenarios"][0]["id"] = "renamed".into();
    std::fs::write(d.join("renamed.json"), v.to_string()).unwrap();
    v["scenarios"][0]["id"] = "s".into();
    v["scenarios"][0]["metrics"] = serde_json::json!({});
    v["scenarios"][0]["error"] = "worker panicked".into();
    std::fs::write(d.join("errored.json"), v.to_string()).unwrap();
    for f in ["renamed.json", "errored.json"] {
        let o = hpjudge()
            .arg("compare")
            .arg(d.join("base.json"))
            .arg(d.join(f))
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(1), "{f}: {}", text(&o));
        assert!(text(&o).contains("Regression"), "{f}: {}", text(&o));
    }
}

/// `hpjudge render SCENE args...` with a fresh out dir.
fn render(scene: &str, args: &[&str]) -> Output {
    let out = tmp("render");
    hpjudge()
        .args(["render", scene])
        .args(args)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap()
}

/// `hpjudge render SCENE args...`, failing the test when it is still
/// rendering after 10 s (killed then).
fn render_within_10_s(scene: &str, args: &[&str]) -> Output {
    let out = tmp("render10");
    let mut c = hpjudge()
        .args(["render", scene])
        .args(args)
        .arg("--out")
        .arg(&out)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped())
        .spawn()
        .unwrap();
    let s = wait_for(&mut c, 10.0);
    let o = c.wait_with_output().unwrap();
    assert!(s.is_some(), "{scene} {args:?}: still rendering after 10 s");
    o
}

/// `--param` reaches the render operation as a manifest case's `params:`
/// would: the voxel cast of 10 incoherent rays writes 10 hits (the camera
/// would write 8x8), two cast paths write the same bytes, and keys the
/// operation does not take (or takes only on the other backend) are refused
/// by name.
#[test]
fn render_passes_operation_parameters_and_refuses_unknown_ones() {
    let sphere = "TESTS/scenes/voxel_sphere.yaml";
    let small = ["--set", "width=8", "--set", "height=8"];
    let t_of = |params: &[&str]| {
        let out = tmp("param");
        let o = hpjudge()
            .args(["render", sphere])
            .args(small)
            .args(params.iter().flat_map(|p| ["--param", p]))
            .arg("--out")
            .arg(&out)
            .output()
            .unwrap();
        assert_eq!(o.status.code(), Some(0), "{params:?}: {}", text(&o));
        std::fs::read(out.join("t.npy")).unwrap()
    };
    let header = |b: &[u8]| String::from_utf8_lossy(&b[..b.len().min(128)]).into_owned();
    let camera = t_of(&[]);
    assert!(header(&camera).contains("(8, 8)"), "{}", header(&camera));
    let ten = t_of(&["rays=incoherent", "count=10", "cast=per_ray"]);
    assert!(header(&ten).contains("(10,)"), "{}", header(&ten));
    assert_eq!(ten, t_of(&["rays=incoherent", "count=10", "cast=lanes"]));
    for (param, expect) in [
        ("nope=1", "takes no parameter \"nope\""),
        ("cast=nope", "cast"),
        ("grad_from=g.npy", "--grad-from"),
        ("beam", "expected key=value"),
        ("beam=false", "the CPU's path is param cast"),
    ] {
        let o = render(sphere, &[&small[..], &["--param", param]].concat());
        assert_eq!(o.status.code(), Some(2), "{param}: {}", text(&o));
        assert!(text(&o).contains(expect), "{param}: {}", text(&o));
    }
}

#[test]
fn path_tracer_refuses_f64_rays_grad_from_and_absurd_spp_before_work() {
    let cornell = "TESTS/scenes/cornell_box.yaml";
    let small = ["--set", "width=8", "--set", "height=8", "--set", "spp=1"];
    let dir = tmp("refuse");
    let npy = dir.join("w.npy");
    std::fs::write(&npy, b"not read").unwrap();
    let npy = npy.to_str().unwrap();
    for (args, expect) in [
        (vec!["--precision", "f64"], "does not run on cpu in f64"),
        (vec!["--grad-from", npy], "--grad-from is not supported"),
        (vec!["--rays", npy], "--rays is not supported"),
    ] {
        let o = render(cornell, &[&small[..], &args].concat());
        assert_ne!(o.status.code(), Some(0), "{args:?}: {}", text(&o));
        assert!(text(&o).contains(expect), "{args:?}: {}", text(&o));
    }
    let o = render_within_10_s(cornell, &["--set", "spp=4294967295"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(
        text(&o).contains("spp") && text(&o).contains("work budget"),
        "{}",
        text(&o)
    );
}

/// Absurd work in each renderer's scene: (op, scene, overrides, key named).
type Work = (
    &'static str,
    &'static str,
    &'static [(&'static str, &'static str)],
    &'static str,
);
const ABSURD_WORK: [Work; 5] = [
    (
        "transport",
        "grin_fibre.yaml",
        &[("task.stop", "{type: steps, n: 4000000000}")],
        "task.stop.n",
    ),
    (
        "transport",
        "kerr_shadow.yaml",
        &[("max_steps", "4000000000")],
        "max_steps",
    ),
    ("voxels", "voxel_sphere.yaml", &[("depth", "22")], "depth"),
    (
        "voxels",
        "menger_sponge.yaml",
        &[("depth", "14"), ("level", "8")],
        "depth",
    ),
    (
        "volume",
        "vol_gaussian.yaml",
        &[
            ("width", "1024"),
            ("height", "1024"),
            ("max_steps", "16777216"),
            ("dt", "2.5e-7"),
            ("early_stop", "0"),
        ],
        "max_steps",
    ),
];

/// The old binary rendered each of these for hours (killed at 10 s) and
/// `check` accepted them.
#[test]
fn absurd_steps_depths_and_samples_are_refused_by_render_and_check_before_work() {
    let d = tmp("work");
    for (op, scene, sets, key) in ABSURD_WORK {
        let args: Vec<String> = sets.iter().map(|(k, v)| format!("--set={k}={v}")).collect();
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let o = render_within_10_s(&format!("TESTS/scenes/{scene}"), &args);
        let t = text(&o);
        assert_eq!(o.status.code(), Some(2), "{scene} {sets:?}: {t}");
        assert!(
            t.contains(scene) && t.contains(key) && t.contains("work budget of 2^"),
            "{t}"
        );
        let set: Vec<String> = sets.iter().map(|(k, v)| format!("{k}: {v}")).collect();
        let case = format!("  - id: a\n    op: {op}.render\n    scene: SCENES/{scene}\n");
        let m = manifest(
            &d,
            &format!("cases:\n{case}    set: {{{}}}\n", set.join(", ")),
        );
        let o = hpjudge().arg("check").arg(&m).output().unwrap();
        assert_eq!(
            o.status.code(),
            Some(2),
            "check {scene} {sets:?}: {}",
            text(&o)
        );
        assert!(text(&o).contains("work budget of 2^"), "{}", text(&o));
    }
}

/// Case ids `-rf` and `--help`: the old binary refused `--filter -rf` as
/// unknown flags (exit 2).
#[test]
fn dash_case_ids_run_filter_and_repro_into_their_own_out_folder() {
    let top = tmp("dash");
    let d = top.join("my dir");
    std::fs::create_dir_all(&d).unwrap();
    let body = "cases:\n  - id: -rf\n    op: selftest.nan_image\n    assert:\n      - no_nan_inf: {}\n  - id: --help\n    op: selftest.good\n    assert:\n      - no_nan_inf: {}\n";
    let m = manifest(&d, body);
    let o = run_out(&m, &d.join("out"), &["--filter", "-rf"]);
    let t = text(&o);
    assert_eq!(o.status.code(), Some(1), "{t}");
    assert!(t.contains("0 passed, 1 failed"), "{t}");
    let board = std::fs::read(d.join("out/scoreboard.json")).unwrap();
    let line = t
        .lines()
        .find(|l| l.trim_start().starts_with("hpjudge run "))
        .expect(&t);
    assert!(
        line.contains("'") && line.contains("--filter=-rf"),
        "{line}"
    );
    let bin = tmp("dashbin");
    std::os::unix::fs::symlink(exe(), bin.join("hpjudge")).unwrap();
    let path = format!(
        "{}:{}",
        bin.display(),
        std::env::var("PATH").unwrap_or_default()
    );
    let r = Command::new("sh")
        .args(["-c", line.trim()])
        .env("PATH", path)
        .env_remove("CI")
        .output()
        .unwrap();
    assert_eq!(r.status.code(), Some(1), "{}", text(&r));
    assert_eq!(
        std::fs::read(d.join("out/scoreboard.json")).unwrap(),
        board,
        "repro overwrote the scoreboard"
    );
    let rb = std::fs::read_to_string(d.join("out/repro/-rf-cpu/scoreboard.json")).unwrap();
    assert!(rb.contains("\"-rf\"") && !rb.contains("--help"), "{rb}");
}

/// `(verdicts by case id, input hashes)` of a `--json` run's stdout.
fn verdicts_and_hashes(o: &Output) -> (Vec<(String, String)>, serde_json::Value) {
    let b: serde_json::Value =
        serde_json::from_slice(&o.stdout).unwrap_or_else(|e| panic!("{e}: {}", text(o)));
    let v = b["cases"]
        .as_array()
        .unwrap()
        .iter()
        .map(|c| {
            let r = &c["results"][0];
            (
                c["id"].as_str().unwrap().to_string(),
                r["verdict"].as_str().unwrap().to_string(),
            )
        })
        .collect();
    (v, b["inputs"].clone())
}

/// A run whose first case is slow (a hang with a 1 s limit); while it runs,
/// the manifest, thresholds and a referenced scene are rewritten so that
/// each later case would FAIL. The verdicts and input hashes must be those
/// of the files as they were at start (the old binary re-read the scene in
/// the worker: `edited_scene` FAILed with the start hashes on the board).
#[test]
fn edits_during_a_run_change_no_verdict_and_no_input_hash() {
    let d = tmp("midrun");
    let scene = std::fs::read_to_string(
        Path::new(env!("CARGO_MANIFEST_DIR")).join("TESTS/scenes/rays_pinhole.yaml"),
    )
    .unwrap()
    .replace("width: 64", "width: 4")
    .replace("height: 64", "height: 4");
    std::fs::write(d.join("edited.yaml"), &scene).unwrap();
    std::fs::write(d.join("fixed.yaml"), &scene).unwrap();
    let body = "cases:
  - id: slow_first
    op: selftest.hang
    timeout: selftest_short
  - id: edited_manifest
    op: selftest.good
    assert:
      - range: {tensor: rgb, min: 0, max: 1}
  - id: edited_thresholds
    op: selftest.gradient
    params: {flip: true}
    assert:
      - fd_rel_err: {a: grad, b: fd, tol: selftest_grad}
  - id: edited_scene
    op: rays.generate
    scene: edited.yaml
    refs:
      ref: {scene: fixed.yaml}
    assert:
      - memcmp_same: {a: d, b: ref.d}
";
    let m = manifest(&d, body);
    let th = d.join("thresholds.yaml");
    let th_text = std::fs::read_to_string(&th).unwrap();
    let th_start = th_text
        .replacen("  selftest_short: 3", "  selftest_short: 1", 1)
        .replacen(
            "  selftest_grad: {rtol: 1.0e-6, floor: 1.0e-9}",
            "  selftest_grad: {rtol: 3.0, floor: 1.0e-9}",
            1,
        );
    std::fs::write(&th, &th_start).unwrap();
    let edit = || {
        std::fs::write(&m, body.replace("min: 0, max: 1", "min: 2, max: 3")).unwrap();
        std::fs::write(
            &th,
            th_start.replace("rtol: 3.0, floor", "rtol: 1.0e-6, floor"),
        )
        .unwrap();
        std::fs::write(
            d.join("edited.yaml"),
            scene.replace("fov_y: 40", "fov_y: 41"),
        )
        .unwrap();
    };
    let run = |out: &str, filter: &str| {
        run_cmd(
            &m,
            &d.join(out),
            &["--json", "--backend", "cpu", "--filter", filter],
        )
    };
    let before = verdicts_and_hashes(&run("before", "edited").output().unwrap());
    let judge = run("during", "_")
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::null())
        .spawn()
        .unwrap();
    let log = d.join("during/slow_first/cpu/worker.log");
    let t = std::time::Instant::now();
    while !log.exists() && t.elapsed().as_secs() < 20 {
        std::thread::sleep(std::time::Duration::from_millis(10));
    }
    edit();
    let during = verdicts_and_hashes(&judge.wait_with_output().unwrap());
    let after = verdicts_and_hashes(&run("after", "edited").output().unwrap());
    let pass = |ids: &[&str], v: &str| -> Vec<(String, String)> {
        ids.iter().map(|i| (i.to_string(), v.to_string())).collect()
    };
    let ids = ["edited_manifest", "edited_scene", "edited_thresholds"];
    assert_eq!(before.0, pass(&ids, "PASS"), "before the edit");
    assert_eq!(after.0, pass(&ids, "FAIL"), "the edit flips every case");
    let mut expect = pass(&ids, "PASS");
    expect.push(("slow_first".into(), "TIMEOUT".into()));
    expect.sort();
    assert_eq!(during.0, expect, "edited during the run");
    assert_eq!(during.1, before.1, "input hashes of the start");
    for k in ["manifest_tree_sha256", "thresholds_sha256", "scenes_sha256"] {
        assert_ne!(after.1[k], before.1[k], "{k} sees the edit");
    }
}

/// `hpjudge bless` runs each case in a worker under the run's limits: a
/// case past its time limit is killed (TIMEOUT) and a panicking one is an
/// ERROR, neither writes a golden, and the goldens of the cases around them
/// are written and listed. The old binary stopped listing at the first bad
/// case (`d_good`'s golden written but never reported).
#[test]
fn bless_kills_a_case_past_its_limit_and_keeps_the_other_goldens() {
    let d = tmp("bless");
    let m = manifest(
        &d,
        "cases:
  - id: a_good
    op: selftest.good
    assert:
      - memcmp_same: {a: rgb, b: \"golden:it/a.npy\"}
  - id: b_hang
    op: selftest.hang
    timeout: selftest_short
    assert:
      - memcmp_same: {a: x, b: \"golden:it/b.npy\"}
  - id: c_panics
    op: selftest.panic
    assert:
      - memcmp_same: {a: x, b: \"golden:it/c.npy\"}
  - id: d_good
    op: selftest.good
    assert:
      - memcmp_same: {a: t, b: \"golden:it/d.npy\"}
",
    );
    let th = d.join("thresholds.yaml");
    let t = std::fs::read_to_string(&th).unwrap();
    std::fs::write(
        &th,
        t.replacen("  selftest_short: 3", "  selftest_short: 1", 1),
    )
    .unwrap();
    let mut c = hpjudge();
    c.arg("bless")
        .arg(&m)
        .stdout(std::process::Stdio::piped())
        .stderr(std::process::Stdio::piped());
    let mut child = c.spawn().unwrap();
    let status = wait_for(&mut child, 30.0).expect("bless still running after 30 s");
    let o = child.wait_with_output().unwrap();
    let t = text(&o);
    assert_eq!(status.code(), Some(1), "{t}");
    let g = d.join("GOLDENS/it");
    for (f, blessed) in [("a", true), ("b", false), ("c", false), ("d", true)] {
        assert_eq!(g.join(format!("{f}.npy")).is_file(), blessed, "{f}: {t}");
        let line = format!("blessed {}", g.join(format!("{f}.npy")).display());
        assert_eq!(t.contains(&line), blessed, "{f}: {t}");
    }
    assert!(
        t.contains("b_hang: TIMEOUT") && t.contains("c_panics: ERROR"),
        "{t}"
    );
}
