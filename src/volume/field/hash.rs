//! The hash-grid + MLP field (seed 000 HP7; Instant-NGP's multiresolution
//! hash encoding, Müller et al. 2022): density and colour from one network.
//!
//! ## Encoding
//!
//! `L` levels of `F` features each, one table of `T = 2^log2_table` entries
//! per level. Level `l` has resolution `N_l = floor(N_min b^l)` with the
//! geometric growth factor `b = exp((ln N_max - ln N_min) / (L - 1))` (1 for
//! `L = 1`). A world point `x` maps to `p = clamp((x - min) / (max - min),
//! 0, 1)` per axis and to `u = p N_l` on level `l`; the cell's base corner is
//! `i0 = min(floor(u), N_l - 1)`, the fraction `f = u - i0`. Corner
//! `(i, j, k)` (each in `0..=N_l`) indexes the level's table
//! - densely, `i + (N_l + 1) (j + (N_l + 1) k)`, when `(N_l + 1)^3 <= T`;
//! - else by the spatial hash `(i * 1) xor (j * 2654435761) xor (k *
//!   805459861)` in wrapping u32 arithmetic, modulo `T` (collisions share an
//!   entry).
//!
//! The level's features are the trilinear blend over corners `d = 0..8`
//! (bit `a` of `d` = offset on axis `a`), weights `prod_a (f_a or 1 - f_a)`
//! multiplied x, y, z, corners summed in order `d = 0..8`. Levels are
//! concatenated level-major: input `h[l F + c]`.
//!
//! ## Network
//!
//! Layers `z = W h + b` (`W` row-major (out, in), each output summed as
//! `b_o + W_o0 h_0 + W_o1 h_1 + ...` in index order: a fixed matvec order,
//! so results are bit-reproducible), ReLU after every hidden layer (widths
//! 16..=64, one to three hidden layers), four outputs: `sigma =
//! softplus(z_0)` (or `relu(z_0)`, `density: relu`, which can be exactly 0
//! and so lets the occupancy grid skip), `rgb = sigmoid(z_1..3)`.
//!
//! ## Parameters
//!
//! One flat vector, the order of [`HashMlpDesc::flat`]: the tables (L, T, F)
//! then per layer `W` then `b`. Gradients (`diff/`) come in the same order.

use crate::error::{Error, Result};
use crate::real::Real;

/// The spatial-hash primes (Instant-NGP).
pub const PRIMES: [u32; 3] = [1, 2654435761, 805459861];

/// Widest layer input or output accepted (stack buffers of the hot loop).
pub const MAX_WIDTH: usize = 64;

/// Most hidden layers accepted.
pub const MAX_HIDDEN: usize = 3;

/// Density activation of output 0.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum DensityAct {
    Softplus,
    Relu,
}

/// The encoding's hyper-parameters.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct HashConfig {
    pub levels: usize,
    pub features: usize,
    pub log2_table: u32,
    pub n_min: u32,
    pub n_max: u32,
}

impl HashConfig {
    pub fn table_size(&self) -> usize {
        1usize << self.log2_table
    }

    /// Geometric growth factor `b` between levels.
    pub fn growth(&self) -> f64 {
        if self.levels <= 1 {
            1.0
        } else {
            (((self.n_max as f64).ln() - (self.n_min as f64).ln()) / (self.levels - 1) as f64).exp()
        }
    }

    /// `N_l = floor(N_min b^l + 1e-9)` (the 1e-9 keeps `N_{L-1} = N_max`
    /// where `b^l` rounds just below an integer ratio).
    pub fn resolution(&self, l: usize) -> u32 {
        ((self.n_min as f64 * self.growth().powi(l as i32) + 1e-9).floor() as u32).max(1)
    }

    /// Whether level `l` is indexed densely (its grid fits the table).
    pub fn dense(&self, l: usize) -> bool {
        let n = self.resolution(l) as u64 + 1;
        n * n * n <= self.table_size() as u64
    }

    /// Length of the encoding (network input).
    pub fn width(&self) -> usize {
        self.levels * self.features
    }

    /// Entries of all tables together.
    pub fn table_len(&self) -> usize {
        self.levels * self.table_size() * self.features
    }

    /// Checks the ranges; `at` names the scene key.
    pub fn validate(&self, at: &str) -> Result<()> {
        let bad = |k: &str, m: String| Err(Error::invalid(format!("{at}.{k}"), m));
        if !(1..=16).contains(&self.levels) {
            return bad("levels", format!("{} is not in 1..=16", self.levels));
        }
        if !(1..=8).contains(&self.features) {
            return bad("features", format!("{} is not in 1..=8", self.features));
        }
        if self.width() > MAX_WIDTH {
            return bad(
                "features",
                format!("levels x features = {} is over {MAX_WIDTH}", self.width()),
            );
        }
        if !(4..=22).contains(&self.log2_table) {
            return bad(
                "log2_table",
                format!("{} is not in 4..=22", self.log2_table),
            );
        }
        if self.n_min < 1 || self.n_max < self.n_min || self.n_max > 1 << 16 {
            return bad(
                "n_min",
                format!(
                    "need 1 <= n_min <= n_max <= 65536, got {} and {}",
                    self.n_min, self.n_max
                ),
            );
        }
        Ok(())
    }
}

/// One dense layer, f64: `w` row-major (out, inp).
#[derive(Clone, Debug, PartialEq)]
pub struct LayerDesc {
    pub out: usize,
    pub inp: usize,
    pub w: Vec<f64>,
    pub b: Vec<f64>,
}

/// The field as described (f64 parameters).
#[derive(Clone, Debug, PartialEq)]
pub struct HashMlpDesc {
    pub cfg: HashConfig,
    pub density: DensityAct,
    /// The world box the encoding spans.
    pub bmin: [f64; 3],
    pub bmax: [f64; 3],
    /// (L, T, F) in C order.
    pub table: Vec<f64>,
    pub layers: Vec<LayerDesc>,
}

impl HashMlpDesc {
    /// A seeded initialisation: table entries uniform in `[-table_scale,
    /// table_scale]` from `rand(seed, index, 0, 0)`; layer `q` weights
    /// uniform in `[-sqrt(6 / in), sqrt(6 / in)]` (He) from `rand(seed,
    /// index, q + 1, 0)`; biases 0 except the density bias `density_bias`.
    #[allow(clippy::too_many_arguments)]
    pub fn init(
        cfg: HashConfig,
        density: DensityAct,
        hidden: &[usize],
        bmin: [f64; 3],
        bmax: [f64; 3],
        seed: u32,
        table_scale: f64,
        density_bias: f64,
    ) -> HashMlpDesc {
        use crate::rng::rand_f64;
        let table = (0..cfg.table_len())
            .map(|i| (2.0 * rand_f64(seed, i as u32, 0, 0) - 1.0) * table_scale)
            .collect();
        let mut widths = vec![cfg.width()];
        widths.extend_from_slice(hidden);
        widths.push(4);
        let layers = (0..widths.len() - 1)
            .map(|q| {
                let (inp, out) = (widths[q], widths[q + 1]);
                let lim = (6.0 / inp as f64).sqrt();
                let w = (0..out * inp)
                    .map(|i| (2.0 * rand_f64(seed, i as u32, q as u32 + 1, 0) - 1.0) * lim)
                    .collect();
                let mut b = vec![0.0; out];
                if q + 2 == widths.len() {
                    b[0] = density_bias;
                }
                LayerDesc { out, inp, w, b }
            })
            .collect();
        HashMlpDesc {
            cfg,
            density,
            bmin,
            bmax,
            table,
            layers,
        }
    }

    /// Checks shapes, widths and values; `at` names the source (file or key).
    pub fn validate(&self, at: &str) -> Result<()> {
        self.cfg.validate(at)?;
        if self.table.len() != self.cfg.table_len() {
            return Err(Error::invalid(
                format!("{at}.table"),
                format!(
                    "{} entries, need levels x 2^log2_table x features = {}",
                    self.table.len(),
                    self.cfg.table_len()
                ),
            ));
        }
        if let Some((i, v)) = self.table.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(Error::invalid(
                format!("{at}.table"),
                format!("value {v} at flat index {i} is not finite"),
            ));
        }
        let nl = self.layers.len();
        if !(2..=MAX_HIDDEN + 1).contains(&nl) {
            return Err(Error::invalid(
                format!("{at}.hidden"),
                format!(
                    "need 1..={MAX_HIDDEN} hidden layers, got {}",
                    nl.saturating_sub(1)
                ),
            ));
        }
        let mut inp = self.cfg.width();
        for (q, l) in self.layers.iter().enumerate() {
            let want_out = if q + 1 == nl { 4 } else { l.out };
            if q + 1 < nl && !(16..=MAX_WIDTH).contains(&l.out) {
                return Err(Error::invalid(
                    format!("{at}.layer {q}"),
                    format!("hidden width {} is not in 16..={MAX_WIDTH}", l.out),
                ));
            }
            if l.inp != inp || l.out != want_out || l.w.len() != l.out * l.inp || l.b.len() != l.out
            {
                return Err(Error::invalid(
                    format!("{at}.layer {q}"),
                    format!(
                        "shape ({}, {}) with {} weights and {} biases; need ({want_out}, {inp})",
                        l.out,
                        l.inp,
                        l.w.len(),
                        l.b.len()
                    ),
                ));
            }
            if let Some((i, v)) =
                l.w.iter()
                    .chain(&l.b)
                    .enumerate()
                    .find(|(_, v)| !v.is_finite())
            {
                return Err(Error::invalid(
                    format!("{at}.layer {q}"),
                    format!("value {v} at flat index {i} (weights, then biases) is not finite"),
                ));
            }
            inp = l.out;
        }
        if (0..3).any(|a| {
            !(self.bmin[a].is_finite() && self.bmax[a].is_finite() && self.bmin[a] < self.bmax[a])
        }) {
            return Err(Error::invalid(
                at,
                "the encoding box is empty or not finite",
            ));
        }
        Ok(())
    }

    /// Number of parameters (the flat vector's length).
    pub fn param_count(&self) -> usize {
        self.table.len()
            + self
                .layers
                .iter()
                .map(|l| l.w.len() + l.b.len())
                .sum::<usize>()
    }

    /// All parameters in the flat order of the module doc.
    pub fn flat(&self) -> Vec<f64> {
        let mut v = self.table.clone();
        for l in &self.layers {
            v.extend_from_slice(&l.w);
            v.extend_from_slice(&l.b);
        }
        v
    }

    /// Replaces every parameter from a flat vector (same order as [`flat`](Self::flat)).
    pub fn set_flat(&mut self, v: &[f64]) {
        let mut o = self.table.len();
        self.table.copy_from_slice(&v[..o]);
        for l in &mut self.layers {
            let (nw, nb) = (l.w.len(), l.b.len());
            l.w.copy_from_slice(&v[o..o + nw]);
            l.b.copy_from_slice(&v[o + nw..o + nw + nb]);
            o += nw + nb;
        }
    }

    /// Whether sigma can be non-zero in [lo, hi]: interval bounds of the
    /// features (min / max of every table entry a corner of a touched cell
    /// reads) propagated through the network. Conservative; with
    /// `softplus` density is never 0, so every cell is occupied.
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        if self.density == DensityAct::Softplus {
            return true;
        }
        let cfg = &self.cfg;
        let (t, nf) = (cfg.table_size(), cfg.features);
        let mut hl = Vec::with_capacity(cfg.width());
        let mut hh = Vec::with_capacity(cfg.width());
        for l in 0..cfg.levels {
            let n = cfg.resolution(l) as f64;
            let mut r = [(0usize, 0usize); 3];
            for a in 0..3 {
                let ext = self.bmax[a] - self.bmin[a];
                let p0 = ((lo[a] - self.bmin[a]) / ext).clamp(0.0, 1.0) * n;
                let p1 = ((hi[a] - self.bmin[a]) / ext).clamp(0.0, 1.0) * n;
                r[a] = (
                    p0.floor().min(n - 1.0) as usize,
                    (p1.floor() + 1.0).min(n) as usize,
                );
            }
            let (mut mn, mut mx) = (vec![f64::INFINITY; nf], vec![f64::NEG_INFINITY; nf]);
            for k in r[2].0..=r[2].1 {
                for j in r[1].0..=r[1].1 {
                    for i in r[0].0..=r[0].1 {
                        let e = corner_index(cfg, l, [i as u32, j as u32, k as u32]);
                        for c in 0..nf {
                            let v = self.table[(l * t + e) * nf + c];
                            mn[c] = mn[c].min(v);
                            mx[c] = mx[c].max(v);
                        }
                    }
                }
            }
            hl.extend(mn);
            hh.extend(mx);
        }
        let nl = self.layers.len();
        for (q, layer) in self.layers.iter().enumerate() {
            let (mut zl, mut zh) = (layer.b.clone(), layer.b.clone());
            for o in 0..layer.out {
                for i in 0..layer.inp {
                    let w = layer.w[o * layer.inp + i];
                    let (a, b) = (w * hl[i], w * hh[i]);
                    zl[o] += a.min(b);
                    zh[o] += a.max(b);
                }
            }
            if q + 1 == nl {
                return zh[0] > 0.0;
            }
            hl = zl.iter().map(|v| v.max(0.0)).collect();
            hh = zh.iter().map(|v| v.max(0.0)).collect();
        }
        true
    }
}

/// Table entry of corner `c` on level `l` (dense or hashed; module doc).
#[inline(always)]
pub fn corner_index(cfg: &HashConfig, l: usize, c: [u32; 3]) -> usize {
    let n1 = cfg.resolution(l) + 1;
    if cfg.dense(l) {
        (c[0] + n1 * (c[1] + n1 * c[2])) as usize
    } else {
        let h = c[0].wrapping_mul(PRIMES[0])
            ^ c[1].wrapping_mul(PRIMES[1])
            ^ c[2].wrapping_mul(PRIMES[2]);
        (h as usize) & (cfg.table_size() - 1)
    }
}

/// One level's precomputed geometry.
#[derive(Clone, Copy, Debug)]
pub struct Level<F> {
    pub n: F,
    /// `N_l - 1` as an integer (the top base corner).
    pub top: u32,
    pub n1: u32,
    pub dense: bool,
}

/// A layer in precision `F`.
#[derive(Clone, Debug)]
pub struct Layer<F> {
    pub out: usize,
    pub inp: usize,
    pub w: Vec<F>,
    pub b: Vec<F>,
}

/// The field in precision `F`.
#[derive(Clone, Debug)]
pub struct HashMlp<F> {
    pub levels: Vec<Level<F>>,
    pub features: usize,
    pub tsize: usize,
    pub density: DensityAct,
    pub bmin: [F; 3],
    /// `1 / (max - min)` per axis.
    pub inv_ext: [F; 3],
    pub table: Vec<F>,
    pub layers: Vec<Layer<F>>,
}

/// The encoding of one point: per level the table rows of the eight
/// corners and their weights, and d(weight)/dx (for the position gradient).
#[derive(Clone, Copy, Debug)]
pub struct Corners<F> {
    /// Row (`l T + entry`) of corner `d` of level `l`: `rows[l][d]`.
    pub rows: [[u32; 8]; 16],
    pub w: [[F; 8]; 16],
    /// Fractions per level and axis, and whether the axis is clamped.
    pub f: [[F; 3]; 16],
    pub free: [bool; 3],
}

impl<F: Real> HashMlp<F> {
    pub fn from_desc(d: &HashMlpDesc) -> HashMlp<F> {
        let cfg = &d.cfg;
        HashMlp {
            levels: (0..cfg.levels)
                .map(|l| {
                    let n = cfg.resolution(l);
                    Level {
                        n: F::of(n as f64),
                        top: n - 1,
                        n1: n + 1,
                        dense: cfg.dense(l),
                    }
                })
                .collect(),
            features: cfg.features,
            tsize: cfg.table_size(),
            density: d.density,
            bmin: d.bmin.map(F::of),
            inv_ext: [0, 1, 2].map(|a| F::of(1.0 / (d.bmax[a] - d.bmin[a]))),
            table: d.table.iter().map(|&v| F::of(v)).collect(),
            layers: d
                .layers
                .iter()
                .map(|l| Layer {
                    out: l.out,
                    inp: l.inp,
                    w: l.w.iter().map(|&v| F::of(v)).collect(),
                    b: l.b.iter().map(|&v| F::of(v)).collect(),
                })
                .collect(),
        }
    }

    /// Corner rows and weights of `x` on every level (module doc).
    #[inline(always)]
    pub fn corners(&self, x: [F; 3]) -> Corners<F> {
        let mut c = Corners {
            rows: [[0; 8]; 16],
            w: [[F::zero(); 8]; 16],
            f: [[F::zero(); 3]; 16],
            free: [true; 3],
        };
        let mut p = [F::zero(); 3];
        for a in 0..3 {
            let v = (x[a] - self.bmin[a]) * self.inv_ext[a];
            c.free[a] = v >= F::zero() && v <= F::one();
            p[a] = super::fmin(super::fmax(v, F::zero()), F::one());
        }
        let one = F::one();
        for (l, lv) in self.levels.iter().enumerate() {
            let mut i0 = [0u32; 3];
            for a in 0..3 {
                let u = p[a] * lv.n;
                let (fl, _) = super::floor_i64(u);
                let b = (fl.max(0) as u32).min(lv.top);
                i0[a] = b;
                c.f[l][a] = u - F::of(b as f64);
            }
            let f = c.f[l];
            let base = (l * self.tsize) as u32;
            for d in 0..8 {
                let o = [d & 1, d >> 1 & 1, d >> 2 & 1].map(|v| v as u32);
                let ci = [i0[0] + o[0], i0[1] + o[1], i0[2] + o[2]];
                let e = if lv.dense {
                    ci[0] + lv.n1 * (ci[1] + lv.n1 * ci[2])
                } else {
                    (ci[0].wrapping_mul(PRIMES[0])
                        ^ ci[1].wrapping_mul(PRIMES[1])
                        ^ ci[2].wrapping_mul(PRIMES[2]))
                        & (self.tsize as u32 - 1)
                };
                c.rows[l][d] = base + e;
                let wx = if o[0] == 1 { f[0] } else { one - f[0] };
                let wy = if o[1] == 1 { f[1] } else { one - f[1] };
                let wz = if o[2] == 1 { f[2] } else { one - f[2] };
                c.w[l][d] = wx * wy * wz;
            }
        }
        c
    }

    /// The encoding `h` (length `L F`) of the corners.
    #[inline(always)]
    pub fn encode(&self, c: &Corners<F>, h: &mut [F; MAX_WIDTH]) {
        let nf = self.features;
        for l in 0..self.levels.len() {
            for q in 0..nf {
                let mut s = F::zero();
                for d in 0..8 {
                    s += c.w[l][d] * self.table[c.rows[l][d] as usize * nf + q];
                }
                h[l * nf + q] = s;
            }
        }
    }

    /// Runs the network on `h`, keeping every layer's pre-activation in
    /// `z[q]`; returns the four raw outputs.
    #[inline(always)]
    #[allow(clippy::needless_range_loop)] // index loops state the fixed matvec order
    pub fn mlp(&self, h: &[F; MAX_WIDTH], z: &mut [[F; MAX_WIDTH]; MAX_HIDDEN + 1]) -> [F; 4] {
        let mut cur = *h;
        let nl = self.layers.len();
        for (q, layer) in self.layers.iter().enumerate() {
            for o in 0..layer.out {
                let row = &layer.w[o * layer.inp..(o + 1) * layer.inp];
                let mut s = layer.b[o];
                for (w, v) in row.iter().zip(&cur[..layer.inp]) {
                    s += *w * *v;
                }
                z[q][o] = s;
            }
            if q + 1 < nl {
                for o in 0..layer.out {
                    cur[o] = super::fmax(z[q][o], F::zero());
                }
            }
        }
        let zl = &z[nl - 1];
        [zl[0], zl[1], zl[2], zl[3]]
    }

    /// `(sigma, rgb)` of raw outputs.
    #[inline(always)]
    pub fn head(&self, o: [F; 4]) -> (F, [F; 3]) {
        let sigma = match self.density {
            DensityAct::Softplus => softplus(o[0]),
            DensityAct::Relu => super::fmax(o[0], F::zero()),
        };
        (sigma, [sigmoid(o[1]), sigmoid(o[2]), sigmoid(o[3])])
    }

    /// `(sigma, rgb)` at world point `x`.
    #[inline]
    pub fn query(&self, x: [F; 3]) -> (F, [F; 3]) {
        let c = self.corners(x);
        let mut h = [F::zero(); MAX_WIDTH];
        self.encode(&c, &mut h);
        let mut z = [[F::zero(); MAX_WIDTH]; MAX_HIDDEN + 1];
        self.head(self.mlp(&h, &mut z))
    }

    /// Number of parameters (the flat order of the module doc).
    pub fn param_count(&self) -> usize {
        self.table.len()
            + self
                .layers
                .iter()
                .map(|l| l.w.len() + l.b.len())
                .sum::<usize>()
    }
}

/// `ln(1 + e^x)`, stable for large `|x|`.
#[inline(always)]
pub fn softplus<F: Real>(x: F) -> F {
    super::fmax(x, F::zero()) + (-x.abs()).exp().ln_1p()
}

/// `1 / (1 + e^-x)`.
#[inline(always)]
pub fn sigmoid<F: Real>(x: F) -> F {
    F::one() / (F::one() + (-x).exp())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn cfg() -> HashConfig {
        HashConfig {
            levels: 4,
            features: 2,
            log2_table: 8,
            n_min: 2,
            n_max: 16,
        }
    }

    #[test]
    fn resolutions_grow_geometrically_from_n_min_to_n_max() {
        let c = cfg();
        assert_eq!(
            (0..4).map(|l| c.resolution(l)).collect::<Vec<_>>(),
            [2, 4, 8, 16]
        );
        // (2+1)^3 = 27 and (4+1)^3 = 125 fit 256 entries; 9^3 does not.
        assert_eq!(
            (0..4).map(|l| c.dense(l)).collect::<Vec<_>>(),
            [true, true, false, false]
        );
    }

    #[test]
    fn corner_weights_sum_to_one_and_nodes_read_one_entry() {
        let d = HashMlpDesc::init(
            cfg(),
            DensityAct::Softplus,
            &[16],
            [-1.0; 3],
            [1.0; 3],
            3,
            0.5,
            0.0,
        );
        let m: HashMlp<f64> = HashMlp::from_desc(&d);
        let c = m.corners([0.13, -0.4, 0.77]);
        for l in 0..4 {
            assert!((c.w[l].iter().sum::<f64>() - 1.0).abs() < 1e-14);
        }
        // x = 0 is node 1 of level 0 (N = 2) on every axis: weight 1 on corner 0.
        let c = m.corners([0.0; 3]);
        assert_eq!(c.w[0][0], 1.0);
        assert_eq!(c.rows[0][0] as usize, corner_index(&d.cfg, 0, [1, 1, 1]));
    }

    #[test]
    fn softplus_and_sigmoid_are_finite_at_extremes() {
        assert_eq!(softplus(1e4f32), 1e4);
        assert_eq!(softplus(-1e4f32), 0.0);
        assert!((softplus(0.0f64) - 2f64.ln()).abs() < 1e-15);
        assert_eq!(sigmoid(-1e4f32), 0.0);
        assert_eq!(sigmoid(1e4f32), 1.0);
    }

    #[test]
    fn relu_density_occupancy_is_conservative() {
        let mut d = HashMlpDesc::init(
            cfg(),
            DensityAct::Relu,
            &[16],
            [-1.0; 3],
            [1.0; 3],
            5,
            1.0,
            -0.3,
        );
        let m: HashMlp<f64> = HashMlp::from_desc(&d);
        for i in 0..8 {
            for j in 0..8 {
                let lo = [-1.0 + 0.25 * i as f64, -1.0 + 0.25 * j as f64, -0.2];
                let hi = [lo[0] + 0.25, lo[1] + 0.25, 0.05];
                if !d.may_be_nonzero(lo, hi) {
                    for s in 0..64u32 {
                        let x = [0, 1, 2].map(|a| {
                            lo[a]
                                + (hi[a] - lo[a]) * crate::rng::rand_f64(1, s, i * 8 + j, a as u32)
                        });
                        assert_eq!(m.query(x).0, 0.0, "{x:?}");
                    }
                }
            }
        }
        // The bound must leave something to skip for a negative density bias.
        d.layers[1].b[0] = -50.0;
        assert!(!d.may_be_nonzero([-1.0; 3], [1.0; 3]));
    }
}
