//! `f_fused` for 8 rays at once in AVX2 lanes (issue 18, forward speed).
//!
//! [`LaneMarch::march8`] runs the per-ray loop of [`super::fused::march_ray`]
//! for up to [`LANES`] rays in lockstep, one ray per 32-bit lane of an
//! `__m256`: lattice point, sample position, the trilinear index and
//! weights, the emission-absorption step and its compensated sums are lane
//! operations; a lane leaves the loop when its lattice ends or its
//! transmittance falls below the early-stop threshold (masks, no refill: a
//! group is one row of an 8 x 8 tile, whose rays have nearly the same
//! length). Every lane performs the scalar loop's IEEE operations in the
//! scalar order (separate multiplies and adds, no FMA), so results are
//! bit-identical to [`super::fused::march_ray`], which stays the referee
//! (`lanes_equal_the_scalar_march_bit_for_bit` below; the manifest case
//! `vol_grid_gaussian_fused_equals_unfused_f32` compares against `f_samp` +
//! `f_int`).
//!
//! Each in-grid lane's cell is four 32-byte loads (two corners x four
//! channels of the packed `[sigma, r, g, b]` grid per row) with the x, y and
//! z lerps of `lerp_cell4` on them, with the strides precomputed. Lanes
//! whose cell touches the grid's border, and `alpha_of`'s `tau >= 0.25`
//! branch (`expf`), run per lane through the scalar functions.
//!
//! Used for f32, the packed grid with `oob: zero`, fixed sampling, the
//! product transmittance path and no occupancy bitfield, on x86-64 CPUs
//! with AVX2 (detected at run time); everything else takes the scalar path.

use super::field::{Grid, Medium, Oob};
use super::integrate::RayAcc;
use super::occupancy::Occupancy;
use super::sample::{March, Sampling, TransPath};
use crate::real::Real;

/// Rays per lane group.
pub const LANES: usize = 8;

/// One ray of a lane group: origin, direction, clipped interval (f32).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LaneRay {
    pub o: [f32; 3],
    pub d: [f32; 3],
    pub t0: f32,
    pub t1: f32,
}

/// The packed f32 grid and the march, as the lanes read them.
#[derive(Clone, Copy, Debug)]
/// (The backward's lanes, `diff/lanes.rs`, index the same grid through it.)
pub struct LaneMarch<'a> {
    pub(super) data: &'a [f32],
    pub(super) bmin: [f32; 3],
    pub(super) scale: [f32; 3],
    /// `n - 1` per axis.
    pub(super) top: [i32; 3],
    /// Element strides of y and z (x is 4).
    pub(super) sy: i32,
    pub(super) sz: i32,
    pub(super) m: March<f32>,
}

impl<'a> LaneMarch<'a> {
    /// The lane march for this render, or `None` when the lanes do not
    /// cover it (module doc) or the CPU has no AVX2.
    pub fn new<F: Real>(
        medium: &'a Medium<F>,
        m: &March<F>,
        occ: Option<&Occupancy<F>>,
    ) -> Option<LaneMarch<'a>> {
        let Medium::Packed(g) = medium else {
            return None;
        };
        let data = F::as_f32_slice(&g.data)?;
        if occ.is_some()
            || m.sampling != Sampling::Fixed
            || m.path != TransPath::Product
            || !covered(g)
            || !avx2()
        {
            return None;
        }
        let f = |v: F| v.f64() as f32;
        Some(LaneMarch {
            data,
            bmin: g.bmin.map(f),
            scale: g.scale.map(f),
            top: [g.nx, g.ny, g.nz].map(|n| n as i32 - 1),
            sy: (4 * g.nx) as i32,
            sz: (4 * g.nx * g.ny) as i32,
            m: March {
                dt: f(m.dt),
                max_steps: m.max_steps,
                early_stop: f(m.early_stop),
                sampling: m.sampling,
                path: m.path,
                background: m.background.map(f),
            },
        })
    }

    /// The background in f32 (for `RayAcc::finish`).
    pub fn background(&self) -> [f32; 3] {
        self.m.background
    }

    /// Marches `rays` (at most [`LANES`]); `query` is the scalar medium
    /// query for lanes whose cell touches the grid's border ([`query_of`]).
    /// Returns each ray's accumulator and flags, as `walk_lattice` +
    /// `RayAcc` would.
    pub fn march8(&self, rays: &[LaneRay], query: &Query) -> [(RayAcc<f32>, u8); LANES] {
        self.march8_into(rays, query, &mut ())
    }

    /// [`LaneMarch::march8`], handing every integrated sample to `sink`
    /// (lane by lane in lattice order).
    pub fn march8_into<S: LaneSink>(
        &self,
        rays: &[LaneRay],
        query: &Query,
        sink: &mut S,
    ) -> [(RayAcc<f32>, u8); LANES] {
        assert!(rays.len() <= LANES);
        let mut r = [LaneRay::default(); LANES];
        r[..rays.len()].copy_from_slice(rays);
        #[cfg(target_arch = "x86_64")]
        {
            // SAFETY: `new` built `self` only after detecting AVX2.
            unsafe { avx2::march8(self, &r, query, sink) }
        }
        #[cfg(not(target_arch = "x86_64"))]
        {
            let _ = (query, r, sink);
            unreachable!("LaneMarch::new returns None off x86-64")
        }
    }
}

/// The scalar medium query in f32 (for lanes at the grid's border).
pub type Query<'a> = dyn Fn([f32; 3]) -> (f32, [f32; 3]) + Sync + 'a;

/// `medium.query` with f32 arguments and results (exact for f32 media).
pub fn query_of<F: Real>(medium: &Medium<F>) -> impl Fn([f32; 3]) -> (f32, [f32; 3]) + Sync + '_ {
    move |x| {
        let (s, c) = medium.query(x.map(|v| F::of(v as f64)));
        (s.f64() as f32, c.map(|v| v.f64() as f32))
    }
}

/// One step of a lane group, as the backward's replay records it: lane
/// `l`'s integrated sample `k` where bit `l` of `live` is set.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct LaneStep {
    pub k: u32,
    pub live: u8,
    pub t: [f32; LANES],
    pub dt: [f32; LANES],
    pub sigma: [f32; LANES],
    pub c: [[f32; LANES]; 3],
    /// `log T` before the sample.
    pub log_t: [f32; LANES],
    pub alpha: [f32; LANES],
}

/// Receives the lanes' steps (in lattice order); `()` records nothing (and
/// the loop then stores none of them).
pub trait LaneSink {
    const RECORD: bool;
    fn step(&mut self, s: &LaneStep);
}

impl LaneSink for () {
    const RECORD: bool = false;
    fn step(&mut self, _: &LaneStep) {}
}

/// Grids the lanes index with 32-bit offsets: 4-channel, `oob: zero`, at
/// least 2 nodes per axis, under 2^31 elements.
fn covered<F>(g: &Grid<F>) -> bool {
    g.ch == 4
        && g.oob == Oob::Zero
        && g.nx >= 2
        && g.ny >= 2
        && g.nz >= 2
        && (g.data.len() as u64) < (1u64 << 31)
}

fn avx2() -> bool {
    #[cfg(target_arch = "x86_64")]
    {
        std::arch::is_x86_feature_detected!("avx2")
    }
    #[cfg(not(target_arch = "x86_64"))]
    {
        false
    }
}

#[cfg(target_arch = "x86_64")]
pub(super) mod avx2 {
    use std::arch::x86_64::*;

    use super::{LaneMarch, LaneRay, LaneSink, LaneStep, Query, LANES};
    use crate::volume::integrate::{alpha_of, RayAcc};
    use crate::volume::sample::{sample_k, FLAG_HIT, FLAG_STOPPED, FLAG_TRUNCATED};

    /// Kahan step on lanes (`kahan_add`'s operations), kept only where
    /// `live` is set.
    #[inline]
    #[target_feature(enable = "avx2")]
    pub(in crate::volume) unsafe fn kahan(
        sum: &mut __m256,
        comp: &mut __m256,
        x: __m256,
        live: __m256,
    ) {
        let y = _mm256_sub_ps(x, *comp);
        let t = _mm256_add_ps(*sum, y);
        let c = _mm256_sub_ps(_mm256_sub_ps(t, *sum), y);
        *comp = _mm256_blendv_ps(*comp, c, live);
        *sum = _mm256_blendv_ps(*sum, t, live);
    }

    /// `alpha_of::<f32>`'s series branch on lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn alpha_series(tau: __m256) -> __m256 {
        let c = |v: f64| _mm256_set1_ps(v as f32);
        let t2 = _mm256_mul_ps(tau, tau);
        let t4 = _mm256_mul_ps(t2, t2);
        let p01 = _mm256_sub_ps(c(1.0), _mm256_mul_ps(c(1.0 / 2.0), tau));
        let p23 = _mm256_sub_ps(c(1.0 / 6.0), _mm256_mul_ps(c(1.0 / 24.0), tau));
        let p45 = _mm256_sub_ps(c(1.0 / 120.0), _mm256_mul_ps(c(1.0 / 720.0), tau));
        let hi = _mm256_add_ps(p45, _mm256_mul_ps(t2, c(1.0 / 5040.0)));
        let p = _mm256_add_ps(
            _mm256_add_ps(p01, _mm256_mul_ps(t2, p23)),
            _mm256_mul_ps(t4, hi),
        );
        _mm256_mul_ps(tau, p)
    }

    /// `lerp_cell4` of one lane: rows of two corners (32 bytes) weighted
    /// in x, then y on `[row 0 | row 1]` pairs, then z; the same products
    /// and sums as the scalar lerps.
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn cell(d: *const f32, b: usize, sy: usize, sz: usize, f: [f32; 3]) -> __m128 {
        let one = _mm_set1_ps(1.0);
        let w = |v: f32| {
            let v1 = _mm_set1_ps(v);
            _mm256_set_m128(v1, _mm_sub_ps(one, v1))
        };
        let wx = w(f[0]);
        let p00 = _mm256_mul_ps(_mm256_loadu_ps(d.add(b)), wx);
        let p10 = _mm256_mul_ps(_mm256_loadu_ps(d.add(b + sy)), wx);
        let p01 = _mm256_mul_ps(_mm256_loadu_ps(d.add(b + sz)), wx);
        let p11 = _mm256_mul_ps(_mm256_loadu_ps(d.add(b + sz + sy)), wx);
        // [c00 | c01] and [c10 | c11], each c = lo * x0 + hi * x1.
        let a = _mm256_add_ps(
            _mm256_permute2f128_ps(p00, p01, 0x20),
            _mm256_permute2f128_ps(p00, p01, 0x31),
        );
        let bb = _mm256_add_ps(
            _mm256_permute2f128_ps(p10, p11, 0x20),
            _mm256_permute2f128_ps(p10, p11, 0x31),
        );
        let y1 = _mm256_set1_ps(f[1]);
        let y0 = _mm256_sub_ps(_mm256_set1_ps(1.0), y1);
        let c = _mm256_add_ps(_mm256_mul_ps(a, y0), _mm256_mul_ps(bb, y1));
        let e = _mm256_mul_ps(c, w(f[2]));
        _mm_add_ps(_mm256_castps256_ps128(e), _mm256_extractf128_ps(e, 1))
    }

    #[target_feature(enable = "avx2")]
    pub(super) unsafe fn march8<S: LaneSink>(
        lm: &LaneMarch,
        rays: &[LaneRay; LANES],
        query: &Query,
        sink: &mut S,
    ) -> [(RayAcc<f32>, u8); LANES] {
        let lane = |f: &dyn Fn(&LaneRay) -> f32| {
            let v: [f32; LANES] = std::array::from_fn(|l| f(&rays[l]));
            _mm256_loadu_ps(v.as_ptr())
        };
        let o = [lane(&|r| r.o[0]), lane(&|r| r.o[1]), lane(&|r| r.o[2])];
        let dir = [lane(&|r| r.d[0]), lane(&|r| r.d[1]), lane(&|r| r.d[2])];
        let (t0, t1) = (lane(&|r| r.t0), lane(&|r| r.t1));
        let m = &lm.m;
        let (dt, es) = (_mm256_set1_ps(m.dt), _mm256_set1_ps(m.early_stop));
        let (zero, one, half) = (
            _mm256_setzero_ps(),
            _mm256_set1_ps(1.0),
            _mm256_set1_ps(0.5),
        );
        let bmin = lm.bmin.map(|v| _mm256_set1_ps(v));
        let scale = lm.scale.map(|v| _mm256_set1_ps(v));
        let top = lm.top.map(|v| _mm256_set1_epi32(v));
        let (sx, sy, sz) = (
            _mm256_set1_epi32(4),
            _mm256_set1_epi32(lm.sy),
            _mm256_set1_epi32(lm.sz),
        );
        let minus1 = _mm256_set1_epi32(-1);
        let sign = _mm256_set1_ps(-0.0);
        let mut a = t0;
        let mut live = _mm256_castsi256_ps(_mm256_set1_epi32(-1));
        let (mut ended, mut stopped) = (zero, zero);
        let mut trans = one;
        let (mut log_t, mut log_c) = (zero, zero);
        let (mut rgb, mut rgb_c) = ([zero; 3], [zero; 3]);
        let (mut depth, mut depth_c) = (zero, zero);
        let (mut n, mut sat) = (_mm256_setzero_si256(), _mm256_setzero_si256());
        let d = lm.data.as_ptr();
        for k in 0..m.max_steps {
            let a_next = _mm256_add_ps(t0, _mm256_mul_ps(_mm256_set1_ps((k + 1) as f32), dt));
            let b = _mm256_min_ps(a_next, t1);
            let ok = _mm256_and_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(a, t1),
                _mm256_cmp_ps::<_CMP_GT_OQ>(b, a),
            );
            ended = _mm256_or_ps(ended, _mm256_andnot_ps(ok, live));
            live = _mm256_and_ps(live, ok);
            let stop = _mm256_and_ps(live, _mm256_cmp_ps::<_CMP_LT_OQ>(trans, es));
            stopped = _mm256_or_ps(stopped, stop);
            live = _mm256_andnot_ps(stop, live);
            if _mm256_movemask_ps(live) == 0 {
                break;
            }
            let h = _mm256_sub_ps(b, a);
            let t = _mm256_mul_ps(_mm256_add_ps(a, b), half);
            a = a_next;
            let x: [__m256; 3] =
                std::array::from_fn(|i| _mm256_add_ps(o[i], _mm256_mul_ps(t, dir[i])));
            // Trilinear index and weights (`Grid::trilinear`, oob zero).
            let mut inside = live;
            let mut idx = _mm256_setzero_si256();
            let mut f = [zero; 3];
            let strides = [sx, sy, sz];
            for ax in 0..3 {
                let u = _mm256_mul_ps(_mm256_sub_ps(x[ax], bmin[ax]), scale[ax]);
                let ti = _mm256_cvttps_epi32(u);
                let tf = _mm256_cvtepi32_ps(ti);
                let corr = _mm256_cmp_ps::<_CMP_GT_OQ>(tf, u);
                let fl = _mm256_add_epi32(ti, _mm256_castps_si256(corr));
                let ff = _mm256_sub_ps(tf, _mm256_and_ps(corr, one));
                f[ax] = _mm256_sub_ps(u, ff);
                let ok = _mm256_and_si256(
                    _mm256_cmpgt_epi32(fl, minus1),
                    _mm256_cmpgt_epi32(top[ax], fl),
                );
                inside = _mm256_and_ps(inside, _mm256_castsi256_ps(ok));
                idx = _mm256_add_epi32(idx, _mm256_mullo_epi32(fl, strides[ax]));
            }
            let in_bits = _mm256_movemask_ps(inside);
            let edge_bits = _mm256_movemask_ps(live) & !in_bits;
            let mut idx_a = [0i32; LANES];
            _mm256_storeu_si256(idx_a.as_mut_ptr().cast(), idx);
            let mut fa = [[0f32; LANES]; 3];
            for ax in 0..3 {
                _mm256_storeu_ps(fa[ax].as_mut_ptr(), f[ax]);
            }
            let mut q = [[0f32; 4]; LANES];
            for l in 0..LANES {
                if in_bits & (1 << l) != 0 {
                    let v = cell(
                        d,
                        idx_a[l] as usize,
                        lm.sy as usize,
                        lm.sz as usize,
                        [fa[0][l], fa[1][l], fa[2][l]],
                    );
                    _mm_storeu_ps(q[l].as_mut_ptr(), v);
                } else if edge_bits & (1 << l) != 0 {
                    let mut xl = [[0f32; LANES]; 3];
                    for ax in 0..3 {
                        _mm256_storeu_ps(xl[ax].as_mut_ptr(), x[ax]);
                    }
                    let (s, c) = query([xl[0][l], xl[1][l], xl[2][l]]);
                    q[l] = [s, c[0], c[1], c[2]];
                }
            }
            let ch = |c: usize| {
                _mm256_setr_ps(
                    q[0][c], q[1][c], q[2][c], q[3][c], q[4][c], q[5][c], q[6][c], q[7][c],
                )
            };
            // `Medium::query`: sigma = fmax(v, 0) (idempotent on the
            // scalar-queried lanes).
            let sigma = _mm256_max_ps(ch(0), zero);
            let col = [ch(1), ch(2), ch(3)];
            // `RayAcc::step`.
            let tau = _mm256_mul_ps(sigma, h);
            let mut alpha = alpha_series(tau);
            let big = _mm256_movemask_ps(_mm256_andnot_ps(
                _mm256_cmp_ps::<_CMP_LT_OQ>(tau, _mm256_set1_ps(0.25)),
                live,
            ));
            if big != 0 {
                let mut ta = [0f32; LANES];
                let mut aa = [0f32; LANES];
                _mm256_storeu_ps(ta.as_mut_ptr(), tau);
                _mm256_storeu_ps(aa.as_mut_ptr(), alpha);
                for l in 0..LANES {
                    if big & (1 << l) != 0 {
                        aa[l] = alpha_of::<f32>(ta[l]);
                    }
                }
                alpha = _mm256_loadu_ps(aa.as_ptr());
            }
            if S::RECORD {
                let st = |v: __m256| {
                    let mut a = [0f32; LANES];
                    _mm256_storeu_ps(a.as_mut_ptr(), v);
                    a
                };
                sink.step(&LaneStep {
                    k,
                    live: _mm256_movemask_ps(live) as u8,
                    t: st(t),
                    dt: st(h),
                    sigma: st(sigma),
                    c: col.map(st),
                    log_t: st(log_t),
                    alpha: st(alpha),
                });
            }
            let w = _mm256_mul_ps(trans, alpha);
            for c in 0..3 {
                kahan(&mut rgb[c], &mut rgb_c[c], _mm256_mul_ps(w, col[c]), live);
            }
            kahan(&mut depth, &mut depth_c, _mm256_mul_ps(w, t), live);
            kahan(&mut log_t, &mut log_c, _mm256_xor_ps(tau, sign), live);
            let tn = _mm256_mul_ps(trans, _mm256_sub_ps(one, alpha));
            trans = _mm256_blendv_ps(trans, tn, live);
            let live_i = _mm256_castps_si256(live);
            n = _mm256_sub_epi32(n, live_i);
            let full = _mm256_and_ps(live, _mm256_cmp_ps::<_CMP_EQ_OQ>(alpha, one));
            sat = _mm256_sub_epi32(sat, _mm256_castps_si256(full));
        }
        let st = |v: __m256| {
            let mut a = [0f32; LANES];
            _mm256_storeu_ps(a.as_mut_ptr(), v);
            a
        };
        let sti = |v: __m256i| {
            let mut a = [0i32; LANES];
            _mm256_storeu_si256(a.as_mut_ptr().cast(), v);
            a
        };
        let (tr, lt, lc, dp, dc) = (st(trans), st(log_t), st(log_c), st(depth), st(depth_c));
        let (cs, cc) = (rgb.map(st), rgb_c.map(st));
        let (na, sa) = (sti(n), sti(sat));
        let (eb, sb) = (_mm256_movemask_ps(ended), _mm256_movemask_ps(stopped));
        std::array::from_fn(|l| {
            let r = &rays[l];
            let acc = RayAcc {
                trans: tr[l],
                log_t: lt[l],
                log_c: lc[l],
                rgb: [cs[0][l], cs[1][l], cs[2][l]],
                rgb_c: [cc[0][l], cc[1][l], cc[2][l]],
                depth: dp[l],
                depth_c: dc[l],
                n: na[l] as u32,
                saturated: sa[l] as u32,
            };
            // `walk_lattice`'s flags.
            let flags = if r.t1 <= r.t0 {
                0
            } else if eb & (1 << l) != 0 {
                FLAG_HIT
            } else {
                let mut f = FLAG_HIT;
                if sb & (1 << l) != 0 {
                    f |= FLAG_STOPPED;
                }
                if sample_k(r.t0, r.t1, m.dt, m.max_steps, m.sampling, 0).is_some() {
                    f |= FLAG_TRUNCATED;
                }
                f
            };
            (acc, flags)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::rays::clip_aabb;
    use crate::volume::field::GridDesc;
    use crate::volume::fused::march_ray;
    use crate::volume::integrate::RayOut;
    use crate::volume::sample::{FLAG_STOPPED, FLAG_TRUNCATED};

    fn hash(i: u64) -> f64 {
        let mut x = i.wrapping_mul(0x9E37_79B9_7F4A_7C15) ^ 0xD1B5_4A32_D192_ED03;
        x ^= x >> 31;
        x = x.wrapping_mul(0xBF58_476D_1CE4_E5B9);
        x ^= x >> 29;
        (x >> 11) as f64 / (1u64 << 53) as f64
    }

    /// A packed 9 x 7 x 8 grid over [-1, 1]^3: densities in [-5, 60] (so
    /// fmax, the `tau >= 0.25` branch and early stops all occur at dt 0.01),
    /// random colours.
    fn medium() -> Medium<f32> {
        let mut g = GridDesc::filled([8, 7, 9], &[0.0; 4], [-1.0; 3], [1.0; 3], Oob::Zero);
        for (i, v) in g.data.iter_mut().enumerate() {
            let u = hash(i as u64);
            *v = if i % 4 == 0 { -5.0 + 65.0 * u * u } else { u };
        }
        Medium::Packed(Grid::from_desc(&g))
    }

    fn bits(r: &RayOut<f32>) -> Vec<u32> {
        let mut v: Vec<u32> = r.rgb.iter().map(|x| x.to_bits()).collect();
        v.extend([r.trans, r.log_trans, r.depth, r.opacity].map(f32::to_bits));
        v.extend([r.n, r.saturated, r.flags as u32]);
        v
    }

    #[test]
    fn lanes_equal_the_scalar_march_bit_for_bit() {
        let med = medium();
        let Medium::Packed(g) = &med else {
            unreachable!()
        };
        let query = query_of(&med);
        let mut seen = [0usize; 5];
        for (case, (es, steps)) in [(1e-3f32, 4096u32), (0.0, 4096), (1e-4, 37)]
            .into_iter()
            .enumerate()
        {
            let m = March {
                dt: 0.01f32,
                max_steps: steps,
                early_stop: es,
                sampling: Sampling::Fixed,
                path: TransPath::Product,
                background: [0.25, 0.5, 1.0],
            };
            let Some(lm) = LaneMarch::new(&med, &m, None) else {
                eprintln!("no AVX2: the lanes are not used here; skipped");
                return;
            };
            for group in 0..60u64 {
                let len = 1 + (group % 8) as usize;
                let rays: Vec<LaneRay> = (0..len as u64)
                    .map(|l| {
                        let s = 1000 * case as u64 + 8 * group + l;
                        let r = |k: u64| hash(16 * s + k) as f32;
                        // Origins anywhere in [-2, 2]^3 (some inside the
                        // grid), clipped to a box larger than the grid so
                        // lanes cross its border; every 7th ray misses.
                        let o = [0, 1, 2].map(|a| 4.0 * r(a) - 2.0);
                        let aim = [0, 1, 2].map(|a| 1.6 * r(3 + a) - 0.8);
                        let mut d = [0, 1, 2].map(|a| aim[a] - o[a]);
                        if s % 7 == 0 {
                            d = [-o[0], 10.0, -o[2]];
                        }
                        let (t0, t1) = clip_aabb(o, d, [-1.2; 3], [1.1; 3], 0.0, 1e30);
                        LaneRay { o, d, t0, t1 }
                    })
                    .collect();
                let got = lm.march8(&rays, &query);
                for (r, (acc, flags)) in rays.iter().zip(got) {
                    let (want, _) = march_ray(r.o, r.d, r.t0, r.t1, 0, &med, &m, None);
                    let have = acc.finish::<false>(m.background, flags);
                    assert_eq!(bits(&have), bits(&want), "{r:?}: {have:?} vs {want:?}");
                    seen[0] += (want.flags == 0) as usize;
                    seen[1] += (want.flags & FLAG_STOPPED != 0) as usize;
                    seen[2] += (want.flags & FLAG_TRUNCATED != 0) as usize;
                    seen[3] += want.n as usize;
                    seen[4] += want.saturated as usize;
                }
            }
        }
        // Misses, early stops and truncations all occurred.
        assert!(seen[0] > 0 && seen[1] > 0 && seen[2] > 0, "{seen:?}");
        assert!(g.nx == 9 && seen[3] > 10_000, "{seen:?}");
    }

    #[test]
    fn lanes_decline_what_they_do_not_cover() {
        let med = medium();
        let m = March {
            dt: 0.01f32,
            max_steps: 100,
            early_stop: 0.0,
            sampling: Sampling::Fixed,
            path: TransPath::Log,
            background: [0.0; 3],
        };
        assert!(LaneMarch::new(&med, &m, None).is_none());
        let strat = March {
            sampling: Sampling::Stratified { seed: 1 },
            path: TransPath::Product,
            ..m
        };
        assert!(LaneMarch::new(&med, &strat, None).is_none());
        let m64 = March {
            dt: 0.01f64,
            max_steps: 100,
            early_stop: 0.0,
            sampling: Sampling::Fixed,
            path: TransPath::Product,
            background: [0.0; 3],
        };
        let Medium::Packed(g) = medium() else {
            unreachable!()
        };
        let g64 = Grid::<f64> {
            data: g.data.iter().map(|&v| v as f64).collect(),
            bmin: g.bmin.map(|v| v as f64),
            scale: g.scale.map(|v| v as f64),
            nx: g.nx,
            ny: g.ny,
            nz: g.nz,
            ch: g.ch,
            oob: g.oob,
        };
        assert!(LaneMarch::new(&Medium::Packed(g64), &m64, None).is_none());
    }
}
