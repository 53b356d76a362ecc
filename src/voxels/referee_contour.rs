//! The contour slab's part of the parity referee: whether a ray meets a
//! voxel's contour slab (`contour::slab_interval`) within rounding of the
//! slab test flipping. The cube referee (`referee::referee`) judges voxel
//! boundaries only; a contour cast also skips a solid leaf whose slab the
//! ray misses inside the voxel, and where the slab interval and the voxel's
//! interval just touch, an f32 cast with fused multiply-adds (the H100) and
//! one without (the CPU, lavapipe) can decide that test differently.
//! f64, written from the box and slab intervals; it never calls the cast.
//! The same box intervals give the other parity ties that need a box
//! rather than the cube referee's finest voxel: a voxel's entry time
//! ([`voxel_entry`]), an LOD cut's box entered through an edge
//! ([`box_face_tie`]) and t at a slab entry ([`slab_entry_t_tie`]).

use super::contour::slab_interval;

/// The t interval of `o + t d` in the box `[lo, lo + s]^3`, with the axis
/// whose plane sets each end: `((t_enter, axis), (t_exit, axis))`.
fn box_interval(lo: [f64; 3], s: f64, o: [f64; 3], d: [f64; 3]) -> ((f64, usize), (f64, usize)) {
    let mut enter = (f64::NEG_INFINITY, 0);
    let mut exit = (f64::INFINITY, 0);
    for a in 0..3 {
        if d[a] == 0.0 {
            if o[a] < lo[a] || o[a] > lo[a] + s {
                return ((f64::INFINITY, a), (f64::NEG_INFINITY, a));
            }
            continue;
        }
        let (t0, t1) = ((lo[a] - o[a]) / d[a], (lo[a] + s - o[a]) / d[a]);
        let (t0, t1) = (t0.min(t1), t0.max(t1));
        if t0 > enter.0 {
            enter = (t0, a);
        }
        if t1 < exit.0 {
            exit = (t1, a);
        }
    }
    (enter, exit)
}

/// The depth-`depth` voxel `voxel`'s edge, low corner and centre.
fn voxel_box(depth: u32, voxel: [u32; 3]) -> (f64, [f64; 3], [f64; 3]) {
    let s = 2.0 / (1u64 << depth) as f64;
    let lo = voxel.map(|i| -1.0 + i as f64 * s);
    (s, lo, lo.map(|x| x + 0.5 * s))
}

/// The t at which `o + t d` enters the depth-`depth` voxel `voxel`'s box.
pub fn voxel_entry(depth: u32, voxel: [u32; 3], o: [f64; 3], d: [f64; 3]) -> f64 {
    let (s, lo, _) = voxel_box(depth, voxel);
    box_interval(lo, s, o, d).0 .0
}

/// Whether the ray `o + t d` over `[near, far]` meets contour `v`'s slab in
/// the depth-`depth` voxel `voxel` within rounding of that test flipping:
/// the slab interval met with the voxel's interval is empty or not by no
/// more than the rounding of its two ends. An end set by a slab plane
/// carries `slack / |n . d|` (the plane's offset `n . (o - c) - p s`
/// rounded by about `slack` world units, divided by the ray's rate across
/// it); an end set by a face of axis `a` carries `slack / |d_a|`; `near`
/// and `far` are exact. `false` for `v == 0` (no contour: a cube, the cube
/// referee's case).
pub fn slab_tie(
    v: u32,
    depth: u32,
    voxel: [u32; 3],
    o: [f64; 3],
    d: [f64; 3],
    (near, far): (f64, f64),
    slack: f64,
) -> bool {
    if v == 0 {
        return false;
    }
    let (s, lo, c) = voxel_box(depth, voxel);
    let ((te, ae), (tx, ax)) = box_interval(lo, s, o, d);
    let (ta, tb) = slab_interval(v, c, s, o, d);
    // A ray that misses the box (a corner or edge within rounding is the
    // cube referee's tie) or the slab's whole plane pair is no slab tie.
    if te > tx || ta > tb {
        return false;
    }
    let (n, _, _) = super::contour::decode::<f64>(v);
    let nd = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]).abs();
    let plane = if nd > 0.0 { slack / nd } else { 0.0 };
    let face = |a: usize| slack / d[a].abs();
    let (lower, lower_err) = if ta >= te && ta >= near {
        (ta, plane)
    } else if te >= near {
        (te, face(ae))
    } else {
        (near, 0.0)
    };
    let (upper, upper_err) = if tb <= tx && tb <= far {
        (tb, plane)
    } else if tx <= far {
        (tx, face(ax))
    } else {
        (far, 0.0)
    };
    (lower - upper).abs() <= lower_err + upper_err
}

/// The axis of an entry face's normal `n` (a unit axis vector pointing
/// back along `d`), `None` for any other vector.
fn entry_axis(n: [f32; 3], d: [f64; 3]) -> Option<usize> {
    let a = n.iter().position(|&x| x != 0.0)?;
    let axis_only = (0..3).all(|b| b == a || n[b] == 0.0);
    (axis_only && d[a] != 0.0 && n[a] as f64 == -d[a].signum()).then_some(a)
}

/// Whether `o + t d` enters the box of the level-`level` voxel that holds
/// the depth-`depth` voxel `voxel` through an edge or corner within
/// rounding, between the two faces `normals` name: two different entry
/// faces (each normal a unit axis vector against `d`) whose entry times are
/// within `slack / |d_a|` of the box's entry time. The cube referee judges
/// the finest solid voxel on the ray; an LOD cut stops at a coarser box,
/// whose edges that voxel need not share (an H200 cut at a level-6 box
/// entered 3.2e-7 apart in t through its y and z faces, where the
/// referee's voxel lay beyond the box, no tie).
pub fn box_face_tie(
    (depth, level): (u32, u32),
    voxel: [u32; 3],
    o: [f64; 3],
    d: [f64; 3],
    normals: [[f32; 3]; 2],
    slack: f64,
) -> bool {
    let (Some(a), Some(b)) = (entry_axis(normals[0], d), entry_axis(normals[1], d)) else {
        return false;
    };
    if a == b {
        return false;
    }
    let level = level.min(depth);
    let s = 2.0 / (1u64 << level) as f64;
    let lo = voxel.map(|i| -1.0 + (i >> (depth - level)) as f64 * s);
    let ((te, _), _) = box_interval(lo, s, o, d);
    // Both axes are entry faces, so d is not 0 along either.
    [a, b].iter().all(|&k| {
        let x = if d[k] > 0.0 { lo[k] } else { lo[k] + s };
        te - (x - o[k]) / d[k] <= slack / d[k].abs()
    })
}

/// The least `|n . d|` [`slab_entry_t_tie`] divides by: below it a slab
/// entry's rounding is not excused further (the H200's grazing slab entries
/// went down to 0.012).
pub const MIN_SLAB_RATE: f64 = 0.01;

/// Whether two contour casts' t in the depth-`depth` voxel `voxel` are
/// both contour `v`'s slab entry within its rounding: the exact (f64) slab
/// entry `ta` is no earlier than the box's (within that rounding), so t is
/// the slab's, and each t is within `slack / |n . d|` of `ta`, the slab
/// plane's offset `n . (o - c) - p s` rounded by about `slack` world units
/// (it cancels terms of size |o| to leave a few hundredths) over the ray's
/// rate across the plane, that rate taken as at least [`MIN_SLAB_RATE`]. On
/// grazing slabs this is far over `voxel_t_f32`: an H200 against the CPU,
/// |n . d| 0.012 to 0.07, t 1.3e-6 to 2.4e-6 apart relative. `false` for
/// `v == 0` (no contour) and a ray parallel to the plane.
pub fn slab_entry_t_tie(
    v: u32,
    depth: u32,
    voxel: [u32; 3],
    (o, d): ([f64; 3], [f64; 3]),
    slack: f64,
    ts: [f64; 2],
) -> bool {
    if v == 0 {
        return false;
    }
    let (s, lo, c) = voxel_box(depth, voxel);
    let ((te, _), _) = box_interval(lo, s, o, d);
    let (ta, _) = slab_interval(v, c, s, o, d);
    let (n, _, _) = super::contour::decode::<f64>(v);
    let nd = (n[0] * d[0] + n[1] * d[1] + n[2] * d[2]).abs();
    let tol = slack / nd.max(MIN_SLAB_RATE);
    nd > 0.0 && ta + tol >= te && ts.iter().all(|t| (t - ta).abs() <= tol)
}

#[cfg(test)]
/// A ray that leaves voxel `[3, 3, 3]` (depth 3, edge 0.25) through its
/// +x face just where it enters the slab of a contour tilted in x and
/// y: the slab test sits exactly on its edge; moved along the slab's
/// normal by `shift` world units, the ray enters the slab inside the
/// voxel or after it.
pub(crate) fn grazing(shift: f64) -> (u32, [f64; 3], [f64; 3]) {
    let v = super::contour::encode([0.6, 0.8, 0.0], 0.1, 0.05);
    let (n, p, h) = super::contour::decode::<f64>(v);
    let s = 0.25;
    let c = [-0.125; 3];
    // On the +x face, on the slab's lower plane n . (x - c) = (p - h) s.
    let x = c[0] + 0.5 * s;
    let y = c[1] + ((p - h) * s - n[0] * 0.5 * s) / n[1];
    let hit = [x, y, c[2]];
    assert!((y - c[1]).abs() < 0.5 * s, "the point is on the face");
    // Rising across the lower plane (n . d > 0) while leaving through +x.
    let d = [0.8, 0.6, 0.0];
    let o = [0, 1, 2].map(|a| hit[a] - 2.0 * d[a] + shift * n[a]);
    (v, o, d)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_ray_touching_the_slab_as_it_leaves_the_voxel_is_a_tie() {
        let slack = 2f64.powi(-22);
        let cube = (0.0, f64::INFINITY);
        let (v, o, d) = grazing(0.0);
        assert!(slab_tie(v, 3, [3, 3, 3], o, d, cube, slack));
        // A thousandth of a voxel either way is no tie: inside the slab
        // before the face, or past the voxel before the slab.
        for shift in [2.5e-4, -2.5e-4] {
            let (v, o, d) = grazing(shift);
            assert!(!slab_tie(v, 3, [3, 3, 3], o, d, cube, slack), "{shift}");
        }
        // Within the rounding it is: a shift of a tenth of the slack.
        let (v, o, d) = grazing(0.1 * slack);
        assert!(slab_tie(v, 3, [3, 3, 3], o, d, cube, slack));
        assert!(!slab_tie(0, 3, [3, 3, 3], o, d, cube, slack), "no contour");
        // Parallel to the x faces and outside them: the voxel is missed.
        let (o, d) = ([0.5, -0.2, -0.1], [0.0, 1.0, 0.0]);
        assert!(!slab_tie(v, 3, [3, 3, 3], o, d, cube, slack), "box missed");
    }

    #[test]
    fn an_lod_box_entered_at_its_edge_is_a_normal_tie_at_its_level_only() {
        // Through (-1, -1, -0.9) at t = 2, slope sqrt 2 in x-y: the level-1
        // box [-1, 0]^3 is entered on its edge x = y = -1; its depth-3 voxel
        // [1, 1, 0] ([-0.75, -0.5]^2 in x-y) through the x face alone, the y
        // face 0.13 earlier in t.
        let (a, b) = (1.0 / 3f64.sqrt(), (2.0 / 3.0f64).sqrt());
        let d = [a, b, 0.0];
        let o = [-1.0 - 2.0 * a, -1.0 - 2.0 * b, -0.9];
        let slack = 2f64.powi(-22);
        let (x, y, z) = ([-1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]);
        assert!(box_face_tie((3, 1), [1, 1, 0], o, d, [x, y], slack));
        assert!(!box_face_tie((3, 3), [1, 1, 0], o, d, [x, y], slack));
        assert!(
            !box_face_tie((3, 1), [1, 1, 0], o, d, [x, z], slack),
            "z face"
        );
        // One face named twice, or a face the ray leaves by: no edge tie.
        assert!(
            !box_face_tie((3, 1), [1, 1, 0], o, d, [x, x], slack),
            "one face"
        );
        let flipped = [1.0, 0.0, 0.0];
        assert!(
            !box_face_tie((3, 1), [1, 1, 0], o, d, [flipped, y], slack),
            "exit face"
        );
    }

    #[test]
    fn slab_entry_times_differ_within_the_plane_rounding_only() {
        // `grazing` enters the slab of voxel [3, 3, 3] as it leaves the box,
        // past the box entry; |n . d| = 0.96, so the bound is 2.5e-7.
        let slack = 2f64.powi(-22);
        let (v, o, d) = grazing(0.0);
        let entry = |v, o, d| {
            let (s, _, c) = voxel_box(3, [3, 3, 3]);
            slab_interval(v, c, s, o, d).0
        };
        let ta = entry(v, o, d);
        let tie = |v, (o, d), ts| slab_entry_t_tie(v, 3, [3, 3, 3], (o, d), slack, ts);
        assert!(tie(v, (o, d), [ta + 1e-7, ta - 1e-7]));
        assert!(!tie(v, (o, d), [ta + 1e-6, ta]));
        assert!(!tie(0, (o, d), [ta, ta]), "no contour");
        // Nearly parallel to a z slab (|n . d| 1e-7): its lower plane
        // z = c + (p - h) s (about -0.2375) met 0.1 after the box's -x face
        // at t = 0.75. Both casts at the slab entry tie; one at the box's
        // face does not, however grazing the slab ([`MIN_SLAB_RATE`]).
        let z = crate::voxels::contour::encode([0.0, 0.0, 1.0], 0.0, 0.45);
        let (_, p, h) = crate::voxels::contour::decode::<f64>(z);
        let lower = -0.125 + (p - h) * 0.25;
        let (o, d) = ([-1.0, -0.125, lower - 1e-7 * 0.85], [1.0, 0.0, 1e-7]);
        let ta = entry(z, o, d);
        assert!((ta - 0.85).abs() < 1e-6, "{ta}");
        assert!(tie(z, (o, d), [ta, ta]));
        assert!(!tie(z, (o, d), [0.75, ta]), "box face");
        // The same slab, 0.45 edges either side of the centre: a ray
        // entering the box's -x face 0.15 edges above the centre is in the
        // slab already, its t the face's: no slab entry.
        let (o, d) = ([-1.0, -0.125, -0.125], [1.0, 0.0, 0.05]);
        let te = (-0.25 - o[0]) / d[0];
        assert!(!tie(z, (o, d), [te, te]), "face");
    }
}
