//! Shapes of the path tracer (seed 004 "Geometry System"): spheres and
//! parallelogram quads behind ONE intersection function, [`intersect`], so a
//! BVH can replace the loop later without touching callers.
//!
//! Directions passed to these functions are unit vectors (the integrator
//! only makes unit directions; [`intersect`] relies on `d . d = 1`).
//!
//! Self-intersection: a ray leaving a surface starts at [`spawn_origin`], the
//! hit point pushed along the geometric normal (to the side the new ray
//! leaves on) by `OFFSET_REL * (1 + max_i |p_i|)`, i.e. scaled to the
//! position's magnitude, which bounds the f32 rounding error of the hit
//! point (a few ulps of `|p|`; sphere hits are also re-projected onto the
//! sphere). With that origin every ray is tested for `t > 0` only.
//!
//! WGSL twin (GPU issue to come): the same loop over the same closed list.

use glam::Vec3A;

/// Relative normal offset of a spawned ray origin (see module docs). The
/// hit point's rounding error is about 3 ulps of `|p|` (~4e-7 |p|); 2e-5
/// leaves a factor ~50 of margin while staying far below every feature size
/// of the Cornell box (the light hangs 0.01 below the ceiling).
pub const OFFSET_REL: f32 = 2e-5;

/// A sphere `|p - centre| = radius`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Sphere {
    pub centre: Vec3A,
    pub radius: f32,
}

/// The parallelogram `corner + a u + b v`, a and b in [0, 1]. Its geometric
/// normal is `normalize(u x v)` (the side a one-sided light emits towards).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Quad {
    pub corner: Vec3A,
    pub u: Vec3A,
    pub v: Vec3A,
    /// Dual edge vectors: for `h` in the plane, `a = h . ua`, `b = h . vb`
    /// (`ua = (v x n) / (u . (v x n))`, `vb = (n x u) / (v . (n x u))`).
    ua: Vec3A,
    vb: Vec3A,
    normal: Vec3A,
    area: f32,
    /// The axis the plane is perpendicular to (the normal is exactly +-e_axis,
    /// as for every Cornell box wall), or 3 for a tilted plane.
    axis: usize,
}

impl Quad {
    /// A quad from a corner and two edge vectors; `None` when the edges are
    /// parallel or degenerate (zero area) or not finite.
    pub fn new(corner: Vec3A, u: Vec3A, v: Vec3A) -> Option<Quad> {
        let n = u.cross(v);
        let nn = n.length_squared();
        if !(nn > 0.0 && nn.is_finite() && corner.is_finite()) {
            return None;
        }
        let normal = n / nn.sqrt();
        let (vn, nu) = (v.cross(normal), normal.cross(u));
        let (ua, vb) = (vn / u.dot(vn), nu / v.dot(nu));
        if !(ua.is_finite() && vb.is_finite()) {
            return None;
        }
        let axis = (0..3)
            .find(|&a| {
                normal[a].abs() == 1.0 && normal[(a + 1) % 3] == 0.0 && normal[(a + 2) % 3] == 0.0
            })
            .unwrap_or(3);
        Some(Quad {
            corner,
            u,
            v,
            ua,
            vb,
            normal,
            area: nn.sqrt(),
            axis,
        })
    }

    pub fn normal(&self) -> Vec3A {
        self.normal
    }

    /// The dual edge vectors `(ua, vb)`: `a = h . ua`, `b = h . vb`.
    pub fn dual(&self) -> (Vec3A, Vec3A) {
        (self.ua, self.vb)
    }

    pub fn area(&self) -> f32 {
        self.area
    }

    /// The axis the plane is perpendicular to (0..2), or 3 for a tilted plane.
    pub fn axis(&self) -> usize {
        self.axis
    }

    /// The point at parameters (a, b) in [0, 1]^2 (uniform in area).
    #[inline]
    pub fn point(&self, a: f32, b: f32) -> Vec3A {
        self.corner + a * self.u + b * self.v
    }
}

/// The closed list of shape kinds (one `match` per method; mirrored as kind
/// codes in WGSL).
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Shape {
    Sphere(Sphere),
    Quad(Quad),
}

impl Shape {
    /// Nearest `t` in `(0, tmax)` where `o + t d` meets the shape.
    #[inline]
    pub fn hit_t(&self, o: Vec3A, d: Vec3A, tmax: f32) -> Option<f32> {
        match self {
            Shape::Sphere(s) => sphere_t(s, o, d, tmax),
            Shape::Quad(q) => quad_t(q, o, d, tmax),
        }
    }

    /// Hit point (sphere hits re-projected onto the sphere) and unit outward
    /// geometric normal at `o + t d`.
    #[inline]
    pub fn surface(&self, o: Vec3A, d: Vec3A, t: f32) -> (Vec3A, Vec3A) {
        let p = o + t * d;
        match self {
            Shape::Sphere(s) => {
                let r = p - s.centre;
                let n = r / r.length();
                (s.centre + n * s.radius, n)
            }
            Shape::Quad(q) => (p, q.normal),
        }
    }
}

/// Ray-sphere intersection with the stable quadratic (Ray Tracing Gems ch. 7).
/// With `f = o - c`, `|d| = 1`: half-b `b = -f.d`, the discriminant computed
/// from the perpendicular part `l = f + b d` as `disc = r^2 - l.l` (no
/// cancellation of two large squares), `q = b + sign(b) sqrt(disc)`, roots
/// `t = c/q` and `t = q` with `c = f.f - r^2` (the seed's
/// `q = -0.5 (B + sign(B) sqrt(B^2 - 4AC))` with `B = 2 f.d = -2b`, `A = 1`).
/// A tangent ray (`disc = 0`) hits. Returns the nearest root in (0, tmax).
#[inline]
pub fn sphere_t(s: &Sphere, o: Vec3A, d: Vec3A, tmax: f32) -> Option<f32> {
    let f = o - s.centre;
    let b = -f.dot(d);
    let r2 = s.radius * s.radius;
    let c = f.length_squared() - r2;
    // Origin outside and sphere behind: both roots negative.
    if c > 0.0 && b < 0.0 {
        return None;
    }
    let l = f + b * d;
    let disc = r2 - l.length_squared();
    if disc < 0.0 {
        return None;
    }
    let q = b + disc.sqrt().copysign(b);
    let (t0, t1) = if q == 0.0 { (0.0, 0.0) } else { (c / q, q) };
    let (lo, hi) = if t0 <= t1 { (t0, t1) } else { (t1, t0) };
    if lo > 0.0 && lo < tmax {
        Some(lo)
    } else if hi > 0.0 && hi < tmax {
        Some(hi)
    } else {
        None
    }
}

/// Ray-parallelogram intersection: plane hit `t = (corner - o).n / d.n`,
/// (for a plane perpendicular to an axis simply `(corner_k - o_k) / d_k`),
/// then with `h = o + t d - corner` the edge coordinates `a = h . ua`,
/// `b = h . vb` (dual basis of u, v in the plane); inside when both lie in
/// [0, 1]. Rays parallel to the plane miss.
#[inline]
pub fn quad_t(q: &Quad, o: Vec3A, d: Vec3A, tmax: f32) -> Option<f32> {
    let t = if q.axis < 3 {
        let k = q.axis;
        if d[k] == 0.0 {
            return None;
        }
        (q.corner[k] - o[k]) / d[k]
    } else {
        let dn = d.dot(q.normal);
        if dn == 0.0 {
            return None;
        }
        (q.corner - o).dot(q.normal) / dn
    };
    if !(t > 0.0 && t < tmax) {
        return None;
    }
    let h = o + t * d - q.corner;
    let a = h.dot(q.ua);
    let b = h.dot(q.vb);
    if (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b) {
        Some(t)
    } else {
        None
    }
}

/// The nearest hit of `o + t d`, t in (0, tmax), over `shapes`: `(t, index)`.
/// This is the one intersection routine of the renderer.
#[inline]
pub fn intersect(shapes: &[Shape], o: Vec3A, d: Vec3A, tmax: f32) -> Option<(f32, usize)> {
    let mut best = None;
    let mut tbest = tmax;
    for (i, s) in shapes.iter().enumerate() {
        if let Some(t) = s.hit_t(o, d, tbest) {
            tbest = t;
            best = Some((t, i));
        }
    }
    best
}

/// Whether anything lies on `o + t d` for t in (0, tmax) (shadow rays).
#[inline]
pub fn occluded(shapes: &[Shape], o: Vec3A, d: Vec3A, tmax: f32) -> bool {
    shapes.iter().any(|s| s.hit_t(o, d, tmax).is_some())
}

/// Origin for a ray leaving the surface point `p` (geometric normal `n`) in
/// direction `w`: `p` pushed to `w`'s side by `OFFSET_REL (1 + max|p_i|)`.
#[inline]
pub fn spawn_origin(p: Vec3A, n: Vec3A, w: Vec3A) -> Vec3A {
    let eps = OFFSET_REL * (1.0 + p.abs().max_element());
    if w.dot(n) >= 0.0 {
        p + eps * n
    } else {
        p - eps * n
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rng::rand_f32;

    fn v(x: f32, y: f32, z: f32) -> Vec3A {
        Vec3A::new(x, y, z)
    }

    const UNIT: Sphere = Sphere {
        centre: Vec3A::ZERO,
        radius: 1.0,
    };

    #[test]
    fn centre_hit_is_distance_minus_radius() {
        let t = sphere_t(&UNIT, v(0.0, 0.0, 5.0), v(0.0, 0.0, -1.0), f32::INFINITY).unwrap();
        assert_eq!(t, 4.0);
    }

    #[test]
    fn tangent_ray_hits_once_at_the_touching_point() {
        // f = (-5, 1, 0), f.d = -5, l = (0, 1, 0): disc = 1 - 1 = 0 exactly.
        let t = sphere_t(&UNIT, v(-5.0, 1.0, 0.0), v(1.0, 0.0, 0.0), f32::INFINITY).unwrap();
        assert_eq!(t, 5.0);
        assert!(sphere_t(&UNIT, v(-5.0, 1.0001, 0.0), v(1.0, 0.0, 0.0), f32::INFINITY).is_none());
    }

    #[test]
    fn miss_and_behind_return_none() {
        assert!(sphere_t(&UNIT, v(0.0, 2.0, 5.0), v(0.0, 0.0, -1.0), f32::INFINITY).is_none());
        assert!(sphere_t(&UNIT, v(0.0, 0.0, 5.0), v(0.0, 0.0, 1.0), f32::INFINITY).is_none());
        assert!(sphere_t(&UNIT, v(0.0, 0.0, 5.0), v(0.0, 0.0, -1.0), 3.9).is_none());
    }

    #[test]
    fn ray_from_inside_hits_the_far_wall() {
        let t = sphere_t(&UNIT, v(0.0, 0.0, 0.5), v(0.0, 0.0, -1.0), f32::INFINITY).unwrap();
        assert_eq!(t, 1.5);
    }

    #[test]
    fn far_small_sphere_keeps_relative_precision() {
        // A naive b^2 - 4ac loses all digits here; the stable form does not.
        let s = Sphere {
            centre: v(0.0, 0.0, -1.0e4),
            radius: 1.0e-2,
        };
        let t = sphere_t(&s, Vec3A::ZERO, v(0.0, 0.0, -1.0), f32::INFINITY).unwrap();
        assert!((t - (1.0e4 - 1.0e-2)).abs() <= 1.0e-3, "{t}");
    }

    #[test]
    fn quad_hits_inside_and_misses_outside_and_parallel() {
        let q = Quad::new(v(-1.0, -1.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 2.0, 0.0)).unwrap();
        assert_eq!(q.normal(), v(0.0, 0.0, 1.0));
        assert_eq!(q.area(), 4.0);
        assert_eq!(
            quad_t(&q, v(0.5, 0.5, 3.0), v(0.0, 0.0, -1.0), f32::INFINITY),
            Some(4.0)
        );
        assert!(quad_t(&q, v(1.5, 0.5, 3.0), v(0.0, 0.0, -1.0), f32::INFINITY).is_none());
        assert!(quad_t(&q, v(0.0, 0.0, 3.0), v(1.0, 0.0, 0.0), f32::INFINITY).is_none());
        // Two-sided: a ray from behind hits too.
        assert_eq!(
            quad_t(&q, v(0.0, 0.0, -3.0), v(0.0, 0.0, 1.0), f32::INFINITY),
            Some(2.0)
        );
        assert!(Quad::new(Vec3A::ZERO, v(1.0, 0.0, 0.0), v(2.0, 0.0, 0.0)).is_none());
    }

    #[test]
    fn tilted_quad_matches_its_plane_and_edges() {
        // The plane x + z = 0 through the origin, edges (1, 0, -1) and (0, 1, 0).
        let q = Quad::new(v(0.0, 0.0, 0.0), v(1.0, 0.0, -1.0), v(0.0, 1.0, 0.0)).unwrap();
        let t = quad_t(&q, v(0.5, 0.5, 2.0), v(0.0, 0.0, -1.0), f32::INFINITY).unwrap();
        assert!((t - 2.5).abs() < 1e-6, "{t}");
        assert!(quad_t(&q, v(1.5, 0.5, 2.0), v(0.0, 0.0, -1.0), f32::INFINITY).is_none());
        assert!(quad_t(&q, v(0.5, 1.5, 2.0), v(0.0, 0.0, -1.0), f32::INFINITY).is_none());
    }

    #[test]
    fn nearest_of_several_shapes_wins() {
        let shapes = [
            Shape::Quad(
                Quad::new(v(-1.0, -1.0, -1.0), v(2.0, 0.0, 0.0), v(0.0, 2.0, 0.0)).unwrap(),
            ),
            Shape::Sphere(Sphere {
                centre: Vec3A::ZERO,
                radius: 0.5,
            }),
        ];
        let (t, i) =
            intersect(&shapes, v(0.0, 0.0, 3.0), v(0.0, 0.0, -1.0), f32::INFINITY).unwrap();
        assert_eq!((t, i), (2.5, 1));
        assert!(occluded(&shapes, v(0.0, 0.0, 3.0), v(0.0, 0.0, -1.0), 3.0));
        assert!(!occluded(&shapes, v(0.0, 0.0, 3.0), v(0.0, 0.0, -1.0), 2.4));
    }

    /// Rays spawned from hit points never re-hit their own surface at t ~ 0
    /// (acne), whichever side they leave on.
    #[test]
    fn spawned_rays_do_not_self_intersect() {
        let s = Sphere {
            centre: v(0.4, -0.6, -0.2),
            radius: 0.4,
        };
        let shape = [Shape::Sphere(s)];
        let mut acne = 0;
        for i in 0..20_000u32 {
            let r = |k| rand_f32(1, i, 0, k) * 2.0 - 1.0;
            let o = v(r(0) * 3.0, r(1) * 3.0, 3.0);
            let d = (s.centre + v(r(2), r(3), r(4)) * 0.3 - o).normalize();
            let Some(t) = sphere_t(&s, o, d, f32::INFINITY) else {
                continue;
            };
            let (p, n) = shape[0].surface(o, d, t);
            // Leaving outward: must not hit the (convex) sphere again.
            let w = (n + v(r(5), r(6), r(7)) * 0.9).normalize();
            if w.dot(n) > 0.0
                && intersect(&shape, spawn_origin(p, n, w), w, f32::INFINITY).is_some()
            {
                acne += 1;
            }
            // Entering (refraction): must hit the far side (where the ray
            // leaves, (q - c).w > 0), not the entry point again at t ~ 0.
            let w = -w;
            if w.dot(n) < 0.0 {
                let o2 = spawn_origin(p, n, w);
                match intersect(&shape, o2, w, f32::INFINITY) {
                    Some((t2, _)) if (o2 + t2 * w - s.centre).dot(w) > 0.0 => {}
                    _ => acne += 1,
                }
            }
        }
        assert_eq!(acne, 0);
    }
}
