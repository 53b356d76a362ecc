//! Shared statistics and numerical rules, written once: the judge's
//! assertions and every renderer's referees use these.
//!
//! | file | what |
//! | --- | --- |
//! | `mod.rs` | [`sidak`]: the per-test level of a family of tests |
//! | `ks.rs` | Kolmogorov–Smirnov test against U(0, 1) |
//! | `chi2.rs` | Pearson chi-square of a direction sampler against its pdf |
//! | `summary.rs` | medians, quartiles, log-log slopes |
//! | `image.rs` | image means, MSE, neighbourhood outliers (fireflies) |
//! | `quadrature.rs` | sphere midpoint rule, Gauss–Legendre |
//!
//! Nothing here knows a renderer: inputs are slices and closures.

pub mod chi2;
pub mod image;
pub mod ks;
pub mod quadrature;
pub mod summary;
pub mod ztest;

pub use ks::ks_uniform_p;
pub use summary::quartiles;
pub use ztest::{z_test, ZTest};

/// Šidák-corrected per-test significance level for `tests` tests at
/// family-wise level `alpha`: `1 - (1 - alpha)^(1 / tests)`.
pub fn sidak(alpha: f64, tests: usize) -> f64 {
    1.0 - (1.0 - alpha).powf(1.0 / tests.max(1) as f64)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sidak_of_one_test_is_alpha() {
        assert!((sidak(0.01, 1) - 0.01).abs() < 1e-15);
        assert!(sidak(0.01, 10) < 0.001006 && sidak(0.01, 10) > 0.001004);
    }
}
