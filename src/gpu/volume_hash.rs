//! The hash-grid + MLP field's GPU input (`kernels/hash_mlp.wgsl`, issue
//! 19): its typed description [`GpuHash`] (rounded to f32 by the renderer,
//! `src/volume/gpu.rs`), the uniform [`HashParams`], the checks the kernels
//! rely on, and the bound of loop back-edges one network evaluation takes
//! (Mesa llvmpipe caps them per invocation, so the network runs one thread
//! a sample: `f_hash_fill`, `f_diff_hash`). CPU twin:
//! `src/volume/field/hash.rs` `HashMlp`; parity cases
//! `TESTS/volume/manifest_gpu_hash.yaml`.

use bytemuck::{Pod, Zeroable};

use super::context::GpuContext;
use crate::error::{Error, Result};

/// One level's geometry (`hash.rs` `Level`).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GpuLevel {
    pub n: f32,
    pub top: u32,
    pub n1: u32,
    pub dense: bool,
}

/// The field as the kernels read it.
#[derive(Clone, Copy, Debug)]
pub struct GpuHash<'a> {
    pub levels: &'a [GpuLevel],
    pub features: u32,
    /// Entries per level's table (a power of two).
    pub tsize: u32,
    /// `density: relu` (else softplus).
    pub relu: bool,
    pub bmin: [f32; 3],
    pub inv_ext: [f32; 3],
    /// `(in, out)` per layer.
    pub layers: &'a [[u32; 2]],
    /// Every parameter in the flat order of `HashMlpDesc::flat`.
    pub params: &'a [f32],
}

/// Uniform of `kernels/hash_mlp.wgsl` (keep in sync with `struct
/// HashParams` there): 4 vec4, 16 + 16 level vec4, 4 layer vec4; 640 bytes.
#[repr(C)]
#[derive(Clone, Copy, Debug, Pod, Zeroable)]
pub struct HashParams {
    pub bmin: [f32; 4],
    pub inv_ext: [f32; 4],
    pub dims: [u32; 4],
    pub misc: [u32; 4],
    pub level_n: [[f32; 4]; 16],
    pub level_u: [[u32; 4]; 16],
    pub layer: [[u32; 4]; 4],
}
const _: () = assert!(std::mem::size_of::<HashParams>() == 640);

impl GpuHash<'_> {
    /// Entries of all tables together (`L T F`).
    pub fn table_len(&self) -> u64 {
        self.levels.len() as u64 * self.tsize as u64 * self.features as u64
    }

    /// The uniform (layer offsets into the flat parameters).
    pub fn uniform(&self) -> HashParams {
        let mut p = HashParams::zeroed();
        p.bmin = [self.bmin[0], self.bmin[1], self.bmin[2], 0.0];
        p.inv_ext = [self.inv_ext[0], self.inv_ext[1], self.inv_ext[2], 0.0];
        p.dims = [
            self.levels.len() as u32,
            self.features,
            self.tsize,
            self.layers.len() as u32,
        ];
        p.misc[0] = self.relu as u32;
        for (l, lv) in self.levels.iter().enumerate().take(16) {
            p.level_n[l][0] = lv.n;
            p.level_u[l] = [lv.top, lv.n1, lv.dense as u32, 0];
        }
        let mut o = self.table_len() as u32;
        for (q, &[inp, out]) in self.layers.iter().enumerate().take(4) {
            p.layer[q] = [inp, out, o, o + inp * out];
            o += inp * out + out;
        }
        p
    }

    /// Loop back-edges of one network evaluation and its back-propagation
    /// (`hash_corners`, `hash_encode`, `hash_mlp`, `hash_backward`): a bound.
    pub fn loop_iters(&self) -> u64 {
        let (l, f) = (self.levels.len() as u64, self.features as u64);
        let mlp: u64 = self
            .layers
            .iter()
            .map(|&[i, o]| (o as u64) * (i as u64 + 2) + i as u64)
            .sum();
        let forward = 3 + l * (3 + 8) + l * f * 9 + mlp;
        forward + 2 * mlp + l * 8 * (f + 12)
    }

    /// Checks what the kernels assume, and one evaluation against the
    /// driver's loop cap.
    pub fn validate(&self, ctx: &GpuContext) -> Result<()> {
        let at = "gpu hash_mlp input";
        let bad = |m: String| Err(Error::invalid(at, m));
        let nl = self.layers.len();
        if !(1..=16).contains(&self.levels.len()) || !(2..=4).contains(&nl) {
            return bad(format!(
                "{} levels, {nl} layers: the kernel holds 1..=16 and 2..=4",
                self.levels.len()
            ));
        }
        if !self.tsize.is_power_of_two() {
            return bad(format!("table size {} is not a power of two", self.tsize));
        }
        let mut inp = self.levels.len() as u32 * self.features;
        let mut count = self.table_len();
        for (q, &[i, o]) in self.layers.iter().enumerate() {
            let last = q + 1 == nl;
            if i != inp || i > 64 || o > 64 || (last && o != 4) {
                return bad(format!(
                    "layer {q} is ({o}, {i}); the chain needs input {inp}, widths <= 64, 4 outputs last"
                ));
            }
            count += (i as u64 + 1) * o as u64;
            inp = o;
        }
        if count != self.params.len() as u64 {
            return bad(format!(
                "{} parameters for a field of {count}",
                self.params.len()
            ));
        }
        if let Some(cap) = ctx.max_loop_iterations() {
            if self.loop_iters() > cap {
                return Err(Error::NotSupported(format!(
                    "one network evaluation takes up to {} loop iterations, over this driver's \
                     cap of {cap} per invocation (Mesa llvmpipe)",
                    self.loop_iters()
                )));
            }
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn layer_offsets_follow_the_flat_parameter_order() {
        let levels = [GpuLevel {
            n: 4.0,
            top: 3,
            n1: 5,
            dense: true,
        }; 3];
        let h = GpuHash {
            levels: &levels,
            features: 2,
            tsize: 256,
            relu: false,
            bmin: [-1.0; 3],
            inv_ext: [0.5; 3],
            layers: &[[6, 16], [16, 4]],
            params: &[],
        };
        let p = h.uniform();
        // Tables 3 x 256 x 2 = 1536; W0 96, b0 16; W1 64, b1 4.
        assert_eq!(p.layer[0], [6, 16, 1536, 1632]);
        assert_eq!(p.layer[1], [16, 4, 1648, 1712]);
        assert_eq!(p.dims, [3, 2, 256, 2]);
    }
}
