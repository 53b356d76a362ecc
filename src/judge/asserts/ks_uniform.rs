//! `ks_uniform`: each tensor passes a Kolmogorov–Smirnov test against U[0, 1) at the Šidák-corrected level of the family gate `alpha`.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(
    kind: &str,
    ev: &Evidence,
    tensors: &Vec<String>,
    alpha: &String,
) -> Result<Check, String> {
    let fam = ev.gate(alpha)?;
    let each = sidak(fam, tensors.len());
    let mut minp = 1.0f64;
    let mut worst = None;
    let mut parts = Vec::new();
    for (i, n) in tensors.iter().enumerate() {
        let v = ev.tensor(n)?.to_f64_vec();
        if v.is_empty() {
            return Err(format!("{n} is empty"));
        }
        let p = ks_uniform_p(&v);
        parts.push(format!("{n}: p = {p:.4} (n = {})", v.len()));
        if p < minp || worst.is_none() {
            minp = p.min(minp);
            worst = Some(i);
        }
    }
    let msg = format!(
        "{}; Šidák alpha per test {each:.4} (family {fam})",
        parts.join(", ")
    );
    Ok(check(
        kind,
        "min_p_value",
        minp,
        each,
        worst,
        minp >= each,
        msg,
    ))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn a_uniform_grid_passes_and_zeros_fail() {
        let grid: Vec<f64> = (0..200).map(|i| (i as f64 + 0.5) / 200.0).collect();
        let f = fixture(&[("u", &grid), ("z", &[0.0; 16])]);
        let g = "g".to_string();
        assert!(
            eval("ks_uniform", &f.ev(), &vec!["u".into()], &g)
                .unwrap()
                .passed
        );
        assert!(
            !eval("ks_uniform", &f.ev(), &vec!["u".into(), "z".into()], &g)
                .unwrap()
                .passed
        );
    }
}
