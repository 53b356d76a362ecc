//! Order statistics and fitted rates: medians, quartiles, log-log slopes.

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

/// Upper median of `v` (sorts it in place): `v[len / 2]` after sorting.
pub fn median(v: &mut [f64]) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// Least-squares slope of `ln y` against `ln x`.
pub fn loglog_slope(x: &[f64], y: &[f64]) -> f64 {
    let lx: Vec<f64> = x.iter().map(|v| v.ln()).collect();
    let ly: Vec<f64> = y.iter().map(|v| v.max(1e-300).ln()).collect();
    let n = lx.len() as f64;
    let (mx, my) = (lx.iter().sum::<f64>() / n, ly.iter().sum::<f64>() / n);
    let sxy: f64 = lx.iter().zip(&ly).map(|(a, b)| (a - mx) * (b - my)).sum();
    let sxx: f64 = lx.iter().map(|a| (a - mx) * (a - mx)).sum();
    if sxx > 0.0 {
        sxy / sxx
    } else {
        0.0
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn quartiles_of_one_to_five() {
        assert_eq!(quartiles(&[5.0, 1.0, 3.0, 2.0, 4.0]), (3.0, 2.0, 4.0));
    }

    #[test]
    fn loglog_slope_of_inverse_sqrt_is_minus_half() {
        let x = [4.0, 16.0, 64.0, 256.0];
        let y: Vec<f64> = x.iter().map(|v: &f64| 3.0 / v.sqrt()).collect();
        assert!((loglog_slope(&x, &y) + 0.5).abs() < 1e-12);
    }

    #[test]
    fn median_is_the_upper_middle_value() {
        assert_eq!(median(&mut [3.0, 1.0, 2.0]), 2.0);
        assert_eq!(median(&mut [4.0, 1.0, 3.0, 2.0]), 3.0);
    }
}
