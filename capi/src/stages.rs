//! The stages: `hp_ray` (f_ray), `hp_samp` (f_samp), `hp_int` (f_int),
//! `hp_img` (f_img), `hp_diff` (f_diff): thin adapters that read the caller's
//! tensor views, call the engine's stage of the same name and write the
//! results back. Bit for bit the numbers `hpjudge render` computes: the
//! engine's fused and unfused chains agree exactly, and these adapters
//! convert nothing (float outputs must have the plan's precision).
//!
//! Workspace: every stage takes `ws_bytes` as its memory budget (see
//! `hp_workspace_size`); the CPU backend allocates its scratch itself and
//! does not touch `ws`, which may be NULL only when `ws_bytes` is 0.

use hotpath::budget::{bytes_for, MemBudget};
use hotpath::rays::{f_ray, Rays};
use hotpath::real::{Precision, Real};
use hotpath::volume::compose::{f_img, Compose};
use hotpath::volume::diff::{f_diff, DiffOptions, Forward, Reduce, Upstream};
use hotpath::volume::field::Medium;
use hotpath::volume::integrate::{f_int, Integrated, RayOut};
use hotpath::volume::sample::{f_samp, Samples};
use hotpath::volume::{Chain, VolumeParams};

use crate::abi::*;
use crate::fail::{guard, Fail, Result};
use crate::field::HpField;
use crate::plan::{in_ref, no_next, out_ptr, HpPlan};
use crate::view::{is_empty, DType, View, Want};

/// The plan's float type: its dtype in views.
trait Prec: Real + 'static {
    const DT: DType;
}
impl Prec for f32 {
    const DT: DType = DType::F32;
}
impl Prec for f64 {
    const DT: DType = DType::F64;
}

fn view(
    t: &HpTensor,
    name: &str,
    dt: DType,
    shape: &[Option<usize>],
    output: bool,
) -> Result<View> {
    View::check(
        t,
        &Want {
            name,
            dtypes: &[dt],
            shape,
            output,
        },
    )
}

/// `None` for an absent optional output, else its checked view.
fn opt_view(t: &HpTensor, name: &str, dt: DType, shape: &[Option<usize>]) -> Result<Option<View>> {
    if is_empty(t) {
        Ok(None)
    } else {
        view(t, name, dt, shape, true).map(Some)
    }
}

fn count_of(n: u64, name: &str) -> Result<usize> {
    usize::try_from(n)
        .ok()
        .filter(|&v| v <= u32::MAX as usize)
        .ok_or_else(|| Fail::error(format!("{name}: {n} is too large")))
}

fn budget_of(ws: *mut std::ffi::c_void, ws_bytes: usize) -> Result<MemBudget> {
    if ws.is_null() && ws_bytes > 0 {
        return Err(Fail::error(format!(
            "ws is NULL but ws_bytes is {ws_bytes}"
        )));
    }
    Ok(MemBudget::fixed(ws_bytes as u64))
}

/// Runs `f32` or `f64` by the plan's precision.
macro_rules! by_precision {
    ($plan:expr, $f:ident ( $($arg:expr),* )) => {
        match $plan.precision {
            Precision::F32 => $f::<f32>($($arg),*),
            Precision::F64 => $f::<f64>($($arg),*),
        }
    };
}

// ---------------------------------------------------------------------------
// Rays.

struct RayViews {
    n: usize,
    o: View,
    d: View,
    t0: View,
    t1: View,
    pixel: View,
}

fn ray_views<F: Prec>(r: &HpRays, name: &str, output: bool) -> Result<RayViews> {
    no_next(r.next, name)?;
    let n = count_of(r.count, &format!("{name}.count"))?;
    let s1 = [Some(n)];
    let s3 = [Some(n), Some(3)];
    Ok(RayViews {
        n,
        o: view(&r.o, &format!("{name}.o"), F::DT, &s3, output)?,
        d: view(&r.d, &format!("{name}.d"), F::DT, &s3, output)?,
        t0: view(&r.t0, &format!("{name}.t0"), F::DT, &s1, output)?,
        t1: view(&r.t1, &format!("{name}.t1"), F::DT, &s1, output)?,
        pixel: view(&r.pixel, &format!("{name}.pixel"), DType::U32, &s1, output)?,
    })
}

/// Reads rays: finite values, unit directions (within 1e-6, as `render --rays`).
fn read_rays<F: Prec>(r: &HpRays, name: &str, budget: &MemBudget) -> Result<Rays<F>> {
    let v = ray_views::<F>(r, name, false)?;
    budget.check("rays copy", bytes_for(v.n as u64, Rays::<F>::BYTES_PER_RAY))?;
    let mut out = Rays::with_capacity(v.n);
    for i in 0..v.n {
        let (o, d, t0, t1, p) = unsafe {
            (
                [0, 1, 2].map(|c| v.o.get_real::<F>(i * 3 + c)),
                [0, 1, 2].map(|c| v.d.get_real::<F>(i * 3 + c)),
                v.t0.get_real::<F>(i),
                v.t1.get_real::<F>(i),
                v.pixel.get_u32(i),
            )
        };
        if o.iter().chain(&d).chain(&[t0, t1]).any(|x| !x.is_finite()) {
            return Err(Fail::error(format!(
                "{name}: ray {i} has a non-finite value"
            )));
        }
        let dl = d.iter().map(|x| x.f64() * x.f64()).sum::<f64>().sqrt();
        if (dl - 1.0).abs() > 1e-6 {
            return Err(Fail::error(format!("{name}: ray {i}: |d| = {dl}, not 1")));
        }
        out.push(o, d, t0, t1, p);
    }
    Ok(out)
}

fn write_rays<F: Prec>(r: &Rays<F>, out: &HpRays) -> Result<()> {
    let v = ray_views::<F>(out, "rays", true)?;
    if v.n != r.len() {
        return Err(Fail::error(format!(
            "rays.count is {}, the frame has {} rays (hp_plan_ray_count)",
            v.n,
            r.len()
        )));
    }
    unsafe {
        for i in 0..v.n {
            for c in 0..3 {
                v.o.put(i * 3 + c, r.o[i][c]);
                v.d.put(i * 3 + c, r.d[i][c]);
            }
            v.t0.put(i, r.t0[i]);
            v.t1.put(i, r.t1[i]);
            v.pixel.put(i, r.pixel[i]);
        }
    }
    Ok(())
}

fn ray_impl<F: Prec>(
    plan: &HpPlan,
    ovr: Option<&HpRays>,
    rays: &HpRays,
    budget: &MemBudget,
) -> Result<()> {
    let r = match ovr {
        Some(o) => read_rays::<F>(o, "override", budget)?,
        None => f_ray::<F>(&plan.cam, &plan.gen, budget)?,
    };
    write_rays(&r, rays)
}

#[no_mangle]
pub unsafe extern "C" fn hp_ray(
    plan: *const HpPlan,
    override_or_null: *const HpRays,
    rays: *mut HpRays,
    ws: *mut std::ffi::c_void,
    ws_bytes: usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_ray", || {
        let plan = in_ref(plan, "plan")?;
        let rays = out_ptr(rays, "rays")?;
        let budget = budget_of(ws, ws_bytes)?;
        by_precision!(
            plan,
            ray_impl(plan, override_or_null.as_ref(), rays, &budget)
        )
    })
}

// ---------------------------------------------------------------------------
// Samples.

/// The plan's `VolumeParams` for fields `fs`, `fc` (no occupancy skipping).
fn params_of(plan: &HpPlan, fs: &HpField, fc: &HpField) -> Result<VolumeParams> {
    let m = &plan.march;
    Ok(VolumeParams {
        field: fs.density(&plan.gen.aabb, "fs")?,
        color: fc.color(&plan.gen.aabb, "fc")?,
        dt: m.dt,
        max_steps: m.max_steps,
        early_stop: m.early_stop,
        sampling: m.sampling,
        path: m.path,
        background: m.background,
        occupancy: 0,
    })
}

struct SampViews {
    off: View,
    flags: View,
    ray_id: View,
    t: View,
    dt: View,
    sigma: View,
    color: View,
}

/// Views of `s` for `n` rays (`None`: from `off`'s extent) and `m` samples.
fn samp_views<F: Prec>(s: &HpSamp, n: Option<usize>, m: usize, output: bool) -> Result<SampViews> {
    no_next(s.next, "samp")?;
    let off = view(&s.off, "samp.off", DType::U32, &[n.map(|n| n + 1)], output)?;
    let n = off.shape[0]
        .checked_sub(1)
        .ok_or_else(|| Fail::error("samp.off: extent 0 (needs n_rays + 1)"))?;
    let s1 = [Some(m)];
    Ok(SampViews {
        off,
        flags: view(&s.flags, "samp.flags", DType::U8, &[Some(n)], output)?,
        ray_id: view(&s.ray_id, "samp.ray_id", DType::U32, &s1, output)?,
        t: view(&s.t, "samp.t", F::DT, &s1, output)?,
        dt: view(&s.dt, "samp.dt", F::DT, &s1, output)?,
        sigma: view(&s.sigma, "samp.sigma", F::DT, &s1, output)?,
        color: view(&s.color, "samp.color", F::DT, &[Some(m), Some(3)], output)?,
    })
}

fn samp_impl<F: Prec>(
    plan: &HpPlan,
    fs: &HpField,
    fc: &HpField,
    rays: &HpRays,
    out: &mut HpSamp,
    budget: &MemBudget,
) -> Result<()> {
    let r = read_rays::<F>(rays, "rays", budget)?;
    let p = params_of(plan, fs, fc)?;
    let medium = Medium::<F>::new(&p.field, &p.color);
    let s = f_samp(&r, &medium, &plan.march::<F>(), None, budget)?;
    out.count = s.len() as u64;
    let query = out.capacity == 0
        && [
            &out.off,
            &out.flags,
            &out.ray_id,
            &out.t,
            &out.dt,
            &out.sigma,
            &out.color,
        ]
        .iter()
        .all(|t| is_empty(t));
    if query {
        return Ok(());
    }
    if out.capacity < out.count {
        return Err(Fail::error(format!(
            "samp.capacity is {}, the rays take {} samples (samp.count holds it: \
             allocate that many and call again)",
            out.capacity, out.count
        )));
    }
    let cap = count_of(out.capacity, "samp.capacity")?;
    let v = samp_views::<F>(out, Some(r.len()), cap, true)?;
    unsafe {
        for (i, &o) in s.off.iter().enumerate() {
            v.off.put(i, o);
        }
        for (i, &f) in s.flags.iter().enumerate() {
            v.flags.put(i, f);
        }
        for k in 0..s.len() {
            v.ray_id.put(k, s.ray_id[k]);
            v.t.put(k, s.t[k]);
            v.dt.put(k, s.dt[k]);
            v.sigma.put(k, s.sigma[k]);
            for c in 0..3 {
                v.color.put(k * 3 + c, s.color[k][c]);
            }
        }
    }
    Ok(())
}

#[no_mangle]
pub unsafe extern "C" fn hp_samp(
    plan: *const HpPlan,
    fs: *const HpField,
    fc: *const HpField,
    rays: *const HpRays,
    samp: *mut HpSamp,
    ws: *mut std::ffi::c_void,
    ws_bytes: usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_samp", || {
        let plan = in_ref(plan, "plan")?;
        let (fs, fc) = (in_ref(fs, "fs")?, in_ref(fc, "fc")?);
        let rays = in_ref(rays, "rays")?;
        let samp = out_ptr(samp, "samp")?;
        let budget = budget_of(ws, ws_bytes)?;
        by_precision!(plan, samp_impl(plan, fs, fc, rays, samp, &budget))
    })
}

/// Reads `samp` (its first `count` samples) back into the engine's layout,
/// checking the offsets: `off[0] = 0`, monotone, `off[n] = count`, and
/// `ray_id` naming the ray whose range holds each sample.
fn read_samples<F: Prec>(s: &HpSamp, budget: &MemBudget) -> Result<Samples<F>> {
    let m = count_of(s.count, "samp.count")?;
    if s.capacity < s.count {
        return Err(Fail::error(format!(
            "samp.count {} is over samp.capacity {}",
            s.count, s.capacity
        )));
    }
    let cap = count_of(s.capacity, "samp.capacity")?;
    let v = samp_views::<F>(s, None, cap, false)?;
    budget.check(
        "samples copy",
        bytes_for(m as u64, Samples::<F>::BYTES_PER_SAMPLE),
    )?;
    let n = v.off.shape[0] - 1;
    let mut out: Samples<F> = Samples {
        off: Vec::with_capacity(n + 1),
        ray_id: Vec::with_capacity(m),
        t: Vec::with_capacity(m),
        dt: Vec::with_capacity(m),
        sigma: Vec::with_capacity(m),
        color: Vec::with_capacity(m),
        flags: Vec::with_capacity(n),
        skipped: 0,
    };
    unsafe {
        for i in 0..=n {
            let o = v.off.get_u32(i);
            let prev = out.off.last().copied();
            if (i == 0 && o != 0) || prev.is_some_and(|p| o < p) || o as usize > m {
                return Err(Fail::error(format!(
                    "samp.off[{i}] = {o}: offsets must start at 0, never decrease and end at count {m}"
                )));
            }
            out.off.push(o);
        }
        if out.off[n] as usize != m {
            return Err(Fail::error(format!(
                "samp.off[{n}] = {} but samp.count is {m}",
                out.off[n]
            )));
        }
        for i in 0..n {
            out.flags.push(v.flags.get_u32(i) as u8);
            for k in out.off[i]..out.off[i + 1] {
                let k = k as usize;
                let rid = v.ray_id.get_u32(k);
                if rid as usize != i {
                    return Err(Fail::error(format!(
                        "samp.ray_id[{k}] = {rid}, but off puts sample {k} in ray {i}"
                    )));
                }
                out.ray_id.push(rid);
                out.t.push(v.t.get_real(k));
                out.dt.push(v.dt.get_real(k));
                out.sigma.push(v.sigma.get_real(k));
                out.color
                    .push([0, 1, 2].map(|c| v.color.get_real(k * 3 + c)));
            }
        }
    }
    if out
        .sigma
        .iter()
        .chain(&out.dt)
        .chain(&out.t)
        .any(|x| !x.is_finite())
        || out.color.iter().flatten().any(|x| !x.is_finite())
    {
        return Err(Fail::error("samp: a non-finite t, dt, sigma or colour"));
    }
    Ok(out)
}

// ---------------------------------------------------------------------------
// Integration.

struct IntlViews {
    rgb: View,
    trans: View,
    logtrans: View,
    depth: View,
    opacity: View,
    nsamples: View,
    flags: View,
    alpha: Option<View>,
    log_t: Option<View>,
}

fn intl_views<F: Prec>(
    it: &HpIntl,
    n: Option<usize>,
    m: Option<usize>,
    output: bool,
) -> Result<IntlViews> {
    no_next(it.next, "intl")?;
    let rgb = view(&it.rgb, "intl.rgb", F::DT, &[n, Some(3)], output)?;
    let n = Some(rgb.shape[0]);
    let s1 = [n];
    let opt = |t: &HpTensor, name: &str| -> Result<Option<View>> {
        if is_empty(t) {
            Ok(None)
        } else {
            view(t, name, F::DT, &[m], output).map(Some)
        }
    };
    Ok(IntlViews {
        rgb,
        trans: view(&it.trans, "intl.trans", F::DT, &s1, output)?,
        logtrans: view(&it.logtrans, "intl.logtrans", F::DT, &s1, output)?,
        depth: view(&it.depth, "intl.depth", F::DT, &s1, output)?,
        opacity: view(&it.opacity, "intl.opacity", F::DT, &s1, output)?,
        nsamples: view(&it.nsamples, "intl.nsamples", DType::I32, &s1, output)?,
        flags: view(&it.flags, "intl.flags", DType::U8, &s1, output)?,
        alpha: opt(&it.alpha, "intl.alpha")?,
        log_t: opt(&it.log_t, "intl.log_t")?,
    })
}

fn int_impl<F: Prec>(plan: &HpPlan, samp: &HpSamp, out: &HpIntl, budget: &MemBudget) -> Result<()> {
    let s = read_samples::<F>(samp, budget)?;
    budget.check(
        "f_int buffers",
        bytes_for(s.len() as u64, Integrated::<F>::BYTES_PER_SAMPLE),
    )?;
    let it = f_int(&s, &plan.march::<F>());
    let n = s.off.len() - 1;
    let v = intl_views::<F>(out, Some(n), Some(s.len()), true)?;
    unsafe {
        for (i, r) in it.rays.iter().enumerate() {
            for c in 0..3 {
                v.rgb.put(i * 3 + c, r.rgb[c]);
            }
            v.trans.put(i, r.trans);
            v.logtrans.put(i, r.log_trans);
            v.depth.put(i, r.depth);
            v.opacity.put(i, r.opacity);
            v.nsamples.put(i, r.n.min(i32::MAX as u32) as i32);
            v.flags.put(i, r.flags);
        }
        if let Some(a) = v.alpha {
            for (k, &x) in it.alpha.iter().enumerate() {
                a.put(k, x);
            }
        }
        if let Some(l) = v.log_t {
            for (k, &x) in it.log_t.iter().enumerate() {
                l.put(k, x);
            }
        }
    }
    Ok(())
}

#[no_mangle]
pub unsafe extern "C" fn hp_int(
    plan: *const HpPlan,
    samp: *const HpSamp,
    intl: *mut HpIntl,
    ws: *mut std::ffi::c_void,
    ws_bytes: usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_int", || {
        let plan = in_ref(plan, "plan")?;
        let samp = in_ref(samp, "samp")?;
        let intl = out_ptr(intl, "intl")?;
        let budget = budget_of(ws, ws_bytes)?;
        by_precision!(plan, int_impl(plan, samp, intl, &budget))
    })
}

/// Per-ray results of `intl` (n rays) as the engine's `RayOut`s.
fn read_ray_outs<F: Prec>(v: &IntlViews, n: usize) -> Result<Vec<RayOut<F>>> {
    let mut out = Vec::with_capacity(n);
    for i in 0..n {
        let r = unsafe {
            RayOut {
                rgb: [0, 1, 2].map(|c| v.rgb.get_real::<F>(i * 3 + c)),
                trans: v.trans.get_real(i),
                log_trans: v.logtrans.get_real(i),
                depth: v.depth.get_real(i),
                opacity: v.opacity.get_real(i),
                n: v.nsamples.get_u32(i),
                saturated: 0,
                flags: v.flags.get_u32(i) as u8,
            }
        };
        let vals = [r.trans, r.log_trans, r.depth, r.opacity];
        if vals.iter().chain(&r.rgb).any(|x| !x.is_finite()) {
            return Err(Fail::error(format!("intl: ray {i} has a non-finite value")));
        }
        out.push(r);
    }
    Ok(out)
}

// ---------------------------------------------------------------------------
// Composition.

fn img_impl<F: Prec>(plan: &HpPlan, intl: &HpIntl, rays: &HpRays, img: &HpImg) -> Result<()> {
    no_next(img.next, "img")?;
    let pv = view(&rays.pixel, "rays.pixel", DType::U32, &[None], false)?;
    let n = pv.shape[0];
    let iv = intl_views::<F>(intl, Some(n), None, false)?;
    let ray_outs = read_ray_outs::<F>(&iv, n)?;
    let pixel: Vec<u32> = (0..n).map(|i| unsafe { pv.get_u32(i) }).collect();
    let (w, h) = (plan.gen.width, plan.gen.height);
    let bg = plan.march::<F>().background;
    let im = f_img(&ray_outs, &pixel, w, (0, 0, w, h), bg, Compose::Sorted)?;
    let (hs, ws) = (Some(h as usize), Some(w as usize));
    let s2 = [hs, ws];
    let put_f = |t: &HpTensor, name: &str, src: &[F]| -> Result<()> {
        if let Some(v) = opt_view(t, name, F::DT, &s2)? {
            for (i, &x) in src.iter().enumerate() {
                unsafe { v.put(i, x) };
            }
        }
        Ok(())
    };
    if let Some(v) = opt_view(&img.rgb, "img.rgb", F::DT, &[hs, ws, Some(3)])? {
        for (i, &x) in im.rgb.iter().flatten().enumerate() {
            unsafe { v.put(i, x) };
        }
    }
    put_f(&img.trans, "img.trans", &im.trans)?;
    put_f(&img.logtrans, "img.logtrans", &im.logtrans)?;
    put_f(&img.depth, "img.depth", &im.depth)?;
    put_f(&img.opacity, "img.opacity", &im.opacity)?;
    if let Some(v) = opt_view(&img.hit, "img.hit", DType::U8, &s2)? {
        for (i, &x) in im.hit.iter().enumerate() {
            unsafe { v.put(i, x) };
        }
    }
    if let Some(v) = opt_view(&img.nsamples, "img.nsamples", DType::I32, &s2)? {
        for (i, &x) in im.nsamples.iter().enumerate() {
            unsafe { v.put(i, x) };
        }
    }
    Ok(())
}

#[no_mangle]
pub unsafe extern "C" fn hp_img(
    plan: *const HpPlan,
    intl: *const HpIntl,
    rays: *const HpRays,
    img: *mut HpImg,
    ws: *mut std::ffi::c_void,
    ws_bytes: usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_img", || {
        let plan = in_ref(plan, "plan")?;
        let intl = in_ref(intl, "intl")?;
        let rays = in_ref(rays, "rays")?;
        let img = out_ptr(img, "img")?;
        budget_of(ws, ws_bytes)?;
        no_next(rays.next, "rays")?;
        by_precision!(plan, img_impl(plan, intl, rays, img))
    })
}

// ---------------------------------------------------------------------------
// Backward.

fn diff_impl<F: Prec>(
    plan: &HpPlan,
    dl: &HpTensor,
    samp: &HpSamp,
    intl: &HpIntl,
    g: &HpGrads,
    budget: &MemBudget,
) -> Result<()> {
    no_next(g.next, "grads")?;
    let fs = in_ref(g.fs, "grads.fs")?;
    let fc = in_ref(g.fc, "grads.fc")?;
    let rays = read_rays::<F>(in_ref(g.rays, "grads.rays")?, "grads.rays", budget)?;
    let samples = read_samples::<F>(samp, budget)?;
    let n = rays.len();
    if samples.off.len() != n + 1 {
        return Err(Fail::error(format!(
            "samp holds {} rays, grads.rays {n}",
            samples.off.len() - 1
        )));
    }
    let iv = intl_views::<F>(intl, Some(n), Some(samples.len()), false)?;
    let (Some(alpha), Some(log_t)) = (iv.alpha, iv.log_t) else {
        return Err(Fail::error(
            "intl.alpha and intl.log_t are needed by hp_diff (hp_int writes them)",
        ));
    };
    let integrated = Integrated {
        rays: read_ray_outs::<F>(&iv, n)?,
        alpha: (0..samples.len())
            .map(|k| unsafe { alpha.get_real(k) })
            .collect(),
        log_t: (0..samples.len())
            .map(|k| unsafe { log_t.get_real(k) })
            .collect(),
    };
    let (w, h) = (plan.gen.width as usize, plan.gen.height as usize);
    let dv = View::check(
        dl,
        &Want {
            name: "dL_dI",
            dtypes: &[DType::F32, DType::F64],
            shape: &[Some(h), Some(w), Some(3)],
            output: false,
        },
    )?;
    // dL/d(ray) = dL/d(pixel) / (rays in that pixel): the image is their mean.
    let mut per_pixel = vec![0u32; w * h];
    for &p in &rays.pixel {
        let slot = per_pixel
            .get_mut(p as usize)
            .ok_or_else(|| Fail::error(format!("grads.rays: pixel {p} is outside {w}x{h}")))?;
        *slot += 1;
    }
    let mut up = Vec::with_capacity(n);
    for &p in &rays.pixel {
        let c = per_pixel[p as usize];
        let g3 = [0, 1, 2].map(|k| unsafe { dv.get(p as usize * 3 + k) });
        if g3.iter().any(|x| !x.is_finite()) {
            return Err(Fail::error(format!(
                "dL_dI: pixel {p} has a non-finite value"
            )));
        }
        up.push(g3.map(|x| {
            if c == 1 {
                F::of(x)
            } else {
                F::of(x / c as f64)
            }
        }));
    }
    let upstream = Upstream {
        rgb: up,
        depth: None,
        opacity: None,
    };
    let params = params_of(plan, fs, fc)?;
    let opt = DiffOptions {
        chain: Chain::Unfused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let fwd = Forward {
        rays,
        samples,
        integrated,
    };
    let grads = f_diff(
        &plan.cam,
        &plan.gen,
        &params,
        &upstream,
        &opt,
        Some(&fwd),
        budget,
    )?;
    write_grid(
        &g.dsigma,
        "grads.dsigma",
        grads.dsigma.as_deref(),
        1,
        &params,
    )?;
    write_grid(
        &g.dcolor,
        "grads.dcolor",
        grads.dcolor.as_deref(),
        3,
        &params,
    )?;
    if let Some(v) = opt_view(&g.dcam, "grads.dcam", F::DT, &[Some(6)])? {
        for (i, &x) in grads.dcam.iter().enumerate() {
            unsafe { v.put(i, x) };
        }
    }
    Ok(())
}

/// Writes a grid-shaped gradient into `t` when the caller asked for it.
fn write_grid<F: Prec>(
    t: &HpTensor,
    name: &str,
    src: Option<&[F]>,
    ch: usize,
    p: &VolumeParams,
) -> Result<()> {
    if is_empty(t) {
        return Ok(());
    }
    let (Some(src), Some(shape)) = (src, grid_shape(p, ch)) else {
        return Err(Fail::not_supported(format!(
            "{name}: the field is not a grid, so it has no grid-shaped gradient"
        )));
    };
    let mut want: Vec<Option<usize>> = shape.iter().map(|&v| Some(v)).collect();
    if ch == 3 {
        want.push(Some(3));
    }
    let v = view(t, name, F::DT, &want, true)?;
    for (i, &x) in src.iter().enumerate() {
        unsafe { v.put(i, x) };
    }
    Ok(())
}

fn grid_shape(p: &VolumeParams, ch: usize) -> Option<[usize; 3]> {
    use hotpath::volume::field::{ColorDesc, FieldDesc};
    match (ch, &p.field, &p.color) {
        (1, FieldDesc::Grid(g), _) => Some(g.shape),
        (3, _, ColorDesc::Grid(g)) => Some(g.shape),
        _ => None,
    }
}

#[no_mangle]
pub unsafe extern "C" fn hp_diff(
    plan: *const HpPlan,
    d_l_d_i: *const HpTensor,
    samp: *const HpSamp,
    intl: *const HpIntl,
    grads: *mut HpGrads,
    ws: *mut std::ffi::c_void,
    ws_bytes: usize,
) -> i32 {
    let last = plan.as_ref().and_then(|p| p.last());
    guard(last, "hp_diff", || {
        let plan = in_ref(plan, "plan")?;
        let dl = in_ref(d_l_d_i, "dL_dI")?;
        let samp = in_ref(samp, "samp")?;
        let intl = in_ref(intl, "intl")?;
        let grads = out_ptr(grads, "grads")?;
        let budget = budget_of(ws, ws_bytes)?;
        by_precision!(plan, diff_impl(plan, dl, samp, intl, grads, &budget))
    })
}
