//! The element-wise two-sample z-test (GPU vs CPU images at equal spp).

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

impl ZTest {
    /// Scalars `p_min`, `sidak_alpha` (Šidák of `alpha` over the tests),
    /// `z2_mean`, `max_abs_z`, `zero_var_mismatch`; counters `tests`,
    /// `worst_index`.
    pub fn to_outputs(&self, alpha: f64, out: &mut crate::tensor::Outputs) {
        use crate::tensor::Tensor;
        out.tensor("p_min", Tensor::scalar(self.p_min));
        out.tensor(
            "sidak_alpha",
            Tensor::scalar(super::sidak(alpha, self.tests)),
        );
        out.tensor("z2_mean", Tensor::scalar(self.z2_mean));
        out.tensor("max_abs_z", Tensor::scalar(self.max_abs_z));
        out.tensor(
            "zero_var_mismatch",
            Tensor::scalar(self.zero_var_mismatch as f64),
        );
        out.counter("tests", self.tests as u64)
            .counter("worst_index", self.worst as u64);
    }
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
