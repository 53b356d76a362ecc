//! Referee of the hash-grid + MLP field (`field/hash.rs`): a direct,
//! unoptimised f64 implementation written from the definition (Müller et
//! al. 2022, as the module doc of `field/hash.rs` states it), sharing only
//! the parameter description. It never calls `field::hash`: resolutions by
//! `powf`, the dense test on `u64`, the hash as a `u64` product reduced
//! `mod 2^32` then `mod T`, corners by nested loops, the network with
//! `Vec`s.

use crate::volume::field::hash::{DensityAct, HashMlpDesc};

/// Resolution of level `l`: `floor(N_min (N_max / N_min)^(l / (L - 1)) + 1e-9)`.
pub fn resolution(d: &HashMlpDesc, l: usize) -> u64 {
    let c = &d.cfg;
    if c.levels == 1 {
        return c.n_min.max(1) as u64;
    }
    let ratio = c.n_max as f64 / c.n_min as f64;
    let v = c.n_min as f64 * ratio.powf(1.0 / (c.levels - 1) as f64).powf(l as f64);
    ((v + 1e-9).floor() as u64).max(1)
}

/// The table entry of integer corner `(i, j, k)` on level `l`.
#[allow(clippy::identity_op)] // `i * 1`: the first prime, written as defined
pub fn entry(d: &HashMlpDesc, l: usize, i: u64, j: u64, k: u64) -> u64 {
    let t = 1u64 << d.cfg.log2_table;
    let n1 = resolution(d, l) + 1;
    if n1 * n1 * n1 <= t {
        i + n1 * j + n1 * n1 * k
    } else {
        let h = (i * 1) ^ (j * 2654435761) ^ (k * 805459861);
        (h % (1u64 << 32)) % t
    }
}

/// The encoding of `x`: `L F` values, level-major.
pub fn encode(d: &HashMlpDesc, x: [f64; 3]) -> Vec<f64> {
    let nf = d.cfg.features;
    let t = 1usize << d.cfg.log2_table;
    let mut out = vec![0.0; d.cfg.levels * nf];
    for l in 0..d.cfg.levels {
        let n = resolution(d, l);
        let mut base = [0u64; 3];
        let mut frac = [0.0; 3];
        for a in 0..3 {
            let p = ((x[a] - d.bmin[a]) / (d.bmax[a] - d.bmin[a])).clamp(0.0, 1.0);
            let u = p * n as f64;
            let b = (u.floor() as u64).min(n - 1);
            base[a] = b;
            frac[a] = u - b as f64;
        }
        for dk in 0..2u64 {
            for dj in 0..2u64 {
                for di in 0..2u64 {
                    let wgt = |o: u64, f: f64| if o == 1 { f } else { 1.0 - f };
                    let w = wgt(di, frac[0]) * wgt(dj, frac[1]) * wgt(dk, frac[2]);
                    let e = entry(d, l, base[0] + di, base[1] + dj, base[2] + dk) as usize;
                    for q in 0..nf {
                        out[l * nf + q] += w * d.table[(l * t + e) * nf + q];
                    }
                }
            }
        }
    }
    out
}

/// The network's four raw outputs for encoding `h`.
#[allow(clippy::needless_range_loop)] // plain index loops, on purpose
pub fn mlp(d: &HashMlpDesc, h: &[f64]) -> Vec<f64> {
    let mut cur = h.to_vec();
    for (q, layer) in d.layers.iter().enumerate() {
        let mut next = Vec::with_capacity(layer.out);
        for o in 0..layer.out {
            let mut s = layer.b[o];
            for i in 0..layer.inp {
                s += layer.w[o * layer.inp + i] * cur[i];
            }
            next.push(if q + 1 < d.layers.len() {
                s.max(0.0)
            } else {
                s
            });
        }
        cur = next;
    }
    cur
}

/// `(sigma, rgb)` at `x`.
pub fn query(d: &HashMlpDesc, x: [f64; 3]) -> (f64, [f64; 3]) {
    let o = mlp(d, &encode(d, x));
    let sigma = match d.density {
        DensityAct::Softplus if o[0] > 30.0 => o[0],
        DensityAct::Softplus => (1.0 + o[0].exp()).ln(),
        DensityAct::Relu => o[0].max(0.0),
    };
    let sig = |v: f64| 1.0 / (1.0 + (-v).exp());
    (sigma, [sig(o[1]), sig(o[2]), sig(o[3])])
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::field::hash::{DensityAct, HashConfig, HashMlp, HashMlpDesc, MAX_WIDTH};

    #[test]
    fn the_referee_and_the_field_agree_on_every_level_with_collisions() {
        let cfg = HashConfig {
            levels: 6,
            features: 2,
            log2_table: 7,
            n_min: 2,
            n_max: 40,
        };
        let d = HashMlpDesc::init(
            cfg,
            DensityAct::Softplus,
            &[16],
            [-1.0; 3],
            [1.0; 3],
            2,
            1.0,
            0.0,
        );
        let m: HashMlp<f64> = HashMlp::from_desc(&d);
        for s in 0..500u32 {
            let x = [0, 1, 2].map(|a| crate::rng::rand_f64(4, s, 0, a) * 2.4 - 1.2);
            let mut h = [0.0; MAX_WIDTH];
            m.encode(&m.corners(x), &mut h);
            let r = encode(&d, x);
            for (i, v) in r.iter().enumerate() {
                assert!((h[i] - v).abs() <= 1e-13, "{x:?} {i}");
            }
            let (a, b) = (m.query(x), query(&d, x));
            assert!((a.0 - b.0).abs() <= 1e-12 * (1.0 + b.0));
        }
    }
}
