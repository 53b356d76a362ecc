//! `gt` / `ge`: `a > b` (`a >= b`) element-wise, `b` a tensor or a number.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    strict: bool,
    a: &String,
    b: &Operand,
    mask: &Option<String>,
) -> Result<Check, String> {
    let at = ev.tensor(a)?;
    let av = at.to_f64_vec();
    let bv = ev.vals(b)?;
    let p = pairs(&av, at.shape(), &bv, a)?;
    let m = ev.mask(mask.as_ref(), at.shape())?;
    let mut bad = 0usize;
    let mut first = None;
    for (i, (x, y)) in p.iter().enumerate() {
        if m.as_ref().is_some_and(|m| !m[i]) {
            continue;
        }
        let ok = if strict { x > y } else { x >= y };
        if !ok {
            bad += 1;
            first.get_or_insert(i);
        }
    }
    let rel = if strict { ">" } else { ">=" };
    let msg = match first {
        Some(i) => format!(
            "{bad} elements fail {a} {rel} {}; first at {i}: {} vs {}",
            op_name(b),
            p[i].0,
            p[i].1
        ),
        None => format!("{a} {rel} {} everywhere checked", op_name(b)),
    };
    Ok(check(
        kind,
        "violations",
        bad as f64,
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
    fn gt_is_strict_and_ge_is_not() {
        let f = fixture(&[("a", &[1.0, 2.0]), ("b", &[1.0, 1.0])]);
        let (a, b, m) = ("a".to_string(), Operand::Name("b".into()), None);
        assert!(!eval("gt", &f.ev(), true, &a, &b, &m).unwrap().passed);
        assert!(eval("ge", &f.ev(), false, &a, &b, &m).unwrap().passed);
        assert!(
            eval("gt", &f.ev(), true, &a, &Operand::Number(0.5), &m)
                .unwrap()
                .passed
        );
    }
}
