//! Timing harnesses of the volume renderer: fused against unfused frames,
//! speed against error over dt, and the backward pass. Each takes the
//! built scene and returns medians as metrics; the ops only wire them.

use std::time::Instant;

use super::process_cpu_s;
use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::judge::plot::{self, Chart, Series};
use crate::rays::RayGen;
use crate::real::Real;
use crate::stats::summary::median;
use crate::tensor::{Outputs, Tensor};
use crate::volume::compose::Compose;
use crate::volume::diff::{
    f_diff, f_diff_prepared, forward_buffers, DiffOptions, Grads, Kernel, Reduce, Upstream,
};
use crate::volume::{prepare, render, render_prepared, Chain, VolumeParams};

/// Fused against unfused medians over `repeats` frames of one prepared plan
/// (built once, as a training loop would): samples_per_s,
/// unfused_samples_per_s, integrated_samples_per_s, pixels_per_s,
/// fused_speedup, samples per CPU second; the last fused frame's outputs.
/// Refuses images that differ between the chains.
pub fn forward<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    repeats: usize,
    budget: &MemBudget,
) -> Result<Outputs> {
    let (mut fused, mut unfused, mut int, mut img) = (vec![], vec![], vec![], vec![]);
    let (mut cpu_fused, mut cpu_unfused) = (0.0, 0.0);
    let mut samples = 0;
    let mut last = None;
    let prep = prepare::<F>(p, &gen.aabb, budget)?;
    for _ in 0..repeats {
        let c0 = process_cpu_s();
        let f = render_prepared(cam, gen, &prep, Chain::Fused, Compose::Sorted, budget)?;
        let c1 = process_cpu_s();
        let u = render_prepared(cam, gen, &prep, Chain::Unfused, Compose::Sorted, budget)?;
        let c2 = process_cpu_s();
        if let (Some(c0), Some(c1), Some(c2)) = (c0, c1, c2) {
            cpu_fused += c1 - c0;
            cpu_unfused += c2 - c1;
        }
        if f.image != u.image {
            return Err(Error::invalid(
                "volume.perf",
                "fused and unfused images differ: speed of different results",
            ));
        }
        fused.push(f.timings.fused + f.timings.img);
        unfused.push(u.timings.ray + u.timings.samp + u.timings.int + u.timings.img);
        int.push(u.timings.int);
        img.push(u.timings.img);
        samples = f.counters.samples;
        last = Some(f);
    }
    let (tf, tu) = (median(&mut fused), median(&mut unfused));
    let (ti, tg) = (median(&mut int), median(&mut img));
    let pixels = gen.region().width as f64 * gen.region().height as f64;
    let mut out = Outputs::default();
    if let Some(f) = last {
        f.to_outputs(&mut out)?;
    }
    let s = samples as f64;
    out.metric("time_s", tf).metric("samples_per_s", s / tf);
    out.metric("unfused_time_s", tu)
        .metric("unfused_samples_per_s", s / tu);
    out.metric("integrated_samples_per_s", s / ti.max(1e-12));
    out.metric("pixels_per_s", pixels / tg.max(1e-12));
    out.metric("fused_speedup", tu / tf);
    out.metric("threads", rayon::current_num_threads() as f64);
    // Frames per CPU second (ray generation to image): the speed of the code
    // on a core it has to itself, whatever else the machine runs.
    if cpu_fused > 0.0 && cpu_unfused > 0.0 {
        let total = (samples * repeats as u64) as f64;
        out.metric("samples_per_cpu_s", total / cpu_fused);
        out.metric("unfused_samples_per_cpu_s", total / cpu_unfused);
    }
    Ok(out)
}

/// Speed against error over `dts` (early stop off, no step cap), f32 and
/// f64: per dt the median seconds of a fused frame and the max |trans -
/// exp(-tau)| against the closed-form optical depths `tau`. Tensors `dt`,
/// `time_f32`, `err_f32`, `time_f64`, `err_f64`, `plot_rgb` (log-log) and,
/// over two or more dts, `err_ratio_f32` / `err_ratio_f64` (each error over
/// the next: 4 per halving at second order); metrics `<column>_dt<dt>`.
pub fn dt_sweep(
    (cam, gen, p): (&Camera, &RayGen, &VolumeParams),
    tau: &[f64],
    dts: &[f64],
    repeats: usize,
    budget: &MemBudget,
) -> Result<Outputs> {
    let mut cols: [Vec<f64>; 4] = Default::default();
    for &dt in dts {
        let max_steps = crate::volume::sample::MAX_STEPS_LIMIT;
        let q = VolumeParams {
            dt,
            early_stop: 0.0,
            max_steps,
            ..p.clone()
        };
        let (t32, e32) = sweep_point::<f32>(cam, gen, &q, tau, repeats, budget)?;
        let (t64, e64) = sweep_point::<f64>(cam, gen, &q, tau, repeats, budget)?;
        for (c, v) in cols.iter_mut().zip([t32, e32, t64, e64]) {
            c.push(v);
        }
    }
    let series = vec![
        Series::new("f32", cols[0].clone(), cols[1].clone()),
        Series::new("f64", cols[2].clone(), cols[3].clone()),
    ];
    let title = "volume forward: speed against error over dt";
    let chart = Chart::loglog(
        title,
        "seconds per frame",
        "max error vs closed form",
        series,
    );
    let mut out = Outputs::default();
    out.tensor("plot_rgb", plot::render(&chart)?);
    out.tensor("dt", Tensor::real(&[dts.len()], dts.to_vec())?);
    for (name, c) in ["time_f32", "err_f32", "time_f64", "err_f64"]
        .iter()
        .zip(cols)
    {
        for (dt, v) in dts.iter().zip(&c) {
            out.metric(&format!("{name}_dt{dt}"), *v);
        }
        if let (Some(prec), true) = (name.strip_prefix("err_"), dts.len() >= 2) {
            let r = successive_ratios(&c);
            out.tensor(&format!("err_ratio_{prec}"), Tensor::real(&[r.len()], r)?);
        }
        out.tensor(name, Tensor::real(&[dts.len()], c)?);
    }
    Ok(out)
}

/// `v[i] / v[i + 1]`: over a dt sweep's errors, how much the error falls
/// from one dt to the next (4 per halving for a second-order rule).
fn successive_ratios(v: &[f64]) -> Vec<f64> {
    v.windows(2).map(|w| w[0] / w[1]).collect()
}

/// One point of the dt sweep: the median seconds of a fused frame and the
/// max |trans - exp(-tau)| against the closed-form optical depths `tau`.
fn sweep_point<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    tau: &[f64],
    repeats: usize,
    budget: &MemBudget,
) -> Result<(f64, f64)> {
    let mut times = vec![];
    let mut err = 0.0f64;
    for _ in 0..repeats {
        let t = Instant::now();
        let r = render::<F>(cam, gen, p, Chain::Fused, Compose::Sorted, budget)?;
        times.push(t.elapsed().as_secs_f64());
        err = r
            .image
            .trans
            .iter()
            .zip(tau)
            .map(|(a, t)| (a.f64() - (-t).exp()).abs())
            .fold(0.0, f64::max);
    }
    Ok((median(&mut times), err))
}

/// Backward medians over `repeats`: forward time, fused chunked (lanes and,
/// interleaved, the scalar walk they replace) and sorted, unfused (from kept
/// forward buffers): grads_per_s (after the set-up), call_time_s (the
/// whole call), bwd_fwd_ratio (wall) and bwd_fwd_cpu_ratio
/// (CPU seconds), each the whole `f_diff` call over the whole fused `render`
/// call (each builds its own f32 medium, once: `prepare`);
/// bwd_fwd_prepared_ratio (wall, the set-up left out on both sides: the
/// backward after its set-up over the forward frame after `prepare`),
/// scalar_grads_per_s and lanes_speedup (scalar / lanes, CPU seconds),
/// bytes_per_sample_fused/unfused. Refuses lanes whose gradients differ
/// from the scalar walk's.
pub fn backward<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    p: &VolumeParams,
    w: &Upstream<F>,
    chunks: u32,
    repeats: usize,
    budget: &MemBudget,
) -> Result<Outputs> {
    let fused = DiffOptions {
        chain: Chain::Fused,
        reduce: Reduce::Chunked { chunks },
        per_sample: false,
    };
    let fused_sorted = DiffOptions {
        reduce: Reduce::Sorted,
        ..fused
    };
    let unfused = DiffOptions {
        chain: Chain::Unfused,
        reduce: Reduce::Sorted,
        per_sample: false,
    };
    let mut t: [Vec<f64>; 7] = Default::default();
    let [tf, tb, tbs, tu, tsc, tfp, tbp] = &mut t;
    let mut cpu = [0.0f64; 3];
    let (mut samples, mut bf, mut bu) = (0, 0, 0);
    let fwd = forward_buffers::<F>(gen, cam, p, budget)?;
    let bits = |g: &Grads<F>| {
        let v = g.dsigma.iter().chain(&g.dcolor).flatten();
        v.chain(&g.dcam)
            .map(|x| x.f64().to_bits())
            .collect::<Vec<_>>()
    };
    for _ in 0..repeats {
        let c0 = process_cpu_s();
        let t0 = Instant::now();
        let r = render::<F>(cam, gen, p, Chain::Fused, Compose::Sorted, budget)?;
        tf.push(t0.elapsed().as_secs_f64());
        tfp.push(r.timings.fused + r.timings.img);
        samples = r.counters.samples;
        let c1 = process_cpu_s();
        let t1 = Instant::now();
        let g = f_diff::<F>(cam, gen, p, w, &fused, None, budget)?;
        tb.push(t1.elapsed().as_secs_f64());
        let c2 = process_cpu_s();
        let prep = prepare::<F>(p, &gen.aabb, budget)?;
        let s = f_diff_prepared(cam, gen, p, &prep, w, &fused, None, budget, Kernel::Scalar)?;
        let c3 = process_cpu_s();
        if bits(&g) != bits(&s) {
            return Err(Error::invalid(
                "volume.grad_perf",
                "lane and scalar backward gradients differ: speed of different results",
            ));
        }
        if let (Some(c0), Some(c1), Some(c2), Some(c3)) = (c0, c1, c2, c3) {
            cpu[0] += c1 - c0;
            cpu[1] += c2 - c1;
            cpu[2] += c3 - c2;
        }
        tbp.push(g.time_s);
        tsc.push(s.time_s);
        bf = g.bytes_per_sample;
        let g = f_diff::<F>(cam, gen, p, w, &fused_sorted, None, budget)?;
        tbs.push(g.time_s);
        let g = f_diff::<F>(cam, gen, p, w, &unfused, Some(&fwd), budget)?;
        tu.push(g.time_s);
        bu = g.bytes_per_sample;
    }
    let [tf, tb, tbs, tu, tsc, tfp, tbp] = t.map(|mut v| median(&mut v));
    let s = samples as f64;
    let mut out = Outputs::default();
    out.metric("forward_time_s", tf);
    out.metric("time_s", tbp).metric("grads_per_s", s / tbp);
    out.metric("call_time_s", tb);
    out.metric("bwd_fwd_ratio", tb / tf);
    out.metric("bwd_fwd_prepared_ratio", tbp / tfp);
    out.metric("scalar_time_s", tsc)
        .metric("scalar_grads_per_s", s / tsc);
    if cpu.iter().all(|&c| c > 0.0) {
        out.metric("bwd_fwd_cpu_ratio", cpu[1] / cpu[0]);
        out.metric("lanes_speedup", cpu[2] / cpu[1]);
    }
    out.metric("sorted_time_s", tbs)
        .metric("sorted_grads_per_s", s / tbs);
    out.metric("unfused_time_s", tu)
        .metric("unfused_grads_per_s", s / tu);
    out.metric("bytes_per_sample_fused", bf as f64);
    out.metric("bytes_per_sample_unfused", bu as f64);
    out.metric("threads", rayon::current_num_threads() as f64);
    out.counter("samples", samples);
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn successive_ratios_divide_each_error_by_the_next() {
        assert_eq!(successive_ratios(&[16.0, 4.0, 2.0]), vec![4.0, 2.0]);
        assert!(successive_ratios(&[1.0]).is_empty());
    }
}
