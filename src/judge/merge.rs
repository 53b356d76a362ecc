//! `hpjudge merge`: joins the scoreboards of a sharded run (`run
//! --partition K/N`, partition.rs) into the one board the unsharded run
//! would have written. Refuses, naming the file: a board that is not a
//! shard, shards of different counts or inputs, the same shard twice, a
//! case in two boards or in the wrong shard (overlap), a missing shard or a
//! shard whose run did not finish (incomplete).

use std::collections::{BTreeMap, BTreeSet};

use super::load::JudgeInputError;
use super::partition::shard_of;
use super::scoreboard::Scoreboard;

/// Reads a scoreboard, naming the file on any error.
pub fn read_board(path: &std::path::Path) -> Result<Scoreboard, JudgeInputError> {
    let at = path.display().to_string();
    let text =
        std::fs::read_to_string(path).map_err(|e| JudgeInputError::new(&at, "", e.to_string()))?;
    serde_json::from_str(&text)
        .map_err(|e| JudgeInputError::new(&at, "", format!("not a scoreboard: {e}")))
}

/// Merges shard boards (each with the file it came from). The result has
/// no partition, every case sorted by id, and counts recomputed.
pub fn merge(boards: &[(String, Scoreboard)]) -> Result<Scoreboard, JudgeInputError> {
    let err = |at: &str, what: String| JudgeInputError::new(at, "", what);
    let Some((first_at, first)) = boards.first() else {
        return Err(err("merge", "no scoreboards given".into()));
    };
    let p0 = first
        .partition
        .ok_or_else(|| err(first_at, "not a shard (run without --partition)".into()))?;
    let mut seen: BTreeMap<u32, &str> = BTreeMap::new();
    let mut owner: BTreeMap<&str, &str> = BTreeMap::new();
    for (at, b) in boards {
        let p = b
            .partition
            .ok_or_else(|| err(at, "not a shard (run without --partition)".into()))?;
        if p.count != p0.count {
            return Err(err(
                at,
                format!("shard {} but {first_at} is shard {}", p.label(), p0.label()),
            ));
        }
        if b.inputs != first.inputs
            || b.environment.get("profile") != first.environment.get("profile")
        {
            return Err(err(
                at,
                format!("other inputs or profile than {first_at}: shards of different runs"),
            ));
        }
        if let Some(other) = seen.insert(p.index, at) {
            return Err(err(
                at,
                format!("overlapping shards: {other} is shard {} too", p.label()),
            ));
        }
        if !b.complete {
            return Err(err(
                at,
                format!(
                    "incomplete shard {}: {} of {} results ({})",
                    p.label(),
                    b.cases_done,
                    b.cases_total,
                    b.stopped.as_deref().unwrap_or("stopped early")
                ),
            ));
        }
        for c in &b.cases {
            if shard_of(&c.id, p.count) != p.index {
                return Err(err(
                    at,
                    format!(
                        "case {} belongs to shard {}/{}, not {}",
                        c.id,
                        shard_of(&c.id, p.count),
                        p.count,
                        p.label()
                    ),
                ));
            }
            if let Some(other) = owner.insert(&c.id, at) {
                return Err(err(
                    at,
                    format!("overlapping shards: case {} is in {other} too", c.id),
                ));
            }
        }
    }
    let missing: BTreeSet<u32> = (1..=p0.count).filter(|k| !seen.contains_key(k)).collect();
    if !missing.is_empty() {
        let m: Vec<String> = missing
            .iter()
            .map(|k| format!("{k}/{}", p0.count))
            .collect();
        return Err(err(
            "merge",
            format!("incomplete shard set: missing {}", m.join(", ")),
        ));
    }
    let mut out = first.clone();
    out.partition = None;
    out.complete = true;
    out.stopped = None;
    out.cases_total = boards.iter().map(|(_, b)| b.cases_total).sum();
    out.cases = boards
        .iter()
        .flat_map(|(_, b)| b.cases.iter().cloned())
        .collect();
    out.finish();
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::partition::Partition;
    use crate::judge::scoreboard::{CaseEntry, Summary};

    fn board(p: Option<Partition>, ids: &[&str]) -> Scoreboard {
        let mut b = Scoreboard {
            schema_version: 2,
            hpjudge_version: "t".into(),
            manifest: "m.yaml".into(),
            complete: true,
            cases_total: ids.len() as u64,
            cases_done: 0,
            stopped: None,
            partition: p,
            inputs: Default::default(),
            environment: serde_json::json!({"profile": "ci"}),
            summary: Summary::default(),
            cases: ids
                .iter()
                .map(|id| CaseEntry {
                    id: id.to_string(),
                    op: "x".into(),
                    scene: None,
                    defined_at: "m.yaml:1".into(),
                    expect: None,
                    results: vec![],
                })
                .collect(),
        };
        b.finish();
        b
    }

    /// Ids split into their shards of `n`.
    fn shards(ids: &[&'static str], n: u32) -> Vec<(String, Scoreboard)> {
        (1..=n)
            .map(|k| {
                let mine: Vec<&str> = ids
                    .iter()
                    .copied()
                    .filter(|i| shard_of(i, n) == k)
                    .collect();
                (
                    format!("s{k}.json"),
                    board(Some(Partition { index: k, count: n }), &mine),
                )
            })
            .collect()
    }

    const IDS: [&str; 6] = ["a", "b", "c", "d", "e", "f"];

    #[test]
    fn merged_shards_hold_every_case_once_sorted() {
        let m = merge(&shards(&IDS, 3)).unwrap();
        let ids: Vec<&str> = m.cases.iter().map(|c| c.id.as_str()).collect();
        assert_eq!(ids, IDS);
        assert!(m.complete && m.partition.is_none());
    }

    #[test]
    fn a_missing_shard_is_refused_as_incomplete() {
        let mut s = shards(&IDS, 3);
        s.remove(1);
        assert!(merge(&s).unwrap_err().to_string().contains("missing 2/3"));
    }

    #[test]
    fn the_same_shard_twice_or_a_case_in_two_shards_is_refused() {
        let mut s = shards(&IDS, 2);
        s.push(s[0].clone());
        assert!(merge(&s).unwrap_err().to_string().contains("overlapping"));
        let mut s = shards(&IDS, 2);
        let stray = s[0].1.cases[0].clone();
        s[1].1.cases.push(stray);
        assert!(merge(&s)
            .unwrap_err()
            .to_string()
            .contains("belongs to shard"));
    }

    #[test]
    fn unfinished_unsharded_or_mismatched_boards_are_refused() {
        let mut s = shards(&IDS, 2);
        s[1].1.complete = false;
        assert!(merge(&s)
            .unwrap_err()
            .to_string()
            .contains("incomplete shard 2/2"));
        let mut s = shards(&IDS, 2);
        s[1].1.partition = None;
        assert!(merge(&s).unwrap_err().to_string().contains("not a shard"));
        let mut s = shards(&IDS, 2);
        s[1].1.inputs.thresholds_sha256 = "other".into();
        assert!(merge(&s)
            .unwrap_err()
            .to_string()
            .contains("different runs"));
        let mut s = shards(&IDS, 2);
        s[1].1.partition = Some(Partition { index: 2, count: 3 });
        assert!(merge(&s).unwrap_err().to_string().contains("shard 2/3"));
    }
}
