//! Gradient-index media: `H = (|p|^2 - n(x)^2) / 2` on `y = (x, p)` (N = 6).
//! Hamilton's equations give `dx/dlambda = p`, `dp/dlambda = grad(n^2) / 2`;
//! on `H = 0`, `|p| = n` and `lambda` is the optical-path parameter
//! (`ds = n dlambda`). The Hamiltonian is separable, so the kick-drift
//! tiers apply.
//!
//! | medium | `n^2(x)` | parameters |
//! | --- | --- | --- |
//! | `Luneburg` | `2 - r^2/R^2` for `r < R`, 1 outside | radius R |
//! | `LuneburgCore` | `2 - r^2/R^2` everywhere (the lens formula continued past its sphere) | radius R |
//! | `FishEye` (Maxwell) | `n0^2 / (1 + r^2/R^2)^2` | n0, R |
//! | `Fibre` (parabolic, axis = x) | `n0^2 (1 - alpha^2 rho^2)`, `rho^2 = y^2 + z^2` | n0, alpha |
//! | `Sech` (axis = x) | `n0^2 sech^2(alpha rho)` | n0, alpha |
//! | `Grid` | `n^2` with n trilinear on a node-aligned grid | see [`Grid`] |

use super::hamiltonian::Hamiltonian;
use crate::error::{Error, Result};
use crate::real::Real;

/// A dense, node-aligned grid of refractive index values (SCENES.md
/// dense-grid convention: `n[k, j, i]` at `x = min.x + i (max.x - min.x) /
/// (nx - 1)`, x fastest), trilinear; outside the box `n = outside` (with
/// zero gradient).
#[derive(Clone, Debug, PartialEq)]
pub struct Grid<F> {
    /// (nx, ny, nz), each >= 2.
    pub dims: [usize; 3],
    pub min: [F; 3],
    pub max: [F; 3],
    /// `nz * ny * nx` values, x fastest.
    pub n: Vec<F>,
    pub outside: F,
}

impl<F: Real> Grid<F> {
    /// Samples `medium`'s n at the nodes of a `dims` grid over `[min, max]`.
    pub fn sample(
        medium: &Medium<F>,
        dims: [usize; 3],
        min: [F; 3],
        max: [F; 3],
        outside: F,
    ) -> Result<Grid<F>> {
        if dims.iter().any(|&d| d < 2) {
            return Err(Error::invalid(
                "grid.dims",
                format!("{dims:?}: each extent must be >= 2"),
            ));
        }
        if (0..3).any(|a| !(max[a] > min[a])) {
            return Err(Error::invalid(
                "grid.aabb",
                "max must exceed min on every axis",
            ));
        }
        let mut n = Vec::with_capacity(dims[0] * dims[1] * dims[2]);
        for k in 0..dims[2] {
            for j in 0..dims[1] {
                for i in 0..dims[0] {
                    let idx = [i, j, k];
                    let p: [F; 3] = std::array::from_fn(|a| {
                        min[a]
                            + (max[a] - min[a]) * F::of(idx[a] as f64) / F::of((dims[a] - 1) as f64)
                    });
                    n.push(medium.n2_grad(&p).0.max(F::zero()).sqrt());
                }
            }
        }
        Ok(Grid {
            dims,
            min,
            max,
            n,
            outside,
        })
    }

    /// Trilinear `n` and its gradient at `x`.
    pub fn n_grad(&self, x: &[F; 3]) -> (F, [F; 3]) {
        let mut cell = [0usize; 3];
        let mut f = [F::zero(); 3];
        let mut inv = [F::zero(); 3];
        for a in 0..3 {
            if !(x[a] >= self.min[a] && x[a] <= self.max[a]) {
                return (self.outside, [F::zero(); 3]);
            }
            let cells = self.dims[a] - 1;
            inv[a] = F::of(cells as f64) / (self.max[a] - self.min[a]);
            let u = (x[a] - self.min[a]) * inv[a];
            let c = u.floor().to_usize().unwrap_or(0).min(cells - 1);
            cell[a] = c;
            f[a] = u - F::of(c as f64);
        }
        let at = |i: usize, j: usize, k: usize| {
            self.n[((cell[2] + k) * self.dims[1] + cell[1] + j) * self.dims[0] + cell[0] + i]
        };
        let one = F::one();
        let mut n = F::zero();
        let mut g = [F::zero(); 3];
        for k in 0..2 {
            for j in 0..2 {
                for i in 0..2 {
                    let v = at(i, j, k);
                    let wx = if i == 1 { f[0] } else { one - f[0] };
                    let wy = if j == 1 { f[1] } else { one - f[1] };
                    let wz = if k == 1 { f[2] } else { one - f[2] };
                    let sx = if i == 1 { one } else { -one };
                    let sy = if j == 1 { one } else { -one };
                    let sz = if k == 1 { one } else { -one };
                    n += v * wx * wy * wz;
                    g[0] += v * sx * wy * wz * inv[0];
                    g[1] += v * wx * sy * wz * inv[1];
                    g[2] += v * wx * wy * sz * inv[2];
                }
            }
        }
        (n, g)
    }
}

/// A GRIN medium (closed set; see the module table).
#[derive(Clone, Debug, PartialEq)]
pub enum Medium<F> {
    Luneburg {
        radius: F,
    },
    /// The Luneburg formula without its exterior: what a ray inside the lens
    /// integrates until the exit event, so that the step straddling the
    /// sphere sees a smooth field (the kink would cost the tier its order).
    LuneburgCore {
        radius: F,
    },
    FishEye {
        n0: F,
        radius: F,
    },
    Fibre {
        n0: F,
        alpha: F,
    },
    Sech {
        n0: F,
        alpha: F,
    },
    Grid(Grid<F>),
}

/// `tanh(u) / u`, exact at u = 0.
#[inline]
fn tanhc<F: Real>(u: F) -> F {
    if u.abs() < F::of(1e-4) {
        F::one() - u * u / F::of(3.0)
    } else {
        u.tanh() / u
    }
}

impl<F: Real> Medium<F> {
    /// `n^2(x)` and `grad n^2(x)`.
    pub fn n2_grad(&self, x: &[F; 3]) -> (F, [F; 3]) {
        let two = F::of(2.0);
        let zero = F::zero();
        match self {
            Medium::Luneburg { radius } => {
                let r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
                let rr = *radius * *radius;
                if r2 < rr {
                    (two - r2 / rr, x.map(|c| -two * c / rr))
                } else {
                    (F::one(), [zero; 3])
                }
            }
            Medium::LuneburgCore { radius } => {
                let r2 = x[0] * x[0] + x[1] * x[1] + x[2] * x[2];
                let rr = *radius * *radius;
                (two - r2 / rr, x.map(|c| -two * c / rr))
            }
            Medium::FishEye { n0, radius } => {
                let q = (x[0] * x[0] + x[1] * x[1] + x[2] * x[2]) / (*radius * *radius);
                let d = F::one() + q;
                let n2 = *n0 * *n0 / (d * d);
                let k = -F::of(4.0) * *n0 * *n0 / (*radius * *radius * d * d * d);
                (n2, x.map(|c| k * c))
            }
            Medium::Fibre { n0, alpha } => {
                let a2 = *alpha * *alpha;
                let k = *n0 * *n0;
                (
                    k * (F::one() - a2 * (x[1] * x[1] + x[2] * x[2])),
                    [zero, -two * k * a2 * x[1], -two * k * a2 * x[2]],
                )
            }
            Medium::Sech { n0, alpha } => {
                let rho = (x[1] * x[1] + x[2] * x[2]).sqrt();
                let u = *alpha * rho;
                let sech = F::one() / u.cosh();
                let n2 = *n0 * *n0 * sech * sech;
                // d(n^2)/d rho = -2 alpha n^2 tanh(u); times (y, z)/rho.
                let k = -two * *alpha * *alpha * n2 * tanhc(u);
                (n2, [zero, k * x[1], k * x[2]])
            }
            Medium::Grid(g) => {
                let (n, gn) = g.n_grad(x);
                (n * n, gn.map(|c| two * n * c))
            }
        }
    }

    /// The lens sphere outside which `n = 1` exactly (rays there are
    /// straight lines), for media that have one.
    pub fn boundary_radius(&self) -> Option<F> {
        match self {
            Medium::Luneburg { radius } | Medium::LuneburgCore { radius } => Some(*radius),
            _ => None,
        }
    }
}

impl<F: Real> Hamiltonian<F, 6> for Medium<F> {
    const SEPARABLE: bool = true;

    fn h(&self, y: &[F; 6]) -> F {
        let (n2, _) = self.n2_grad(&[y[0], y[1], y[2]]);
        (y[3] * y[3] + y[4] * y[4] + y[5] * y[5] - n2) * F::of(0.5)
    }

    fn dx(&self, y: &[F; 6]) -> [F; 6] {
        let z = F::zero();
        [y[3], y[4], y[5], z, z, z]
    }

    fn dp(&self, y: &[F; 6]) -> [F; 6] {
        let (_, g) = self.n2_grad(&[y[0], y[1], y[2]]);
        let h = F::of(0.5);
        let z = F::zero();
        [z, z, z, h * g[0], h * g[1], h * g[2]]
    }

    fn rhs(&self, y: &[F; 6]) -> [F; 6] {
        let (_, g) = self.n2_grad(&[y[0], y[1], y[2]]);
        let h = F::of(0.5);
        [y[3], y[4], y[5], h * g[0], h * g[1], h * g[2]]
    }

    fn scale(&self, _y: &[F; 6]) -> F {
        F::one()
    }

    /// Rescales `p` to `|p| = n(x)`: keeps the direction, changes the
    /// momentum's length only.
    fn project(&self, y: &mut [F; 6]) {
        let (n2, _) = self.n2_grad(&[y[0], y[1], y[2]]);
        let p2 = y[3] * y[3] + y[4] * y[4] + y[5] * y[5];
        if p2 > F::zero() && n2 > F::zero() {
            let s = (n2 / p2).sqrt();
            for v in &mut y[3..6] {
                *v *= s;
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn fd_grad(m: &Medium<f64>, x: [f64; 3]) -> [f64; 3] {
        let e = 1e-6;
        std::array::from_fn(|a| {
            let mut xp = x;
            let mut xm = x;
            xp[a] += e;
            xm[a] -= e;
            (m.n2_grad(&xp).0 - m.n2_grad(&xm).0) / (2.0 * e)
        })
    }

    #[test]
    fn analytic_gradients_match_central_differences() {
        let media = [
            Medium::Luneburg { radius: 1.3 },
            Medium::LuneburgCore { radius: 1.3 },
            Medium::FishEye {
                n0: 2.0,
                radius: 1.0,
            },
            Medium::Fibre {
                n0: 1.5,
                alpha: 0.5,
            },
            Medium::Sech {
                n0: 1.5,
                alpha: 0.5,
            },
        ];
        for m in &media {
            for x in [[0.3, -0.2, 0.5], [0.01, 0.7, -0.1], [-0.4, 1e-5, 2e-5]] {
                let g = m.n2_grad(&x).1;
                let f = fd_grad(m, x);
                for a in 0..3 {
                    assert!((g[a] - f[a]).abs() < 1e-7, "{m:?} at {x:?}: {g:?} vs {f:?}");
                }
            }
        }
    }

    #[test]
    fn closed_form_indices_at_known_points() {
        let l = Medium::Luneburg { radius: 1.0f64 };
        assert!((l.n2_grad(&[0.0; 3]).0 - 2.0).abs() < 1e-15);
        assert_eq!(l.n2_grad(&[1.5, 0.0, 0.0]), (1.0, [0.0; 3]));
        let f = Medium::FishEye {
            n0: 2.0f64,
            radius: 1.0,
        };
        assert!((f.n2_grad(&[1.0, 0.0, 0.0]).0 - 1.0).abs() < 1e-15);
        let s = Medium::Sech {
            n0: 1.5,
            alpha: 0.5,
        };
        let c = (0.5f64 * 2.0).cosh();
        assert!((s.n2_grad(&[7.0, 2.0, 0.0]).0 - 2.25 / (c * c)).abs() < 1e-14);
    }

    #[test]
    fn trilinear_grid_reproduces_a_linear_index_and_its_gradient() {
        // n = 1 + 0.1 x - 0.2 y + 0.05 z is reproduced exactly by trilinear.
        let dims = [5, 4, 3];
        let (min, max) = ([-1.0, -1.0, -1.0], [1.0, 1.0, 1.0]);
        let mut n = vec![];
        for k in 0..3 {
            for j in 0..4 {
                for i in 0..5 {
                    let x = -1.0 + 2.0 * i as f64 / 4.0;
                    let y = -1.0 + 2.0 * j as f64 / 3.0;
                    let z = -1.0 + 2.0 * k as f64 / 2.0;
                    n.push(1.0 + 0.1 * x - 0.2 * y + 0.05 * z);
                }
            }
        }
        let g = Grid {
            dims,
            min,
            max,
            n,
            outside: 1.0,
        };
        for x in [[0.3, -0.7, 0.2], [-1.0, 1.0, 1.0], [0.999, 0.0, -0.5]] {
            let (v, d) = g.n_grad(&x);
            assert!((v - (1.0 + 0.1 * x[0] - 0.2 * x[1] + 0.05 * x[2])).abs() < 1e-14);
            for (a, e) in d.iter().zip([0.1, -0.2, 0.05]) {
                assert!((a - e).abs() < 1e-13, "{d:?}");
            }
        }
        assert_eq!(g.n_grad(&[1.5, 0.0, 0.0]), (1.0, [0.0; 3]));
    }

    #[test]
    fn sampled_grid_matches_the_sampled_medium_at_nodes() {
        let m = Medium::Luneburg { radius: 1.0f64 };
        let g = Grid::sample(&m, [9, 9, 9], [-1.0; 3], [1.0; 3], 1.0).unwrap();
        let x = [0.25, -0.5, 0.0];
        assert!((g.n_grad(&x).0 - m.n2_grad(&x).0.sqrt()).abs() < 1e-14);
        assert!(Grid::sample(&m, [1, 9, 9], [-1.0; 3], [1.0; 3], 1.0).is_err());
    }

    #[test]
    fn projection_restores_the_constraint() {
        let m = Medium::FishEye {
            n0: 2.0f64,
            radius: 1.0,
        };
        let mut y = [0.2, 0.1, 0.0, 3.0, 1.0, 0.5];
        m.project(&mut y);
        assert!(m.h(&y).abs() < 1e-15);
    }
}
