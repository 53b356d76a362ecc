//! The scene's shapes four to a group, as structures of arrays, so one
//! intersection test covers four quads or four spheres (glam `Vec4`, SSE2
//! lanes on x86-64: part of the baseline, no runtime detection needed). The
//! same formulas as `shapes::sphere_t` and `shapes::quad_t` (general-plane
//! form), lane by lane; unused lanes hold shapes that never hit. A unit test
//! holds this against the scalar [`super::shapes::intersect`].

use glam::{Vec3A, Vec4};

use super::shapes::Shape;

/// Four spheres: centres and squared radii (padding: r^2 = -1, never hit).
#[derive(Clone, Copy, Debug)]
struct Spheres4 {
    c: [Vec4; 3],
    r2: Vec4,
    id: [u32; 4],
}

/// Four quads: corner, normal and dual edge vectors (padding: zero normal,
/// so t is NaN and never passes the tests).
#[derive(Clone, Copy, Debug)]
struct Quads4 {
    c: [Vec4; 3],
    n: [Vec4; 3],
    ua: [Vec4; 3],
    vb: [Vec4; 3],
    id: [u32; 4],
}

/// Packed shapes; `id` maps a lane to the shape's index in the scene.
#[derive(Clone, Debug, Default)]
pub struct Packed {
    spheres: Vec<Spheres4>,
    quads: Vec<Quads4>,
}

fn lanes(v: &[Vec3A], pad: Vec3A) -> [Vec4; 3] {
    let g = |i: usize| v.get(i).copied().unwrap_or(pad);
    [0, 1, 2].map(|k| Vec4::new(g(0)[k], g(1)[k], g(2)[k], g(3)[k]))
}

impl Packed {
    pub fn new(shapes: &[Shape]) -> Packed {
        let mut p = Packed::default();
        let (mut sph, mut qua) = (vec![], vec![]);
        for (i, s) in shapes.iter().enumerate() {
            match s {
                Shape::Sphere(s) => sph.push((i as u32, *s)),
                Shape::Quad(q) => qua.push((i as u32, *q)),
            }
        }
        for g in sph.chunks(4) {
            let c: Vec<Vec3A> = g.iter().map(|s| s.1.centre).collect();
            let r2 = |k: usize| g.get(k).map_or(-1.0, |s| s.1.radius * s.1.radius);
            let id = |k: usize| g.get(k).map_or(u32::MAX, |s| s.0);
            p.spheres.push(Spheres4 {
                c: lanes(&c, Vec3A::ZERO),
                r2: Vec4::new(r2(0), r2(1), r2(2), r2(3)),
                id: [id(0), id(1), id(2), id(3)],
            });
        }
        for g in qua.chunks(4) {
            let f = |h: fn(&super::shapes::Quad) -> Vec3A| -> [Vec4; 3] {
                lanes(&g.iter().map(|q| h(&q.1)).collect::<Vec<_>>(), Vec3A::ZERO)
            };
            let id = |k: usize| g.get(k).map_or(u32::MAX, |s| s.0);
            p.quads.push(Quads4 {
                c: f(|q| q.corner),
                n: f(|q| q.normal()),
                ua: f(|q| q.dual().0),
                vb: f(|q| q.dual().1),
                id: [id(0), id(1), id(2), id(3)],
            });
        }
        p
    }

    /// Nearest hit in (0, tmax) as `(t, shape index)`; with `any`, the
    /// first hit found (shadow rays).
    #[inline]
    fn trace(&self, o: Vec3A, d: Vec3A, tmax: f32, any: bool) -> Option<(f32, usize)> {
        let (ox, oy, oz) = (Vec4::splat(o.x), Vec4::splat(o.y), Vec4::splat(o.z));
        let (dx, dy, dz) = (Vec4::splat(d.x), Vec4::splat(d.y), Vec4::splat(d.z));
        let zero = Vec4::ZERO;
        let one = Vec4::ONE;
        let mut tbest = tmax;
        let mut best = None;
        let mut take = |t: Vec4, mask: u32, id: &[u32; 4], tbest: &mut f32| {
            let ta = t.to_array();
            for k in 0..4 {
                if mask & (1 << k) != 0 && ta[k] < *tbest {
                    *tbest = ta[k];
                    best = Some((ta[k], id[k] as usize));
                }
            }
        };
        for s in &self.spheres {
            let (fx, fy, fz) = (ox - s.c[0], oy - s.c[1], oz - s.c[2]);
            let b = -(fx * dx + fy * dy + fz * dz);
            let c = fx * fx + fy * fy + fz * fz - s.r2;
            let (lx, ly, lz) = (fx + b * dx, fy + b * dy, fz + b * dz);
            let disc = s.r2 - (lx * lx + ly * ly + lz * lz);
            let root = disc.max(zero).map(f32::sqrt);
            let q = b + Vec4::select(b.cmplt(zero), -root, root);
            let (t0, t1) = (c / q, q);
            let (lo, hi) = (t0.min(t1), t0.max(t1));
            let t = Vec4::select(lo.cmpgt(zero), lo, hi);
            let outside_behind = c.cmpgt(zero) & b.cmplt(zero);
            let ok = disc.cmpge(zero)
                & !outside_behind
                & t.cmpgt(zero)
                & t.cmplt(Vec4::splat(tbest))
                & q.cmpne(zero);
            let m = ok.bitmask();
            if m != 0 {
                if any {
                    return Some((0.0, 0));
                }
                take(t, m, &s.id, &mut tbest);
            }
        }
        for g in &self.quads {
            let dn = dx * g.n[0] + dy * g.n[1] + dz * g.n[2];
            let num = (g.c[0] - ox) * g.n[0] + (g.c[1] - oy) * g.n[1] + (g.c[2] - oz) * g.n[2];
            let t = num / dn;
            let (hx, hy, hz) = (
                ox + t * dx - g.c[0],
                oy + t * dy - g.c[1],
                oz + t * dz - g.c[2],
            );
            let a = hx * g.ua[0] + hy * g.ua[1] + hz * g.ua[2];
            let bb = hx * g.vb[0] + hy * g.vb[1] + hz * g.vb[2];
            let ok = t.cmpgt(zero)
                & t.cmplt(Vec4::splat(tbest))
                & a.cmpge(zero)
                & a.cmple(one)
                & bb.cmpge(zero)
                & bb.cmple(one);
            let m = ok.bitmask();
            if m != 0 {
                if any {
                    return Some((0.0, 0));
                }
                take(t, m, &g.id, &mut tbest);
            }
        }
        best
    }

    /// The nearest hit of `o + t d`, t in (0, tmax): `(t, shape index)`.
    #[inline]
    pub fn intersect(&self, o: Vec3A, d: Vec3A, tmax: f32) -> Option<(f32, usize)> {
        self.trace(o, d, tmax, false)
    }

    /// Whether anything lies on `o + t d` for t in (0, tmax).
    #[inline]
    pub fn occluded(&self, o: Vec3A, d: Vec3A, tmax: f32) -> bool {
        self.trace(o, d, tmax, true).is_some()
    }
}

/// The Cornell box's walls, light and spheres plus one tilted quad (test scenes).
#[cfg(test)]
pub(crate) fn cornell_shapes() -> Vec<Shape> {
    use super::shapes::{Quad, Sphere};
    let v = Vec3A::new;
    let mut shapes = vec![];
    for (c, u, w) in [
        (v(-1.0, -1.0, -1.0), v(0.0, 0.0, 2.0), v(0.0, 2.0, 0.0)),
        (v(1.0, -1.0, -1.0), v(0.0, 2.0, 0.0), v(0.0, 0.0, 2.0)),
        (v(-1.0, -1.0, -1.0), v(0.0, 2.0, 0.0), v(2.0, 0.0, 0.0)),
        (v(-1.0, -1.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 0.0, 2.0)),
        (v(-1.0, 1.0, -1.0), v(0.0, 0.0, 2.0), v(2.0, 0.0, 0.0)),
        (v(-0.25, 0.99, -0.25), v(0.5, 0.0, 0.0), v(0.0, 0.0, 0.5)),
        (v(0.0, 0.0, 0.0), v(0.3, 0.0, -0.3), v(0.0, 0.4, 0.1)),
    ] {
        shapes.push(Shape::Quad(Quad::new(c, u, w).unwrap()));
    }
    for (c, r) in [
        (v(0.4, -0.6, -0.2), 0.4),
        (v(-0.4, -0.7, 0.3), 0.3),
        (v(0.0, -0.8, 0.5), 0.2),
    ] {
        shapes.push(Shape::Sphere(Sphere {
            centre: c,
            radius: r,
        }));
    }
    shapes
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pathtrace::shapes::{intersect, occluded};
    use crate::rng::rand_f32;

    #[test]
    fn packed_agrees_with_the_scalar_loop() {
        let v = Vec3A::new;
        let shapes = cornell_shapes();
        let p = Packed::new(&shapes);
        let mut hits = 0;
        for i in 0..50_000u32 {
            let r = |k| rand_f32(11, i, 0, k) * 2.0 - 1.0;
            let o = v(r(0), r(1), r(2) * 0.5 + 2.0 * (i % 2) as f32);
            let d = v(r(3), r(4), r(5)).normalize();
            let (a, b) = (
                intersect(&shapes, o, d, f32::INFINITY),
                p.intersect(o, d, f32::INFINITY),
            );
            match (a, b) {
                (Some((ta, ia)), Some((tb, ib))) => {
                    hits += 1;
                    // Rounding may pick the other of two surfaces that meet.
                    assert!((ta - tb).abs() <= 1e-4 * ta.max(1.0), "{ta} {tb}");
                    if (ta - tb).abs() > 1e-5 {
                        assert_eq!(ia, ib);
                    }
                }
                (None, None) => {}
                other => panic!("ray {i}: {other:?}"),
            }
            assert_eq!(
                occluded(&shapes, o, d, 1.0),
                p.occluded(o, d, 1.0),
                "ray {i}"
            );
        }
        assert!(hits > 20_000, "{hits}");
    }
}
