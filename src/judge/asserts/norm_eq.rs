//! `norm_eq`: every vector along the last axis of `tensor` has norm `value` within the tolerance (vectors selected by `where:`).

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    tensor: &String,
    tol: &String,
    value: &f64,
    mask: &Option<String>,
) -> Result<Check, String> {
    let t = ev.tensor(tensor)?;
    let tol = ev.tol(tol)?;
    let shape = t.shape().to_vec();
    let k = *shape
        .last()
        .ok_or("norm_eq needs a tensor with a last axis")?;
    let v = t.to_f64_vec();
    let m = ev.mask(mask.as_ref(), &shape[..shape.len() - 1])?;
    let limit = tol.atol + tol.rtol * value.abs();
    let (mut worst, mut wi, mut bad) = (0.0f64, None, 0usize);
    for (i, vec) in v.chunks(k.max(1)).enumerate() {
        if m.as_ref().is_some_and(|m| !m[i]) {
            continue;
        }
        let n = vec.iter().map(|x| x * x).sum::<f64>().sqrt();
        let dev = (n - value).abs();
        if !(dev <= limit) {
            bad += 1;
        }
        if dev.is_nan() || dev > worst {
            worst = if dev.is_nan() { f64::INFINITY } else { dev };
            wi = Some(i * k);
        }
    }
    let msg =
        format!("{bad} vectors of {tensor} have |norm - {value}| > {limit:e}; worst {worst:e}");
    Ok(check(kind, "max_norm_dev", worst, limit, wi, bad == 0, msg))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn unit_vectors_pass_and_a_long_one_fails() {
        let f = fixture(&[]).shaped("v", &[2, 3], &[1.0, 0.0, 0.0, 0.0, 0.6, 0.8]);
        let (t, v, m) = ("v".to_string(), "t".to_string(), None);
        assert!(eval("norm_eq", &f.ev(), &t, &v, &1.0, &m).unwrap().passed);
        let f = fixture(&[]).shaped("v", &[2, 3], &[1.0, 0.0, 0.0, 0.0, 0.6, 0.9]);
        let c = eval("norm_eq", &f.ev(), &t, &v, &1.0, &m).unwrap();
        assert!(!c.passed && c.worst_index == Some(3), "{c:?}");
    }
}
