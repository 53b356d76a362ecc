//! Back-propagation through the hash-grid + MLP field (`hash.rs`): from
//! `dL/d(sigma, r, g, b)` at one point to `dL/d(parameters)` (the flat order
//! of `HashMlpDesc::flat`) and `dL/dx` (for the camera gradient).
//!
//! Subgradients: ReLU and `relu` density pass the gradient where the
//! pre-activation is `> 0`; a clamped coordinate (outside the encoding box)
//! has `dx = 0`. The loops run in fixed index order (bit-reproducible).

use crate::real::Real;

use super::hash::{sigmoid, Corners, DensityAct, HashMlp, MAX_HIDDEN, MAX_WIDTH};

impl<F: Real> HashMlp<F> {
    /// Back-propagates `g = dL/d(sigma, rgb)` at `x`: adds `dL/dparams`
    /// into `dp` (flat order) when given; returns `dL/dx`.
    #[allow(clippy::needless_range_loop)] // index loops mirror the forward's order
    pub fn backward(&self, x: [F; 3], g: [F; 4], dp: Option<&mut [F]>) -> [F; 3] {
        let c = self.corners(x);
        let mut h = [F::zero(); MAX_WIDTH];
        self.encode(&c, &mut h);
        let mut z = [[F::zero(); MAX_WIDTH]; MAX_HIDDEN + 1];
        let o = self.mlp(&h, &mut z);
        let one = F::one();
        let mut dz = [F::zero(); MAX_WIDTH];
        dz[0] = match self.density {
            DensityAct::Softplus => g[0] * sigmoid(o[0]),
            DensityAct::Relu => {
                if o[0] > F::zero() {
                    g[0]
                } else {
                    F::zero()
                }
            }
        };
        for ch in 1..4 {
            let s = sigmoid(o[ch]);
            dz[ch] = g[ch] * s * (one - s);
        }
        let mut dp = dp;
        let nl = self.layers.len();
        // Flat offsets of each layer's weights.
        let mut off = [0usize; MAX_HIDDEN + 1];
        let mut acc = self.table.len();
        for (q, l) in self.layers.iter().enumerate() {
            off[q] = acc;
            acc += l.w.len() + l.b.len();
        }
        let mut dh = [F::zero(); MAX_WIDTH];
        for q in (0..nl).rev() {
            let layer = &self.layers[q];
            let mut a = [F::zero(); MAX_WIDTH];
            if q == 0 {
                a = h;
            } else {
                for i in 0..layer.inp {
                    a[i] = super::fmax(z[q - 1][i], F::zero());
                }
            }
            if let Some(dp) = dp.as_deref_mut() {
                let (wo, bo) = (off[q], off[q] + layer.w.len());
                for o in 0..layer.out {
                    let row = &mut dp[wo + o * layer.inp..wo + (o + 1) * layer.inp];
                    for (d, ai) in row.iter_mut().zip(&a[..layer.inp]) {
                        *d += dz[o] * *ai;
                    }
                    dp[bo + o] += dz[o];
                }
            }
            dh = [F::zero(); MAX_WIDTH];
            for o in 0..layer.out {
                let row = &layer.w[o * layer.inp..(o + 1) * layer.inp];
                for (d, w) in dh[..layer.inp].iter_mut().zip(row) {
                    *d += *w * dz[o];
                }
            }
            if q > 0 {
                dz = [F::zero(); MAX_WIDTH];
                for i in 0..layer.inp {
                    if z[q - 1][i] > F::zero() {
                        dz[i] = dh[i];
                    }
                }
            }
        }
        let nf = self.features;
        if let Some(dp) = dp {
            for l in 0..self.levels.len() {
                for d in 0..8 {
                    let row = c.rows[l][d] as usize * nf;
                    for q in 0..nf {
                        dp[row + q] += c.w[l][d] * dh[l * nf + q];
                    }
                }
            }
        }
        let mut gx = [F::zero(); 3];
        for (l, lv) in self.levels.iter().enumerate() {
            let f = c.f[l];
            for d in 0..8 {
                let row = c.rows[l][d] as usize * nf;
                let mut v = F::zero();
                for q in 0..nf {
                    v += self.table[row + q] * dh[l * nf + q];
                }
                for (a, gxa) in gx.iter_mut().enumerate() {
                    if !c.free[a] {
                        continue;
                    }
                    let mut dw = if d >> a & 1 == 1 { one } else { -one };
                    for b in 0..3 {
                        if b != a {
                            dw *= if d >> b & 1 == 1 { f[b] } else { one - f[b] };
                        }
                    }
                    *gxa += v * dw * lv.n * self.inv_ext[a];
                }
            }
        }
        gx
    }
}

/// A point where the network sits on ReLU kinks ([`HashMlp::near_kink`]):
/// its corners and each such unit, `(layer, unit)` (the density output is
/// the last layer's unit 0).
#[derive(Clone, Debug)]
pub struct Kink<F> {
    pub corners: Corners<F>,
    pub units: Vec<(usize, usize)>,
}

impl<F: Real> HashMlp<F> {
    /// Whether the network sits within `margin` of a ReLU kink at `x`: a
    /// hidden pre-activation (or, with `relu` density, the density output)
    /// within `margin` times the sum of its terms' magnitudes of 0. There
    /// the backward takes one side of a jump, and a backend whose sample
    /// position differs by an ulp may take the other: an NVIDIA H100 put
    /// z = +1.165e-6 (6.7e-7 of its terms) below 0 on one sample of
    /// vol_hash_init.yaml and so dropped that sample's whole gradient
    /// through the unit from every table value it touches. Returns the
    /// point's corners (the table rows whose gradients the kink moves) and
    /// every unit within the margin (whose fan-in and bias gradients move
    /// too).
    #[allow(clippy::needless_range_loop)] // index loops mirror the forward's order
    pub fn near_kink(&self, x: [F; 3], margin: F) -> Option<Kink<F>> {
        let c = self.corners(x);
        let mut h = [F::zero(); MAX_WIDTH];
        self.encode(&c, &mut h);
        let mut z = [[F::zero(); MAX_WIDTH]; MAX_HIDDEN + 1];
        self.mlp(&h, &mut z);
        let nl = self.layers.len();
        let mut kinked = Vec::new();
        for (q, layer) in self.layers.iter().enumerate() {
            let last = q + 1 == nl;
            let units = match (last, self.density) {
                (false, _) => layer.out,
                (true, DensityAct::Relu) => 1,
                (true, DensityAct::Softplus) => 0,
            };
            for o in 0..units {
                let row = &layer.w[o * layer.inp..(o + 1) * layer.inp];
                let mut mag = layer.b[o].abs();
                for (k, w) in row.iter().enumerate() {
                    let a = if q == 0 {
                        h[k]
                    } else {
                        super::fmax(z[q - 1][k], F::zero())
                    };
                    mag += (*w * a).abs();
                }
                if z[q][o].abs() <= margin * mag {
                    kinked.push((q, o));
                }
            }
        }
        (!kinked.is_empty()).then_some(Kink {
            corners: c,
            units: kinked,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::super::hash::{DensityAct, HashConfig, HashMlp, HashMlpDesc};

    fn desc(act: DensityAct) -> HashMlpDesc {
        let cfg = HashConfig {
            levels: 3,
            features: 2,
            log2_table: 6,
            n_min: 2,
            n_max: 9,
        };
        HashMlpDesc::init(cfg, act, &[16, 16], [-1.0; 3], [1.0; 3], 7, 0.8, 0.2)
    }

    fn loss(d: &HashMlpDesc, x: [f64; 3], g: [f64; 4]) -> f64 {
        let (s, c) = HashMlp::<f64>::from_desc(d).query(x);
        g[0] * s + g[1] * c[0] + g[2] * c[1] + g[3] * c[2]
    }

    #[test]
    fn near_kink_flags_a_point_whose_hidden_unit_is_at_zero() {
        let d = desc(DensityAct::Softplus);
        let mut m: HashMlp<f64> = HashMlp::from_desc(&d);
        let x = [0.31, -0.47, 0.12];
        assert!(m.near_kink(x, 1e-6).is_none());
        // Move unit 3's bias so its pre-activation at x is exactly 0.
        let mut z = [[0.0; super::MAX_WIDTH]; super::MAX_HIDDEN + 1];
        let mut h = [0.0; super::MAX_WIDTH];
        m.encode(&m.corners(x), &mut h);
        m.mlp(&h, &mut z);
        m.layers[0].b[3] -= z[0][3];
        let k = m.near_kink(x, 1e-6).expect("unit 3 sits on its kink");
        assert_eq!(k.corners.rows, m.corners(x).rows);
        assert_eq!(k.units, [(0, 3)]);
        // Unit 5 on its kink too: both reported.
        m.layers[0].b[5] -= z[0][5];
        assert_eq!(m.near_kink(x, 1e-6).unwrap().units, [(0, 3), (0, 5)]);
        m.layers[0].b[5] += z[0][5];
        // Unit 3 moved 1e-3 of its terms' magnitudes off the kink: not flagged.
        m.layers[0].b[3] += 1e-3;
        assert!(m.near_kink(x, 1e-6).is_none());
    }

    #[test]
    fn parameter_and_position_gradients_match_central_differences_f64() {
        for act in [DensityAct::Softplus, DensityAct::Relu] {
            let d = desc(act);
            let m: HashMlp<f64> = HashMlp::from_desc(&d);
            let (x, g) = ([0.31, -0.47, 0.12], [0.7, -0.3, 0.5, 0.9]);
            let mut dp = vec![0.0; m.param_count()];
            let gx = m.backward(x, g, Some(&mut dp));
            let p0 = d.flat();
            let h = 1e-6;
            let mut checked = 0;
            for i in (0..p0.len()).step_by(7) {
                let mut e = d.clone();
                let mut p = p0.clone();
                p[i] += h;
                e.set_flat(&p);
                let lp = loss(&e, x, g);
                p[i] -= 2.0 * h;
                e.set_flat(&p);
                let lm = loss(&e, x, g);
                let fd = (lp - lm) / (2.0 * h);
                assert!(
                    (fd - dp[i]).abs() <= 1e-7 * (1.0 + fd.abs()),
                    "{act:?} param {i}: {} vs {fd}",
                    dp[i]
                );
                checked += (dp[i] != 0.0) as usize;
            }
            assert!(checked > 20, "{checked}");
            for a in 0..3 {
                let (mut xp, mut xm) = (x, x);
                xp[a] += h;
                xm[a] -= h;
                let fd = (loss(&d, xp, g) - loss(&d, xm, g)) / (2.0 * h);
                assert!(
                    (fd - gx[a]).abs() <= 1e-6 * (1.0 + fd.abs()),
                    "{act:?} x{a}: {} vs {fd}",
                    gx[a]
                );
            }
        }
    }
}
