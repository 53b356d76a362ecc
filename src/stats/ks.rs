//! The Kolmogorov–Smirnov test against U(0, 1).

/// The KS statistic `D = sup |F_n(x) - x|` of samples against U(0, 1).
pub fn ks_statistic_uniform(v: &[f64]) -> f64 {
    let mut s: Vec<f64> = v.to_vec();
    s.sort_by(f64::total_cmp);
    let n = s.len() as f64;
    let mut d = 0.0f64;
    for (i, &x) in s.iter().enumerate() {
        let x = x.clamp(0.0, 1.0);
        d = d.max((i as f64 + 1.0) / n - x).max(x - i as f64 / n);
    }
    d
}

/// Kolmogorov's limiting survival function `Q(l) = 2 sum_{k>=1} (-1)^(k-1) exp(-2 k^2 l^2)`.
pub fn kolmogorov_q(l: f64) -> f64 {
    if l < 0.2 {
        return 1.0;
    }
    let mut s = 0.0;
    for k in 1..=100 {
        let k = k as f64;
        let t = (-2.0 * k * k * l * l).exp();
        s += if k as u64 % 2 == 1 { t } else { -t };
        if t < 1e-16 {
            break;
        }
    }
    (2.0 * s).clamp(0.0, 1.0)
}

/// p-value of the KS test of `v` against U(0, 1), with Stephens' small-sample
/// correction `l = (sqrt(n) + 0.12 + 0.11 / sqrt(n)) D`. Values outside [0, 1]
/// make the p-value 0.
pub fn ks_uniform_p(v: &[f64]) -> f64 {
    if v.iter().any(|x| !(0.0..=1.0).contains(x)) {
        return 0.0;
    }
    let n = v.len() as f64;
    let d = ks_statistic_uniform(v);
    let sn = n.sqrt();
    kolmogorov_q((sn + 0.12 + 0.11 / sn) * d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn kolmogorov_tail_matches_tables() {
        // Critical values of the Kolmogorov distribution: Q(1.3581) = 0.05, Q(1.6276) = 0.01.
        assert!((kolmogorov_q(1.3581) - 0.05).abs() < 2e-4);
        assert!((kolmogorov_q(1.6276) - 0.01).abs() < 1e-4);
    }

    #[test]
    fn ks_accepts_a_uniform_lattice_and_rejects_a_squashed_one() {
        let u: Vec<f64> = (0..1000).map(|i| (i as f64 + 0.5) / 1000.0).collect();
        assert!(ks_uniform_p(&u) > 0.99);
        let sq: Vec<f64> = u.iter().map(|x| x * x).collect();
        assert!(ks_uniform_p(&sq) < 1e-6);
    }
}
