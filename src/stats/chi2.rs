//! Pearson chi-square goodness-of-fit of a direction sampler against the
//! density it claims (after Mitsuba 3's `ChiSquareTest`).
//!
//! The sphere is cut into `theta_bins x phi_bins` cells in (theta, phi);
//! each cell's expected count is `N * integral of pdf over the cell`
//! (midpoint rule on `sub x sub` points per cell, in f64, with the
//! `sin(theta)` area element). Samples the sampler rejected (a direction
//! worth 0) go to one extra cell whose expected count is
//! `N * (1 - total mass)`. Cells expecting fewer than 5 samples are pooled;
//! the pool counts as one cell if it expects at least 5. An observation in
//! a cell that expects nothing (more than `1e-5 N`) is a certain failure
//! (p = 0). `p = P(chi2_dof > X)` with `dof = cells - 1`.

use statrs::distribution::{ChiSquared, ContinuousCDF};

/// Outcome of one test.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Chi2 {
    pub statistic: f64,
    pub dof: u32,
    pub p_value: f64,
}

/// Binning of the sphere.
#[derive(Clone, Copy, Debug)]
pub struct Bins {
    pub theta: usize,
    pub phi: usize,
    /// Quadrature points per cell side.
    pub sub: usize,
}

impl Bins {
    /// The cell of a unit direction.
    pub fn cell(&self, w: [f64; 3]) -> usize {
        let th = w[2].clamp(-1.0, 1.0).acos();
        let ph = w[1].atan2(w[0]).rem_euclid(2.0 * std::f64::consts::PI);
        let i = ((th / std::f64::consts::PI * self.theta as f64) as usize).min(self.theta - 1);
        let j = ((ph / (2.0 * std::f64::consts::PI) * self.phi as f64) as usize).min(self.phi - 1);
        i * self.phi + j
    }

    /// Expected probability of each cell under `pdf` (solid-angle density).
    pub fn masses(&self, pdf: impl Fn([f64; 3]) -> f64) -> Vec<f64> {
        let pi = std::f64::consts::PI;
        let (dt, dp) = (pi / self.theta as f64, 2.0 * pi / self.phi as f64);
        let (st, sp) = (dt / self.sub as f64, dp / self.sub as f64);
        let mut m = vec![0.0; self.theta * self.phi];
        for i in 0..self.theta {
            for j in 0..self.phi {
                let mut acc = 0.0;
                for a in 0..self.sub {
                    let th = i as f64 * dt + (a as f64 + 0.5) * st;
                    let (s, c) = th.sin_cos();
                    for b in 0..self.sub {
                        let ph = j as f64 * dp + (b as f64 + 0.5) * sp;
                        acc += pdf([s * ph.cos(), s * ph.sin(), c]) * s;
                    }
                }
                m[i * self.phi + j] = acc * st * sp;
            }
        }
        m
    }
}

/// Chi-square test of `observed` cell counts (plus `rejected` samples)
/// against cell `masses`, for `n` samples in all.
pub fn chi2_test(observed: &[u64], rejected: u64, masses: &[f64], n: u64) -> Chi2 {
    let nf = n as f64;
    let total: f64 = masses.iter().sum();
    let mut cells: Vec<(f64, f64)> = observed
        .iter()
        .zip(masses)
        .map(|(&o, &m)| (o as f64, m * nf))
        .collect();
    cells.push((rejected as f64, (1.0 - total).max(0.0) * nf));
    let (mut stat, mut kept, mut pool_o, mut pool_e) = (0.0, 0u32, 0.0, 0.0);
    for &(o, e) in &cells {
        if e <= 0.0 {
            if o > 1e-5 * nf {
                return Chi2 {
                    statistic: f64::INFINITY,
                    dof: 0,
                    p_value: 0.0,
                };
            }
        } else if e < 5.0 {
            pool_o += o;
            pool_e += e;
        } else {
            stat += (o - e) * (o - e) / e;
            kept += 1;
        }
    }
    if pool_e >= 5.0 {
        stat += (pool_o - pool_e) * (pool_o - pool_e) / pool_e;
        kept += 1;
    }
    let dof = kept.saturating_sub(1).max(1);
    let p_value = ChiSquared::new(dof as f64).map_or(0.0, |d| d.sf(stat));
    Chi2 {
        statistic: stat,
        dof,
        p_value,
    }
}
