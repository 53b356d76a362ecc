//! The materials of [`super::bsdf`] eight lanes at a time, for the
//! whole-vertex packet path ([`super::wave8`]): shading frame, `eval`,
//! `pdf` and `sample` with the lane's material chosen by masks. Each lane
//! runs the scalar formulas of `bsdf.rs` with the same operations in the
//! same order (see [`super::lanes`]), so it returns what the scalar
//! material returns, bit for bit; the scalar `bsdf.rs` is the referee and
//! documents the formulas. The GGX and glass branches run only when some
//! lane holds that material.

use std::f32::consts::{FRAC_1_PI, PI};

use super::bsdf::sin_cos_2pi;
use super::lanes::{F8, LANES, M8, U8, V8};

/// Material kind codes per lane.
pub const LAMBERT: u32 = 0;
pub const METAL: u32 = 1;
pub const GLASS: u32 = 2;
pub const LIGHT: u32 = 3;

/// Eight lanes' materials: kind code, colour (albedo, reflectance or
/// radiance) and scalar parameter (GGX alpha or IOR).
#[derive(Clone, Copy, Debug, Default)]
pub struct Mat8 {
    pub kind: U8,
    pub rgb: V8,
    pub a: F8,
}

impl Mat8 {
    /// Lanes whose material is `kind`.
    #[inline(always)]
    pub fn is(&self, kind: u32) -> M8 {
        self.kind.eq(U8::splat(kind))
    }
}

/// `bsdf::Frame` per lane.
#[derive(Clone, Copy, Debug)]
pub struct Frame8 {
    pub t: V8,
    pub b: V8,
    pub n: V8,
}

impl Frame8 {
    #[inline(always)]
    pub fn new(n: V8) -> Frame8 {
        let s = n.z.sign_of();
        let a = F8::splat(-1.0) / (s + n.z);
        let b = n.x * n.y * a;
        Frame8 {
            t: V8::new(F8::splat(1.0) + s * n.x * n.x * a, s * b, -s * n.x),
            b: V8::new(b, s + n.y * n.y * a, -n.y),
            n,
        }
    }
    #[inline(always)]
    pub fn to_local(&self, v: V8) -> V8 {
        V8::new(v.dot(self.t), v.dot(self.b), v.dot(self.n))
    }
    #[inline(always)]
    pub fn to_world(&self, v: V8) -> V8 {
        self.t.scale(v.x) + self.b.scale(v.y) + self.n.scale(v.z)
    }
}

#[inline(always)]
fn f(x: f32) -> F8 {
    F8::splat(x)
}

/// `bsdf::ggx_d` per lane.
#[inline(always)]
fn ggx_d(c: F8, alpha: F8) -> F8 {
    let a2 = alpha * alpha;
    let k = c * c * (a2 - f(1.0)) + f(1.0);
    c.le(f(0.0)).select(f(0.0), a2 / (f(PI) * k * k))
}

/// `bsdf::smith_g1` per lane.
#[inline(always)]
fn smith_g1(cos: F8, alpha: F8) -> F8 {
    let c = cos.abs();
    let a2 = alpha * alpha;
    f(2.0) * c / (c + (a2 + (f(1.0) - a2) * c * c).sqrt())
}

/// `bsdf::sin_cos_2pi` per lane.
#[inline(always)]
fn sin_cos(u: F8) -> (F8, F8) {
    let (mut s, mut c) = ([0.0f32; LANES], [0.0f32; LANES]);
    for k in 0..LANES {
        (s[k], c[k]) = sin_cos_2pi(u.0[k]);
    }
    (F8(s), F8(c))
}

/// `bsdf::sample_ggx_vndf` per lane.
#[inline(always)]
fn sample_ggx_vndf(wo: V8, alpha: F8, u0: F8, u1: F8) -> V8 {
    let vh = V8::new(alpha * wo.x, alpha * wo.y, wo.z).normalize();
    let lensq = vh.x * vh.x + vh.y * vh.y;
    let t1 = lensq.gt(f(0.0)).select_v(
        V8::new(-vh.y, vh.x, f(0.0)).div(lensq.sqrt()),
        V8::splat([1.0, 0.0, 0.0]),
    );
    let t2 = vh.cross(t1);
    let r = u0.sqrt();
    let (sp, cp) = sin_cos(u1);
    let p1 = r * cp;
    let s = f(0.5) * (f(1.0) + vh.z);
    let p2 = (f(1.0) - s) * (f(1.0) - p1 * p1).max(f(0.0)).sqrt() + s * r * sp;
    let k = (f(1.0) - p1 * p1 - p2 * p2).max(f(0.0)).sqrt();
    let nh = t1.scale(p1) + t2.scale(p2) + vh.scale(k);
    V8::new(alpha * nh.x, alpha * nh.y, nh.z.max(f(0.0))).normalize()
}

/// `Material::eval` for Lambertian and GGX lanes (the lanes that sample
/// lights; 0 elsewhere).
#[inline(always)]
pub fn eval(m: &Mat8, wo: V8, wi: V8) -> V8 {
    let zero = V8::default();
    let front = !(wo.z * wi.z).le(f(0.0));
    let lam = (front & m.is(LAMBERT)).select_v(m.rgb.scale(f(FRAC_1_PI)), zero);
    let metal = front & m.is(METAL);
    if !metal.any() {
        return lam;
    }
    let (o, i) = (wo.z.abs(), wi.z.abs());
    let h = V8::new(wo.x + wi.x, wo.y + wi.y, (wo.z + wi.z).abs()).normalize();
    let g = ggx_d(h.z, m.a) * smith_g1(o, m.a) * smith_g1(i, m.a) / (f(4.0) * o * i);
    metal.select_v(m.rgb.scale(g), lam)
}

/// `Material::pdf` for Lambertian and GGX lanes (0 elsewhere).
#[inline(always)]
pub fn pdf(m: &Mat8, wo: V8, wi: V8) -> F8 {
    let zero = f(0.0);
    let lam = ((wo.z * wi.z).le(zero) | !m.is(LAMBERT)).select(zero, wi.z.abs() * f(FRAC_1_PI));
    let metal = m.is(METAL);
    if !metal.any() {
        return lam;
    }
    let s = wo.z.sign();
    let (o, i) = (wo.scale(s), wi.scale(s));
    let hs = o + i;
    let h = hs.normalize();
    let bad = o.z.le(zero) | hs.dot(hs).eq(zero) | h.z.le(zero) | o.dot(h).le(zero);
    let p = smith_g1(o.z, m.a) * ggx_d(h.z, m.a) / (f(4.0) * o.z);
    metal.select(bad.select(zero, p), lam)
}

/// Eight `BsdfSample`s; `ok` false where `Material::sample` gives `None`.
#[derive(Clone, Copy, Debug, Default)]
pub struct Sample8 {
    pub ok: M8,
    pub wi: V8,
    pub weight: V8,
    pub pdf: F8,
    pub delta: M8,
    pub eta2: F8,
}

/// `Material::sample` per lane for the lanes of `live` (others: not ok);
/// `u_lobe` is drawn only where a lane needs it (glass).
#[inline(always)]
pub fn sample(m: &Mat8, live: M8, wo: V8, u_lobe: impl FnOnce() -> F8, u0: F8, u1: F8) -> Sample8 {
    let (zero, one) = (f(0.0), f(1.0));
    let sz = wo.z.sign();
    // Lambertian: cosine hemisphere.
    let r = u0.sqrt();
    let (s, c) = sin_cos(u1);
    let lz = (one - u0).max(zero).sqrt();
    let lam = live & m.is(LAMBERT);
    let mut out = Sample8 {
        ok: lam,
        wi: V8::new(r * c, r * s, lz * sz),
        weight: m.rgb,
        pdf: lz * f(FRAC_1_PI),
        delta: M8::default(),
        eta2: one,
    };
    let metal = live & m.is(METAL);
    if metal.any() {
        let o = wo.scale(sz);
        let h = sample_ggx_vndf(o, m.a, u0, u1);
        let i = h.scale(f(2.0) * o.dot(h)) - o;
        let ok = metal & !o.z.le(zero) & !i.z.le(zero);
        out.ok = out.ok | ok;
        out.wi = metal.select_v(i.scale(sz), out.wi);
        out.weight = metal.select_v(m.rgb.scale(smith_g1(i.z, m.a)), out.weight);
        let p = smith_g1(o.z, m.a) * ggx_d(h.z, m.a) / (f(4.0) * o.z);
        out.pdf = metal.select(p, out.pdf);
    }
    let glass = live & m.is(GLASS);
    if glass.any() {
        let c = wo.z.abs();
        let eta = wo.z.gt(zero).select(m.a, one / m.a);
        let sin2 = (one - c * c) / (eta * eta);
        let tir = sin2.ge(one);
        let ct = (one - sin2).sqrt();
        let rs = (c - eta * ct) / (c + eta * ct);
        let rp = (eta * c - ct) / (eta * c + ct);
        let fr = tir.select(one, f(0.5) * (rs * rs + rp * rp));
        let ct = tir.select(zero, ct);
        let refl = u_lobe().lt(fr);
        let wt = V8::new(-wo.x / eta, -wo.y / eta, -sz * ct);
        let wr = V8::new(-wo.x, -wo.y, wo.z);
        let w = refl.select(one, one / (eta * eta));
        out.ok = out.ok | glass;
        out.wi = glass.select_v(refl.select_v(wr, wt), out.wi);
        out.weight = glass.select_v(V8::new(w, w, w), out.weight);
        out.pdf = glass.select(zero, out.pdf);
        out.delta = glass;
        out.eta2 = glass.select(refl.select(one, eta * eta), out.eta2);
    }
    out
}
