//! `rel_err` / `fd_rel_err`: `|a - b| / max(|b|, floor)` at most `rtol`,
//! with `floor = max(floor, floor_rel * max|b|)` over the selected elements.

use super::*;

pub(super) fn rel_err(
    kind: &str,
    ev: &Evidence,
    a: &str,
    bn: &str,
    b: Vals,
    tol: &str,
    mask: Option<&String>,
) -> Result<Check, String> {
    let tol = ev.tol(tol)?;
    let at = ev.tensor(a)?;
    let p = pairs(&at.to_f64_vec(), at.shape(), &b, a)?;
    let m = ev.mask(mask, at.shape())?;
    let keep = |i: usize| m.as_ref().is_none_or(|m| m[i]);
    let bmax = p
        .iter()
        .enumerate()
        .filter(|(i, _)| keep(*i))
        .map(|(_, q)| q.1.abs())
        .fold(0.0, f64::max);
    let floor = tol.floor.max(tol.floor_rel * bmax);
    let (mut worst, mut wi) = (0.0f64, None);
    for (i, &(x, y)) in p.iter().enumerate() {
        if !keep(i) {
            continue;
        }
        let den = y.abs().max(floor);
        let e = if x == y {
            0.0
        } else if den > 0.0 {
            (x - y).abs() / den
        } else {
            f64::INFINITY
        };
        let e = if e.is_nan() { f64::INFINITY } else { e };
        if e > worst || wi.is_none() {
            worst = e.max(worst);
            wi = Some(i);
        }
    }
    let msg = match wi {
        Some(i) => format!(
            "max rel err {worst:.3e} at {i} ({a} = {:.6e}, {bn} = {:.6e}); floor {floor:.3e}",
            p[i].0, p[i].1
        ),
        None => "no elements compared".into(),
    };
    Ok(check(
        kind,
        "max_rel_err",
        worst,
        tol.rtol,
        wi,
        worst <= tol.rtol,
        msg,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn relative_error_is_judged_against_rtol_with_a_floor() {
        let f = fixture(&[("a", &[1.0, 0.0]), ("b", &[1.0, 0.0])]);
        let b = f.ev().vals(&Operand::Name("b".into())).unwrap();
        assert!(
            rel_err("rel_err", &f.ev(), "a", "b", b, "t", None)
                .unwrap()
                .passed
        );
        let f = fixture(&[("a", &[1.1, 0.0]), ("b", &[1.0, 0.0])]);
        let b = f.ev().vals(&Operand::Name("b".into())).unwrap();
        let c = rel_err("rel_err", &f.ev(), "a", "b", b, "t", None).unwrap();
        assert!(!c.passed && c.worst_index == Some(0), "{c:?}");
    }
}
