//! Eight rays at a time against every shape (SIMD across rays): the
//! shapes as structures of arrays, each shape broadcast to the eight lanes
//! of a ray packet. AVX2 (`std::arch`, chosen at run time with
//! `is_x86_feature_detected!`, never `-C target-cpu=native`; the same
//! AVX2 code on an AVX-512 CPU: see `avx2::trace`) or a portable lane
//! loop elsewhere. Both run the same IEEE operations in the same order
//! as the per-ray [`super::packed::Packed`] test (the scalar path's
//! intersection), lane by lane, so a packet render equals the scalar one
//! bit for bit; tests below and the case `pt_packet_equals_scalar` hold
//! them equal. Shapes are visited spheres first, then quads, in scene order
//! (as `Packed` visits them), so ties resolve to the same shape.

use super::shapes::Shape;

/// Rays per packet.
pub const LANES: usize = 8;

/// Eight rays, coordinates by lane.
#[derive(Clone, Copy, Debug, Default)]
pub struct Rays8 {
    pub o: [[f32; LANES]; 3],
    pub d: [[f32; LANES]; 3],
}

impl Rays8 {
    /// Origin and direction of lane `k`.
    #[inline]
    pub fn lane(&self, k: usize) -> ([f32; 3], [f32; 3]) {
        let (o, d) = (&self.o, &self.d);
        ([o[0][k], o[1][k], o[2][k]], [d[0][k], d[1][k], d[2][k]])
    }
}

/// Spheres and quads, one array per coordinate.
#[derive(Clone, Debug, Default)]
pub struct Soa8 {
    sc: [Vec<f32>; 3],
    sr2: Vec<f32>,
    sid: Vec<u32>,
    qc: [Vec<f32>; 3],
    qn: [Vec<f32>; 3],
    qua: [Vec<f32>; 3],
    qvb: [Vec<f32>; 3],
    qid: Vec<u32>,
    /// Per quad, `[k, i, j]` when the normal is `+-e_k` and `ua`, `vb` are
    /// `e_i`, `e_j` multiples (the Cornell box walls): the AVX2 test then
    /// skips the products with zero components (see `avx2::quad_axis`).
    qaxis: Vec<Option<[usize; 3]>>,
    isa: Isa,
}

/// The instruction sets the lane code is compiled for, chosen at run time,
/// narrowest first.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, PartialOrd, Ord)]
pub enum Isa {
    /// Plain lane loops (any CPU).
    #[default]
    Portable,
    /// AVX2 + FMA (FMA enabled but never formed: no `mul_add`).
    Avx2,
    /// AVX2 + FMA with AVX-512F/VL/DQ/BW and GFNI enabled for the
    /// wavefront loop (32 vector registers, still eight lanes, the same
    /// IEEE operations; GFNI reverses the Sobol' sampler's bits in two
    /// instructions); the shape tests stay AVX2 code.
    Avx512,
}

impl Isa {
    /// The widest set this CPU has.
    pub fn detect() -> Isa {
        #[cfg(target_arch = "x86_64")]
        {
            use std::arch::is_x86_feature_detected as has;
            if has!("avx2") && has!("fma") {
                let avx512 = has!("avx512f")
                    && has!("avx512vl")
                    && has!("avx512dq")
                    && has!("avx512bw")
                    && has!("gfni");
                return if avx512 { Isa::Avx512 } else { Isa::Avx2 };
            }
        }
        Isa::Portable
    }

    /// Every set this CPU can run, narrowest first (for the referee tests).
    pub fn available() -> Vec<Isa> {
        let all = [Isa::Portable, Isa::Avx2, Isa::Avx512];
        all.into_iter().filter(|&i| i <= Isa::detect()).collect()
    }

    /// Its name in reports.
    pub fn name(self) -> &'static str {
        match self {
            Isa::Portable => "portable",
            Isa::Avx2 => "avx2",
            Isa::Avx512 => "avx512",
        }
    }
}

/// Lane `k` of `mask` is set.
#[inline]
pub fn lane(mask: u8, k: usize) -> bool {
    mask & (1 << k) != 0
}

impl Soa8 {
    /// The shapes in SoA form, tested with `isa` (at most
    /// [`Isa::detect`]; the tests pass narrower ones).
    pub fn new(shapes: &[Shape], isa: Isa) -> Soa8 {
        let mut s = Soa8 {
            isa: isa.min(Isa::detect()),
            ..Soa8::default()
        };
        for (i, sh) in shapes.iter().enumerate() {
            if let Shape::Sphere(sp) = sh {
                for k in 0..3 {
                    s.sc[k].push(sp.centre[k]);
                }
                s.sr2.push(sp.radius * sp.radius);
                s.sid.push(i as u32);
            }
        }
        for (i, sh) in shapes.iter().enumerate() {
            if let Shape::Quad(q) = sh {
                let (ua, vb) = q.dual();
                for k in 0..3 {
                    s.qc[k].push(q.corner[k]);
                    s.qn[k].push(q.normal()[k]);
                    s.qua[k].push(ua[k]);
                    s.qvb[k].push(vb[k]);
                }
                s.qid.push(i as u32);
                let single = |v: glam::Vec3A| {
                    let nz: Vec<usize> = (0..3).filter(|&a| v[a] != 0.0).collect();
                    (nz.len() == 1).then(|| nz[0])
                };
                s.qaxis.push(match (q.axis(), single(ua), single(vb)) {
                    (k, Some(i), Some(j)) if k < 3 => Some([k, i, j]),
                    _ => None,
                });
            }
        }
        s
    }

    /// The instruction set of its tests (and of the wavefront loop over it).
    pub fn isa(&self) -> Isa {
        self.isa
    }

    /// Nearest hit of each active lane (`active` bit k = lane k) in
    /// (0, inf): `(t, shape index)`, index `u32::MAX` on a miss.
    pub fn intersect8(&self, r: &Rays8, active: u8) -> ([f32; LANES], [u32; LANES]) {
        let mut t = [f32::INFINITY; LANES];
        let mut id = [u32::MAX; LANES];
        self.trace(r, active, &mut t, &mut id, false);
        (t, id)
    }

    /// Lanes of `active` whose ray meets a shape in (0, tmax).
    pub fn occluded8(&self, r: &Rays8, tmax: &[f32; LANES], active: u8) -> u8 {
        let mut t = *tmax;
        let mut id = [u32::MAX; LANES];
        self.trace(r, active, &mut t, &mut id, true)
    }

    /// Returns the lanes that found a hit; with `any`, stops once every
    /// active lane has one.
    fn trace(
        &self,
        r: &Rays8,
        active: u8,
        t: &mut [f32; LANES],
        id: &mut [u32; LANES],
        any: bool,
    ) -> u8 {
        // SAFETY: `Soa8::new` keeps `isa` within what this CPU has.
        #[cfg(target_arch = "x86_64")]
        match self.isa {
            Isa::Avx512 | Isa::Avx2 => return unsafe { avx2::trace(self, r, active, t, id, any) },
            Isa::Portable => {}
        }
        self.trace_portable(r, active, t, id, any)
    }

    fn trace_portable(
        &self,
        r: &Rays8,
        active: u8,
        tb: &mut [f32; LANES],
        id: &mut [u32; LANES],
        any: bool,
    ) -> u8 {
        let mut hit = 0u8;
        let g = |v: &[Vec<f32>; 3], i: usize| [v[0][i], v[1][i], v[2][i]];
        let shapes = (0..self.sid.len())
            .map(|s| (self.sid[s], Err(s)))
            .chain((0..self.qid.len()).map(|q| (self.qid[q], Ok(q))));
        for (shape, which) in shapes {
            for k in (0..LANES).filter(|&k| lane(active, k)) {
                let (o, d) = r.lane(k);
                let t = match which {
                    Err(s) => sphere_lane(g(&self.sc, s), self.sr2[s], o, d, tb[k]),
                    Ok(q) => {
                        let (c, n) = (g(&self.qc, q), g(&self.qn, q));
                        quad_lane([c, n, g(&self.qua, q), g(&self.qvb, q)], o, d, tb[k])
                    }
                };
                if let Some(t) = t {
                    tb[k] = t;
                    id[k] = shape;
                    hit |= 1 << k;
                }
            }
            if any && hit == active {
                return hit;
            }
        }
        hit
    }
}

/// `a < b ? a : b` (SSE/AVX `min`: the second operand when either is NaN).
#[inline]
fn vmin(a: f32, b: f32) -> f32 {
    if a < b {
        a
    } else {
        b
    }
}

/// `a > b ? a : b` (SSE/AVX `max`).
#[inline]
fn vmax(a: f32, b: f32) -> f32 {
    if a > b {
        a
    } else {
        b
    }
}

/// One lane of `Packed`'s sphere test (stable quadratic, see
/// `shapes::sphere_t`), the same operations in the same order.
#[inline]
fn sphere_lane(c: [f32; 3], r2: f32, o: [f32; 3], d: [f32; 3], tbest: f32) -> Option<f32> {
    let (fx, fy, fz) = (o[0] - c[0], o[1] - c[1], o[2] - c[2]);
    let b = -(fx * d[0] + fy * d[1] + fz * d[2]);
    let cc = fx * fx + fy * fy + fz * fz - r2;
    let (lx, ly, lz) = (fx + b * d[0], fy + b * d[1], fz + b * d[2]);
    let disc = r2 - (lx * lx + ly * ly + lz * lz);
    let root = vmax(disc, 0.0).sqrt();
    let q = b + if b < 0.0 { -root } else { root };
    let (t0, t1) = (cc / q, q);
    let (lo, hi) = (vmin(t0, t1), vmax(t0, t1));
    let t = if lo > 0.0 { lo } else { hi };
    let ok = disc >= 0.0 && !(cc > 0.0 && b < 0.0) && t > 0.0 && t < tbest && q != 0.0;
    ok.then_some(t)
}

/// One lane of `Packed`'s quad test (general-plane form); `cnab`: corner,
/// normal and the dual edge vectors.
#[inline]
fn quad_lane(cnab: [[f32; 3]; 4], o: [f32; 3], d: [f32; 3], tbest: f32) -> Option<f32> {
    let [c, n, ua, vb] = cnab;
    let dn = d[0] * n[0] + d[1] * n[1] + d[2] * n[2];
    let num = (c[0] - o[0]) * n[0] + (c[1] - o[1]) * n[1] + (c[2] - o[2]) * n[2];
    let t = num / dn;
    let (hx, hy, hz) = (
        o[0] + t * d[0] - c[0],
        o[1] + t * d[1] - c[1],
        o[2] + t * d[2] - c[2],
    );
    let a = hx * ua[0] + hy * ua[1] + hz * ua[2];
    let b = hx * vb[0] + hy * vb[1] + hz * vb[2];
    let ok = t > 0.0 && t < tbest && (0.0..=1.0).contains(&a) && (0.0..=1.0).contains(&b);
    ok.then_some(t)
}

#[cfg(target_arch = "x86_64")]
mod avx2 {
    use std::arch::x86_64::*;

    use super::{Rays8, Soa8, LANES};

    type V3 = [__m256; 3];

    #[inline]
    #[target_feature(enable = "avx2")]
    fn add(a: __m256, b: __m256) -> __m256 {
        _mm256_add_ps(a, b)
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    fn sub(a: __m256, b: __m256) -> __m256 {
        _mm256_sub_ps(a, b)
    }
    #[inline]
    #[target_feature(enable = "avx2")]
    fn mul(a: __m256, b: __m256) -> __m256 {
        _mm256_mul_ps(a, b)
    }
    /// `a.x b.x + a.y b.y + a.z b.z`, summed left to right (as glam and
    /// the lane loop do).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn dot(a: V3, b: V3) -> __m256 {
        add(add(mul(a[0], b[0]), mul(a[1], b[1])), mul(a[2], b[2]))
    }
    /// All of the four masks.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn all4(a: __m256, b: __m256, c: __m256, d: __m256) -> __m256 {
        _mm256_and_ps(_mm256_and_ps(a, b), _mm256_and_ps(c, d))
    }
    /// `0 <= x <= 1` (false for NaN).
    #[inline]
    #[target_feature(enable = "avx2")]
    fn unit(x: __m256) -> __m256 {
        _mm256_and_ps(
            _mm256_cmp_ps::<_CMP_GE_OQ>(x, _mm256_setzero_ps()),
            _mm256_cmp_ps::<_CMP_LE_OQ>(x, _mm256_set1_ps(1.0)),
        )
    }
    /// Shape `k` of the coordinate arrays `v`, broadcast to all lanes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn splat3(v: &[Vec<f32>; 3], k: usize) -> V3 {
        [0, 1, 2].map(|a| _mm256_set1_ps(v[a][k]))
    }

    /// Sphere `(c, r2)` against the eight rays: `(t, hit mask)` for hits
    /// in (0, tbest), the operations of `super::sphere_lane`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn sphere(c: V3, r2: __m256, o: V3, d: V3, tbest: __m256) -> (__m256, __m256) {
        let zero = _mm256_setzero_ps();
        let sign = _mm256_set1_ps(-0.0);
        let f = [sub(o[0], c[0]), sub(o[1], c[1]), sub(o[2], c[2])];
        let b = _mm256_xor_ps(dot(f, d), sign);
        let cc = sub(dot(f, f), r2);
        let l = [0, 1, 2].map(|a| add(f[a], mul(b, d[a])));
        let disc = sub(r2, dot(l, l));
        let root = _mm256_sqrt_ps(_mm256_max_ps(disc, zero));
        let neg = _mm256_cmp_ps::<_CMP_LT_OQ>(b, zero);
        let q = add(b, _mm256_blendv_ps(root, _mm256_xor_ps(root, sign), neg));
        let (t0, t1) = (_mm256_div_ps(cc, q), q);
        let (lo, hi) = (_mm256_min_ps(t0, t1), _mm256_max_ps(t0, t1));
        let t = _mm256_blendv_ps(hi, lo, _mm256_cmp_ps::<_CMP_GT_OQ>(lo, zero));
        let behind = _mm256_and_ps(_mm256_cmp_ps::<_CMP_GT_OQ>(cc, zero), neg);
        let ok = all4(
            _mm256_cmp_ps::<_CMP_GE_OQ>(disc, zero),
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, tbest),
            _mm256_cmp_ps::<_CMP_NEQ_UQ>(q, zero),
        );
        (t, _mm256_andnot_ps(behind, ok))
    }

    /// Quad `(corner, normal, ua, vb)` against the eight rays, the
    /// operations of `super::quad_lane`.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn quad(cnab: [V3; 4], o: V3, d: V3, tbest: __m256) -> (__m256, __m256) {
        let [c, n, ua, vb] = cnab;
        let zero = _mm256_setzero_ps();
        let t = _mm256_div_ps(
            dot([sub(c[0], o[0]), sub(c[1], o[1]), sub(c[2], o[2])], n),
            dot(d, n),
        );
        let h = [0, 1, 2].map(|a| sub(add(o[a], mul(t, d[a])), c[a]));
        let ok = all4(
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, tbest),
            unit(dot(h, ua)),
            unit(dot(h, vb)),
        );
        (t, ok)
    }

    /// [`quad`] for a quad with normal `+-e_k`, `ua` along `e_i` and `vb`
    /// along `e_j`: `t = (c_k - o_k) / d_k`, `a = h_i ua_i`, `b = h_j vb_j`.
    /// The same decisions and `t` bits as [`quad`]: its dot products with
    /// `n`, `ua`, `vb` add only signed zeros to these terms (a zero's sign
    /// passes `0 <= a`), and negating both sides of `t`'s quotient (normal
    /// `-e_k`) is exact; a ray parallel to the plane gets `t` infinite or
    /// NaN in both, which no test passes.
    #[inline]
    #[target_feature(enable = "avx2")]
    fn quad_axis<const K: usize, const I: usize, const J: usize>(
        s: &Soa8,
        q: usize,
        o: V3,
        d: V3,
        tb: __m256,
    ) -> (__m256, __m256) {
        let zero = _mm256_setzero_ps();
        let g = |v: &[f32]| _mm256_set1_ps(v[q]);
        let t = _mm256_div_ps(sub(g(&s.qc[K]), o[K]), d[K]);
        let hi = sub(add(o[I], mul(t, d[I])), g(&s.qc[I]));
        let hj = sub(add(o[J], mul(t, d[J])), g(&s.qc[J]));
        let ok = all4(
            _mm256_cmp_ps::<_CMP_GT_OQ>(t, zero),
            _mm256_cmp_ps::<_CMP_LT_OQ>(t, tb),
            unit(mul(hi, g(&s.qua[I]))),
            unit(mul(hj, g(&s.qvb[J]))),
        );
        (t, ok)
    }

    /// The portable loop's operations on 8 lanes at once. Also the test
    /// under [`super::Isa::Avx512`]: compiled with AVX-512VL it was slower
    /// (mask-register blends: +0.15 CPU-s on a 1.1 CPU-s 256x256 64-spp
    /// render on Zen 4, one run, interleaved).
    ///
    /// # Safety
    /// The CPU must have AVX2 (checked by the caller).
    #[target_feature(enable = "avx2")]
    pub unsafe fn trace(
        s: &Soa8,
        r: &Rays8,
        active: u8,
        tb: &mut [f32; LANES],
        id: &mut [u32; LANES],
        any: bool,
    ) -> u8 {
        let ld = |a: &[f32; LANES]| _mm256_loadu_ps(a.as_ptr());
        let o = [ld(&r.o[0]), ld(&r.o[1]), ld(&r.o[2])];
        let d = [ld(&r.d[0]), ld(&r.d[1]), ld(&r.d[2])];
        let mut tbest = ld(tb);
        let mut ids = _mm256_loadu_si256(id.as_ptr() as *const __m256i);
        let act = active as i32;
        // All-ones in the active lanes.
        let bits = _mm256_setr_epi32(1, 2, 4, 8, 16, 32, 64, 128);
        let actv = _mm256_castsi256_ps(_mm256_cmpgt_epi32(
            _mm256_and_si256(_mm256_set1_epi32(act), bits),
            _mm256_setzero_si256(),
        ));
        // Branch-free updates: a hit or miss per shape and lane is close to
        // random, so a branch on it would be mispredicted often.
        let mut hits = _mm256_setzero_ps();
        let shapes = (0..s.sid.len())
            .map(|k| (s.sid[k], Err(k)))
            .chain((0..s.qid.len()).map(|k| (s.qid[k], Ok(k))));
        for (shape, which) in shapes {
            let (t, ok) = match which {
                Err(k) => sphere(splat3(&s.sc, k), _mm256_set1_ps(s.sr2[k]), o, d, tbest),
                // The axis order as constants, so that the lanes of `o`
                // and `d` stay in registers.
                Ok(k) => match s.qaxis[k] {
                    Some([0, 1, 2]) => quad_axis::<0, 1, 2>(s, k, o, d, tbest),
                    Some([0, 2, 1]) => quad_axis::<0, 2, 1>(s, k, o, d, tbest),
                    Some([1, 0, 2]) => quad_axis::<1, 0, 2>(s, k, o, d, tbest),
                    Some([1, 2, 0]) => quad_axis::<1, 2, 0>(s, k, o, d, tbest),
                    Some([2, 0, 1]) => quad_axis::<2, 0, 1>(s, k, o, d, tbest),
                    Some([2, 1, 0]) => quad_axis::<2, 1, 0>(s, k, o, d, tbest),
                    _ => {
                        let cnab = [&s.qc, &s.qn, &s.qua, &s.qvb].map(|v| splat3(v, k));
                        quad(cnab, o, d, tbest)
                    }
                },
            };
            let ok = _mm256_and_ps(ok, actv);
            tbest = _mm256_blendv_ps(tbest, t, ok);
            let shape = _mm256_set1_epi32(shape as i32);
            ids = _mm256_blendv_epi8(ids, shape, _mm256_castps_si256(ok));
            hits = _mm256_or_ps(hits, ok);
            if any && _mm256_movemask_ps(hits) == act {
                break;
            }
        }
        _mm256_storeu_ps(tb.as_mut_ptr(), tbest);
        _mm256_storeu_si256(id.as_mut_ptr() as *mut __m256i, ids);
        _mm256_movemask_ps(hits) as u8
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::pathtrace::packed::Packed;
    use crate::rng::rand_f32;
    use glam::Vec3A;

    /// Every packet implementation this CPU runs (portable, AVX2) equals the per-ray `Packed` test bit for bit (t and shape), for
    /// nearest hits and shadow tests, with lanes off.
    #[test]
    #[allow(clippy::needless_range_loop)]
    fn packets_equal_the_per_ray_test_bit_for_bit() {
        let shapes = crate::pathtrace::packed::cornell_shapes();
        let p = Packed::new(&shapes);
        for isa in Isa::available() {
            let s = Soa8::new(&shapes, isa);
            assert_eq!(s.isa(), isa);
            let mut hits = 0;
            for i in 0..20_000u32 {
                let mut r = Rays8::default();
                let mut tmax = [0.0f32; LANES];
                for k in 0..LANES {
                    let u = |j| rand_f32(5, i, k as u32, j) * 2.0 - 1.0;
                    let o = Vec3A::new(u(0), u(1), u(2) * 0.5 + 2.0 * (k % 2) as f32);
                    let d = Vec3A::new(u(3), u(4), u(5)).normalize();
                    for a in 0..3 {
                        r.o[a][k] = o[a];
                        r.d[a][k] = d[a];
                    }
                    tmax[k] = u(6) + 1.0;
                }
                let active = (rand_f32(6, i, 0, 0) * 255.0) as u8 | 1;
                let (t, id) = s.intersect8(&r, active);
                let occ = s.occluded8(&r, &tmax, active);
                for k in 0..LANES {
                    let o = Vec3A::new(r.o[0][k], r.o[1][k], r.o[2][k]);
                    let d = Vec3A::new(r.d[0][k], r.d[1][k], r.d[2][k]);
                    if !lane(active, k) {
                        assert_eq!(id[k], u32::MAX);
                        assert!(!lane(occ, k));
                        continue;
                    }
                    match p.intersect(o, d, f32::INFINITY) {
                        Some((tp, ip)) => {
                            hits += 1;
                            assert_eq!(
                                (t[k].to_bits(), id[k]),
                                (tp.to_bits(), ip as u32),
                                "lane {k} ray {i}"
                            );
                        }
                        None => assert_eq!(id[k], u32::MAX),
                    }
                    assert_eq!(lane(occ, k), p.occluded(o, d, tmax[k]), "lane {k} ray {i}");
                }
            }
            assert!(hits > 40_000, "{hits}");
        }
    }
}
