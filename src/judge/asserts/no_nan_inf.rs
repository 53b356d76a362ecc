//! `no_nan_inf`: the named tensors (default: every float output of the main run) are finite.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    tensors: &Option<Vec<String>>,
) -> Result<Check, String> {
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn an_infinity_in_any_output_fails() {
        let f = fixture(&[("a", &[1.0]), ("b", &[2.0])]);
        assert!(eval("no_nan_inf", &f.ev(), &None).unwrap().passed);
        let f = fixture(&[("a", &[1.0]), ("b", &[f64::INFINITY])]);
        assert!(!eval("no_nan_inf", &f.ev(), &None).unwrap().passed);
        assert!(
            eval("no_nan_inf", &f.ev(), &Some(vec!["a".into()]))
                .unwrap()
                .passed
        );
    }
}
