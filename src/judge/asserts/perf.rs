//! `throughput_ge` / `speedup_ge`: a metric (or a ratio of two) at least
//! its gate; outside perf profiles the check reports and does not fail.

use super::*;

/// `throughput_ge`: metric `metric` at least gate `gate`.
pub(super) fn throughput(
    kind: &str,
    ev: &Evidence,
    metric: &str,
    gate: &str,
    enforce: bool,
) -> Result<Check, String> {
    let v = ev.metric(metric)?;
    let g = ev.gate(gate)?;
    Ok(perf_check(kind, metric, v, g, enforce))
}

/// `speedup_ge`: `num / den` at least gate `gate`.
pub(super) fn speedup(
    kind: &str,
    ev: &Evidence,
    (num, den): (&str, &str),
    gate: &str,
    enforce: bool,
) -> Result<Check, String> {
    let (n, d) = (ev.metric(num)?, ev.metric(den)?);
    let g = ev.gate(gate)?;
    let v = if d > 0.0 { n / d } else { f64::INFINITY };
    let mut c = perf_check(kind, &format!("{num}/{den}"), v, g, enforce);
    c.message = format!("{num} = {n:.4e}, {den} = {d:.4e}; {}", c.message);
    Ok(c)
}

fn perf_check(kind: &str, metric: &str, v: f64, g: f64, enforce: bool) -> Check {
    let ok = v >= g;
    let mut c = check(
        kind,
        metric,
        v,
        g,
        None,
        ok || !enforce,
        format!("{metric} = {v:.4e}, gate {g:.4e}"),
    );
    c.enforced = enforce;
    if !enforce {
        c.message += if ok {
            " (reported; met)"
        } else {
            " (reported; below gate, not enforced in this profile)"
        };
    }
    c
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::judge::asserts::test_fixture::fixture;

    #[test]
    fn gates_fail_only_where_enforced() {
        let f = fixture(&[]).metric("fast", 3.0).metric("slow", 1.0);
        assert!(
            throughput("throughput_ge", &f.ev(), "fast", "two", true)
                .unwrap()
                .passed
        );
        let c = throughput("throughput_ge", &f.ev(), "slow", "two", true).unwrap();
        assert!(!c.passed && c.enforced);
        let c = throughput("throughput_ge", &f.ev(), "slow", "two", false).unwrap();
        assert!(c.passed && !c.enforced && c.message.contains("below gate"));
        assert!(
            !speedup("speedup_ge", &f.ev(), ("slow", "fast"), "two", true)
                .unwrap()
                .passed
        );
    }
}
