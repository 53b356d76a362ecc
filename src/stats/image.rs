//! Statistics of linear RGB images given as pixel slices (row-major).

/// Image mean over pixels (per channel) and its standard error from the
/// per-pixel variance of the mean: `se = sqrt(sum var_i) / N`.
pub fn image_mean(rgb: &[[f32; 3]], variance: &[[f32; 3]]) -> ([f64; 3], [f64; 3]) {
    let n = rgb.len() as f64;
    let (mut m, mut v) = ([0.0; 3], [0.0; 3]);
    for (p, q) in rgb.iter().zip(variance) {
        for c in 0..3 {
            m[c] += p[c] as f64;
            v[c] += q[c] as f64;
        }
    }
    (m.map(|x| x / n), v.map(|x| x.sqrt() / n))
}

/// Mean squared error over all channels of `a` against `b`, values
/// clamped to [0, 1] first when `clamp`.
pub fn mse(a: &[[f32; 3]], b: &[[f32; 3]], clamp: bool) -> f64 {
    let f = |x: f32| {
        if clamp {
            x.clamp(0.0, 1.0) as f64
        } else {
            x as f64
        }
    };
    let s: f64 = a
        .iter()
        .zip(b)
        .flat_map(|(p, q)| (0..3).map(move |c| (f(p[c]) - f(q[c])).powi(2)))
        .sum();
    s / (3 * a.len()) as f64
}

/// Mean over pixels and channels of a per-pixel variance image: what a
/// reference's own noise adds to an MSE measured against it.
pub fn mean_variance(variance: &[[f32; 3]]) -> f64 {
    variance
        .iter()
        .flat_map(|v| v.iter().map(|&x| x as f64))
        .sum::<f64>()
        / (3 * variance.len()) as f64
}

/// Rec. 709 luminance of linear RGB.
pub fn luminance(p: &[f32; 3]) -> f32 {
    0.2126 * p[0] + 0.7152 * p[1] + 0.0722 * p[2]
}

/// Fraction of pixels of a `w` x `h` image whose luminance exceeds `factor`
/// times the median of their 3x3 neighbourhood (itself included; clipped at
/// borders).
pub fn firefly_fraction(rgb: &[[f32; 3]], w: u32, h: u32, factor: f32) -> f64 {
    let (w, h) = (w as i64, h as i64);
    let lum: Vec<f32> = rgb.iter().map(luminance).collect();
    let mut count = 0u64;
    let mut nb = Vec::with_capacity(9);
    for y in 0..h {
        for x in 0..w {
            nb.clear();
            for dy in -1..=1 {
                for dx in -1..=1 {
                    let (u, v) = (x + dx, y + dy);
                    if u >= 0 && v >= 0 && u < w && v < h {
                        nb.push(lum[(v * w + u) as usize]);
                    }
                }
            }
            nb.sort_by(f32::total_cmp);
            let med = nb[nb.len() / 2];
            if lum[(y * w + x) as usize] > factor * med {
                count += 1;
            }
        }
    }
    count as f64 / (w * h) as f64
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn fireflies_are_pixels_far_above_their_neighbourhood_median() {
        let mut rgb = vec![[0.1; 3]; 16];
        assert_eq!(firefly_fraction(&rgb, 4, 4, 10.0), 0.0);
        rgb[5] = [5.0; 3];
        assert_eq!(firefly_fraction(&rgb, 4, 4, 10.0), 1.0 / 16.0);
    }

    #[test]
    fn mse_clamps_only_when_asked() {
        let (a, b) = ([[2.0f32, 0.5, 0.5]], [[1.0f32, 0.5, 0.5]]);
        assert_eq!(mse(&a, &b, true), 0.0);
        assert!((mse(&a, &b, false) - 1.0 / 3.0).abs() < 1e-15);
    }
}
