//! The parity band of the GPU image contract (issue 17,
//! docs/transport_gpu.md): pixels of a reference render (the f64 CPU run)
//! far from every edge of its per-pixel classes (capture flag, disk hit,
//! Ellis side). The f32 GPU render must give the same classes there; it may
//! differ only within `d` pixels of an edge, where the critical curve (or a
//! disk edge's image) crosses the neighbourhood and f32 rounding of a ray
//! that grazes the photon orbit can decide either way.

use crate::error::{Error, Result};
use crate::tensor::{Outputs, Tensor};

/// Adds to an image render's outputs `far` ([`far_from_edges`] of its
/// `captured`, `disk_hit` and `side`, band `d`) and the metric `near_frac`
/// (the fraction of pixels that are not far): `transport.image_band`.
pub fn band_outputs(out: &mut Outputs, d: usize) -> Result<()> {
    let shape = out.tensors.get("captured").map(|t| t.shape().to_vec());
    let [h, w] = shape.unwrap_or_default()[..] else {
        return Err(Error::invalid("task", "the image band needs a pixel grid"));
    };
    let classes: Vec<Vec<f64>> = ["captured", "disk_hit", "side"]
        .iter()
        .filter_map(|n| out.tensors.get(*n).map(|t| t.to_f64_vec()))
        .collect();
    let far = far_from_edges(h, w, &classes, d);
    let near = far.iter().filter(|&&f| f == 0).count();
    out.metric("near_frac", near as f64 / (h * w) as f64);
    out.tensor("far", Tensor::from_shape_vec(&[h, w], far)?);
    Ok(())
}

/// 1 where every pixel within Chebyshev distance `d` of pixel `i` of the
/// `h x w` row-major image has the same value as pixel `i` in each of
/// `classes` (each of length `h * w`), else 0.
pub fn far_from_edges(h: usize, w: usize, classes: &[Vec<f64>], d: usize) -> Vec<u8> {
    (0..h * w)
        .map(|i| {
            let (v, u) = (i / w, i % w);
            let rows = v.saturating_sub(d)..=(v + d).min(h - 1);
            let same = rows.into_iter().all(|vv| {
                (u.saturating_sub(d)..=(u + d).min(w - 1))
                    .all(|uu| classes.iter().all(|c| c[vv * w + uu] == c[i]))
            });
            same as u8
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn pixels_within_the_band_of_an_edge_are_near_and_others_far() {
        // 5 x 6 image, class 1 in columns >= 3.
        let (h, w) = (5, 6);
        let c: Vec<f64> = (0..h * w).map(|i| (i % w >= 3) as u8 as f64).collect();
        let far = far_from_edges(h, w, std::slice::from_ref(&c), 1);
        for (i, f) in far.iter().enumerate() {
            let u = i % w;
            assert_eq!(*f, (u == 0 || u == 1 || u == 4 || u == 5) as u8, "{i}");
        }
        let far2 = far_from_edges(h, w, &[c], 2);
        assert_eq!(far2.iter().filter(|&&f| f == 1).count(), 2 * h);
        // A second class map adds its own edges.
        let row: Vec<f64> = (0..h * w).map(|i| (i / w == 0) as u8 as f64).collect();
        let both = far_from_edges(h, w, &[vec![0.0; h * w], row], 0);
        assert!(both.iter().all(|&f| f == 1));
        let one = far_from_edges(
            h,
            w,
            &[(0..h * w).map(|i| (i == 14) as u8 as f64).collect()],
            1,
        );
        assert_eq!(one.iter().filter(|&&f| f == 0).count(), 9);
    }
}
