//! Statistics the judge's assertions use: the Kolmogorov–Smirnov test
//! against U(0, 1) and the Šidák correction.

/// Per-test significance for a family-wise level `alpha` over `m` tests:
/// `1 - (1 - alpha)^(1/m)`.
pub fn sidak(alpha: f64, m: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / m.max(1) as f64)
}

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

    #[test]
    fn sidak_of_one_test_is_alpha() {
        assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
        assert!(sidak(0.01, 10) < 0.001006 && sidak(0.01, 10) > 0.001004);
    }
}

/// Median, 25th and 75th percentiles (linear interpolation) of `v`.
pub fn quartiles(v: &[f64]) -> (f64, f64, f64) {
    if v.is_empty() {
        return (f64::NAN, f64::NAN, f64::NAN);
    }
    let mut s = v.to_vec();
    s.sort_by(f64::total_cmp);
    let q = |p: f64| {
        let x = p * (s.len() - 1) as f64;
        let (i, f) = (x.floor() as usize, x.fract());
        if i + 1 < s.len() {
            s[i] * (1.0 - f) + s[i + 1] * f
        } else {
            s[i]
        }
    };
    (q(0.5), q(0.25), q(0.75))
}

#[cfg(test)]
mod quartile_tests {
    use super::*;

    #[test]
    fn quartiles_of_one_to_five() {
        assert_eq!(quartiles(&[5.0, 1.0, 3.0, 2.0, 4.0]), (3.0, 2.0, 4.0));
    }
}

/// Element-wise two-sample z-test of independent estimates: `z_i = (a_i -
/// b_i) / sqrt(va_i + vb_i)` (`va`, `vb` the variances of the estimates).
/// Elements with `va + vb = 0` are not tested; there the values must be
/// equal, else they count in `zero_var_mismatch`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ZTest {
    /// Elements tested (`va + vb > 0`).
    pub tests: usize,
    /// The largest `|z|` and its element index.
    pub max_abs_z: f64,
    pub worst: usize,
    /// Two-sided p-value of `max_abs_z` for one test: `2 (1 - Phi(|z|))`;
    /// compare with `sidak(alpha, tests)`.
    pub p_min: f64,
    /// Mean of `z^2` (1 when the variances are right).
    pub z2_mean: f64,
    pub zero_var_mismatch: usize,
}

pub fn z_test(a: &[f64], va: &[f64], b: &[f64], vb: &[f64]) -> ZTest {
    use statrs::distribution::{ContinuousCDF, Normal};
    let mut r = ZTest {
        tests: 0,
        max_abs_z: 0.0,
        worst: 0,
        p_min: 1.0,
        z2_mean: 0.0,
        zero_var_mismatch: 0,
    };
    let mut z2 = 0.0;
    for i in 0..a.len().min(b.len()).min(va.len()).min(vb.len()) {
        let v = va[i] + vb[i];
        if v.is_nan() || v <= 0.0 {
            if a[i] != b[i] {
                r.zero_var_mismatch += 1;
            }
            continue;
        }
        let z = (a[i] - b[i]) / v.sqrt();
        r.tests += 1;
        z2 += z * z;
        if z.is_nan() || z.abs() > r.max_abs_z {
            r.max_abs_z = z.abs();
            r.worst = i;
        }
    }
    r.z2_mean = z2 / r.tests.max(1) as f64;
    if r.tests > 0 {
        r.p_min = 2.0 * Normal::standard().sf(r.max_abs_z);
    }
    r
}

#[cfg(test)]
mod z_tests {
    use super::*;

    #[test]
    fn z_test_finds_the_shifted_element_and_skips_zero_variance() {
        let a = [1.0, 2.0, 3.0, 0.0];
        let b = [1.0, 2.0, 3.4, 0.0];
        let v = [0.01, 0.01, 0.005, 0.0];
        let r = z_test(&a, &v, &b, &v);
        assert_eq!((r.tests, r.worst, r.zero_var_mismatch), (3, 2, 0));
        // |z| = 0.4 / sqrt(0.01) = 4; p = 2 (1 - Phi(4)) = 6.334e-5.
        assert!((r.max_abs_z - 4.0).abs() < 1e-12);
        assert!((r.p_min - 6.334e-5).abs() < 1e-8, "{}", r.p_min);
        assert!((r.z2_mean - 16.0 / 3.0).abs() < 1e-12);
        let r = z_test(&[1.0], &[0.0], &[2.0], &[0.0]);
        assert_eq!((r.tests, r.zero_var_mismatch, r.p_min), (0, 1, 1.0));
    }
}
