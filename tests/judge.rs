//! The one integration-test binary: drives the `hpjudge` executable on the
//! judge's self-test and on bad inputs, each of which must get a clear
//! error naming what was wrong and exit code 2.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn hpjudge() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_hpjudge"));
    c.current_dir(env!("CARGO_MANIFEST_DIR")).env_remove("CI");
    c
}

fn tmp(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("hpjudge-it-{}-{name}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

fn text(o: &Output) -> String {
    format!(
        "{}{}",
        String::from_utf8_lossy(&o.stdout),
        String::from_utf8_lossy(&o.stderr)
    )
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
    let o = hpjudge()
        .args(["run"])
        .arg(&m)
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
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
    let o = hpjudge()
        .args(["run", "TESTS/selftest/manifest.yaml", "--json", "--out"])
        .arg(&d)
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let b: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
    let cases = b["cases"].as_array().unwrap();
    assert!(cases.len() >= 12);
    for c in cases {
        let expect = c["expect"].as_str().unwrap().to_uppercase();
        let got = c["results"][0]["verdict"].as_str().unwrap();
        assert_eq!(got, expect, "case {}", c["id"]);
    }
    assert_eq!(b["schema_version"], 1);
    let ids: Vec<&str> = cases.iter().map(|c| c["id"].as_str().unwrap()).collect();
    let mut sorted = ids.clone();
    sorted.sort();
    assert_eq!(ids, sorted, "cases sorted by id");
}

#[test]
fn plain_run_ends_with_the_summary_line_and_writes_junit() {
    let d = tmp("summary");
    let o = hpjudge()
        .args([
            "run",
            "TESTS/rays/manifest.yaml",
            "--filter",
            "rays_clip",
            "--out",
        ])
        .arg(&d)
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
    let o = hpjudge()
        .arg("run")
        .arg(&m)
        .arg("--dump-failing")
        .arg("--out")
        .arg(d.join("out"))
        .output()
        .unwrap();
    let t = text(&o);
    assert_eq!(o.status.code(), Some(1), "{t}");
    assert!(
        t.contains("hpjudge run") && t.contains("--filter planted_fail"),
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
