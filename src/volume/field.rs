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

use crate::error::{Error, Result};
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

/// An analytic density, f64 parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum Analytic {
    Constant {
        s: f64,
    },
    /// Piecewise constant along `axis` (0 = x): `breaks` strictly increasing,
    /// `sigma.len() == breaks.len() - 1`.
    Slabs {
        axis: usize,
        breaks: Vec<f64>,
        sigma: Vec<f64>,
    },
    Gaussian {
        amplitude: f64,
        mean: [f64; 3],
        std: f64,
    },
    Shell {
        centre: [f64; 3],
        r0: f64,
        r1: f64,
        s: f64,
    },
    Linear {
        a: f64,
        g: [f64; 3],
    },
}

/// A node-aligned grid of `ch` channels, values in C order (nz, ny, nx, ch).
#[derive(Clone, Debug, PartialEq)]
pub struct GridDesc {
    /// (nz, ny, nx), each >= 2.
    pub shape: [usize; 3],
    pub ch: usize,
    pub data: Vec<f64>,
    pub oob: Oob,
    /// The world box the grid spans (first node at `min`, last at `max`).
    pub bmin: [f64; 3],
    pub bmax: [f64; 3],
}

/// A density field as described (f64).
#[derive(Clone, Debug, PartialEq)]
pub enum FieldDesc {
    Analytic(Analytic),
    Grid(GridDesc),
}

/// A colour field as described (f64).
#[derive(Clone, Debug, PartialEq)]
pub enum ColorDesc {
    Constant([f64; 3]),
    Grid(GridDesc),
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Analytic {
    /// sigma at `x` in f64 (the description's own formula; used for grid
    /// generation and occupancy, never by the renderer's hot loop).
    pub fn eval(&self, x: [f64; 3]) -> f64 {
        match self {
            Analytic::Constant { s } => *s,
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => slab_value(breaks, sigma, x[*axis]),
            Analytic::Gaussian {
                amplitude,
                mean,
                std,
            } => {
                let r2 = (0..3).map(|a| (x[a] - mean[a]).powi(2)).sum::<f64>();
                amplitude * (-r2 / (2.0 * std * std)).exp()
            }
            Analytic::Shell { centre, r0, r1, s } => {
                let r = (0..3)
                    .map(|a| (x[a] - centre[a]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                if *r0 <= r && r <= *r1 {
                    *s
                } else {
                    0.0
                }
            }
            Analytic::Linear { a, g } => (a + dot(*g, x)).max(0.0),
        }
    }

    /// Checks parameters; `bmin`/`bmax` is the world box (for `linear`'s
    /// sign condition). `at` names the scene key.
    pub fn validate(&self, at: &str, bmin: [f64; 3], bmax: [f64; 3]) -> Result<()> {
        let fin = |v: f64, k: &str| -> Result<()> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("{at}.{k}"),
                    format!("{v} is not finite"),
                ))
            }
        };
        let dens = |v: f64, k: &str| -> Result<()> {
            if v.is_finite() && (0.0..=MAX_SIGMA).contains(&v) {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("{at}.{k}"),
                    format!("density {v} is not in [0, {MAX_SIGMA:e}]"),
                ))
            }
        };
        match self {
            Analytic::Constant { s } => dens(*s, "s"),
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => {
                if *axis > 2 {
                    return Err(Error::invalid(format!("{at}.axis"), "must be x, y or z"));
                }
                if breaks.len() < 2 || sigma.len() + 1 != breaks.len() {
                    return Err(Error::invalid(
                        at,
                        format!(
                            "need n + 1 >= 2 breaks for n sigmas, got {} and {}",
                            breaks.len(),
                            sigma.len()
                        ),
                    ));
                }
                for b in breaks {
                    fin(*b, "breaks")?;
                }
                if breaks.windows(2).any(|w| w[0] >= w[1]) {
                    return Err(Error::invalid(
                        format!("{at}.breaks"),
                        "must be strictly increasing",
                    ));
                }
                sigma.iter().try_for_each(|s| dens(*s, "sigma"))
            }
            Analytic::Gaussian {
                amplitude,
                mean,
                std,
            } => {
                dens(*amplitude, "amplitude")?;
                mean.iter().try_for_each(|m| fin(*m, "mean"))?;
                if !(std.is_finite() && *std > 0.0) {
                    return Err(Error::invalid(
                        format!("{at}.std"),
                        format!("{std} is not a positive number"),
                    ));
                }
                Ok(())
            }
            Analytic::Shell { centre, r0, r1, s } => {
                centre.iter().try_for_each(|m| fin(*m, "centre"))?;
                dens(*s, "s")?;
                if !(r0.is_finite() && r1.is_finite() && 0.0 <= *r0 && r0 <= r1) {
                    return Err(Error::invalid(
                        at,
                        format!("need 0 <= r0 <= r1, got r0 = {r0}, r1 = {r1}"),
                    ));
                }
                Ok(())
            }
            Analytic::Linear { a, g } => {
                fin(*a, "a")?;
                g.iter().try_for_each(|v| fin(*v, "g"))?;
                let mut lo = f64::INFINITY;
                let mut hi = f64::NEG_INFINITY;
                for c in 0..8 {
                    let x = [0, 1, 2].map(|k| if c >> k & 1 == 1 { bmax[k] } else { bmin[k] });
                    lo = lo.min(a + dot(*g, x));
                    hi = hi.max(a + dot(*g, x));
                }
                if lo < 0.0 || hi > MAX_SIGMA {
                    return Err(Error::invalid(
                        at,
                        format!("a + g . x ranges over [{lo}, {hi}] on the box; need [0, {MAX_SIGMA:e}]"),
                    ));
                }
                Ok(())
            }
        }
    }

    /// Whether sigma can be non-zero somewhere in the closed box [lo, hi]
    /// (conservative: `true` when unsure). Drives the occupancy bitfield.
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        match self {
            Analytic::Constant { s } => *s > 0.0,
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => (0..sigma.len())
                .any(|i| sigma[i] > 0.0 && breaks[i] <= hi[*axis] && lo[*axis] <= breaks[i + 1]),
            Analytic::Gaussian { amplitude, .. } => *amplitude > 0.0,
            Analytic::Shell { centre, r0, r1, s } => {
                let (mut near2, mut far2) = (0.0, 0.0);
                for a in 0..3 {
                    let (dl, dh) = (lo[a] - centre[a], hi[a] - centre[a]);
                    let n = if dl > 0.0 {
                        dl
                    } else if dh < 0.0 {
                        -dh
                    } else {
                        0.0
                    };
                    near2 += n * n;
                    far2 += dl.abs().max(dh.abs()).powi(2);
                }
                *s > 0.0 && far2.sqrt() >= *r0 && near2.sqrt() <= *r1
            }
            Analytic::Linear { a, g } => {
                let hi_val = a
                    + (0..3)
                        .map(|k| (g[k] * lo[k]).max(g[k] * hi[k]))
                        .sum::<f64>();
                hi_val > 0.0
            }
        }
    }
}

/// The slab value at coordinate `v`: half-open slabs, the last one closed.
fn slab_value(breaks: &[f64], sigma: &[f64], v: f64) -> f64 {
    let n = sigma.len();
    for i in 0..n {
        if breaks[i] <= v && (v < breaks[i + 1] || (i + 1 == n && v <= breaks[n])) {
            return sigma[i];
        }
    }
    0.0
}

impl GridDesc {
    /// A grid sampling `f` at its nodes: node (k, j, i) at
    /// `bmin + (i, j, k) * (bmax - bmin) / (n - 1)`.
    pub fn sample(
        shape: [usize; 3],
        bmin: [f64; 3],
        bmax: [f64; 3],
        oob: Oob,
        f: impl Fn([f64; 3]) -> f64,
    ) -> GridDesc {
        let [nz, ny, nx] = shape;
        let node = |a: usize, i: usize, n: usize| {
            bmin[a] + i as f64 * (bmax[a] - bmin[a]) / (n - 1).max(1) as f64
        };
        let mut data = Vec::with_capacity(nx * ny * nz);
        for k in 0..nz {
            for j in 0..ny {
                for i in 0..nx {
                    data.push(f([node(0, i, nx), node(1, j, ny), node(2, k, nz)]));
                }
            }
        }
        GridDesc {
            shape,
            ch: 1,
            data,
            oob,
            bmin,
            bmax,
        }
    }

    /// A constant `ch`-channel grid.
    pub fn filled(
        shape: [usize; 3],
        value: &[f64],
        bmin: [f64; 3],
        bmax: [f64; 3],
        oob: Oob,
    ) -> GridDesc {
        let n = shape.iter().product::<usize>();
        let data = (0..n).flat_map(|_| value.iter().copied()).collect();
        GridDesc {
            shape,
            ch: value.len(),
            data,
            oob,
            bmin,
            bmax,
        }
    }

    /// Checks shape, box and values: every value finite; densities
    /// (`density = true`) in [0, MAX_SIGMA]. `at` names the source.
    pub fn validate(&self, at: &str, density: bool) -> Result<()> {
        if self.shape.iter().any(|&n| n < 2) {
            return Err(Error::invalid(
                at,
                format!(
                    "grid shape {:?} needs at least 2 nodes per axis",
                    self.shape
                ),
            ));
        }
        let n = self
            .shape
            .iter()
            .try_fold(self.ch, |acc, &s| acc.checked_mul(s));
        if n != Some(self.data.len()) {
            return Err(Error::invalid(
                at,
                format!(
                    "{} values do not fill shape {:?} x {}",
                    self.data.len(),
                    self.shape,
                    self.ch
                ),
            ));
        }
        if (0..3).any(|a| {
            !(self.bmin[a].is_finite() && self.bmax[a].is_finite() && self.bmin[a] < self.bmax[a])
        }) {
            return Err(Error::invalid(
                at,
                format!(
                    "grid box {:?}..{:?} is empty or not finite",
                    self.bmin, self.bmax
                ),
            ));
        }
        if let Some((i, v)) = self.data.iter().enumerate().find(|(_, v)| !v.is_finite()) {
            return Err(Error::invalid(
                at,
                format!("value {v} at flat index {i} is not finite"),
            ));
        }
        if density {
            if let Some((i, v)) = self
                .data
                .iter()
                .enumerate()
                .find(|(_, v)| !(0.0..=MAX_SIGMA).contains(*v))
            {
                return Err(Error::invalid(
                    at,
                    format!("density {v} at flat index {i} is not in [0, {MAX_SIGMA:e}]"),
                ));
            }
        }
        Ok(())
    }

    /// Continuous index coordinate of world coordinate `v` on axis `a` (x = 0).
    fn index_coord(&self, a: usize, v: f64) -> f64 {
        let n = self.shape[2 - a];
        (v - self.bmin[a]) * (n - 1) as f64 / (self.bmax[a] - self.bmin[a])
    }

    /// Whether channel 0 can be non-zero in [lo, hi] (conservative).
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        let mut r = [(0usize, 0usize); 3];
        for a in 0..3 {
            let n = self.shape[2 - a] as f64;
            let (mut l, mut h) = (
                self.index_coord(a, lo[a]).floor(),
                self.index_coord(a, hi[a]).floor() + 1.0,
            );
            if self.oob == Oob::Zero && (h < 0.0 || l > n - 1.0) {
                return false;
            }
            l = l.clamp(0.0, n - 1.0);
            h = h.clamp(0.0, n - 1.0);
            r[a] = (l as usize, h as usize);
        }
        let [_, ny, nx] = self.shape;
        for k in r[2].0..=r[2].1 {
            for j in r[1].0..=r[1].1 {
                for i in r[0].0..=r[0].1 {
                    if self.data[((k * ny + j) * nx + i) * self.ch] > 0.0 {
                        return true;
                    }
                }
            }
        }
        false
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
        }
    }

    /// Whether sigma can be non-zero in [lo, hi] (conservative).
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        match self {
            FieldDesc::Analytic(a) => a.may_be_nonzero(lo, hi),
            FieldDesc::Grid(g) => g.may_be_nonzero(lo, hi),
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
        }
    }
}

impl ColorDesc {
    pub fn to_real<F: Real>(&self) -> ColorField<F> {
        match self {
            ColorDesc::Constant(c) => ColorField::Constant(c.map(F::of)),
            ColorDesc::Grid(g) => ColorField::Grid(Grid::from_desc(g)),
        }
    }
}

/// A node-aligned trilinear grid in precision `F`.
#[derive(Clone, Debug)]
pub struct Grid<F> {
    pub nx: usize,
    pub ny: usize,
    pub nz: usize,
    pub ch: usize,
    pub data: Vec<F>,
    pub oob: Oob,
    /// World position of node (0, 0, 0).
    pub bmin: [F; 3],
    /// Index units per world unit: `(n - 1) / (max - min)` per axis.
    pub scale: [F; 3],
}

impl<F: Real> Grid<F> {
    pub fn from_desc(g: &GridDesc) -> Grid<F> {
        let [nz, ny, nx] = g.shape;
        let n = [nx, ny, nz];
        Grid {
            nx,
            ny,
            nz,
            ch: g.ch,
            data: g.data.iter().map(|&v| F::of(v)).collect(),
            oob: g.oob,
            bmin: g.bmin.map(F::of),
            scale: [0, 1, 2].map(|a| F::of((n[a] - 1) as f64 / (g.bmax[a] - g.bmin[a]))),
        }
    }

    /// Trilinear interpolation of channels `0..C` at world point `x`.
    /// Index coordinate `u = (x - min) * scale`; corner `i0 = floor(u)`,
    /// weight `f = u - i0` per axis; lerp along x, then y, then z (this order
    /// is part of the CPU/GPU contract). `floor` is done by truncation
    /// ([`floor_i64`]): no libm call in the hot loop.
    #[inline(always)]
    pub fn trilinear<const C: usize>(&self, x: [F; 3]) -> [F; C] {
        let n = [self.nx, self.ny, self.nz];
        let mut i0 = [0usize; 3];
        let mut f = [F::zero(); 3];
        let mut inside = true;
        for a in 0..3 {
            let u = (x[a] - self.bmin[a]) * self.scale[a];
            let top = (n[a] - 1) as i64;
            match self.oob {
                Oob::Clamp => {
                    let c = fmin(fmax(u, F::zero()), F::of(top as f64));
                    let (mut fl, mut ff) = floor_i64(c);
                    if fl > top - 1 {
                        (fl, ff) = (top - 1, F::of((top - 1) as f64));
                    }
                    i0[a] = fl as usize;
                    f[a] = c - ff;
                }
                Oob::Zero => {
                    let (fl, ff) = floor_i64(u);
                    // All eight corners outside: the value is exactly 0.
                    if fl < -1 || fl > top {
                        return [F::zero(); C];
                    }
                    if fl < 0 || fl >= top {
                        inside = false;
                    }
                    f[a] = u - ff;
                    // -1 wraps to usize::MAX; `corner` maps it back with wrapping_add.
                    i0[a] = fl as usize;
                }
            }
        }
        // Callers always ask for all channels (C == ch): strides are constants.
        debug_assert_eq!(self.ch, C);
        let (sx, sy) = (C, C * self.nx);
        let sz = sy * self.ny;
        let one = F::one();
        let g = [one - f[0], f[0], one - f[1], f[1], one - f[2], f[2]];
        let mut out = [F::zero(); C];
        if inside {
            // The x-neighbours of a corner are adjacent: four rows of 2C values.
            let b = i0[2] * sz + i0[1] * sy + i0[0] * sx;
            let d = &self.data;
            let r00 = &d[b..b + 2 * C];
            let r10 = &d[b + sy..b + sy + 2 * C];
            let r01 = &d[b + sz..b + sz + 2 * C];
            let r11 = &d[b + sz + sy..b + sz + sy + 2 * C];
            for (c, o) in out.iter_mut().enumerate() {
                let c00 = r00[c] * g[0] + r00[C + c] * g[1];
                let c10 = r10[c] * g[0] + r10[C + c] * g[1];
                let c01 = r01[c] * g[0] + r01[C + c] * g[1];
                let c11 = r11[c] * g[0] + r11[C + c] * g[1];
                let c0 = c00 * g[2] + c10 * g[3];
                let c1 = c01 * g[2] + c11 * g[3];
                *o = c0 * g[4] + c1 * g[5];
            }
            return out;
        }
        let corner = |di: usize, dj: usize, dk: usize, c: usize| -> F {
            let (i, j, k) = (
                i0[0].wrapping_add(di),
                i0[1].wrapping_add(dj),
                i0[2].wrapping_add(dk),
            );
            if i < self.nx && j < self.ny && k < self.nz {
                self.data[k * sz + j * sy + i * sx + c]
            } else {
                F::zero()
            }
        };
        for (c, o) in out.iter_mut().enumerate() {
            let c00 = corner(0, 0, 0, c) * g[0] + corner(1, 0, 0, c) * g[1];
            let c10 = corner(0, 1, 0, c) * g[0] + corner(1, 1, 0, c) * g[1];
            let c01 = corner(0, 0, 1, c) * g[0] + corner(1, 0, 1, c) * g[1];
            let c11 = corner(0, 1, 1, c) * g[0] + corner(1, 1, 1, c) * g[1];
            let c0 = c00 * g[2] + c10 * g[3];
            let c1 = c01 * g[2] + c11 * g[3];
            *o = c0 * g[4] + c1 * g[5];
        }
        out
    }
}

/// `floor(x)` as an integer and as a float, by truncation and a correction
/// (no libm call: x86-64 without SSE4.1 has no floor instruction). Values
/// beyond +-4.6e18 saturate there, which callers treat as outside.
#[inline(always)]
pub fn floor_i64<F: Real>(x: F) -> (i64, F) {
    let lim = F::of(4.6e18);
    let x = fmin(fmax(x, -lim), lim);
    let t = x.to_i64().unwrap_or(0);
    let tf = F::of(t as f64);
    if tf > x {
        (t - 1, tf - F::one())
    } else {
        (t, tf)
    }
}

/// `min` for operands known not to be NaN: one compare-select (the
/// NaN-aware `f32::min` costs four more instructions in the hot loop).
#[inline(always)]
pub fn fmin<F: Real>(a: F, b: F) -> F {
    if a < b {
        a
    } else {
        b
    }
}

/// `max` for operands known not to be NaN (see [`fmin`]).
#[inline(always)]
pub fn fmax<F: Real>(a: F, b: F) -> F {
    if a > b {
        a
    } else {
        b
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
        }
    }
}

/// A colour field in precision `F`.
#[derive(Clone, Debug)]
pub enum ColorField<F> {
    Constant([F; 3]),
    Grid(Grid<F>),
}

impl<F: Real> ColorField<F> {
    #[inline]
    pub fn color(&self, x: [F; 3]) -> [F; 3] {
        match self {
            ColorField::Constant(c) => *c,
            ColorField::Grid(g) => g.trilinear::<3>(x),
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
}

impl<F: Real> Medium<F> {
    /// The medium of `field` and `color` in precision `F`.
    pub fn new(field: &FieldDesc, color: &ColorDesc) -> Medium<F> {
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
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const B0: [f64; 3] = [-1.0; 3];
    const B1: [f64; 3] = [1.0; 3];

    #[test]
    fn trilinear_is_exact_for_linear_functions_and_hits_nodes() {
        let f = |x: [f64; 3]| 2.0 + x[0] + 0.5 * x[1] - 0.25 * x[2];
        let g = GridDesc::sample([5, 4, 3], B0, B1, Oob::Zero, f);
        let r: Grid<f64> = Grid::from_desc(&g);
        for x in [
            [0.1, -0.3, 0.7],
            [-1.0, -1.0, -1.0],
            [1.0, 1.0, 1.0],
            [0.99, -0.99, 0.5],
        ] {
            assert!((r.trilinear::<1>(x)[0] - f(x)).abs() < 1e-14, "{x:?}");
        }
        // Node (k, j, i) = (1, 2, 0) sits at x = -1, y = -1 + 2 * 2 / 3, z = -1 + 2 / 4.
        let v = r.trilinear::<1>([-1.0, -1.0 + 4.0 / 3.0, -0.5])[0];
        assert_eq!(v, g.data[(4 + 2) * 3]);
    }

    #[test]
    fn oob_zero_fades_and_clamp_holds_the_face_value() {
        let g = GridDesc::filled([3, 3, 3], &[2.0], B0, B1, Oob::Zero);
        let z: Grid<f64> = Grid::from_desc(&g);
        let c: Grid<f64> = Grid::from_desc(&GridDesc {
            oob: Oob::Clamp,
            ..g
        });
        // Half an index cell beyond x = +1: half the corners are outside.
        assert!((z.trilinear::<1>([1.5, 0.0, 0.0])[0] - 1.0).abs() < 1e-15);
        assert_eq!(z.trilinear::<1>([3.1, 0.0, 0.0])[0], 0.0);
        assert_eq!(z.trilinear::<1>([-2.5, 0.0, 0.0])[0], 0.0);
        assert_eq!(c.trilinear::<1>([1.5, 0.0, 0.0])[0], 2.0);
        assert_eq!(c.trilinear::<1>([-7.0, 9.0, 0.3])[0], 2.0);
    }

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

    #[test]
    fn analytic_fields_follow_their_formulas() {
        let slabs = Analytic::Slabs {
            axis: 0,
            breaks: vec![-1.0, -0.2, 0.3, 1.0],
            sigma: vec![0.5, 8.0, 1.0],
        };
        let f: Field<f32> = FieldDesc::Analytic(slabs.clone()).to_real();
        assert_eq!(f.sigma([-0.2, 0.0, 0.0]), 8.0);
        assert_eq!(f.sigma([0.3, 0.0, 0.0]), 1.0);
        assert_eq!(f.sigma([1.0, 0.0, 0.0]), 1.0);
        assert_eq!(f.sigma([1.0001, 0.0, 0.0]), 0.0);
        let shell = FieldDesc::Analytic(Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        });
        let s: Field<f64> = shell.to_real();
        assert_eq!(s.sigma([0.65, 0.0, 0.0]), 30.0);
        assert_eq!(s.sigma([0.0, 0.5, 0.0]), 0.0);
        let g: Field<f64> = FieldDesc::Analytic(Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.0; 3],
            std: 0.3,
        })
        .to_real();
        assert!((g.sigma([0.3, 0.0, 0.0]) - 20.0 * (-0.5f64).exp()).abs() < 1e-13);
    }

    #[test]
    fn invalid_fields_are_refused_with_their_key() {
        let bad = Analytic::Slabs {
            axis: 0,
            breaks: vec![0.0, 0.0],
            sigma: vec![1.0],
        };
        assert!(bad
            .validate("field", B0, B1)
            .unwrap_err()
            .to_string()
            .contains("increasing"));
        let neg = Analytic::Linear {
            a: 0.5,
            g: [1.0, 0.0, 0.0],
        };
        assert!(neg.validate("field", B0, B1).is_err());
        let mut g = GridDesc::filled([2, 2, 2], &[1.0], B0, B1, Oob::Zero);
        g.data[3] = f64::NAN;
        assert!(g
            .validate("grid.npy", true)
            .unwrap_err()
            .to_string()
            .contains("flat index 3"));
        g.data[3] = -1.0;
        assert!(g.validate("grid.npy", true).is_err());
        assert!(g.validate("colour.npy", false).is_ok());
    }

    #[test]
    fn occupancy_tests_are_conservative() {
        let shell = Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        };
        assert!(!shell.may_be_nonzero([-0.1; 3], [0.1; 3]));
        assert!(shell.may_be_nonzero([0.6, 0.0, 0.0], [0.7, 0.1, 0.1]));
        assert!(!shell.may_be_nonzero([0.9, 0.9, 0.9], [1.0, 1.0, 1.0]));
        let g = GridDesc::sample([9, 9, 9], B0, B1, Oob::Zero, |x| {
            if x[0] > 0.6 {
                1.0
            } else {
                0.0
            }
        });
        assert!(!g.may_be_nonzero([-1.0; 3], [0.2, 1.0, 1.0]));
        assert!(g.may_be_nonzero([0.3, -1.0, -1.0], [0.5, 1.0, 1.0]));
    }
}
