//! The independent referee: an Amanatides–Woo DDA over the finest voxel
//! grid that evaluates the scene predicate ([`Shape::solid`]) voxel by voxel,
//! in f64 with exact decisions. No octree code, no dense grid.
//!
//! Every decision compares two *times*: the crossing of a grid plane
//! `x_a = -1 + 2k / 2^d` on axis a, `T = (x - o_a) / d_a`, or a given time
//! (near, far). Plane coordinates are exact in f64, so the sign of
//! `(x_a - o_a) d_b - (x_b - o_b) d_a` is computed exactly from an
//! error-free expansion (two-sum, fused two-product, Shewchuk's grow
//! expansion) whenever the rounded times are too close to order safely:
//! the referee's voxel sequence is the exact one for the given f64 ray.
//!
//! Conventions: a point on a voxel boundary belongs to the voxel the ray
//! moves into; an axis the ray does not move along uses
//! `i = floor((x + 1) / 2 * 2^d)` clamped to the grid; when the ray crosses
//! two or three planes at the same instant (an edge or a corner) it steps
//! all of them at once. `t` is the hit voxel's entry time (or the start time
//! when the ray starts inside it), the normal is the outward normal of the
//! entered face (zero when the ray starts inside the hit voxel).
//!
//! Ties: the result depends on the convention exactly when the ray touches
//! a solid voxel it does not enter (it passes through an edge or corner of
//! it, lies in one of its face planes, or starts on its boundary), or enters
//! the hit voxel through an edge or corner (the normal is ambiguous). Such
//! rays are flagged `tie`. `near_tie` flags the same situations when the
//! distances involved are below a margin (world units; a plane crossing on
//! axis a within `margin / |d_a|` in t), for comparing a lower-precision cast.

use std::cmp::Ordering;

use super::shape::Shape;

/// What the referee found for one ray. On a miss `t = -1`, voxel zero.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RefHit {
    pub hit: bool,
    pub t: f64,
    pub voxel: [u32; 3],
    pub normal: [i8; 3],
    pub tie: bool,
    pub near_tie: bool,
    /// Voxels visited.
    pub steps: u32,
}

#[inline]
fn two_sum(a: f64, b: f64) -> (f64, f64) {
    let s = a + b;
    let bb = s - a;
    let e = (a - (s - bb)) + (b - bb);
    (s, e)
}

#[inline]
fn two_prod(a: f64, b: f64) -> (f64, f64) {
    let p = a * b;
    (p, a.mul_add(b, -p))
}

/// The exact sign of `terms[0] + terms[1] + ...` (finite, no overflow):
/// grows a non-overlapping expansion with two-sum and zero elimination; its
/// largest component carries the sign.
pub fn sign_of_sum(terms: &[f64]) -> Ordering {
    let mut e = [0.0f64; 24];
    let mut n = 0usize;
    for &b in terms {
        let mut q = b;
        let mut m = 0usize;
        for i in 0..n {
            let (s, h) = two_sum(q, e[i]);
            q = s;
            if h != 0.0 {
                e[m] = h;
                m += 1;
            }
        }
        if q != 0.0 {
            e[m] = q;
            m += 1;
        }
        n = m;
    }
    if n == 0 {
        Ordering::Equal
    } else {
        e[n - 1].partial_cmp(&0.0).unwrap_or(Ordering::Equal)
    }
}

/// A time along the ray: a plane crossing or a given value.
#[derive(Clone, Copy, Debug, PartialEq)]
enum Time {
    Plane { axis: usize, x: f64 },
    At(f64),
}

struct Ray {
    o: [f64; 3],
    d: [f64; 3],
}

impl Ray {
    #[inline]
    fn approx(&self, t: Time) -> f64 {
        match t {
            Time::Plane { axis, x } => (x - self.o[axis]) / self.d[axis],
            Time::At(s) => s,
        }
    }

    /// Exact order of two times.
    fn cmp(&self, x: Time, y: Time) -> Ordering {
        let (vx, vy) = (self.approx(x), self.approx(y));
        if !vx.is_finite() || !vy.is_finite() || (vx - vy).abs() > 1e-13 * (vx.abs() + vy.abs()) {
            return vx.partial_cmp(&vy).unwrap_or(Ordering::Equal);
        }
        match (x, y) {
            (Time::At(s), Time::At(u)) => s.partial_cmp(&u).unwrap_or(Ordering::Equal),
            (Time::Plane { axis, x }, Time::At(s)) => {
                let (s1, e1) = two_sum(x, -self.o[axis]);
                let (q, f) = two_prod(s, self.d[axis]);
                let o = sign_of_sum(&[s1, e1, -q, -f]);
                if self.d[axis] < 0.0 {
                    o.reverse()
                } else {
                    o
                }
            }
            (Time::At(_), Time::Plane { .. }) => self.cmp(y, x).reverse(),
            (Time::Plane { axis: a, x: p }, Time::Plane { axis: b, x: q }) => {
                if a == b {
                    let o = p.partial_cmp(&q).unwrap_or(Ordering::Equal);
                    return if self.d[a] < 0.0 { o.reverse() } else { o };
                }
                let (s1, e1) = two_sum(p, -self.o[a]);
                let (s2, e2) = two_sum(q, -self.o[b]);
                let (p1, f1) = two_prod(s1, self.d[b]);
                let (p2, f2) = two_prod(e1, self.d[b]);
                let (p3, f3) = two_prod(-s2, self.d[a]);
                let (p4, f4) = two_prod(-e2, self.d[a]);
                let o = sign_of_sum(&[p1, f1, p2, f2, p3, f3, p4, f4]);
                if (self.d[a] < 0.0) != (self.d[b] < 0.0) {
                    o.reverse()
                } else {
                    o
                }
            }
        }
    }
}

/// Whether any voxel `c + delta`, `delta_b` in `{0, alt[b]}`, `delta != 0`, is solid.
fn ambiguous(shape: &Shape, depth: u32, c: [i64; 3], alt: [i64; 3]) -> bool {
    if alt == [0; 3] {
        return false;
    }
    for m in 1..8u32 {
        if (0..3).any(|b| m >> b & 1 == 1 && alt[b] == 0) {
            continue;
        }
        let v = [0, 1, 2].map(|b| c[b] + if m >> b & 1 == 1 { alt[b] } else { 0 });
        if solid(shape, depth, v) {
            return true;
        }
    }
    false
}

#[inline]
fn solid(shape: &Shape, depth: u32, v: [i64; 3]) -> bool {
    let n = 1i64 << depth;
    v.iter().all(|&x| (0..n).contains(&x)) && shape.solid(depth, v.map(|x| x as u32))
}

/// Casts `o + t d`, t in `[near, far]`, through the depth-`depth` grid of
/// `shape` (see the module doc for conventions, ties and `margin`).
pub fn referee(
    shape: &Shape,
    depth: u32,
    o: [f64; 3],
    d: [f64; 3],
    near: f64,
    far: f64,
    margin: f64,
) -> RefHit {
    let miss = |steps: u32| RefHit {
        hit: false,
        t: -1.0,
        voxel: [0; 3],
        normal: [0; 3],
        tie: false,
        near_tie: false,
        steps,
    };
    let n = 1i64 << depth;
    let w = 2.0 / n as f64;
    let plane = |k: i64| -1.0 + k as f64 * w;
    let ray = Ray { o, d };
    let sgn = d.map(|v| {
        if v > 0.0 {
            1i64
        } else if v < 0.0 {
            -1
        } else {
            0
        }
    });
    let inv = d.map(|v| if v != 0.0 { 1.0 / v.abs() } else { 0.0 });
    let close = |ta: f64, ia: f64, tb: f64, ib: f64| (ta - tb).abs() < margin * (ia + ib);

    // Root interval, exactly.
    let mut t_in = Time::At(near);
    let mut entry = 0u8;
    let mut t_out = Time::At(far);
    for a in 0..3 {
        if sgn[a] == 0 {
            if o[a] < -1.0 || o[a] > 1.0 {
                return miss(0);
            }
            continue;
        }
        let (pin, pout) = if sgn[a] > 0 {
            (plane(0), plane(n))
        } else {
            (plane(n), plane(0))
        };
        let ti = Time::Plane { axis: a, x: pin };
        match ray.cmp(ti, t_in) {
            Ordering::Greater => {
                t_in = ti;
                entry = 1 << a;
            }
            Ordering::Equal => entry |= 1 << a,
            Ordering::Less => {}
        }
        let to = Time::Plane { axis: a, x: pout };
        if ray.cmp(to, t_out) == Ordering::Less {
            t_out = to;
        }
    }
    if ray.cmp(t_in, t_out) != Ordering::Less {
        return miss(0);
    }
    let t_in_v = ray.approx(t_in);
    let inv_in = match t_in {
        Time::Plane { axis, .. } => inv[axis],
        Time::At(_) => 0.0,
    };

    // Start voxel, and the voxels the start instant also touches.
    let mut c = [0i64; 3];
    let (mut static_e, mut static_n) = ([0i64; 3], [0i64; 3]);
    let (mut alt_e, mut alt_n) = ([0i64; 3], [0i64; 3]);
    let (mut cross_e, mut cross_n) = (entry.count_ones(), entry.count_ones());
    for b in 0..3 {
        if sgn[b] == 0 {
            let mut k = (((o[b] + 1.0) / w).floor() as i64).clamp(0, n - 1);
            while k < n - 1 && o[b] >= plane(k + 1) {
                k += 1;
            }
            while k > 0 && o[b] < plane(k) {
                k -= 1;
            }
            c[b] = k;
            if k > 0 && o[b] == plane(k) {
                static_e[b] = -1;
                static_n[b] = -1;
            } else if k > 0 && o[b] - plane(k) < margin {
                static_n[b] = -1;
            } else if k < n - 1 && plane(k + 1) - o[b] < margin {
                static_n[b] = 1;
            }
            continue;
        }
        if entry >> b & 1 == 1 {
            c[b] = if sgn[b] > 0 { 0 } else { n - 1 };
            continue;
        }
        let guess = ((o[b] + t_in_v * d[b] + 1.0) / w).floor();
        let mut k = if guess.is_finite() {
            (guess as i64).clamp(0, n - 1)
        } else {
            0
        };
        let crossed = |k: i64| Time::Plane {
            axis: b,
            x: plane(k),
        };
        if sgn[b] > 0 {
            while k < n - 1 && ray.cmp(crossed(k + 1), t_in) != Ordering::Greater {
                k += 1;
            }
            while k > 0 && ray.cmp(crossed(k), t_in) == Ordering::Greater {
                k -= 1;
            }
        } else {
            while k > 0 && ray.cmp(crossed(k), t_in) != Ordering::Greater {
                k -= 1;
            }
            while k < n - 1 && ray.cmp(crossed(k + 1), t_in) == Ordering::Greater {
                k += 1;
            }
        }
        c[b] = k;
        let (back, front) = if sgn[b] > 0 {
            (plane(k), plane(k + 1))
        } else {
            (plane(k + 1), plane(k))
        };
        let tb = Time::Plane { axis: b, x: back };
        if ray.cmp(tb, t_in) == Ordering::Equal {
            alt_e[b] = -sgn[b];
            alt_n[b] = -sgn[b];
            cross_e += 1;
            cross_n += 1;
        } else if close(ray.approx(tb), inv[b], t_in_v, inv_in) {
            alt_n[b] = -sgn[b];
            cross_n += 1;
        } else if close(
            ray.approx(Time::Plane { axis: b, x: front }),
            inv[b],
            t_in_v,
            inv_in,
        ) {
            alt_n[b] = sgn[b];
            cross_n += 1;
        }
    }
    // Starting inside, the start point itself counts as one "crossing" for the normal.
    let inside = entry == 0;
    if inside {
        cross_e += (cross_e > 0) as u32;
        cross_n += (cross_n > 0) as u32;
    }
    let mut t_cur = t_in;
    let mut entered: Option<usize> = (0..3).find(|&a| entry >> a & 1 == 1);
    let (mut tie, mut near_tie) = (false, false);
    let mut steps = 0u32;
    let combine = |s: [i64; 3], a: [i64; 3]| [0, 1, 2].map(|b| if a[b] != 0 { a[b] } else { s[b] });
    loop {
        steps += 1;
        tie |= ambiguous(shape, depth, c, combine(static_e, alt_e));
        near_tie |= tie || ambiguous(shape, depth, c, combine(static_n, alt_n));
        if solid(shape, depth, c) {
            tie |= cross_e >= 2;
            near_tie |= tie || cross_n >= 2;
            let mut normal = [0i8; 3];
            if let Some(a) = entered {
                normal[a] = -sgn[a] as i8;
            }
            return RefHit {
                hit: true,
                t: ray.approx(t_cur),
                voxel: c.map(|x| x as u32),
                normal,
                tie,
                near_tie,
                steps,
            };
        }
        // Next crossing: the earliest plane ahead on the moving axes.
        let mut next = [None; 3];
        let mut tmin: Option<(usize, Time)> = None;
        for b in 0..3 {
            if sgn[b] == 0 {
                continue;
            }
            let x = if sgn[b] > 0 {
                plane(c[b] + 1)
            } else {
                plane(c[b])
            };
            let tb = Time::Plane { axis: b, x };
            next[b] = Some(tb);
            tmin = match tmin {
                Some((a, ta)) if ray.cmp(ta, tb) != Ordering::Greater => Some((a, ta)),
                _ => Some((b, tb)),
            };
        }
        let Some((amin, tm)) = tmin else {
            return RefHit {
                tie,
                near_tie,
                ..miss(steps)
            }; // not moving: the start voxel was the only one
        };
        if ray.cmp(tm, t_out) != Ordering::Less {
            return RefHit {
                tie,
                near_tie,
                ..miss(steps)
            };
        }
        let tmv = ray.approx(tm);
        alt_e = [0; 3];
        alt_n = [0; 3];
        cross_e = 0;
        cross_n = 0;
        entered = None;
        for b in 0..3 {
            let Some(tb) = next[b] else { continue };
            if b == amin || ray.cmp(tb, tm) == Ordering::Equal {
                c[b] += sgn[b];
                alt_e[b] = -sgn[b];
                alt_n[b] = -sgn[b];
                cross_e += 1;
                cross_n += 1;
                entered = entered.or(Some(b));
            } else if close(ray.approx(tb), inv[b], tmv, inv[amin]) {
                alt_n[b] = sgn[b];
                cross_n += 1;
            }
        }
        t_cur = tm;
        if steps > 4 * n as u32 + 8 {
            return RefHit {
                tie,
                near_tie,
                ..miss(steps)
            };
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::voxels::shape::VoxelBox;

    #[test]
    fn exact_sign_sees_what_rounding_hides() {
        assert_eq!(sign_of_sum(&[1e30, 1.0, -1e30]), Ordering::Greater);
        // 0.1 + 0.2 exceeds 0.3 in the exact values of the three doubles.
        assert_eq!(sign_of_sum(&[0.1, 0.2, -0.3]), Ordering::Greater);
        assert_eq!(sign_of_sum(&[-0.1, -0.2, 0.3]), Ordering::Less);
        assert_eq!(sign_of_sum(&[1.0, -1.0]), Ordering::Equal);
        assert_eq!(sign_of_sum(&[2f64.powi(-60), 1.0, -1.0]), Ordering::Greater);
    }

    #[test]
    fn axis_ray_through_voxel_centres_hits_the_first_solid_voxel() {
        let s = Shape::Boxes {
            boxes: vec![VoxelBox {
                min: [3, 2, 5],
                max: [3, 2, 5],
            }],
        };
        // Depth 3: voxel 3 in x is [-0.25, 0], centre -0.125; y 2 centre -0.375.
        let r = referee(
            &s,
            3,
            [-0.125, -0.375, 2.0],
            [0.0, 0.0, -1.0],
            0.0,
            f64::INFINITY,
            0.0,
        );
        assert!(r.hit && !r.tie);
        assert_eq!(r.voxel, [3, 2, 5]);
        // z face of voxel 5 at -1 + 6/4 = 0.5, so t = 1.5.
        assert_eq!(r.t, 1.5);
        assert_eq!(r.normal, [0, 0, 1]);
    }

    #[test]
    fn rays_along_edges_and_through_corners_are_flagged_ties() {
        let s = Shape::Boxes {
            boxes: vec![VoxelBox {
                min: [3, 2, 5],
                max: [3, 2, 5],
            }],
        };
        // Along the edge x = 0 (between voxels 3 and 4) at y centre of 2.
        let r = referee(
            &s,
            3,
            [0.0, -0.375, 2.0],
            [0.0, 0.0, -1.0],
            0.0,
            f64::INFINITY,
            0.0,
        );
        assert!(r.tie, "{r:?}");
        // A diagonal through the voxel's max corner (0, -0.25, 0.5) that
        // touches it at that point only: o = corner - 1.5 s, d = u s.
        let u = 1.0 / 3f64.sqrt();
        let sg = [1.0, -1.0, 1.0];
        let d = sg.map(|x| x * u);
        let corner = [0.0, -0.25, 0.5];
        let o = [0, 1, 2].map(|a| corner[a] - 1.5 * sg[a]);
        let r = referee(&s, 3, o, d, 0.0, f64::INFINITY, 0.0);
        assert!(r.tie, "{r:?}");
        // The same line shifted off the corner is no tie and misses cleanly.
        let r = referee(&s, 3, [o[0] + 0.01, o[1], o[2]], d, 0.0, f64::INFINITY, 0.0);
        assert!(!r.tie && !r.hit, "{r:?}");
    }

    #[test]
    fn start_inside_solid_hits_at_near_with_no_normal() {
        let s = Shape::Sphere { radius: 0.8 };
        let r = referee(
            &s,
            6,
            [0.01, 0.02, 0.03],
            [0.6, 0.0, 0.8],
            0.0,
            f64::INFINITY,
            0.0,
        );
        assert!(r.hit && !r.tie);
        assert_eq!((r.t, r.normal, r.voxel), (0.0, [0, 0, 0], [32, 32, 32]));
    }

    #[test]
    fn near_ties_flag_rays_that_pass_close_to_solid_edges() {
        let s = Shape::Boxes {
            boxes: vec![VoxelBox {
                min: [3, 2, 5],
                max: [3, 2, 5],
            }],
        };
        let r = referee(
            &s,
            3,
            [0.0 + 1e-9, -0.375, 2.0],
            [0.0, 0.0, -1.0],
            0.0,
            f64::INFINITY,
            1e-6,
        );
        assert!(!r.tie && r.near_tie && !r.hit, "{r:?}");
        let r = referee(
            &s,
            3,
            [0.0 + 1e-3, -0.375, 2.0],
            [0.0, 0.0, -1.0],
            0.0,
            f64::INFINITY,
            1e-6,
        );
        assert!(!r.near_tie, "{r:?}");
    }
}
