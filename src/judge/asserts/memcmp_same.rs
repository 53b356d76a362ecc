//! `memcmp_same`: `a` and `b` bit-identical (same dtype, shape and bytes).

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(kind: &str, ev: &Evidence, a: &String, b: &String) -> Result<Check, String> {
    let (x, y) = (ev.tensor(a)?, ev.tensor(b)?);
    if x.dtype() != y.dtype() || x.shape() != y.shape() {
        let msg = format!(
            "{a} is {} {:?}, {b} is {} {:?}",
            x.dtype(),
            x.shape(),
            y.dtype(),
            y.shape()
        );
        return Ok(check(
            kind,
            "differing_elements",
            f64::INFINITY,
            0.0,
            None,
            false,
            msg,
        ));
    }
    let (xb, yb) = (x.to_bytes(), y.to_bytes());
    let es = x.elem_size();
    let diff: Vec<usize> = xb
        .chunks(es)
        .zip(yb.chunks(es))
        .enumerate()
        .filter(|(_, (p, q))| p != q)
        .map(|(i, _)| i)
        .collect();
    let msg = match diff.first() {
        Some(i) => format!(
            "{} of {} elements differ; first at {i}",
            diff.len(),
            x.len()
        ),
        None => format!("{} elements bit-identical", x.len()),
    };
    Ok(check(
        kind,
        "differing_elements",
        diff.len() as f64,
        0.0,
        diff.first().copied(),
        diff.is_empty(),
        msg,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn one_differing_bit_fails() {
        let (a, b) = ("a".to_string(), "b".to_string());
        let f = fixture(&[("a", &[1.0, 2.0]), ("b", &[1.0, 2.0])]);
        assert!(eval("memcmp_same", &f.ev(), &a, &b).unwrap().passed);
        let f = fixture(&[
            ("a", &[1.0, 2.0]),
            ("b", &[1.0, f64::from_bits(2f64.to_bits() + 1)]),
        ]);
        let c = eval("memcmp_same", &f.ev(), &a, &b).unwrap();
        assert!(!c.passed && c.worst_index == Some(1));
    }
}
