//! Quadrature rules: the midpoint rule over the sphere and composite
//! Gauss–Legendre on an interval.

use std::f64::consts::PI;

use glam::Vec3A;

/// The unit direction at polar angle `theta` and azimuth `phi` (z up).
pub fn dir(theta: f64, phi: f64) -> Vec3A {
    Vec3A::new(
        (theta.sin() * phi.cos()) as f32,
        (theta.sin() * phi.sin()) as f32,
        theta.cos() as f32,
    )
}

/// Midpoint quadrature over the sphere, `n` x `2n` cells in (theta, phi).
pub fn sphere_quad(n: usize, g: impl Fn(Vec3A) -> f64) -> f64 {
    let (dt, dp) = (PI / n as f64, PI / n as f64);
    let mut sum = 0.0;
    for i in 0..n {
        let th = (i as f64 + 0.5) * dt;
        for j in 0..2 * n {
            sum += g(dir(th, (j as f64 + 0.5) * dp)) * th.sin() * dt * dp;
        }
    }
    sum
}

/// Gauss–Legendre nodes and weights on [-1, 1] (Newton on P_n).
pub fn gauss_legendre(n: usize) -> Vec<(f64, f64)> {
    (1..=n)
        .map(|i| {
            let mut x = (PI * (i as f64 - 0.25) / (n as f64 + 0.5)).cos();
            let mut dp = 1.0;
            for _ in 0..100 {
                let (mut p0, mut p1) = (1.0, x);
                for k in 2..=n {
                    let p2 = ((2 * k - 1) as f64 * x * p1 - (k - 1) as f64 * p0) / k as f64;
                    p0 = p1;
                    p1 = p2;
                }
                dp = n as f64 * (x * p1 - p0) / (x * x - 1.0);
                let dx = p1 / dp;
                x -= dx;
                if dx.abs() < 1e-16 {
                    break;
                }
            }
            (x, 2.0 / ((1.0 - x * x) * dp * dp))
        })
        .collect()
}

/// `int_a^b f` by composite 20-point Gauss–Legendre on `panels` panels.
pub fn integrate(f: impl Fn(f64) -> f64, a: f64, b: f64, panels: usize) -> f64 {
    let gl = gauss_legendre(20);
    let w = (b - a) / panels as f64;
    (0..panels)
        .map(|p| {
            let (lo, hi) = (a + p as f64 * w, a + (p + 1) as f64 * w);
            let (c, r) = (0.5 * (lo + hi), 0.5 * (hi - lo));
            gl.iter().map(|(x, wt)| wt * f(c + r * x)).sum::<f64>() * r
        })
        .sum()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn sphere_quad_of_one_is_four_pi_to_second_order() {
        // Midpoint rule in theta: error 4 pi (pi / n)^2 / 24 = 1.29e-4 at n = 200.
        let err = sphere_quad(200, |_| 1.0) - 4.0 * PI;
        assert!(
            err > 0.0 && err < 4.0 * PI * (PI / 200.0).powi(2) / 20.0,
            "{err}"
        );
    }

    #[test]
    fn gauss_legendre_integrates_a_polynomial_exactly() {
        let v = integrate(|x| x.powi(7) - 3.0 * x * x, -1.0, 2.0, 1);
        assert!((v - (255.0 / 8.0 - 9.0)).abs() < 1e-12);
    }
}
