//! Four f64 lanes for the lane path ([`super::lane_trace`]): one trait,
//! [`Lanes`], with two implementations chosen at run time, never by
//! `-C target-cpu`:
//!
//! | type | instructions | `mul_add` |
//! | --- | --- | --- |
//! | [`Avx2`] | AVX2 `__m256d` (x86_64, entered only after `is_x86_feature_detected!("avx2")` and `("fma")`) | fused (one rounding) |
//! | [`Portable`] | `[f64; 4]`, plain Rust | `a * b + c` (two roundings) |
//!
//! and [`sin_cos`], a branch-free sine and cosine on any `Lanes` (Cody–Waite
//! reduction by pi/2 in three parts, fdlibm's kernel polynomials on
//! `[-pi/4, pi/4]`). Measured against `f64::sin_cos` over `|x| <= 1e4`:
//! at most 1 ulp (unit test below). The scalar path (`f64::sin_cos`, no
//! FMA) is the referee the lane results are held to.

// fdlibm's constants below keep their digits as published.
#![allow(clippy::excessive_precision)]

use std::ops::{Add, Div, Mul, Neg, Sub};

/// Four f64 lanes with the arithmetic the lane kernels use. Masks are lane
/// values with all bits set (true) or clear (false).
pub trait Lanes:
    Copy
    + Add<Output = Self>
    + Sub<Output = Self>
    + Mul<Output = Self>
    + Div<Output = Self>
    + Neg<Output = Self>
{
    fn splat(x: f64) -> Self;
    fn load(a: &[f64; 4]) -> Self;
    fn store(self) -> [f64; 4];
    /// `self * b + c` (fused where the type says so).
    fn mul_add(self, b: Self, c: Self) -> Self;
    fn abs(self) -> Self;
    fn max(self, o: Self) -> Self;
    fn min(self, o: Self) -> Self;
    fn sqrt(self) -> Self;
    /// Rounds to the nearest integer, ties to even.
    fn round(self) -> Self;
    fn floor(self) -> Self;
    /// Mask of `self > o`.
    fn gt(self, o: Self) -> Self;
    /// `a` where `mask`, else `b`.
    fn select(mask: Self, a: Self, b: Self) -> Self;
    /// Lane `i` true when `self` is finite there.
    fn finite(self) -> [bool; 4] {
        self.store().map(f64::is_finite)
    }
}

/// The portable lanes: plain Rust on `[f64; 4]`.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Portable(pub [f64; 4]);

macro_rules! portable_op {
    ($tr:ident, $f:ident, $op:tt) => {
        impl $tr for Portable {
            type Output = Portable;
            #[inline(always)]
            fn $f(self, o: Portable) -> Portable {
                let (a, b) = (self.0, o.0);
                Portable([a[0] $op b[0], a[1] $op b[1], a[2] $op b[2], a[3] $op b[3]])
            }
        }
    };
}
portable_op!(Add, add, +);
portable_op!(Sub, sub, -);
portable_op!(Mul, mul, *);
portable_op!(Div, div, /);

impl Neg for Portable {
    type Output = Portable;
    #[inline(always)]
    fn neg(self) -> Portable {
        Portable(self.0.map(|v| -v))
    }
}

impl Portable {
    #[inline(always)]
    fn map2(self, o: Portable, f: impl Fn(f64, f64) -> f64) -> Portable {
        let (a, b) = (self.0, o.0);
        Portable([f(a[0], b[0]), f(a[1], b[1]), f(a[2], b[2]), f(a[3], b[3])])
    }
}

const TRUE: f64 = f64::from_bits(u64::MAX);

impl Lanes for Portable {
    #[inline(always)]
    fn splat(x: f64) -> Self {
        Portable([x; 4])
    }
    #[inline(always)]
    fn load(a: &[f64; 4]) -> Self {
        Portable(*a)
    }
    #[inline(always)]
    fn store(self) -> [f64; 4] {
        self.0
    }
    #[inline(always)]
    fn mul_add(self, b: Self, c: Self) -> Self {
        self * b + c
    }
    #[inline(always)]
    fn abs(self) -> Self {
        Portable(self.0.map(f64::abs))
    }
    #[inline(always)]
    fn max(self, o: Self) -> Self {
        self.map2(o, f64::max)
    }
    #[inline(always)]
    fn min(self, o: Self) -> Self {
        self.map2(o, f64::min)
    }
    #[inline(always)]
    fn sqrt(self) -> Self {
        Portable(self.0.map(f64::sqrt))
    }
    #[inline(always)]
    fn round(self) -> Self {
        Portable(self.0.map(f64::round_ties_even))
    }
    #[inline(always)]
    fn floor(self) -> Self {
        Portable(self.0.map(f64::floor))
    }
    #[inline(always)]
    fn gt(self, o: Self) -> Self {
        self.map2(o, |a, b| if a > b { TRUE } else { 0.0 })
    }
    #[inline(always)]
    fn select(mask: Self, a: Self, b: Self) -> Self {
        let m = mask.0;
        Portable(std::array::from_fn(|i| {
            if m[i].to_bits() != 0 {
                a.0[i]
            } else {
                b.0[i]
            }
        }))
    }
}

#[cfg(target_arch = "x86_64")]
pub use avx2::Avx2;

#[cfg(target_arch = "x86_64")]
mod avx2 {
    //! Safety: every intrinsic here needs AVX (and FMA for `mul_add`).
    //! `Avx2` values are created only inside functions that the lane path
    //! enters after `is_x86_feature_detected!("avx2")` and `("fma")`
    //! returned true ([`super::super::lane_trace`]), so the CPU has them.
    use super::Lanes;
    use std::arch::x86_64::*;
    use std::ops::{Add, Div, Mul, Neg, Sub};

    /// Four f64 lanes in one AVX2 register.
    #[derive(Clone, Copy, Debug)]
    pub struct Avx2(__m256d);

    macro_rules! avx_op {
        ($tr:ident, $f:ident, $intr:ident) => {
            impl $tr for Avx2 {
                type Output = Avx2;
                #[inline(always)]
                fn $f(self, o: Avx2) -> Avx2 {
                    // SAFETY: see the module comment (AVX present).
                    Avx2(unsafe { $intr(self.0, o.0) })
                }
            }
        };
    }
    avx_op!(Add, add, _mm256_add_pd);
    avx_op!(Sub, sub, _mm256_sub_pd);
    avx_op!(Mul, mul, _mm256_mul_pd);
    avx_op!(Div, div, _mm256_div_pd);

    impl Neg for Avx2 {
        type Output = Avx2;
        #[inline(always)]
        fn neg(self) -> Avx2 {
            // SAFETY: see the module comment.
            Avx2(unsafe { _mm256_xor_pd(self.0, _mm256_set1_pd(-0.0)) })
        }
    }

    // SAFETY (every method): see the module comment (AVX2 and FMA present).
    impl Lanes for Avx2 {
        #[inline(always)]
        fn splat(x: f64) -> Self {
            Avx2(unsafe { _mm256_set1_pd(x) })
        }
        #[inline(always)]
        fn load(a: &[f64; 4]) -> Self {
            Avx2(unsafe { _mm256_loadu_pd(a.as_ptr()) })
        }
        #[inline(always)]
        fn store(self) -> [f64; 4] {
            let mut o = [0.0; 4];
            unsafe { _mm256_storeu_pd(o.as_mut_ptr(), self.0) };
            o
        }
        #[inline(always)]
        fn mul_add(self, b: Self, c: Self) -> Self {
            Avx2(unsafe { _mm256_fmadd_pd(self.0, b.0, c.0) })
        }
        #[inline(always)]
        fn abs(self) -> Self {
            Avx2(unsafe { _mm256_andnot_pd(_mm256_set1_pd(-0.0), self.0) })
        }
        #[inline(always)]
        fn max(self, o: Self) -> Self {
            Avx2(unsafe { _mm256_max_pd(self.0, o.0) })
        }
        #[inline(always)]
        fn min(self, o: Self) -> Self {
            Avx2(unsafe { _mm256_min_pd(self.0, o.0) })
        }
        #[inline(always)]
        fn sqrt(self) -> Self {
            Avx2(unsafe { _mm256_sqrt_pd(self.0) })
        }
        #[inline(always)]
        fn round(self) -> Self {
            Avx2(unsafe {
                _mm256_round_pd::<{ _MM_FROUND_TO_NEAREST_INT | _MM_FROUND_NO_EXC }>(self.0)
            })
        }
        #[inline(always)]
        fn floor(self) -> Self {
            Avx2(unsafe { _mm256_floor_pd(self.0) })
        }
        #[inline(always)]
        fn gt(self, o: Self) -> Self {
            Avx2(unsafe { _mm256_cmp_pd::<_CMP_GT_OQ>(self.0, o.0) })
        }
        #[inline(always)]
        fn select(mask: Self, a: Self, b: Self) -> Self {
            Avx2(unsafe { _mm256_blendv_pd(b.0, a.0, mask.0) })
        }
    }
}

// fdlibm: pi/2 in three 33-bit parts, and the kernel polynomials.
const PIO2_1: f64 = 1.570_796_326_734_125_614_17e0;
const PIO2_2: f64 = 6.077_100_506_303_965_976_6e-11;
const PIO2_3: f64 = 2.022_266_248_711_166_455_8e-21;
const S1: f64 = -1.666_666_666_666_663_243_48e-1;
const S2: f64 = 8.333_333_333_322_489_461_24e-3;
const S3: f64 = -1.984_126_982_985_794_931_34e-4;
const S4: f64 = 2.755_731_370_707_006_767_89e-6;
const S5: f64 = -2.505_076_025_340_686_341_95e-8;
const S6: f64 = 1.589_690_995_211_550_102_21e-10;
const C1: f64 = 4.166_666_666_666_660_190_37e-2;
const C2: f64 = -1.388_888_888_887_410_957_49e-3;
const C3: f64 = 2.480_158_728_947_672_941_78e-5;
const C4: f64 = -2.755_731_435_139_066_330_35e-7;
const C5: f64 = 2.087_572_321_298_174_827_90e-9;
const C6: f64 = -1.135_964_755_778_819_482_65e-11;

/// `(sin x, cos x)` per lane, branch-free: `q = round(2x/pi)`,
/// `r = x - q pi/2` (three parts, exact products for `|q| < 2^20`), the
/// fdlibm polynomials on `r`, then the quadrant `q mod 4` picks and signs
/// them. Within 1 ulp of `f64::sin_cos` for `|x| <= 1e4` (measured in
/// the unit test); larger `|x|` loses accuracy with the reduction.
#[inline(always)]
pub fn sin_cos<V: Lanes>(x: V) -> (V, V) {
    let s = V::splat;
    let q = (x * s(std::f64::consts::FRAC_2_PI)).round();
    let r = (-q).mul_add(s(PIO2_1), x);
    let r = (-q).mul_add(s(PIO2_2), r);
    let r = (-q).mul_add(s(PIO2_3), r);
    let z = r * r;
    let ps = z.mul_add(s(S6), s(S5)).mul_add(z, s(S4)).mul_add(z, s(S3));
    let ps = ps.mul_add(z, s(S2));
    let sin_r = (z * r).mul_add(z.mul_add(ps, s(S1)), r);
    let pc = z.mul_add(s(C6), s(C5)).mul_add(z, s(C4)).mul_add(z, s(C3));
    let pc = pc.mul_add(z, s(C2)).mul_add(z, s(C1)) * z;
    let hz = s(0.5) * z;
    let w = s(1.0) - hz;
    let cos_r = w + (((s(1.0) - w) - hz) + z * pc);
    let qm = q - s(4.0) * (q * s(0.25)).floor();
    let b1 = (qm * s(0.5)).floor();
    let b0 = qm - s(2.0) * b1;
    let swap = b0.gt(s(0.5));
    let (sv, cv) = (V::select(swap, cos_r, sin_r), V::select(swap, sin_r, cos_r));
    let sin_sign = s(1.0) - s(2.0) * b1;
    let flip = b0 + b1 - s(2.0) * b0 * b1;
    let cos_sign = s(1.0) - s(2.0) * flip;
    (sv * sin_sign, cv * cos_sign)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn ulps(a: f64, b: f64) -> f64 {
        let ulp = (b.abs().max(f64::MIN_POSITIVE) * f64::EPSILON).max(f64::from_bits(1));
        (a - b).abs() / ulp
    }

    fn worst<V: Lanes>() -> f64 {
        let mut xs: Vec<f64> = (0..200_001).map(|i| -1e4 + 0.1 * i as f64).collect();
        for k in -8..=8 {
            let c = k as f64 * std::f64::consts::FRAC_PI_2;
            xs.extend([
                c,
                c + 1e-9,
                c - 1e-12,
                c + 0.5 * std::f64::consts::FRAC_PI_4,
            ]);
        }
        xs.extend((0..10_000).map(|i| 1e-3 * i as f64 + 0.123));
        let mut w = 0.0f64;
        for c in xs.chunks(4) {
            let mut a = [0.0; 4];
            a[..c.len()].copy_from_slice(c);
            let (s, co) = sin_cos(V::load(&a));
            let (s, co) = (s.store(), co.store());
            for i in 0..c.len() {
                let (rs, rc) = a[i].sin_cos();
                // Near a zero of sin or cos the absolute error counts
                // (the result is the reduced argument's rounding).
                let es = ulps(s[i], rs).min((s[i] - rs).abs() / f64::EPSILON);
                let ec = ulps(co[i], rc).min((co[i] - rc).abs() / f64::EPSILON);
                w = w.max(es).max(ec);
            }
        }
        w
    }

    #[test]
    fn portable_sin_cos_is_within_one_ulp_of_std() {
        let w = worst::<Portable>();
        assert!(w <= 1.0, "worst {w} ulp");
    }

    #[cfg(target_arch = "x86_64")]
    #[test]
    fn avx2_sin_cos_is_within_one_ulp_of_std() {
        if !(is_x86_feature_detected!("avx2") && is_x86_feature_detected!("fma")) {
            return;
        }
        #[target_feature(enable = "avx2,fma")]
        unsafe fn run() -> f64 {
            worst::<Avx2>()
        }
        // SAFETY: the features were detected above.
        let w = unsafe { run() };
        assert!(w <= 1.0, "worst {w} ulp");
    }

    #[test]
    fn portable_masks_select_and_round_to_even() {
        let v = Portable([0.5, 1.5, 2.5, -0.5]).round();
        assert_eq!(v.0, [0.0, 2.0, 2.0, -0.0]);
        let m = Portable([1.0, 0.0, 3.0, -1.0]).gt(Portable::splat(0.5));
        let s = Portable::select(m, Portable::splat(1.0), Portable::splat(2.0));
        assert_eq!(s.0, [1.0, 2.0, 1.0, 2.0]);
        assert_eq!(
            Portable([1.0, f64::NAN, f64::INFINITY, 0.0]).finite(),
            [true, false, false, true]
        );
    }
}
