//! Forward results as named tensors (SCENES.md volume outputs): the image,
//! a render's counters and chain time, the unfused chain's per-sample
//! buffers, and the GPU's stability mask. The judge's volume ops return
//! these; nothing here computes.

use crate::error::Result;
use crate::rays::Rays;
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};

use super::compose::Image;
use super::gpu::GpuRender;
use super::integrate::Integrated;
use super::sample::Samples;
use super::Render;

impl<F: Real> Image<F> {
    /// rgb (H, W, 3), trans, logtrans, depth, opacity, nsamples, hit (H, W).
    pub fn to_outputs(&self, out: &mut Outputs) -> Result<()> {
        let s = [self.height, self.width];
        out.tensor("rgb", Tensor::real3(&s, &self.rgb)?);
        out.tensor("trans", Tensor::real(&s, self.trans.clone())?);
        out.tensor("logtrans", Tensor::real(&s, self.logtrans.clone())?);
        out.tensor("depth", Tensor::real(&s, self.depth.clone())?);
        out.tensor("opacity", Tensor::real(&s, self.opacity.clone())?);
        out.tensor(
            "nsamples",
            Tensor::from_shape_vec(&s, self.nsamples.clone())?,
        );
        out.tensor("hit", Tensor::from_shape_vec(&s, self.hit.clone())?);
        Ok(())
    }
}

impl<F: Real> Render<F> {
    /// The image, the counters, `samples_total`, and metrics `time_s` (the
    /// chain's stages) and `samples_per_s`.
    pub fn to_outputs(&self, out: &mut Outputs) -> Result<()> {
        self.image.to_outputs(out)?;
        for (k, v) in self.counters.pairs() {
            out.counter(k, v);
        }
        out.tensor(
            "samples_total",
            Tensor::scalar(self.counters.samples as f64),
        );
        let t = &self.timings;
        let chain_s = t.fused + t.ray + t.samp + t.int + t.img;
        out.metric("time_s", chain_s);
        out.metric(
            "samples_per_s",
            self.counters.samples as f64 / chain_s.max(1e-12),
        );
        Ok(())
    }
}

impl<F: Real> Samples<F> {
    /// off (int32, rays + 1), ray_id (int32), t, dt, sigma (per sample).
    pub fn to_outputs(&self, out: &mut Outputs) -> Result<()> {
        let m = [self.len()];
        let off = self.off.iter().map(|&o| o as i32).collect();
        out.tensor("off", Tensor::from_shape_vec(&[self.off.len()], off)?);
        let ids = self.ray_id.iter().map(|&o| o as i32).collect();
        out.tensor("ray_id", Tensor::from_shape_vec(&m, ids)?);
        out.tensor("t", Tensor::real(&m, self.t.clone())?);
        out.tensor("dt", Tensor::real(&m, self.dt.clone())?);
        out.tensor("sigma", Tensor::real(&m, self.sigma.clone())?);
        Ok(())
    }

    /// The stratified offset of every sample, `u_k = (t_k - a_k) / dt_k`
    /// with `a_k = t0 + k dt` and k the sample's place in its ray (meaningful
    /// without occupancy skipping), in f64, clamped to [0, 1].
    pub fn strata(&self, rays: &Rays<F>, dt: f64) -> Vec<f64> {
        let mut u = Vec::with_capacity(self.len());
        for r in 0..self.off.len() - 1 {
            for (k, j) in (self.off[r] as usize..self.off[r + 1] as usize).enumerate() {
                let a = rays.t0[r].f64() + k as f64 * dt;
                u.push(((self.t[j].f64() - a) / self.dt[j].f64()).clamp(0.0, 1.0));
            }
        }
        u
    }
}

impl<F: Real> Integrated<F> {
    /// alpha and log_t (per sample).
    pub fn to_outputs(&self, out: &mut Outputs) -> Result<()> {
        let m = [self.alpha.len()];
        out.tensor("alpha", Tensor::real(&m, self.alpha.clone())?);
        out.tensor("log_t", Tensor::real(&m, self.log_t.clone())?);
        Ok(())
    }
}

impl GpuRender {
    /// The render's outputs, `stable` (uint8, H x W), `unstable_frac`
    /// (scalar) and counter `unstable` (`gpu.rs` says what stable means).
    pub fn to_outputs(self, out: &mut Outputs) -> Result<()> {
        self.render.to_outputs(out)?;
        let shape = [self.render.image.height, self.render.image.width];
        let unstable = self.stable.iter().filter(|&&s| s == 0).count();
        let frac = unstable as f64 / self.stable.len().max(1) as f64;
        out.tensor("unstable_frac", Tensor::scalar(frac));
        out.tensor("stable", Tensor::from_shape_vec(&shape, self.stable)?);
        out.counter("unstable", unstable as u64);
        Ok(())
    }
}
