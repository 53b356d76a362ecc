//! `range`: every selected value of `tensor` lies in `[min, max]`.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    tensor: &String,
    min: &f64,
    max: &f64,
    mask: &Option<String>,
) -> Result<Check, String> {
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
    let msg = format!("{bad} values of {tensor} outside [{min}, {max}]; seen [{lo}, {hi}]");
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn values_outside_the_closed_interval_fail() {
        let f = fixture(&[("v", &[0.0, 1.0])]);
        let v = "v".to_string();
        assert!(
            eval("range", &f.ev(), &v, &0.0, &1.0, &None)
                .unwrap()
                .passed
        );
        let c = eval("range", &f.ev(), &v, &0.0, &0.5, &None).unwrap();
        assert!(!c.passed && c.worst_index == Some(1));
    }
}
