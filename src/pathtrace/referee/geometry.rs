//! The f64 geometry referee: first hits of listed rays by closed forms
//! written apart from `pathtrace::shapes` and `pathtrace::packed` (a
//! geometric sphere test, Cramer's rule for quads), with private vector
//! helpers so that nothing is shared with the code it checks.

use crate::pathtrace::listed::{unit, HitList, ShapeParam};

fn sub(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}
fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// Geometric sphere test in f64: closest approach `tca = (c - o).d`,
/// squared miss distance `m2 = |c - o|^2 - tca^2`, half chord
/// `thc = sqrt(r^2 - m2)`; roots `tca -+ thc`. Quad: solve
/// `o + t d = corner + a u + b v` by Cramer's rule on the 3x3 system.
/// Written apart from `pathtrace::shapes` so that each checks the other.
pub fn reference_hit(sp: &ShapeParam, o: [f64; 3], d: [f64; 3]) -> Option<(f64, [f64; 3])> {
    match *sp {
        ShapeParam::Sphere { center, radius } => {
            let l = sub(center, o);
            let tca = dot(l, d);
            let m2 = dot(l, l) - tca * tca;
            if m2 > radius * radius {
                return None;
            }
            let thc = (radius * radius - m2).max(0.0).sqrt();
            let t = [tca - thc, tca + thc].into_iter().find(|&t| t > 0.0)?;
            let p = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
            Some((t, sub(p, center).map(|x| x / radius)))
        }
        ShapeParam::Quad { corner, u, v } => {
            // [u v -d] [a b t]^T = o - corner.
            let rhs = sub(o, corner);
            let md = d.map(|x| -x);
            let det = dot(u, cross(v, md));
            if det == 0.0 {
                return None;
            }
            let a = dot(rhs, cross(v, md)) / det;
            let b = dot(u, cross(rhs, md)) / det;
            let t = dot(u, cross(v, rhs)) / det;
            if !(t > 0.0 && (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b)) {
                return None;
            }
            let n = cross(u, v);
            let nl = dot(n, n).sqrt();
            Some((t, n.map(|x| x / nl)))
        }
    }
}

/// The nearest reference hit of each ray over all `shapes`.
pub fn intersect_reference(rays: &[[f64; 6]], shapes: &[ShapeParam]) -> HitList {
    let mut hits = HitList::default();
    for r in rays {
        let (o, d) = unit(r);
        let best = shapes
            .iter()
            .enumerate()
            .filter_map(|(k, sp)| reference_hit(sp, o, d).map(|(t, n)| (t, k, n)))
            .min_by(|a, b| a.0.total_cmp(&b.0));
        hits.push(best);
    }
    hits
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn reference_hits_agree_on_a_centre_hit_and_a_quad() {
        let s = ShapeParam::Sphere {
            center: [0.0; 3],
            radius: 1.0,
        };
        assert_eq!(
            reference_hit(&s, [0.0, 0.0, 5.0], [0.0, 0.0, -1.0])
                .unwrap()
                .0,
            4.0
        );
        let q = ShapeParam::Quad {
            corner: [-1.0, -1.0, 0.0],
            u: [2.0, 0.0, 0.0],
            v: [0.0, 2.0, 0.0],
        };
        let (t, n) = reference_hit(&q, [0.5, 0.5, 2.0], [0.0, 0.0, -1.0]).unwrap();
        assert_eq!((t, n), (2.0, [0.0, 0.0, 1.0]));
    }
}
