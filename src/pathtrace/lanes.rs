//! Eight-lane values for the whole-vertex packet path ([`super::wave8`]):
//! `F8` (f32), `U8` (u32), `M8` (masks: all ones or zero per lane) and
//! `V8` (three `F8`, a vector per lane). Every operation is a loop over the
//! eight lanes doing exactly the scalar operation of that lane, in the
//! same order as glam's `Vec3A` (dot products `(x x' + y y') + z z'`,
//! `normalize` = `v / sqrt(v . v)`), so a lane computes what the scalar
//! path computes, bit for bit. Inlined into a function compiled with
//! `#[target_feature(enable = "avx2,fma")]` the loops become AVX2
//! instructions; elsewhere the same code runs as plain (or SSE2) code.
//! No lane loop uses `mul_add` and Rust never contracts `a * b + c` into
//! an FMA on its own, so enabling FMA does not change a result.

use std::ops::{Add, BitAnd, BitOr, Div, Mul, Neg, Not, Sub};

/// Lanes per packet.
pub const LANES: usize = 8;

/// Eight f32 lanes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct F8(pub [f32; LANES]);

/// Eight u32 lanes.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct U8(pub [u32; LANES]);

/// Eight lane masks, `u32::MAX` (true) or 0 (false).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
#[repr(C, align(32))]
pub struct M8(pub [u32; LANES]);

#[inline(always)]
fn map<T: Copy, R: Copy + Default>(a: [T; LANES], f: impl Fn(T) -> R) -> [R; LANES] {
    let mut r = [R::default(); LANES];
    for k in 0..LANES {
        r[k] = f(a[k]);
    }
    r
}

#[inline(always)]
fn zip<T: Copy, U: Copy, R: Copy + Default>(
    a: [T; LANES],
    b: [U; LANES],
    f: impl Fn(T, U) -> R,
) -> [R; LANES] {
    let mut r = [R::default(); LANES];
    for k in 0..LANES {
        r[k] = f(a[k], b[k]);
    }
    r
}

#[inline(always)]
fn mask(b: bool) -> u32 {
    if b {
        u32::MAX
    } else {
        0
    }
}

macro_rules! binop {
    ($t:ident, $tr:ident, $f:ident, $e:expr) => {
        impl $tr for $t {
            type Output = $t;
            #[inline(always)]
            fn $f(self, o: $t) -> $t {
                $t(zip(self.0, o.0, $e))
            }
        }
    };
}
binop!(F8, Add, add, |a, b| a + b);
binop!(F8, Sub, sub, |a, b| a - b);
binop!(F8, Mul, mul, |a, b| a * b);
binop!(F8, Div, div, |a, b| a / b);
binop!(M8, BitAnd, bitand, |a, b| a & b);
binop!(M8, BitOr, bitor, |a, b| a | b);
binop!(U8, Add, add, |a: u32, b: u32| a.wrapping_add(b));

impl Neg for F8 {
    type Output = F8;
    #[inline(always)]
    fn neg(self) -> F8 {
        F8(map(self.0, |a| -a))
    }
}

impl Not for M8 {
    type Output = M8;
    #[inline(always)]
    fn not(self) -> M8 {
        M8(map(self.0, |a| !a))
    }
}

impl F8 {
    #[inline(always)]
    pub fn splat(x: f32) -> F8 {
        F8([x; LANES])
    }
    #[inline(always)]
    pub fn sqrt(self) -> F8 {
        F8(map(self.0, f32::sqrt))
    }
    #[inline(always)]
    pub fn abs(self) -> F8 {
        F8(map(self.0, f32::abs))
    }
    /// `f32::min` per lane.
    #[inline(always)]
    pub fn min(self, o: F8) -> F8 {
        F8(zip(self.0, o.0, f32::min))
    }
    /// `f32::max` per lane.
    #[inline(always)]
    pub fn max(self, o: F8) -> F8 {
        F8(zip(self.0, o.0, f32::max))
    }
    /// `a > b ? a : b` per lane (SSE `max`, as glam's `max_element`).
    #[inline(always)]
    pub fn vmax(self, o: F8) -> F8 {
        F8(zip(self.0, o.0, |a, b| if a > b { a } else { b }))
    }
    /// `floor` per lane.
    #[inline(always)]
    pub fn floor(self) -> F8 {
        F8(map(self.0, f32::floor))
    }
    /// `1.0f32.copysign(x)` per lane.
    #[inline(always)]
    pub fn sign_of(self) -> F8 {
        F8(map(self.0, |a| 1.0f32.copysign(a)))
    }
    /// `x < 0 ? -1 : 1` per lane (`bsdf::sign`).
    #[inline(always)]
    pub fn sign(self) -> F8 {
        F8(map(self.0, |a| if a < 0.0 { -1.0 } else { 1.0 }))
    }
    #[inline(always)]
    pub fn lt(self, o: F8) -> M8 {
        M8(zip(self.0, o.0, |a, b| mask(a < b)))
    }
    #[inline(always)]
    pub fn le(self, o: F8) -> M8 {
        M8(zip(self.0, o.0, |a, b| mask(a <= b)))
    }
    #[inline(always)]
    pub fn gt(self, o: F8) -> M8 {
        o.lt(self)
    }
    #[inline(always)]
    pub fn ge(self, o: F8) -> M8 {
        o.le(self)
    }
    #[inline(always)]
    pub fn eq(self, o: F8) -> M8 {
        M8(zip(self.0, o.0, |a, b| mask(a == b)))
    }
    /// `x as i32` per lane (truncation; the values used are small and >= 0).
    #[inline(always)]
    pub fn to_i32(self) -> U8 {
        U8(map(self.0, |a| a as i32 as u32))
    }
}

impl U8 {
    #[inline(always)]
    pub fn splat(x: u32) -> U8 {
        U8([x; LANES])
    }
    /// `x as i32 as f32` per lane.
    #[inline(always)]
    pub fn to_f32(self) -> F8 {
        F8(map(self.0, |a| a as i32 as f32))
    }
    #[inline(always)]
    pub fn mul(self, o: U8) -> U8 {
        U8(zip(self.0, o.0, u32::wrapping_mul))
    }
    #[inline(always)]
    pub fn min(self, o: U8) -> U8 {
        U8(zip(self.0, o.0, u32::min))
    }
    #[inline(always)]
    pub fn and(self, o: U8) -> U8 {
        U8(zip(self.0, o.0, |a, b| a & b))
    }
    #[inline(always)]
    pub fn eq(self, o: U8) -> M8 {
        M8(zip(self.0, o.0, |a, b| mask(a == b)))
    }
    #[inline(always)]
    pub fn ge(self, o: U8) -> M8 {
        M8(zip(self.0, o.0, |a, b| mask(a >= b)))
    }
    /// `rand` of [`super::sampler::PathRng::f`] (independent) per lane: keys `self`,
    /// dimensions `dim`: `(pcg(key ^ dim) >> 8) 2^-24`.
    #[inline(always)]
    pub fn rand(self, dim: U8) -> F8 {
        F8(zip(self.0, dim.0, |k, d| {
            ((crate::rng::pcg(k ^ d) >> 8) as i32 as f32) * (1.0 / 16_777_216.0)
        }))
    }
}

impl M8 {
    /// Lane `k` set where bit `k` of `b` is.
    #[inline(always)]
    pub fn from_bits(b: u8) -> M8 {
        let mut m = [0u32; LANES];
        for (k, x) in m.iter_mut().enumerate() {
            *x = mask(b & (1 << k) != 0);
        }
        M8(m)
    }
    /// Bit `k` set where lane `k` is.
    #[inline(always)]
    pub fn bits(self) -> u8 {
        let mut b = 0u8;
        for k in 0..LANES {
            b |= ((self.0[k] >> 31) as u8) << k;
        }
        b
    }
    #[inline(always)]
    pub fn any(self) -> bool {
        self.bits() != 0
    }
    /// `self ? a : b` per lane, bit for bit.
    #[inline(always)]
    pub fn select(self, a: F8, b: F8) -> F8 {
        let mut r = [0.0f32; LANES];
        for k in 0..LANES {
            let m = self.0[k];
            r[k] = f32::from_bits((a.0[k].to_bits() & m) | (b.0[k].to_bits() & !m));
        }
        F8(r)
    }
    /// `self ? a : b` per lane for masks.
    #[inline(always)]
    pub fn select_m(self, a: M8, b: M8) -> M8 {
        (self & a) | (!self & b)
    }
    /// `self ? a : b` per lane for u32 lanes.
    #[inline(always)]
    pub fn select_u(self, a: U8, b: U8) -> U8 {
        let mut r = [0u32; LANES];
        for k in 0..LANES {
            r[k] = (a.0[k] & self.0[k]) | (b.0[k] & !self.0[k]);
        }
        U8(r)
    }
    /// `self ? a : b` per lane for vectors.
    #[inline(always)]
    pub fn select_v(self, a: V8, b: V8) -> V8 {
        V8 {
            x: self.select(a.x, b.x),
            y: self.select(a.y, b.y),
            z: self.select(a.z, b.z),
        }
    }
}

/// A 3-vector per lane.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct V8 {
    pub x: F8,
    pub y: F8,
    pub z: F8,
}

impl Add for V8 {
    type Output = V8;
    #[inline(always)]
    fn add(self, o: V8) -> V8 {
        V8::new(self.x + o.x, self.y + o.y, self.z + o.z)
    }
}
impl Sub for V8 {
    type Output = V8;
    #[inline(always)]
    fn sub(self, o: V8) -> V8 {
        V8::new(self.x - o.x, self.y - o.y, self.z - o.z)
    }
}
/// Componentwise product.
impl Mul for V8 {
    type Output = V8;
    #[inline(always)]
    fn mul(self, o: V8) -> V8 {
        V8::new(self.x * o.x, self.y * o.y, self.z * o.z)
    }
}
impl Neg for V8 {
    type Output = V8;
    #[inline(always)]
    fn neg(self) -> V8 {
        V8::new(-self.x, -self.y, -self.z)
    }
}

impl V8 {
    #[inline(always)]
    pub fn new(x: F8, y: F8, z: F8) -> V8 {
        V8 { x, y, z }
    }
    /// The same vector in every lane.
    #[inline(always)]
    pub fn splat(v: [f32; 3]) -> V8 {
        V8::new(F8::splat(v[0]), F8::splat(v[1]), F8::splat(v[2]))
    }
    /// Every component times the lane's `s` (glam `v * s`).
    #[inline(always)]
    pub fn scale(self, s: F8) -> V8 {
        V8::new(self.x * s, self.y * s, self.z * s)
    }
    /// Every component divided by the lane's `s` (glam `v / s`).
    #[inline(always)]
    pub fn div(self, s: F8) -> V8 {
        V8::new(self.x / s, self.y / s, self.z / s)
    }
    #[inline(always)]
    pub fn dot(self, o: V8) -> F8 {
        self.x * o.x + self.y * o.y + self.z * o.z
    }
    #[inline(always)]
    pub fn cross(self, o: V8) -> V8 {
        V8::new(
            self.y * o.z - self.z * o.y,
            self.z * o.x - self.x * o.z,
            self.x * o.y - self.y * o.x,
        )
    }
    #[inline(always)]
    pub fn length(self) -> F8 {
        self.dot(self).sqrt()
    }
    #[inline(always)]
    pub fn normalize(self) -> V8 {
        self.div(self.length())
    }
    #[inline(always)]
    pub fn abs(self) -> V8 {
        V8::new(self.x.abs(), self.y.abs(), self.z.abs())
    }
    /// glam's `max_element` (SSE order: `max(max(x, z), max(y, z))`).
    #[inline(always)]
    pub fn max_element(self) -> F8 {
        self.x.vmax(self.z).vmax(self.y.vmax(self.z))
    }
    /// All three components of the lane are 0.
    #[inline(always)]
    pub fn is_zero(self) -> M8 {
        let z = F8::splat(0.0);
        self.x.eq(z) & self.y.eq(z) & self.z.eq(z)
    }
    /// Lane `k` as an array.
    #[inline(always)]
    pub fn lane(&self, k: usize) -> [f32; 3] {
        [self.x.0[k], self.y.0[k], self.z.0[k]]
    }
    /// Sets lane `k`.
    #[inline(always)]
    pub fn set_lane(&mut self, k: usize, v: [f32; 3]) {
        self.x.0[k] = v[0];
        self.y.0[k] = v[1];
        self.z.0[k] = v[2];
    }
}

/// A column of a scene table (one `u32` per row: f32 bits or a code),
/// read per lane by row index. Stored in chunks of eight so that AVX2 reads
/// a chunk with one lane permute (`vpermd`) instead of eight scalar loads
/// and stores (which also stall the next eight-lane load of the result).
#[derive(Clone, Debug, Default)]
pub struct Column {
    chunks: Vec<U8>,
}

impl Column {
    /// The column of `values`, row `i` at index `i`.
    pub fn new(values: impl IntoIterator<Item = u32>) -> Column {
        let v: Vec<u32> = values.into_iter().collect();
        let chunks = v
            .chunks(LANES)
            .map(|c| {
                let mut u = [0u32; LANES];
                u[..c.len()].copy_from_slice(c);
                U8(u)
            })
            .collect();
        Column { chunks }
    }

    /// The f32 column of `values`.
    pub fn of_f32(values: impl IntoIterator<Item = f32>) -> Column {
        Column::new(values.into_iter().map(f32::to_bits))
    }

    /// Row `idx` per lane; an index past the rows gives some row's value
    /// (for lanes whose result is masked off), never a fault.
    #[inline(always)]
    pub fn get(&self, idx: U8, avx2: bool) -> U8 {
        #[cfg(target_arch = "x86_64")]
        if avx2 {
            // SAFETY: the caller passes `avx2` only where AVX2 was detected.
            return unsafe { self.get_avx2(idx) };
        }
        let _ = avx2;
        let n = self.chunks.len() * LANES;
        U8(map(idx.0, |i| {
            let i = (i as usize).min(n - 1);
            self.chunks[i / LANES].0[i % LANES]
        }))
    }

    /// [`Column::get`] as f32 lanes.
    #[inline(always)]
    pub fn get_f(&self, idx: U8, avx2: bool) -> F8 {
        F8(map(self.get(idx, avx2).0, f32::from_bits))
    }

    /// One permute per chunk, chunk chosen by `idx / 8`.
    #[cfg(target_arch = "x86_64")]
    #[inline]
    #[target_feature(enable = "avx2")]
    unsafe fn get_avx2(&self, idx: U8) -> U8 {
        use std::arch::x86_64::*;
        let i = _mm256_loadu_si256(idx.0.as_ptr() as *const __m256i);
        let hi = _mm256_srli_epi32::<3>(i);
        let ld = |c: &U8| _mm256_loadu_si256(c.0.as_ptr() as *const __m256i);
        let mut r = _mm256_permutevar8x32_epi32(ld(&self.chunks[0]), i);
        for (c, chunk) in self.chunks.iter().enumerate().skip(1) {
            let v = _mm256_permutevar8x32_epi32(ld(chunk), i);
            let m = _mm256_cmpeq_epi32(hi, _mm256_set1_epi32(c as i32));
            r = _mm256_blendv_epi8(r, v, m);
        }
        let mut out = U8::default();
        _mm256_storeu_si256(out.0.as_mut_ptr() as *mut __m256i, r);
        out
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use glam::Vec3A;

    /// Lane operations equal glam's `Vec3A` operations bit for bit.
    #[test]
    fn lane_vectors_equal_glam_bit_for_bit() {
        for i in 0..500u32 {
            let r = |d| crate::rng::rand_f32(9, i, 0, d) * 4.0 - 2.0;
            let (a, b) = (Vec3A::new(r(0), r(1), r(2)), Vec3A::new(r(3), r(4), r(5)));
            let (va, vb) = (V8::splat(a.to_array()), V8::splat(b.to_array()));
            let s = r(6);
            let same = |v: V8, g: Vec3A| assert_eq!(v.lane(3), g.to_array());
            same(va.normalize(), a.normalize());
            same(va.cross(vb), a.cross(b));
            same(va.div(F8::splat(s)), a / s);
            same(va.scale(F8::splat(s)) + vb, a * s + b);
            assert_eq!(va.dot(vb).0[5], a.dot(b));
            assert_eq!(va.length().0[0], a.length());
            assert_eq!(va.abs().max_element().0[7], a.abs().max_element());
        }
    }

    /// A column read by lane indices returns each lane's row, with AVX2
    /// (when the CPU has it) and without, for tables of 1 to 20 rows.
    #[test]
    fn columns_return_the_indexed_rows() {
        let avx2 = {
            #[cfg(target_arch = "x86_64")]
            {
                std::arch::is_x86_feature_detected!("avx2")
            }
            #[cfg(not(target_arch = "x86_64"))]
            {
                false
            }
        };
        for n in 1..=20u32 {
            let col = Column::new((0..n).map(|i| 1000 + 7 * i));
            for start in 0..n {
                let idx = U8(std::array::from_fn(|k| (start + 3 * k as u32) % n));
                let want = U8(idx.0.map(|i| 1000 + 7 * i));
                assert_eq!(col.get(idx, false), want);
                assert_eq!(col.get(idx, avx2), want);
            }
        }
    }

    #[test]
    fn masks_select_and_count_lanes() {
        let m = M8::from_bits(0b1010_0101);
        assert_eq!(m.bits(), 0b1010_0101);
        let s = m.select(F8::splat(1.0), F8::splat(2.0));
        assert_eq!(s.0, [1.0, 2.0, 1.0, 2.0, 2.0, 1.0, 2.0, 1.0]);
        assert!(!M8::from_bits(0).any());
        assert_eq!((!m).bits(), 0b0101_1010);
    }
}
