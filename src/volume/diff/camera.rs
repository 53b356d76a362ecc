//! Camera derivatives for `f_diff`: the active clip planes and the pose.

use crate::camera::Camera;
use crate::real::Real;

/// axes whose slab plane attains it. A ray through an edge or corner has
/// several (a kink of t0 or t1): its derivative is then the mean of the
/// one-sided ones, which is what a central difference converges to. No
/// axis where `near` / `far` holds. Same operations as `rays::clip_aabb`.
#[allow(clippy::type_complexity)]
#[inline]
pub fn clip_planes<F: Real>(
    o: [F; 3],
    d: [F; 3],
    bmin: [F; 3],
    bmax: [F; 3],
    near: F,
    far: F,
) -> ((F, [bool; 3]), (F, [bool; 3])) {
    let (mut lo, mut hi) = (near, far);
    let mut ends = [(F::zero(), F::zero()); 3];
    for a in 0..3 {
        if d[a] == F::zero() {
            continue;
        }
        let inv = F::one() / d[a];
        let ta = (bmin[a] - o[a]) * inv;
        let tb = (bmax[a] - o[a]) * inv;
        ends[a] = (ta.min(tb), ta.max(tb));
        lo = lo.max(ends[a].0);
        hi = hi.min(ends[a].1);
    }
    let mut m0 = [false; 3];
    let mut m1 = [false; 3];
    for a in 0..3 {
        if d[a] != F::zero() {
            m0[a] = lo != near && ends[a].0 == lo;
            m1[a] = hi != far && ends[a].1 == hi;
        }
    }
    ((lo, m0), (hi, m1))
}

pub(super) fn cross<F: Real>(a: [F; 3], b: [F; 3]) -> [F; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

/// The pose in precision `F`: rotation rows and centre of C2W.
#[derive(Clone, Copy, Debug)]
pub(super) struct Pose<F> {
    r: [[F; 3]; 3],
    pub(super) c: [F; 3],
}

impl<F: Real> Pose<F> {
    pub(super) fn of(cam: &Camera) -> Pose<F> {
        let m = cam.c2w();
        Pose {
            r: [0, 1, 2].map(|i| [0, 1, 2].map(|j| F::of(m[i][j]))),
            c: [0, 1, 2].map(|i| F::of(m[i][3])),
        }
    }

    /// `R^T v`.
    pub(super) fn rt(&self, v: [F; 3]) -> [F; 3] {
        [0, 1, 2].map(|j| self.r[0][j] * v[0] + self.r[1][j] * v[1] + self.r[2][j] * v[2])
    }
}
