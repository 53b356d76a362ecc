//! The beam pre-pass (Laine & Karras 2010, "beam optimization"), made
//! conservative: each tile of [`TILE`] x [`TILE`] pixels of a camera image
//! (rays shaped (H, W); runs of `TILE^2` consecutive rays otherwise,
//! [`Tiling`]) whose rays share one origin is bounded by a cone about the
//! sum of its first and last directions that holds every one of them
//! ([`ConeAcc`]); a walk of the tree finds the smallest
//! distance from the origin to a non-empty node box that meets the cone
//! ([`start_distance`]). A tile whose cone meets no non-empty box is
//! answered as misses without a cast; every other ray's cast starts at the
//! tile's distance ([`tile_near`]) instead of at `near`, in the lane cast
//! (f32) or the per-ray loop ([`cast_all_beam`]).
//!
//! Why the start never passes a hit: a ray's hit point lies in a solid
//! leaf, so inside a non-empty node at every level above it, and inside the
//! cone (the ray is in it); so some box the walk accepts contains it, and
//! its distance from the origin, `t |d|`, is at least that box's distance.
//! The walk prunes only boxes that are empty, miss the cone (bounding-sphere
//! test, the sphere grown by twice the distance the cast's rounding can move
//! a ray, [`Cone::slack`], so a voxel the f32 cast finds on a ray is in a
//! grown box the cone meets) or lie farther than the best box found; so a
//! tile it finds nothing for holds no ray the cast could find a hit on. The
//! start is pulled back by [`MARGIN`] (relative) and by the tile's bound on
//! the rounding of the cast's plane times ([`Cone::time_error`], from
//! [`plane_time_error`]), so the cast begins strictly in the empty space
//! before its first solid voxel even as its own f32 arithmetic sees it,
//! and it then makes the same decisions as the cast from `near` from that
//! voxel on: same `hit`, `t`, `leaf`, `normal` (bit for bit; fewer
//! iterations). Tiles with differing origins, wider cones than
//! [`MAX_HALF_ANGLE`], or an LOD cut (whose stop voxel need not hold solid
//! at the ray) are cast from `near` unchanged.
//! Referee: the per-ray cast (`voxel_beam_*` cases, unit tests below).

use std::ops::Range;

use super::cast::{cast_with, Addressing, CastParams, CastReal};
use super::hits::{cast_chunks, GRAIN};
use super::render::VoxelHits;
use super::set_bits::set_bits;
use super::tiles::Tiling;

/// Pixels per side of a beam tile.
pub const TILE: usize = 8;

/// Relative pull-back of each start distance.
pub const MARGIN: f64 = 1e-5;

/// Cones wider than this (radians) are not walked: the bound would be poor.
pub const MAX_HALF_ANGLE: f64 = 0.5;

/// `cos(MAX_HALF_ANGLE)`: a cone is walked when its half-angle's cosine is
/// at least this (kernels/voxel_beam.wgsl holds the same constant).
pub const COS_MAX_HALF_ANGLE: f64 = 0.8775825618903728;

/// Radians each cone's half-angle is widened by, for the rounding of its
/// cosine (kernels/voxel_beam.wgsl holds the same constant).
pub const WIDEN: f64 = 1e-9;

/// A cone from `o` about the unit `axis` with half-angle `half`; boxes are
/// grown by `slack` (world units) when tested against it. `time_error`
/// bounds the cast's plane-time rounding ([`plane_time_error`]) on every
/// ray it was built from, and `len_max` their largest `|d|`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cone {
    pub o: [f64; 3],
    pub axis: [f64; 3],
    pub half: f64,
    pub slack: f64,
    pub time_error: f64,
    pub len_max: f64,
    cos2_half: f64,
    sin_half: f64,
    tan_half: f64,
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn unit(v: [f64; 3]) -> Option<[f64; 3]> {
    let l = dot(v, v).sqrt();
    (l > 0.0 && l.is_finite()).then(|| v.map(|x| x / l))
}

/// `a` where it is less than `b`, else `b`.
#[inline(always)]
fn less(a: f64, b: f64) -> f64 {
    if a < b {
        a
    } else {
        b
    }
}

/// A [`Cone`] being built from rays one at a time about a given axis.
#[derive(Clone, Copy, Debug)]
pub struct ConeAcc<F> {
    o: [F; 3],
    axis: [f64; 3],
    /// The smallest cos^2 of a ray's angle to the axis.
    cos2_min: f64,
    /// Each axis's smallest `|d_a|`, and the largest `|d|^2`.
    dmin: [f64; 3],
    len2_max: f64,
    ok: bool,
}

impl<F: CastReal> ConeAcc<F> {
    /// An empty cone from `o` about `axis` (need not be unit; `None` when
    /// zero).
    pub fn new(o: [F; 3], axis: [f64; 3]) -> Option<Self> {
        Some(ConeAcc {
            o,
            axis: unit(axis)?,
            cos2_min: 1.0,
            dmin: [f64::INFINITY; 3],
            len2_max: 0.0,
            ok: true,
        })
    }

    /// Takes ray `(o, d)` in; a differing origin, a zero, NaN or infinite
    /// direction, or one 90 degrees or more off the axis spoils the cone.
    #[inline]
    pub fn add(&mut self, o: [F; 3], d: [F; 3]) {
        let d = d.map(|x| x.f64());
        let (c, l2) = (dot(d, self.axis), dot(d, d));
        // Without short circuits or NaN-aware min and max (a NaN or
        // infinite direction spoils `ok`): selects the compiler keeps
        // branch-free.
        self.ok &= (o == self.o) & (c > 0.0) & (l2 > 0.0) & (l2 < f64::INFINITY);
        self.cos2_min = less(c * c / l2, self.cos2_min);
        self.dmin = [0, 1, 2].map(|a| less(d[a].abs(), self.dmin[a]));
        self.len2_max = -less(-l2, -self.len2_max);
    }

    /// The cone holding every ray taken in, its `slack` twice the largest
    /// distance the cast's rounding can put one from where it is
    /// (`time_error` times `|d|`, bounded with each axis's smallest `|d_a|`);
    /// `None` when spoilt, empty, or wider than [`MAX_HALF_ANGLE`].
    pub fn finish(&self) -> Option<Cone> {
        if !self.ok || self.len2_max == 0.0 {
            return None;
        }
        // The half-angle widened by `WIDEN` radians, as cosine and sine
        // (no trigonometric function: the GPU twin has none in f64):
        // cos(h + w) = c cos w - s sin w, sin(h + w) = s cos w + c sin w,
        // with cos w = 1 and sin w = w in f64 at w = 1e-9.
        let c2 = self.cos2_min.clamp(0.0, 1.0);
        let (c, s) = (c2.sqrt(), (1.0 - c2).sqrt());
        let (cos_half, sin_half) = (c - s * WIDEN, s + c * WIDEN);
        let time_error = plane_time_error(self.o, self.dmin.map(F::of));
        let len_max = self.len2_max.sqrt();
        (cos_half >= COS_MAX_HALF_ANGLE).then(|| Cone {
            o: self.o.map(|x| x.f64()),
            axis: self.axis,
            half: sin_half.atan2(cos_half),
            slack: 2.0 * time_error * len_max,
            time_error,
            len_max,
            cos2_half: cos_half * cos_half,
            sin_half,
            tan_half: sin_half / cos_half,
        })
    }
}

impl Cone {
    /// Whether the ball of radius `r + slack` about `o + v` may meet the
    /// cone. Seen from `o` (at distance `l`) the ball covers the
    /// directions within `asin(r / l)` of `v`, and two such caps meet when
    /// the angle between their centres is at most the sum of their
    /// half-angles; as cosines, times `l`: `v . axis + sin(half) r >=
    /// cos(half) sqrt(l^2 - r^2)`, squared so that neither a square root
    /// nor a division is taken (the right side is positive past the early
    /// return, so the left side must not be negative: the `lhs >= 0` guard
    /// makes the squared form equivalent). The `1e-9 (1 + l^2)` term stands
    /// for a rounding slack of `1e-9 l`, except where `l` is within a few
    /// ulps of `r` (`l^2 - r^2` cancels): the origin on the ball's surface,
    /// where the ball spans a half-space of directions and a ray through
    /// the box passes far from the test's boundary.
    #[inline]
    pub fn meets_sphere(&self, v: [f64; 3], r: f64) -> bool {
        let r = r + self.slack;
        let l2 = dot(v, v);
        if l2 <= r * r {
            return true;
        }
        let lhs = dot(v, self.axis) + self.sin_half * r + 1e-9 * (1.0 + l2);
        lhs >= 0.0 && lhs * lhs >= self.cos2_half * (l2 - r * r)
    }
}

/// The squared Euclidean distance from `o` to the box `[lo, hi]` (0 inside).
#[inline]
fn box_distance2(o: [f64; 3], lo: [f64; 3], hi: [f64; 3]) -> f64 {
    let g = [0, 1, 2].map(|a| (lo[a] - o[a]).max(o[a] - hi[a]).max(0.0));
    dot(g, g)
}

/// A walk's stack entry: squared distance, slot, level, world low corner.
type Entry = (f64, usize, u32, [f64; 3]);

/// A node met by the walk: its descriptor's masks, its children's size
/// and bounding radius, and whether they end the walk (no non-leaf child,
/// or the finest level).
struct WalkNode {
    desc: u32,
    nonleaf: u32,
    valid: u32,
    size: f64,
    radius: f64,
    last: bool,
}

impl WalkNode {
    #[inline(always)]
    fn read(nodes: &[u32], slot: usize, level: u32, depth: u32) -> WalkNode {
        let desc = nodes[2 * slot];
        let nonleaf = desc & 0xFF;
        let size = 2.0 / (1u64 << (level + 1)) as f64;
        WalkNode {
            desc,
            nonleaf,
            valid: desc >> 8 & 0xFF,
            size,
            radius: 0.5 * 3f64.sqrt() * size,
            last: nonleaf == 0 || level + 1 >= depth,
        }
    }
}

/// Pushes `e` among the entries above `base`, nearest on top.
#[inline(always)]
fn push_nearest_last(stack: &mut Vec<Entry>, base: usize, e: Entry) {
    stack.push(e);
    let mut i = stack.len() - 1;
    while i > base && stack[i - 1].0 < e.0 {
        stack.swap(i - 1, i);
        i -= 1;
    }
}

/// The smallest distance from the cone's origin to a non-empty box of the
/// tree `nodes` (addressing `A`, depth `depth`) that meets the cone, walked
/// down to boxes no wider than the cone there (or solid leaves), nearest
/// child first, pruning boxes no nearer than the best so far. `f64::INFINITY`
/// when no non-empty box meets the cone. Distances are compared squared;
/// box corners are exact (dyadic) in f64.
///
/// On a CPU with AVX-512F each node's eight children are tested at once
/// ([`start_distance_avx512`], the same distance); single-thread harness,
/// Zen 5, 512^2 camera rays, the pre-pass (cones, walks, starts) 13.4-13.9
/// -> 11.0-11.2 ns a ray on sphere d10, 11.5-12.1 -> 9.7 on Menger d10
/// (docs/PERF.md, eighteenth session).
pub fn start_distance<A: Addressing>(nodes: &[u32], depth: u32, cone: &Cone) -> f64 {
    // Defensive: with a finite origin no NaN reaches the vector `max`,
    // whose NaN rule differs from the scalar one.
    #[cfg(target_arch = "x86_64")]
    if std::arch::is_x86_feature_detected!("avx512f") && cone.o.iter().all(|x| x.is_finite()) {
        // SAFETY: the CPU has AVX-512F.
        return unsafe { start_distance_avx512::<A>(nodes, depth, cone) };
    }
    start_distance_scalar::<A>(nodes, depth, cone)
}

/// [`start_distance`], one child at a time.
fn start_distance_scalar<A: Addressing>(nodes: &[u32], depth: u32, cone: &Cone) -> f64 {
    let tan2 = cone.tan_half * cone.tan_half;
    let mut best = f64::INFINITY;
    let mut stack: Vec<Entry> = Vec::with_capacity(8 * depth as usize + 1);
    stack.push((0.0, 0, 0, [-1.0; 3]));
    while let Some((dist2, slot, level, lo)) = stack.pop() {
        if dist2 >= best {
            continue;
        }
        let n = WalkNode::read(nodes, slot, level, depth);
        let base = stack.len();
        for c in set_bits(n.valid) {
            let c = c as u32;
            let wlo = [0, 1, 2].map(|a| lo[a] + (c >> a & 1) as f64 * n.size);
            let whi = wlo.map(|x| x + n.size);
            let d2 = box_distance2(cone.o, wlo, whi);
            if d2 >= best {
                continue;
            }
            let v = [0, 1, 2].map(|a| wlo[a] + 0.5 * n.size - cone.o[a]);
            if !cone.meets_sphere(v, n.radius) {
                continue;
            }
            let fine = n.size * n.size <= 4.0 * d2 * tan2;
            if n.last || n.nonleaf >> c & 1 == 0 || fine {
                best = d2;
            } else {
                // Into this node's children on the stack, nearest on top.
                let child = A::child(nodes, slot, n.desc, n.desc << (7 - c), c);
                push_nearest_last(&mut stack, base, (d2, child, level + 1, wlo));
            }
        }
    }
    best.sqrt()
}

/// [`start_distance`] with each node's eight children tested at once in
/// AVX-512 f64 lanes (lane `c` is child `c`): the scalar walk's operations
/// on the same operands, so the same boxes pass; the children that end the
/// walk lower `best` before the others are pushed (a child box is never
/// nearer than its parent, so the minimum is the same; fewer boxes are
/// walked).
///
/// # Safety
/// The CPU must have AVX-512F.
#[cfg(target_arch = "x86_64")]
#[target_feature(enable = "avx512f")]
unsafe fn start_distance_avx512<A: Addressing>(nodes: &[u32], depth: u32, cone: &Cone) -> f64 {
    use std::arch::x86_64::*;
    let tan2 = cone.tan_half * cone.tan_half;
    let mut best = f64::INFINITY;
    let mut stack: Vec<Entry> = Vec::with_capacity(8 * depth as usize + 1);
    stack.push((0.0, 0, 0, [-1.0; 3]));
    let zero = _mm512_setzero_pd();
    let o = cone.o.map(|x| _mm512_set1_pd(x));
    let axis = cone.axis.map(|x| _mm512_set1_pd(x));
    // Lanes whose child has bit `a` set: +x, +y, +z halves.
    let bit: [__mmask8; 3] = [0xAA, 0xCC, 0xF0];
    while let Some((dist2, slot, level, lo)) = stack.pop() {
        if dist2 >= best {
            continue;
        }
        let n = WalkNode::read(nodes, slot, level, depth);
        let (sz, half_sz) = (_mm512_set1_pd(n.size), _mm512_set1_pd(0.5 * n.size));
        let (mut g2, mut l2, mut vax) = (zero, zero, zero);
        for a in 0..3 {
            // `lo + (c >> a & 1) * size`: `lo + size` on the lanes with bit
            // `a`, `lo` (`lo + 0`) on the others.
            let l = _mm512_set1_pd(lo[a]);
            let wlo = _mm512_mask_add_pd(l, bit[a], l, sz);
            let whi = _mm512_add_pd(wlo, sz);
            let g = _mm512_max_pd(
                _mm512_max_pd(_mm512_sub_pd(wlo, o[a]), _mm512_sub_pd(o[a], whi)),
                zero,
            );
            let v = _mm512_sub_pd(_mm512_add_pd(wlo, half_sz), o[a]);
            if a == 0 {
                g2 = _mm512_mul_pd(g, g);
                l2 = _mm512_mul_pd(v, v);
                vax = _mm512_mul_pd(v, axis[a]);
            } else {
                g2 = _mm512_add_pd(g2, _mm512_mul_pd(g, g));
                l2 = _mm512_add_pd(l2, _mm512_mul_pd(v, v));
                vax = _mm512_add_pd(vax, _mm512_mul_pd(v, axis[a]));
            }
        }
        // `Cone::meets_sphere` on every lane.
        let r = n.radius + cone.slack;
        let r2 = _mm512_set1_pd(r * r);
        let inside = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(l2, r2);
        let lhs = _mm512_add_pd(
            _mm512_add_pd(vax, _mm512_set1_pd(cone.sin_half * r)),
            _mm512_mul_pd(_mm512_set1_pd(1e-9), _mm512_add_pd(_mm512_set1_pd(1.0), l2)),
        );
        let rhs = _mm512_mul_pd(_mm512_set1_pd(cone.cos2_half), _mm512_sub_pd(l2, r2));
        let meets = inside
            | (_mm512_cmp_pd_mask::<_CMP_GE_OQ>(lhs, zero)
                & _mm512_cmp_pd_mask::<_CMP_GE_OQ>(_mm512_mul_pd(lhs, lhs), rhs));
        // `!(d2 >= best)`, as the scalar walk skips.
        let near = !_mm512_cmp_pd_mask::<_CMP_GE_OQ>(g2, _mm512_set1_pd(best));
        let acc = n.valid as __mmask8 & near & meets;
        if acc == 0 {
            continue;
        }
        let fine = _mm512_cmp_pd_mask::<_CMP_LE_OQ>(
            _mm512_set1_pd(n.size * n.size),
            _mm512_mul_pd(_mm512_mul_pd(_mm512_set1_pd(4.0), g2), _mm512_set1_pd(tan2)),
        );
        let ends = if n.last {
            acc
        } else {
            acc & (!(n.nonleaf as __mmask8) | fine)
        };
        let mut d2 = [0.0f64; 8];
        _mm512_storeu_pd(d2.as_mut_ptr(), g2);
        for c in set_bits(ends as u32) {
            best = less(d2[c], best);
        }
        let base = stack.len();
        for c in set_bits((acc & !ends) as u32) {
            if d2[c] >= best {
                continue;
            }
            let c = c as u32;
            let wlo = [0, 1, 2].map(|a| lo[a] + (c >> a & 1) as f64 * n.size);
            let child = A::child(nodes, slot, n.desc, n.desc << (7 - c), c);
            push_nearest_last(&mut stack, base, (d2[c as usize], child, level + 1, wlo));
        }
    }
    best.sqrt()
}

/// The `near` of every ray of a tile whose cone is `cone` and whose start
/// distance is `dist`: infinite (misses, answered without a cast) when the
/// cone met no non-empty box; else the distance over the tile's largest
/// `|d|` ([`Cone::len_max`], so no ray of the tile starts past `dist` from
/// the origin), pulled back by [`MARGIN`] and by [`Cone::time_error`] (the
/// tile's bound on the cast's plane-time rounding, so the cast's own
/// rounded plane times cannot put the start past the hit voxel's entry),
/// and never below `p.near`. One value per tile: no square root or
/// division per ray.
pub fn tile_near(p: &CastParams, cone: &Cone, dist: f64) -> f64 {
    if dist == f64::INFINITY {
        return f64::INFINITY;
    }
    let s = dist / cone.len_max * (1.0 - MARGIN) - cone.time_error;
    if s.is_finite() && s > p.near {
        s
    } else {
        p.near
    }
}

/// A bound on the rounding error of the cast's plane times for ray `(o, d)`
/// in precision `F`: each is `x * coef_a - bias_a` with `x` in [1, 2],
/// `coef_a = 1 / |dir_a|` (`dir = d / 2`, clamped to `2^EPS_LOG2` as the cast
/// does) and `|bias_a| <= coef_a (|o_a / 2 + 1.5| + 3)`, three roundings of
/// half an ulp each: at most `2^EPS_LOG2 * 2 coef_a (|o_a / 2 + 1.5| + 5)`,
/// doubled here for margin. A grazing axis (tiny `dir_a`) makes it large and
/// the start falls back to `near`.
pub fn plane_time_error<F: CastReal>(o: [F; 3], d: [F; 3]) -> f64 {
    let eps = F::exp2i(F::EPS_LOG2).f64();
    (0..3)
        .map(|a| {
            let dir = (0.5 * d[a].f64().abs()).max(eps);
            4.0 * eps / dir * ((0.5 * o[a].f64() + 1.5).abs() + 5.0)
        })
        .fold(0.0, f64::max)
}

/// The cones of band `b`'s tiles, each about the sum of its first and last
/// rays' directions, built in one pass over the band in memory order.
fn band_cones<F: CastReal>(
    tiles: &Tiling,
    b: usize,
    o: &[[F; 3]],
    d: &[[F; 3]],
) -> Vec<Option<Cone>> {
    let mut ends = vec![None; tiles.across()];
    tiles.each_part(b, |j, part| {
        let e: &mut Option<(usize, usize)> = &mut ends[j];
        *e = Some((e.map_or(part.start, |e| e.0), part.end - 1));
    });
    let mut acc: Vec<Option<ConeAcc<F>>> = ends
        .iter()
        .map(|e| {
            let (first, last) = (*e)?;
            ConeAcc::new(
                o[first],
                [0, 1, 2].map(|a| d[first][a].f64() + d[last][a].f64()),
            )
        })
        .collect();
    tiles.each_part(b, |j, part| {
        if let Some(c) = acc[j].as_mut().filter(|c| c.ok) {
            let mut local = *c;
            for i in part {
                local.add(o[i], d[i]);
                // Spoilt for good (rays without a shared origin): the
                // rest would cost a division each for nothing.
                if !local.ok {
                    break;
                }
            }
            *c = local;
        }
    });
    acc.iter().map(|c| c.as_ref()?.finish()).collect()
}

/// The `near` of every ray of the bands numbered `bands` from its tile's
/// beam ([`tile_near`]; `p.near` where the tile has no cone), element 0
/// for ray `tiles.band(bands.start).start`; `None` when no tile of these
/// bands has one (rays without a shared origin, or an LOD cut).
/// Sequential: the caller fans bands out.
/// GPU twin: `kernels/voxel_beam.wgsl` `beam_nears` (one invocation a tile,
/// in f64; unit test `gpu_beam_tiles_match_the_cpu_beam`, and every
/// `voxel_gpu_*` camera parity case casts from its starts).
pub fn beam_nears<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    tiles: &Tiling,
    bands: Range<usize>,
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> Option<Vec<f64>> {
    if p.lod.is_some() {
        return None;
    }
    let (first, mut near, mut any) = (tiles.band(bands.start).start, Vec::new(), false);
    for b in bands {
        let starts: Vec<Option<f64>> = band_cones(tiles, b, o, d)
            .iter()
            .map(|c| c.map(|c| tile_near(p, &c, start_distance::<A>(nodes, depth, &c))))
            .collect();
        if starts.iter().all(Option::is_none) {
            if any {
                near.resize(near.len() + tiles.band(b).len(), p.near);
            }
            continue;
        }
        if !any {
            near.resize(tiles.band(b).start - first, p.near);
            any = true;
        }
        tiles.each_part(b, |j, part| {
            near.resize(near.len() + part.len(), starts[j].unwrap_or(p.near))
        });
    }
    any.then_some(near)
}

/// Rays per beam cast task: whole bands, at least [`GRAIN`] where there
/// are that many.
fn task_grain(tiles: &Tiling) -> usize {
    let band = tiles.band(0).len().max(1);
    band * GRAIN.div_ceil(band)
}

/// The numbers of the bands that hold rays `r`, a range that starts on a
/// band's first ray (a task of [`task_grain`] rays).
fn bands_of(tiles: &Tiling, r: &Range<usize>) -> Range<usize> {
    let band = tiles.band(0).len().max(1);
    r.start / band..r.end.div_ceil(band)
}

/// Every ray cast from its tile's beam start ([`beam_nears`]) by the lane
/// cast (f32) or the per-ray loop (other precisions): `hit`, `t`, `leaf`,
/// `normal` identical to the per-ray cast from `near`, fewer `iters`. Each
/// task ([`task_grain`] rays, whole bands) finds its rays' starts and casts
/// them, so they are read once more while still in cache (a band of a
/// camera image is 8 rows: 98 KB of rays at 512 wide).
pub fn cast_all_beam<F: CastReal, A: Addressing>(
    nodes: &[u32],
    depth: u32,
    shape: &[usize],
    o: &[[F; 3]],
    d: &[[F; 3]],
    p: &CastParams,
) -> VoxelHits<F> {
    let tiles = Tiling::new(shape, o.len(), TILE);
    cast_chunks("voxels.cast_beam", o.len(), task_grain(&tiles), |r, out| {
        let near = beam_nears::<F, A>(nodes, depth, &tiles, bands_of(&tiles, &r), o, d, p);
        debug_assert!(near.as_ref().is_none_or(|n| n.len() == r.len()));
        let part = near.as_deref();
        if F::SIMD {
            F::cast_lanes::<A>(nodes, depth, &o[r.clone()], &d[r], p, part, out);
        } else {
            for (k, (i, h)) in r.zip(out).enumerate() {
                *h = cast_with::<F, A>(nodes, depth, o[i], d[i], &p.for_ray(part, k), None);
            }
        }
    })
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::camera::Camera;
    use crate::rays::RayGen;
    use crate::real::Real;
    use crate::rng::rand_f64;
    use crate::voxels::batch::Batch;
    use crate::voxels::cast::{Absolute, Relative};
    use crate::voxels::dag::build_dag;
    use crate::voxels::fixtures::incoherent_in;
    use crate::voxels::octree::build;
    use crate::voxels::render::{cast_all, cast_all_dag};
    use crate::voxels::shape::Shape;

    const SPHERE: Shape = Shape::Sphere { radius: 0.8 };

    /// The cone of `rays` about the sum of their first and last directions,
    /// as `band_cones` builds a tile's.
    fn cone_around<F: CastReal>(
        rays: impl Iterator<Item = ([F; 3], [F; 3])> + Clone,
    ) -> Option<Cone> {
        let (o0, first) = rays.clone().next()?;
        let (_, last) = rays.clone().last()?;
        let mut acc = ConeAcc::new(o0, [0, 1, 2].map(|a| first[a].f64() + last[a].f64()))?;
        rays.for_each(|(o, d)| acc.add(o, d));
        acc.finish()
    }

    /// [`Cone::meets_sphere`] for the bounding sphere of the box `[lo, hi]`.
    fn meets_box(cone: &Cone, lo: [f64; 3], hi: [f64; 3]) -> bool {
        let v = [0, 1, 2].map(|a| 0.5 * (lo[a] + hi[a]) - cone.o[a]);
        let e = [0, 1, 2].map(|a| hi[a] - lo[a]);
        cone.meets_sphere(v, 0.5 * dot(e, e).sqrt())
    }

    fn camera_rays<F: Real>(size: u32) -> Batch<F> {
        image_rays(size, size)
    }

    fn image_rays<F: Real>(w: u32, h: u32) -> Batch<F> {
        let cam = Camera::pinhole_look_at([2.0, 1.5, 2.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, w, h)
            .unwrap();
        let gen = RayGen::new(w, h);
        Batch::camera(&cam, &gen, &MemBudget::fixed(1 << 30)).unwrap()
    }

    fn same_but_iters<F: CastReal>(a: &VoxelHits<F>, b: &VoxelHits<F>) {
        assert_eq!(a.hit, b.hit);
        assert_eq!(a.leaf, b.leaf);
        for i in 0..a.t.len() {
            assert_eq!(a.t[i].bits(), b.t[i].bits(), "ray {i}");
            assert_eq!(a.normal[i].map(|x| x.bits()), b.normal[i].map(|x| x.bits()));
        }
    }

    /// `b`'s directions lengthened by 1, 1.5, .., 3 in turn, so a tile's
    /// rays have differing `|d|`.
    fn unnormalised<F: CastReal>(mut b: Batch<F>) -> Batch<F> {
        for (i, d) in b.d.iter_mut().enumerate() {
            let k = 1.0 + 0.5 * (i % 5) as f64;
            *d = d.map(|x| F::of(x.f64() * k));
        }
        b
    }

    fn bound_holds<F: CastReal>(s: &Shape, depth: u32, b: &Batch<F>) {
        let t = build(s, depth, &MemBudget::fixed(1 << 30)).unwrap();
        let p = b.params(None, 1 << 16);
        let exact = cast_all::<F>(&t, &b.o, &b.d, &p);
        for tile in [2, TILE] {
            let tiles = Tiling::new(&b.shape, b.o.len(), tile);
            let near = beam_nears::<F, Relative>(
                &t.nodes,
                depth,
                &tiles,
                0..tiles.bands(),
                &b.o,
                &b.d,
                &p,
            )
            .expect("camera tiles share an origin");
            let (mut raised, mut hits, mut answered) = (0, 0, 0);
            for (i, &ni) in near.iter().enumerate() {
                raised += (ni > p.near) as u32;
                answered += (ni == f64::INFINITY) as u32;
                if exact.hit[i] == 1 {
                    hits += 1;
                    let th = exact.t[i].f64();
                    assert!(ni < th, "{s:?} tile {tile} ray {i}: {ni} >= {th}");
                }
            }
            assert!(hits > 200 && raised >= hits, "{hits} {raised}");
            assert!(
                answered > 500,
                "{s:?} tile {tile}: {answered} rays answered as misses"
            );
        }
    }

    #[test]
    fn the_beam_start_never_passes_the_exact_casts_hit() {
        for (s, depth) in [
            (Shape::Sphere { radius: 0.8 }, 8),
            (Shape::Menger { level: 4 }, 8),
        ] {
            bound_holds::<f64>(&s, depth, &camera_rays(96));
            bound_holds::<f32>(&s, depth, &camera_rays(96));
            bound_holds::<f32>(&s, depth, &unnormalised(camera_rays(96)));
        }
    }

    #[test]
    #[cfg(target_arch = "x86_64")]
    fn the_vector_walk_finds_the_scalar_walks_distance() {
        if !std::arch::is_x86_feature_detected!("avx512f") {
            eprintln!("no AVX-512F on this CPU: the vector walk is not run, nothing to compare");
            return;
        }
        for (s, depth) in [
            (Shape::Sphere { radius: 0.8 }, 8),
            (Shape::Menger { level: 4 }, 8),
        ] {
            let budget = MemBudget::fixed(1 << 30);
            let t = build(&s, depth, &budget).unwrap();
            let g = build_dag(&t, &budget).unwrap();
            let b = camera_rays::<f32>(96);
            let tiles = Tiling::new(&b.shape, b.o.len(), TILE);
            let mut cones: Vec<Cone> = (0..tiles.bands())
                .flat_map(|band| band_cones(&tiles, band, &b.o, &b.d))
                .flatten()
                .collect();
            // Narrow and wide cones from origins outside and inside the root.
            for k in 0..2000u32 {
                let u = |dim: u32| rand_f64(7, k, 0, dim);
                let o = [0, 1, 2].map(|a| 5.0 * u(a) - 2.5);
                // Toward the root, or anywhere.
                let to_root = k % 2 == 0;
                let axis =
                    [0, 1, 2].map(|a| if to_root { -o[a] } else { 0.0 } + u(3 + a as u32) - 0.5);
                let w = [0.002, 0.05, 0.3][k as usize % 3];
                let d: Vec<[f64; 3]> = (0..4)
                    .map(|r| [0, 1, 2].map(|a| axis[a] + w * (u(6 + 3 * r + a as u32) - 0.5)))
                    .collect();
                cones.extend(cone_around(d.into_iter().map(|d| (o, d))));
            }
            let (mut found, mut missed) = (0, 0);
            for c in &cones {
                let scalar = start_distance_scalar::<Relative>(&t.nodes, depth, c);
                // SAFETY: the CPU has AVX-512F (checked above).
                let vector = unsafe { start_distance_avx512::<Relative>(&t.nodes, depth, c) };
                assert_eq!(scalar.to_bits(), vector.to_bits(), "{s:?} octree {c:?}");
                // The DAG, its own addressing, holds the same boxes.
                // SAFETY: as above.
                let dag = unsafe { start_distance_avx512::<Absolute>(&g.nodes, depth, c) };
                let dag_scalar = start_distance_scalar::<Absolute>(&g.nodes, depth, c);
                assert_eq!(dag_scalar.to_bits(), dag.to_bits(), "{s:?} DAG {c:?}");
                assert_eq!(dag.to_bits(), vector.to_bits(), "{s:?} DAG vs octree {c:?}");
                found += scalar.is_finite() as u32;
                missed += (scalar == f64::INFINITY) as u32;
            }
            assert!(
                found > 200 && missed > 300,
                "{s:?}: {found} found, {missed} missed"
            );
        }
    }

    #[test]
    fn grazing_axes_widen_the_pull_back() {
        let o = [2.0f32, 1.5, 2.5];
        let steep = plane_time_error(o, [-0.6f32, -0.4, -0.7]);
        let grazing = plane_time_error(o, [-0.6f32, 0.0, -0.7]);
        assert!(steep < 1e-4 && grazing > 1.0, "{steep} {grazing}");
        assert!(plane_time_error([2.0f64, 1.5, 2.5], [-0.6f64, -0.4, -0.7]) < 1e-13);
    }

    #[test]
    fn beam_casts_equal_the_per_ray_cast_with_fewer_iterations() {
        let budget = MemBudget::fixed(1 << 30);
        for (s, depth) in [
            (Shape::Sphere { radius: 0.8 }, 9),
            (Shape::Menger { level: 5 }, 8),
        ] {
            let t = build(&s, depth, &budget).unwrap();
            let g = build_dag(&t, &budget).unwrap();
            let b = camera_rays::<f32>(128);
            let p = b.params(None, 1 << 16);
            let per_ray = cast_all::<f32>(&t, &b.o, &b.d, &p);
            let beam = cast_all_beam::<f32, Relative>(&t.nodes, depth, &b.shape, &b.o, &b.d, &p);
            same_but_iters(&beam, &per_ray);
            let u = unnormalised(camera_rays::<f32>(128));
            same_but_iters(
                &cast_all_beam::<f32, Relative>(&t.nodes, depth, &u.shape, &u.o, &u.d, &p),
                &cast_all::<f32>(&t, &u.o, &u.d, &p),
            );
            let it = |h: &VoxelHits<f32>| h.iters.iter().map(|&x| x as i64).sum::<i64>();
            assert!(it(&beam) < it(&per_ray), "{} {}", it(&beam), it(&per_ray));
            let dag = cast_all_beam::<f32, Absolute>(&g.nodes, depth, &b.shape, &b.o, &b.d, &p);
            same_but_iters(&dag, &cast_all_dag::<f32>(&g, &b.o, &b.d, &p));
            let b = camera_rays::<f64>(64);
            let p = b.params(None, 1 << 16);
            let beam = cast_all_beam::<f64, Relative>(&t.nodes, depth, &b.shape, &b.o, &b.d, &p);
            same_but_iters(&beam, &cast_all::<f64>(&t, &b.o, &b.d, &p));
        }
    }

    #[test]
    fn each_tasks_starts_are_its_slice_of_the_whole_sets() {
        // Runs of 64 camera rays (one origin each) with one incoherent run
        // first in the second task: every task's starts, found from its
        // own bands, are the whole set's starts for its rays.
        let t = build(&SPHERE, 8, &MemBudget::fixed(1 << 30)).unwrap();
        let cam = camera_rays::<f32>(96);
        let p = cam.params(None, 1 << 16);
        let (mut o, mut d) = (cam.o.clone(), cam.d.clone());
        let (io, id) = incoherent_in::<f32>(64, 5);
        let grain = GRAIN;
        o[grain..grain + 64].copy_from_slice(&io);
        d[grain..grain + 64].copy_from_slice(&id);
        let shape = [o.len()];
        let tiles = Tiling::new(&shape, o.len(), TILE);
        assert_eq!(task_grain(&tiles), grain);
        let whole =
            beam_nears::<f32, Relative>(&t.nodes, 8, &tiles, 0..tiles.bands(), &o, &d, &p).unwrap();
        assert!(whole[grain..grain + 64].iter().all(|&x| x == p.near));
        for start in (0..o.len()).step_by(grain) {
            let r = start..(start + grain).min(o.len());
            let bands = bands_of(&tiles, &r);
            let part = beam_nears::<f32, Relative>(&t.nodes, 8, &tiles, bands, &o, &d, &p)
                .unwrap_or_else(|| vec![p.near; r.len()]);
            assert_eq!(part, whole[r.clone()], "task at {start}");
        }
        let beam = cast_all_beam::<f32, Relative>(&t.nodes, 8, &shape, &o, &d, &p);
        same_but_iters(&beam, &cast_all::<f32>(&t, &o, &d, &p));
    }

    #[test]
    fn images_of_partial_tiles_and_tasks_are_cast_as_by_the_per_ray_cast() {
        // 61 x 203 pixels: partial tiles on the right and bottom, six
        // tasks, the last short; and images smaller than one band.
        let t = build(&SPHERE, 8, &MemBudget::fixed(1 << 30)).unwrap();
        for (w, h) in [(61, 203), (5, 3), (1, 1)] {
            let b = image_rays::<f32>(w, h);
            let p = b.params(None, 1 << 16);
            let beam = cast_all_beam::<f32, Relative>(&t.nodes, 8, &b.shape, &b.o, &b.d, &p);
            same_but_iters(&beam, &cast_all::<f32>(&t, &b.o, &b.d, &p));
        }
        let none =
            cast_all_beam::<f32, Relative>(&t.nodes, 8, &[0], &[], &[], &CastParams::default());
        assert!(none.hit.is_empty());
    }

    #[test]
    fn an_infinite_direction_spoils_the_cone() {
        let d = [
            [0.1f32, 0.0, 1.0],
            [f32::INFINITY, 0.0, 1.0],
            [0.0, 0.1, 1.0],
        ];
        assert!(cone_around(d.iter().map(|&d| ([0.0f32; 3], d))).is_none());
        let d = d.map(|d| d.map(|x| x as f64));
        assert!(cone_around(d.iter().map(|&d| ([0.0f64; 3], d))).is_none());
        let finite = [[0.1f64, 0.0, 1.0], [0.0, 0.1, 1.0]];
        assert!(cone_around(finite.iter().map(|&d| ([0.0f64; 3], d))).is_some());
    }

    #[test]
    fn runs_without_a_shared_origin_are_cast_from_near() {
        let t = build(&SPHERE, 7, &MemBudget::fixed(1 << 30)).unwrap();
        let (o, d) = incoherent_in::<f32>(512, 3);
        let p = CastParams::default();
        let shape = [o.len()];
        let tiles = Tiling::new(&shape, o.len(), TILE);
        assert!(
            beam_nears::<f32, Relative>(&t.nodes, 7, &tiles, 0..tiles.bands(), &o, &d, &p)
                .is_none()
        );
        let beam = cast_all_beam::<f32, Relative>(&t.nodes, 7, &shape, &o, &d, &p);
        assert_eq!(beam, cast_all::<f32>(&t, &o, &d, &p));
    }

    #[test]
    fn bands_without_a_cone_beside_one_with_a_cone_are_cast_from_near() {
        // Runs of 64 rays: incoherent, 64 camera rays across the sphere
        // (one origin), incoherent; one cast task holds all three bands.
        let t = build(&SPHERE, 7, &MemBudget::fixed(1 << 30)).unwrap();
        let cam = camera_rays::<f32>(96);
        let p = cam.params(None, 1 << 16);
        let (io, id) = incoherent_in::<f32>(128, 3);
        let mid = 48 * 96 + 16..48 * 96 + 80;
        let o = [&io[..64], &cam.o[mid.clone()], &io[64..]].concat();
        let d = [&id[..64], &cam.d[mid], &id[64..]].concat();
        let shape = [o.len()];
        let tiles = Tiling::new(&shape, o.len(), TILE);
        let near = beam_nears::<f32, Relative>(&t.nodes, 7, &tiles, 0..tiles.bands(), &o, &d, &p)
            .expect("the middle band has a cone");
        assert_eq!(near.len(), o.len());
        assert!(near[64..128].iter().all(|&x| x > p.near));
        assert!(near[..64].iter().chain(&near[128..]).all(|&x| x == p.near));
        let beam = cast_all_beam::<f32, Relative>(&t.nodes, 7, &shape, &o, &d, &p);
        same_but_iters(&beam, &cast_all::<f32>(&t, &o, &d, &p));
    }

    #[test]
    fn the_cone_test_keeps_every_box_a_ray_of_the_cone_passes_through() {
        // No axis of a direction near zero: the cast's rounding bound (the
        // cone's slack) stays tiny.
        let d = [[1.0f64, 0.01, 0.01], [1.0, 0.1, 0.01], [1.0, 0.01, 0.1]];
        let cone = cone_around(d.iter().map(|&d| ([0.0; 3], d))).unwrap();
        // A tiny box on the ray (1, 0.1, 0.01) at distance ~5.
        let c = [5.0, 0.5, 0.05];
        assert!(meets_box(&cone, c.map(|x| x - 1e-3), c.map(|x| x + 1e-3)));
        // A box well outside, behind, and one holding the origin.
        assert!(!meets_box(&cone, [5.0, 3.0, 3.0], [5.1, 3.1, 3.1]));
        assert!(!meets_box(&cone, [-5.1, 0.0, 0.0], [-5.0, 0.1, 0.1]));
        assert!(meets_box(&cone, [-1.0; 3], [1.0; 3]));
        assert_eq!(
            box_distance2([0.0; 3], [3.0, -1.0, 4.0], [5.0, 1.0, 6.0]),
            25.0
        );
        let origins = [[0.0; 3], [1.0, 0.0, 0.0]];
        assert!(cone_around(origins.into_iter().zip(d)).is_none());
    }

    #[test]
    fn the_gpu_twin_holds_the_same_constants() {
        assert!((COS_MAX_HALF_ANGLE - MAX_HALF_ANGLE.cos()).abs() <= 1e-16);
        let k = include_str!("../../kernels/voxel_beam.wgsl");
        let cast = include_str!("../../kernels/voxels.wgsl");
        let value = |name: &str| -> f64 {
            let head = format!("const {name}: f64 = ");
            let line = k.lines().find(|l| l.starts_with(&head)).unwrap();
            line[head.len()..].trim_end_matches("lf;").parse().unwrap()
        };
        assert_eq!(value("MARGIN"), MARGIN);
        assert_eq!(value("COS_MAX_HALF_ANGLE"), COS_MAX_HALF_ANGLE);
        assert_eq!(value("WIDEN"), WIDEN);
        assert!(cast.contains(&format!("const BEAM_TILE: u32 = {TILE}u;")));
    }

    #[test]
    fn the_cosine_cone_test_agrees_with_the_angle_test() {
        // The trigonometric form of [`Cone::meets_sphere`] (without slack) on boxes
        // scattered about a cone: never a false `false`, and the two agree
        // away from the boundary.
        let d = [[1.0f64, 0.2, -0.1], [1.0, 0.25, -0.05], [1.0, 0.18, -0.02]];
        let cone = cone_around(d.iter().map(|&d| ([0.3, -0.2, 0.1], d))).unwrap();
        assert!(cone.slack < 1e-9, "{}", cone.slack);
        let (mut inside, mut outside) = (0, 0);
        let mut x = 0x2545_f491_4f6c_dd1du64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64
        };
        for _ in 0..20000 {
            let c = [
                0.3 + 6.0 * next(),
                -0.2 + 3.0 * next() - 1.0,
                0.1 + 3.0 * next() - 1.5,
            ];
            let h = 0.2 * next();
            let (lo, hi) = (c.map(|v| v - h), c.map(|v| v + h));
            let v = [0, 1, 2].map(|a| c[a] - cone.o[a]);
            let (l, r) = (dot(v, v).sqrt(), 3f64.sqrt() * h);
            let ang = (dot(v, cone.axis) / l).clamp(-1.0, 1.0).acos();
            let margin = ang - (cone.half + (r / l).min(1.0).asin());
            let meets = meets_box(&cone, lo, hi);
            if l <= r || margin <= 0.0 {
                assert!(meets, "false false at {c:?} {h}");
                inside += 1;
            } else if margin > 1e-6 {
                assert!(!meets, "{c:?} {h}: margin {margin}");
                outside += 1;
            }
        }
        assert!(inside > 500 && outside > 1000, "{inside} {outside}");
    }
}
