//! Sharded runs and the report (issue 21), driving the `hpjudge` binary:
//! the shards of a run, merged, give the unsharded run's verdicts; an
//! incomplete shard set is refused; `hpjudge report` lists every case.

mod common;

use std::collections::BTreeMap;
use std::path::Path;
use std::process::Output;

use common::{hpjudge, run_cmd, text};

fn tmp(name: &str) -> common::TmpDir {
    common::tmp_in("shards", name)
}

/// The self-test and ray suites: every verdict kind, ~40 results, seconds.
const MANIFESTS: [&str; 2] = ["TESTS/selftest/manifest.yaml", "TESTS/rays/manifest.yaml"];

fn run(manifest: &str, out: &Path, extra: &[&str]) -> Output {
    run_cmd(manifest, out, &["--backend", "cpu", "--profile", "ci"])
        .args(extra)
        .output()
        .unwrap()
}

/// (case, backend) -> verdict of a scoreboard file.
fn verdicts(board: &Path) -> BTreeMap<(String, String), String> {
    let v: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(board).unwrap()).unwrap();
    let mut m = BTreeMap::new();
    for c in v["cases"].as_array().unwrap() {
        for r in c["results"].as_array().unwrap() {
            let key = (
                c["id"].as_str().unwrap().to_string(),
                r["backend"].as_str().unwrap().to_string(),
            );
            m.insert(key, r["verdict"].as_str().unwrap().to_string());
        }
    }
    m
}

#[test]
fn merged_shards_equal_the_unsharded_runs_verdicts() {
    for (i, manifest) in MANIFESTS.iter().enumerate() {
        let d = tmp(&format!("m{i}"));
        run(manifest, &d.join("whole"), &[]);
        let whole = verdicts(&d.join("whole/scoreboard.json"));
        assert!(whole.len() >= 10, "{manifest}: {} results", whole.len());
        let mut boards = vec![];
        for k in 1..=3 {
            let out = d.join(format!("s{k}"));
            run(manifest, &out, &["--partition", &format!("{k}/3")]);
            boards.push(out.join("scoreboard.json"));
        }
        let sizes: Vec<usize> = boards.iter().map(|b| verdicts(b).len()).collect();
        assert!(
            sizes.iter().all(|&n| n < whole.len()),
            "a shard ran everything: {sizes:?}"
        );
        let merged = d.join("merged.json");
        let o = hpjudge()
            .arg("merge")
            .args(&boards)
            .arg("-o")
            .arg(&merged)
            .arg("--junit")
            .arg(d.join("j.xml"))
            .output()
            .unwrap();
        assert!(
            o.status.code() == Some(0) || o.status.code() == Some(1),
            "{}",
            text(&o)
        );
        assert_eq!(verdicts(&merged), whole, "{manifest}");
        assert!(std::fs::read_to_string(d.join("j.xml"))
            .unwrap()
            .contains("<testsuite"));
    }
}

#[test]
fn an_incomplete_or_overlapping_shard_set_is_refused() {
    let d = tmp("refuse");
    let m = MANIFESTS[1];
    run(m, &d.join("s1"), &["--partition", "1/2"]);
    run(m, &d.join("s2"), &["--partition", "2/2"]);
    let merge = |boards: &[&str]| {
        let mut c = hpjudge();
        c.arg("merge");
        for b in boards {
            c.arg(d.join(b).join("scoreboard.json"));
        }
        c.arg("-o").arg(d.join("m.json")).output().unwrap()
    };
    let o = merge(&["s1"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("missing 2/2"), "{}", text(&o));
    let o = merge(&["s1", "s2", "s1"]);
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
    assert!(text(&o).contains("overlapping"), "{}", text(&o));
    let o = hpjudge()
        .args(["run", m, "--partition", "3/2"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{}", text(&o));
}

#[test]
fn the_report_lists_every_case_with_its_checks_and_repro() {
    let d = tmp("report");
    run(MANIFESTS[0], &d, &[]);
    let o = hpjudge().arg("report").arg(&d).output().unwrap();
    assert_eq!(o.status.code(), Some(0), "{}", text(&o));
    let html = std::fs::read_to_string(d.join("report.html")).unwrap();
    let board = verdicts(&d.join("scoreboard.json"));
    for (id, _) in board.keys() {
        assert!(
            html.contains(&format!("data-case=\"{id}\"")),
            "no {id} in the report"
        );
    }
    assert!(html.contains("class=\"checks\"") && html.contains("class=\"repro\""));
    assert!(
        !html.contains("src=\"http") && !html.contains("href=\"http"),
        "the page must not need the network"
    );
}
