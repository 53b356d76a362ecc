//! `monotone_t`: sample times `t` strictly increase within each ray of the packed offsets `off`.

use super::*;

/// Evaluates the assertion (`kind` as written) against `ev`.
pub(super) fn eval(kind: &str, ev: &Evidence, t: &String, off: &String) -> Result<Check, String> {
    let tv = ev.tensor(t)?.to_f64_vec();
    let ov = ev.tensor(off)?.to_f64_vec();
    let mut bad = 0usize;
    let mut first = None;
    for w in ov.windows(2) {
        let (s, e) = (w[0] as usize, (w[1] as usize).min(tv.len()));
        for i in s + 1..e.max(s + 1) {
            if !(tv[i] > tv[i - 1]) {
                bad += 1;
                first.get_or_insert(i);
            }
        }
    }
    let msg = format!("{bad} samples where {t} does not increase within its ray");
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
    fn t_must_increase_within_each_ray_only() {
        let f = fixture(&[("t", &[0.1, 0.2, 0.05, 0.3]), ("off", &[0.0, 2.0, 4.0])]);
        let (t, off) = ("t".to_string(), "off".to_string());
        assert!(eval("monotone_t", &f.ev(), &t, &off).unwrap().passed);
        let f = fixture(&[("t", &[0.1, 0.2, 0.3, 0.3]), ("off", &[0.0, 2.0, 4.0])]);
        let c = eval("monotone_t", &f.ev(), &t, &off).unwrap();
        assert!(!c.passed && c.worst_index == Some(3));
    }
}
