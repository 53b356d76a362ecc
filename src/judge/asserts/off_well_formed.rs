//! `off_well_formed`: packed offsets start at 0, never decrease and end at M (the length of `m`).

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    off: &String,
    m: &Option<String>,
) -> Result<Check, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn offsets_start_at_zero_rise_and_end_at_m() {
        let f = fixture(&[("off", &[0.0, 2.0, 3.0]), ("t", &[0.0; 3])]);
        let (off, m) = ("off".to_string(), Some("t".to_string()));
        assert!(eval("off_well_formed", &f.ev(), &off, &m).unwrap().passed);
        let f = fixture(&[("off", &[0.0, 2.0, 1.0]), ("t", &[0.0; 3])]);
        let c = eval("off_well_formed", &f.ev(), &off, &m).unwrap();
        assert!(!c.passed && c.value == Some(2.0), "{c:?}");
    }
}
