//! `equal_count`: at most `max` elements of `a` and `b` differ.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    a: &String,
    b: &String,
    max: &u64,
) -> Result<Check, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn differences_up_to_max_pass() {
        let f = fixture(&[("a", &[1.0, 2.0, 3.0]), ("b", &[1.0, 0.0, 3.0])]);
        let (a, b) = ("a".to_string(), "b".to_string());
        assert!(eval("equal_count", &f.ev(), &a, &b, &1).unwrap().passed);
        assert!(!eval("equal_count", &f.ev(), &a, &b, &0).unwrap().passed);
    }
}
