//! `max_abs`: `|a - b| <= atol + rtol |b|` element-wise; the worst element by its ratio to its limit.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    a: &String,
    b: &Operand,
    tol: &String,
    mask: &Option<String>,
) -> Result<Check, String> {
    let tol = ev.tol(tol)?;
    let at = ev.tensor(a)?;
    let p = pairs(&at.to_f64_vec(), at.shape(), &ev.vals(b)?, a)?;
    let m = ev.mask(mask.as_ref(), at.shape())?;
    let (mut worst, mut wi, mut bad, mut wlim) = (0.0f64, None, 0usize, tol.atol);
    let mut worst_ratio = -1.0f64;
    for (i, &(x, y)) in p.iter().enumerate() {
        if m.as_ref().is_some_and(|m| !m[i]) {
            continue;
        }
        let close = tol.close(x, y);
        let d = if x == y { 0.0 } else { (x - y).abs() };
        let lim = tol.atol + tol.rtol * y.abs();
        let ratio = if d.is_nan() {
            f64::INFINITY
        } else if lim > 0.0 {
            d / lim
        } else if d > 0.0 {
            f64::INFINITY
        } else {
            0.0
        };
        if !close {
            bad += 1;
        }
        if ratio > worst_ratio {
            (worst_ratio, worst, wi, wlim) = (
                ratio,
                if d.is_nan() { f64::INFINITY } else { d },
                Some(i),
                lim,
            );
        }
    }
    let msg = match wi {
        Some(i) => format!(
            "{bad} elements out of tolerance; worst at {i}: {a} = {}, {} = {}",
            p[i].0,
            op_name(b),
            p[i].1
        ),
        None => "no elements compared".into(),
    };
    Ok(check(kind, "max_abs_diff", worst, wlim, wi, bad == 0, msg))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn within_atol_passes_and_nan_fails() {
        let (a, b, t, m) = (
            "a".to_string(),
            Operand::Name("b".into()),
            "t".to_string(),
            None,
        );
        let f = fixture(&[("a", &[1.0, 2.0005]), ("b", &[1.0, 2.0])]);
        assert!(eval("max_abs", &f.ev(), &a, &b, &t, &m).unwrap().passed);
        let f = fixture(&[("a", &[1.0, f64::NAN]), ("b", &[1.0, 2.0])]);
        let c = eval("max_abs", &f.ev(), &a, &b, &t, &m).unwrap();
        assert!(!c.passed && c.worst_index == Some(1), "{c:?}");
    }

    #[test]
    fn a_mask_selecting_nothing_is_an_error() {
        let f = fixture(&[("a", &[1.0]), ("b", &[5.0]), ("none", &[0.0])]);
        let (a, b, t) = ("a".to_string(), Operand::Name("b".into()), "t".to_string());
        assert!(eval("max_abs", &f.ev(), &a, &b, &t, &Some("none".into())).is_err());
    }
}
