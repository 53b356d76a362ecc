//! The f64 quadrature referee of the forward pass: a plain loop per pixel
//! with the density, colour and trilinear lookups written apart from
//! `volume::field`, `volume::sample` and `volume::integrate` (a test in
//! `referee/mod.rs` holds this file to that).

use crate::error::Result;
use crate::rays::Rays;
use crate::rng::rand_f64;
use crate::tensor::{Outputs, Tensor};
use crate::volume::field::{Analytic, ColorDesc, FieldDesc, GridDesc, Oob};
use crate::volume::sample::{Sampling, TransPath};
use crate::volume::VolumeParams;

/// Density at `x`, from the parameters, written apart from `volume::field`.
pub fn ref_sigma(f: &FieldDesc, x: [f64; 3]) -> f64 {
    match f {
        FieldDesc::HashMlp(h) => super::hash::query(h, x).0,
        FieldDesc::Analytic(Analytic::Constant { s }) => *s,
        FieldDesc::Analytic(Analytic::Slabs {
            axis,
            breaks,
            sigma,
        }) => {
            let v = x[*axis];
            let last = sigma.len() - 1;
            match breaks.iter().rposition(|&b| b <= v) {
                Some(i) if i < last => sigma[i],
                Some(i) if v <= breaks[last + 1] => sigma[i.min(last)],
                _ => 0.0,
            }
        }
        FieldDesc::Analytic(Analytic::Gaussian {
            amplitude,
            mean,
            std,
        }) => {
            let d2: f64 = x.iter().zip(mean).map(|(a, b)| (a - b) * (a - b)).sum();
            amplitude * (-d2 / (2.0 * std * std)).exp()
        }
        FieldDesc::Analytic(Analytic::Shell { centre, r0, r1, s }) => {
            let r = x
                .iter()
                .zip(centre)
                .map(|(a, b)| (a - b) * (a - b))
                .sum::<f64>()
                .sqrt();
            if r >= *r0 && r <= *r1 {
                *s
            } else {
                0.0
            }
        }
        FieldDesc::Analytic(Analytic::Linear { a, g }) => {
            a + g[0] * x[0] + g[1] * x[1] + g[2] * x[2]
        }
        FieldDesc::Grid(g) => ref_grid(g, x, 0),
    }
}

/// Trilinear value of channel `c` (align_corners = True semantics).
pub fn ref_grid(g: &GridDesc, x: [f64; 3], c: usize) -> f64 {
    let [nz, ny, nx] = g.shape;
    let n = [nx, ny, nz];
    let mut lo = [0i64; 3];
    let mut w = [0.0; 3];
    for a in 0..3 {
        let mut u = (x[a] - g.bmin[a]) / (g.bmax[a] - g.bmin[a]) * (n[a] - 1) as f64;
        if g.oob == Oob::Clamp {
            u = u.clamp(0.0, (n[a] - 1) as f64);
        }
        let f = u.floor().min(if g.oob == Oob::Clamp {
            (n[a] - 2) as f64
        } else {
            f64::INFINITY
        });
        lo[a] = f as i64;
        w[a] = u - f;
    }
    let mut v = 0.0;
    for corner in 0..8 {
        let idx = [0, 1, 2].map(|a| lo[a] + (corner >> a & 1) as i64);
        if (0..3).any(|a| idx[a] < 0 || idx[a] >= n[a] as i64) {
            continue;
        }
        let wt: f64 = (0..3)
            .map(|a| {
                if corner >> a & 1 == 1 {
                    w[a]
                } else {
                    1.0 - w[a]
                }
            })
            .product();
        let flat = ((idx[2] as usize * ny + idx[1] as usize) * nx + idx[0] as usize) * g.ch + c;
        v += wt * g.data[flat];
    }
    v
}

/// Colour at `x`; the hash field's colour head needs the density field.
pub fn ref_color(p: &VolumeParams, x: [f64; 3]) -> [f64; 3] {
    match (&p.color, &p.field) {
        (ColorDesc::Constant(v), _) => *v,
        (ColorDesc::Grid(g), _) => [0, 1, 2].map(|k| ref_grid(g, x, k)),
        (ColorDesc::Mlp, FieldDesc::HashMlp(h)) => super::hash::query(h, x).1,
        // Refused by `check_pairing` when the scene is built.
        (ColorDesc::Mlp, _) => [f64::NAN; 3],
    }
}

/// Per pixel: `rgb`, `trans`, `logtrans`, `depth`, `opacity`, `nsamples`, `hit`.
pub struct Quadrature {
    pub rgb: Vec<[f64; 3]>,
    pub trans: Vec<f64>,
    pub logtrans: Vec<f64>,
    pub depth: Vec<f64>,
    pub opacity: Vec<f64>,
    pub nsamples: Vec<i32>,
    pub hit: Vec<u8>,
}

impl Quadrature {
    /// Tensors named as the fields, of image shape `s` (H, W).
    pub fn to_outputs(self, s: &[usize]) -> Result<Outputs> {
        let mut out = Outputs::default();
        out.tensor("rgb", Tensor::real3(s, &self.rgb)?);
        out.tensor("trans", Tensor::real(s, self.trans)?);
        out.tensor("logtrans", Tensor::real(s, self.logtrans)?);
        out.tensor("depth", Tensor::real(s, self.depth)?);
        out.tensor("opacity", Tensor::real(s, self.opacity)?);
        out.tensor("nsamples", Tensor::from_shape_vec(s, self.nsamples)?);
        out.tensor("hit", Tensor::from_shape_vec(s, self.hit)?);
        Ok(out)
    }
}

/// The forward pass of `p` along each of `rays` by midpoint (or stratified)
/// quadrature with step `dt`, `max_steps` and early stop as `p` says.
pub fn quadrature(rays: &Rays<f64>, p: &VolumeParams) -> Quadrature {
    let n = rays.len();
    let (mut rgb, mut trans, mut logt, mut depth, mut opac, mut ns, mut hit) = (
        vec![[0.0; 3]; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0.0; n],
        vec![0i32; n],
        vec![0u8; n],
    );
    for i in 0..n {
        let (o, d, t0, t1) = (rays.o[i], rays.d[i], rays.t0[i], rays.t1[i]);
        let (mut tr, mut lt, mut c, mut dep, mut taken) =
            (1.0f64, 0.0f64, [0.0f64; 3], 0.0f64, 0i32);
        if t1 > t0 {
            hit[i] = 1;
            let mut k: u32 = 0;
            while k < p.max_steps {
                let a = t0 + k as f64 * p.dt;
                if a >= t1 {
                    break;
                }
                if tr < p.early_stop {
                    break;
                }
                let b = (t0 + (k + 1) as f64 * p.dt).min(t1);
                let t = match p.sampling {
                    Sampling::Fixed => 0.5 * (a + b),
                    Sampling::Stratified { seed } => {
                        a + rand_f64(seed, rays.pixel[i], 0, k) * (b - a)
                    }
                };
                let x = [o[0] + t * d[0], o[1] + t * d[1], o[2] + t * d[2]];
                let tau = ref_sigma(&p.field, x) * (b - a);
                let alpha = -(-tau).exp_m1();
                let col = ref_color(p, x);
                for ch in 0..3 {
                    c[ch] += tr * alpha * col[ch];
                }
                dep += tr * alpha * t;
                lt -= tau;
                tr = match p.path {
                    TransPath::Product => tr * (1.0 - alpha),
                    TransPath::Log => lt.exp(),
                };
                taken += 1;
                k += 1;
            }
        }
        rgb[i] = [0, 1, 2].map(|ch| c[ch] + tr * p.background[ch]);
        (trans[i], logt[i], depth[i], opac[i], ns[i]) = (tr, lt, dep, 1.0 - tr, taken);
    }
    Quadrature {
        rgb,
        trans,
        logtrans: logt,
        depth,
        opacity: opac,
        nsamples: ns,
        hit,
    }
}

/// `n` probe points uniform in [-1.5, 1.5]^3 (`rand(seed, i, 0, axis)`),
/// the same on both sides of the grid-probe comparison.
pub fn probe_points(n: u32, seed: u32) -> Vec<[f64; 3]> {
    (0..n)
        .map(|i| [0, 1, 2].map(|d| rand_f64(seed, i, 0, d) * 3.0 - 1.5))
        .collect()
}

/// The referee's probe of `g` at `pts`: `value` (trilinear, channel 0),
/// `inside` (the grid's box) and `beyond` ([`beyond_one_cell`]).
pub fn grid_probe_outputs(pts: &[[f64; 3]], g: &GridDesc) -> Result<Outputs> {
    let (v, inside) = grid_probe(pts, g);
    let mut out = Outputs::default();
    out.tensor("value", Tensor::real(&[pts.len()], v)?);
    out.tensor("inside", Tensor::from_shape_vec(&[pts.len()], inside)?);
    let beyond = beyond_one_cell(pts, g);
    out.tensor("beyond", Tensor::from_shape_vec(&[pts.len()], beyond)?);
    Ok(out)
}

/// Reference trilinear value of channel 0 at each point, and whether the
/// point lies inside the grid's box.
pub fn grid_probe(pts: &[[f64; 3]], g: &GridDesc) -> (Vec<f64>, Vec<u8>) {
    let v: Vec<f64> = pts.iter().map(|&x| ref_grid(g, x, 0)).collect();
    let inside: Vec<u8> = pts
        .iter()
        .map(|x| (0..3).all(|a| x[a] >= g.bmin[a] && x[a] <= g.bmax[a]) as u8)
        .collect();
    (v, inside)
}

/// Whether each point lies more than one index cell outside the grid on
/// some axis (index coordinate `u < -1` or `u >= n`): all eight corners
/// are outside, so the `zero` policy's value there is exactly 0.
pub fn beyond_one_cell(pts: &[[f64; 3]], g: &GridDesc) -> Vec<u8> {
    pts.iter()
        .map(|x| {
            (0..3).any(|a| {
                let n = g.shape[2 - a] as f64;
                let u = (x[a] - g.bmin[a]) * (n - 1.0) / (g.bmax[a] - g.bmin[a]);
                u < -1.0 || u >= n
            }) as u8
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slab_reference_uses_half_open_membership() {
        let f = FieldDesc::Analytic(Analytic::Slabs {
            axis: 0,
            breaks: vec![-1.0, -0.2, 0.3, 1.0],
            sigma: vec![0.5, 8.0, 1.0],
        });
        assert_eq!(ref_sigma(&f, [-0.2, 0.0, 0.0]), 8.0);
        assert_eq!(ref_sigma(&f, [1.0, 0.0, 0.0]), 1.0);
        assert_eq!(ref_sigma(&f, [-1.0, 0.0, 0.0]), 0.5);
        assert_eq!(ref_sigma(&f, [1.5, 0.0, 0.0]), 0.0);
    }

    #[test]
    fn beyond_one_cell_marks_points_whose_eight_corners_are_all_outside() {
        let g = GridDesc::sample([5, 5, 5], [-1.0; 3], [1.0; 3], Oob::Zero, |_| 3.0);
        let pts = [
            [-1.6, 0.0, 0.0],
            [-1.4, 0.0, 0.0],
            [0.0, 1.4, 0.0],
            [0.0, 0.0, 1.5],
            [0.0, 0.0, 0.0],
        ];
        assert_eq!(beyond_one_cell(&pts, &g), vec![1, 0, 0, 1, 0]);
    }
}
