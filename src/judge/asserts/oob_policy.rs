//! `oob_policy`: values outside the box (`inside` = 0) are 0 (`zero`) or equal `clamped` (`clamp`).

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    value: &String,
    inside: &String,
    policy: &OobKind,
    clamped: &Option<String>,
) -> Result<Check, String> {
    let vt = ev.tensor(value)?;
    let v = vt.to_f64_vec();
    let ins = ev.tensor(inside)?;
    same_shape(vt.shape(), ins.shape(), value, inside)?;
    let ins = ins.to_f64_vec();
    let cv = match (policy, clamped) {
        (OobKind::Clamp, Some(c)) => Some(ev.tensor(c)?.to_f64_vec()),
        (OobKind::Clamp, None) => return Err("oob_policy clamp needs `clamped`".into()),
        (OobKind::Zero, _) => None,
    };
    let mut bad = 0usize;
    let mut first = None;
    for i in 0..v.len() {
        if ins[i] != 0.0 {
            continue;
        }
        let want = cv.as_ref().map_or(0.0, |c| c[i]);
        if v[i] != want {
            bad += 1;
            first.get_or_insert(i);
        }
    }
    let msg = format!("{bad} outside samples of {value} break the {policy:?} policy");
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
    fn zero_policy_wants_zeros_outside_only() {
        let f = fixture(&[("v", &[3.0, 0.0]), ("in", &[1.0, 0.0])]);
        let (v, i) = ("v".to_string(), "in".to_string());
        assert!(
            eval("oob_policy", &f.ev(), &v, &i, &OobKind::Zero, &None)
                .unwrap()
                .passed
        );
        let f = fixture(&[("v", &[3.0, 0.5]), ("in", &[1.0, 0.0])]);
        assert!(
            !eval("oob_policy", &f.ev(), &v, &i, &OobKind::Zero, &None)
                .unwrap()
                .passed
        );
        assert!(eval("oob_policy", &f.ev(), &v, &i, &OobKind::Clamp, &None).is_err());
    }
}
