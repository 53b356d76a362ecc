//! Density and colour fields (seed 000, module 7 `field_*`; SCENES.md
//! "Dense grid" and "Analytic fields").
//!
//! A field is described once in f64 ([`FieldDesc`], [`ColorDesc`]: what a
//! scene or a `.npy` file gives) and rounded once to the render precision
//! ([`Field`], [`ColorField`]) before rendering. Interfaces are closed enums;
//! [`FieldKind`] codes are the WGSL `switch` values of the GPU twin
//! (`kernels/volume.wgsl` `sigma_at`), defined once in `src/gpu/codes.rs`.
//!
//! | kind | sigma(x) |
//! | --- | --- |
//! | `constant` | `s` (the world box is applied by ray clipping) |
//! | `slabs` | `sigma[i]` for `breaks[i] <= x_axis < breaks[i+1]`, the last slab closed; 0 outside |
//! | `gaussian` | `A exp(-abs(x - m)^2 / (2 s^2))` |
//! | `shell` | `s` where `r0 <= abs(x - centre) <= r1`, else 0 |
//! | `linear` | `max(a + g . x, 0)` (validated `>= 0` on the box) |
//! | `grid` | node-aligned trilinear interpolation of an (nz, ny, nx) array, OOB `zero` or `clamp` |
//! | `hash_mlp` | multiresolution hash encoding + MLP (`hash.rs`); its colour head is the colour (`ColorDesc::Mlp`) |

mod analytic;
mod grid;
pub mod hash;
mod hash_grad;
mod hash_outputs;

pub use analytic::Analytic;
pub use grid::{floor_i64, fmax, fmin, Grid, GridDesc};
pub use hash::{HashMlp, HashMlpDesc};

use crate::real::Real;

/// Largest density accepted: keeps `sigma * dt` and sums of it finite in f32.
pub const MAX_SIGMA: f64 = 1e15;

pub use crate::gpu::codes::FieldKind;

/// Out-of-box policy of a dense grid (SCENES.md): `Zero`: a corner outside
/// the index range contributes 0; `Clamp`: coordinates clamp to the box.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Oob {
    Zero = 0,
    Clamp = 1,
}

/// A density field as described (f64).
#[derive(Clone, Debug, PartialEq)]
pub enum FieldDesc {
    Analytic(Analytic),
    Grid(GridDesc),
    HashMlp(Box<HashMlpDesc>),
}

/// A colour field as described (f64).
#[derive(Clone, Debug, PartialEq)]
pub enum ColorDesc {
    Constant([f64; 3]),
    Grid(GridDesc),
    /// The colour head of a `hash_mlp` density (valid with that field only).
    Mlp,
}

impl ColorDesc {
    /// The colour when it is the same everywhere (a constant, or a grid of
    /// equal nodes), else `None`.
    pub fn uniform(&self) -> Option<[f64; 3]> {
        match self {
            ColorDesc::Constant(c) => Some(*c),
            ColorDesc::Grid(g) if g.data.chunks(3).all(|v| v == &g.data[..3]) => {
                Some([g.data[0], g.data[1], g.data[2]])
            }
            ColorDesc::Grid(_) | ColorDesc::Mlp => None,
        }
    }
}

impl FieldDesc {
    pub fn kind(&self) -> FieldKind {
        match self {
            FieldDesc::Analytic(Analytic::Constant { .. }) => FieldKind::Constant,
            FieldDesc::Analytic(Analytic::Slabs { .. }) => FieldKind::Slabs,
            FieldDesc::Analytic(Analytic::Gaussian { .. }) => FieldKind::Gaussian,
            FieldDesc::Analytic(Analytic::Shell { .. }) => FieldKind::Shell,
            FieldDesc::Analytic(Analytic::Linear { .. }) => FieldKind::Linear,
            FieldDesc::Grid(_) => FieldKind::Grid,
            FieldDesc::HashMlp(_) => FieldKind::HashMlp,
        }
    }

    /// Whether sigma can be non-zero in [lo, hi] (conservative).
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        match self {
            FieldDesc::Analytic(a) => a.may_be_nonzero(lo, hi),
            FieldDesc::Grid(g) => g.may_be_nonzero(lo, hi),
            FieldDesc::HashMlp(h) => h.may_be_nonzero(lo, hi),
        }
    }

    /// The field in precision `F`.
    pub fn to_real<F: Real>(&self) -> Field<F> {
        match self {
            FieldDesc::Analytic(a) => match a {
                Analytic::Constant { s } => Field::Constant { s: F::of(*s) },
                Analytic::Slabs {
                    axis,
                    breaks,
                    sigma,
                } => Field::Slabs {
                    axis: *axis,
                    breaks: breaks.iter().map(|&b| F::of(b)).collect(),
                    sigma: sigma.iter().map(|&b| F::of(b)).collect(),
                },
                Analytic::Gaussian {
                    amplitude,
                    mean,
                    std,
                } => Field::Gaussian {
                    amplitude: F::of(*amplitude),
                    mean: mean.map(F::of),
                    inv_two_var: F::of(1.0 / (2.0 * std * std)),
                },
                Analytic::Shell { centre, r0, r1, s } => Field::Shell {
                    centre: centre.map(F::of),
                    r0: F::of(*r0),
                    r1: F::of(*r1),
                    s: F::of(*s),
                },
                Analytic::Linear { a, g } => Field::Linear {
                    a: F::of(*a),
                    g: g.map(F::of),
                },
            },
            FieldDesc::Grid(g) => Field::Grid(Grid::from_desc(g)),
            FieldDesc::HashMlp(h) => Field::HashMlp(Box::new(HashMlp::from_desc(h))),
        }
    }
}

impl ColorDesc {
    pub fn to_real<F: Real>(&self) -> ColorField<F> {
        match self {
            ColorDesc::Constant(c) => ColorField::Constant(c.map(F::of)),
            ColorDesc::Grid(g) => ColorField::Grid(Grid::from_desc(g)),
            ColorDesc::Mlp => ColorField::Mlp,
        }
    }
}

/// A density field in precision `F` (see the module table).
#[derive(Clone, Debug)]
pub enum Field<F> {
    Constant {
        s: F,
    },
    Slabs {
        axis: usize,
        breaks: Vec<F>,
        sigma: Vec<F>,
    },
    Gaussian {
        amplitude: F,
        mean: [F; 3],
        inv_two_var: F,
    },
    Shell {
        centre: [F; 3],
        r0: F,
        r1: F,
        s: F,
    },
    Linear {
        a: F,
        g: [F; 3],
    },
    Grid(Grid<F>),
    HashMlp(Box<HashMlp<F>>),
}

impl<F: Real> Field<F> {
    /// sigma at world point `x` (finite, >= 0).
    #[inline]
    pub fn sigma(&self, x: [F; 3]) -> F {
        match self {
            Field::Constant { s } => *s,
            Field::Slabs {
                axis,
                breaks,
                sigma,
            } => {
                let v = x[*axis];
                let n = sigma.len();
                for i in 0..n {
                    if breaks[i] <= v && (v < breaks[i + 1] || (i + 1 == n && v <= breaks[n])) {
                        return sigma[i];
                    }
                }
                F::zero()
            }
            Field::Gaussian {
                amplitude,
                mean,
                inv_two_var,
            } => {
                let (dx, dy, dz) = (x[0] - mean[0], x[1] - mean[1], x[2] - mean[2]);
                *amplitude * (-(dx * dx + dy * dy + dz * dz) * *inv_two_var).exp()
            }
            Field::Shell { centre, r0, r1, s } => {
                let (dx, dy, dz) = (x[0] - centre[0], x[1] - centre[1], x[2] - centre[2]);
                let r = (dx * dx + dy * dy + dz * dz).sqrt();
                if *r0 <= r && r <= *r1 {
                    *s
                } else {
                    F::zero()
                }
            }
            Field::Linear { a, g } => (*a + g[0] * x[0] + g[1] * x[1] + g[2] * x[2]).max(F::zero()),
            Field::Grid(g) => fmax(g.trilinear::<1>(x)[0], F::zero()),
            Field::HashMlp(h) => h.query(x).0,
        }
    }
}

/// A colour field in precision `F`.
#[derive(Clone, Debug)]
pub enum ColorField<F> {
    Constant([F; 3]),
    Grid(Grid<F>),
    /// The colour head of the `hash_mlp` density: [`Medium::Hash`] queries
    /// it; [`check_pairing`] keeps it from any other density.
    Mlp,
}

impl<F: Real> ColorField<F> {
    #[inline]
    pub fn color(&self, x: [F; 3]) -> [F; 3] {
        match self {
            ColorField::Constant(c) => *c,
            ColorField::Grid(g) => g.trilinear::<3>(x),
            ColorField::Mlp => [F::zero(); 3],
        }
    }
}

/// What a sample queries: density and colour together. When both are
/// dense grids on the same nodes (shape, box, OOB policy), they are packed
/// into one 4-channel grid `[sigma, r, g, b]` per node, so one set of eight
/// corner loads (16 contiguous bytes each in f32) serves both; each channel
/// is interpolated with the same operations as the split grids, so the
/// values are bit-identical to the split query.
#[derive(Clone, Debug)]
pub enum Medium<F> {
    Split {
        sigma: Field<F>,
        color: ColorField<F>,
    },
    Packed(Grid<F>),
    /// A `hash_mlp` field: density and colour from one network evaluation.
    Hash(Box<HashMlp<F>>),
}

impl<F: Real> Medium<F> {
    /// The medium of `field` and `color` in precision `F`.
    pub fn new(field: &FieldDesc, color: &ColorDesc) -> Medium<F> {
        if let FieldDesc::HashMlp(h) = field {
            return Medium::Hash(Box::new(HashMlp::from_desc(h)));
        }
        if let (FieldDesc::Grid(d), ColorDesc::Grid(c)) = (field, color) {
            if d.shape == c.shape
                && d.bmin == c.bmin
                && d.bmax == c.bmax
                && d.oob == c.oob
                && d.ch == 1
                && c.ch == 3
            {
                let n = d.data.len();
                let mut data = Vec::with_capacity(4 * n);
                for i in 0..n {
                    data.push(d.data[i]);
                    data.extend_from_slice(&c.data[3 * i..3 * i + 3]);
                }
                return Medium::Packed(Grid::from_desc(&GridDesc {
                    ch: 4,
                    data,
                    ..d.clone()
                }));
            }
        }
        Medium::Split {
            sigma: field.to_real(),
            color: color.to_real(),
        }
    }

    /// `(sigma, colour)` at `x`.
    #[inline(always)]
    pub fn query(&self, x: [F; 3]) -> (F, [F; 3]) {
        match self {
            Medium::Split { sigma, color } => (sigma.sigma(x), color.color(x)),
            Medium::Packed(g) => {
                let v = g.trilinear::<4>(x);
                (fmax(v[0], F::zero()), [v[1], v[2], v[3]])
            }
            Medium::Hash(h) => h.query(x),
        }
    }
}

/// A `hash_mlp` density goes with `color: {type: mlp}` and only with it.
pub fn check_pairing(field: &FieldDesc, color: &ColorDesc, at: &str) -> crate::error::Result<()> {
    match (field, color) {
        (FieldDesc::HashMlp(_), ColorDesc::Mlp) => Ok(()),
        (FieldDesc::HashMlp(_), _) => Err(crate::error::Error::invalid(
            at,
            "a hash_mlp field takes its colour from its network: use `color: {type: mlp}`",
        )),
        (_, ColorDesc::Mlp) => Err(crate::error::Error::invalid(
            at,
            "`color: {type: mlp}` needs a `field: {type: hash_mlp}`",
        )),
        _ => Ok(()),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const B0: [f64; 3] = [-1.0; 3];
    const B1: [f64; 3] = [1.0; 3];

    #[test]
    fn packed_grids_query_the_same_bits_as_split_grids() {
        let d = GridDesc::sample([5, 6, 7], B0, B1, Oob::Zero, |x| 3.0 + x[0] * x[1] - x[2]);
        let mut c = GridDesc::sample([5, 6, 7], B0, B1, Oob::Zero, |x| x[2]);
        c.data = c.data.iter().flat_map(|&v| [v, 2.0 * v, v * v]).collect();
        c.ch = 3;
        let (fd, cd) = (FieldDesc::Grid(d), ColorDesc::Grid(c));
        let packed = Medium::<f32>::new(&fd, &cd);
        assert!(matches!(packed, Medium::Packed(_)));
        let split = Medium::<f32>::Split {
            sigma: fd.to_real(),
            color: cd.to_real(),
        };
        for i in 0..2000u32 {
            let x = [0, 1, 2].map(|k| crate::rng::rand_f32(5, i, 0, k) * 2.4 - 1.2);
            assert_eq!(packed.query(x), split.query(x), "{x:?}");
        }
    }
}
