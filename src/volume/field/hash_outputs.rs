//! The hash-grid + MLP field at listed points as named tensors: its
//! encoding, sigma and rgb, and the gradients of `sum_q g_q . (sigma, rgb)`
//! (the field's own code; `referee/hash_probes.rs` gives the referee's).

use crate::error::Result;
use crate::real::Real;
use crate::tensor::{Outputs, Tensor};

use super::hash::{HashMlp, MAX_WIDTH};

impl<F: Real> HashMlp<F> {
    /// enc (n, `width`), sigma (n), rgb (n, 3) at `pts`.
    pub fn probe_outputs(&self, pts: &[[f64; 3]], width: usize) -> Result<Outputs> {
        let (mut enc, mut sig, mut rgb) = (vec![], vec![], vec![]);
        for x in pts {
            let x = x.map(F::of);
            let mut h = [F::zero(); MAX_WIDTH];
            self.encode(&self.corners(x), &mut h);
            enc.extend_from_slice(&h[..width]);
            let (s, c) = self.query(x);
            sig.push(s);
            rgb.push(c);
        }
        let mut out = Outputs::default();
        out.tensor("enc", Tensor::real(&[pts.len(), width], enc)?);
        out.tensor("sigma", Tensor::real(&[pts.len()], sig)?);
        out.tensor("rgb", Tensor::real3(&[pts.len()], &rgb)?);
        Ok(out)
    }

    /// dparams (every parameter) and dx (n, 3) of `sum_q g(q) . (sigma, rgb)`.
    pub fn grad_outputs(&self, pts: &[[f64; 3]], g: impl Fn(u32) -> [f64; 4]) -> Result<Outputs> {
        let mut dp = vec![F::zero(); self.param_count()];
        let mut dx = Vec::with_capacity(pts.len());
        for (q, x) in pts.iter().enumerate() {
            dx.push(self.backward(x.map(F::of), g(q as u32).map(F::of), Some(&mut dp)));
        }
        let mut out = Outputs::default();
        out.tensor("dparams", Tensor::real(&[dp.len()], dp)?);
        out.tensor("dx", Tensor::real3(&[pts.len()], &dx)?);
        Ok(out)
    }
}
