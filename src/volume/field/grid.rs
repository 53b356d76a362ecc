//! Dense node-aligned grids (SCENES.md "Dense grid"): the f64 description
//! ([`GridDesc`]), the render-precision grid ([`Grid`]) with its trilinear
//! query, and the libm-free `floor` / `min` / `max` of the hot loop.

use crate::error::{Error, Result};
use crate::real::Real;

use super::{Oob, MAX_SIGMA};

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

    /// This grid's shape, box and OOB policy with `ch` channels and no
    /// values, for code that reads a cell's geometry only (the backward's
    /// cells when the values live in the packed medium). A value read from
    /// it panics (index out of bounds); it never returns a wrong value.
    pub fn geometry(&self, ch: usize) -> Grid<F> {
        Grid {
            nx: self.nx,
            ny: self.ny,
            nz: self.nz,
            ch,
            data: Vec::new(),
            oob: self.oob,
            bmin: self.bmin,
            scale: self.scale,
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
            if C == 4 {
                if let Some(d32) = F::as_f32_slice(d) {
                    let (fx, fy, fz) = (f[0].f64() as f32, f[1].f64() as f32, f[2].f64() as f32);
                    let v = lerp_cell4(d32, b, sy, sz, fx, fy, fz);
                    return std::array::from_fn(|c| F::of(v[c] as f64));
                }
            }
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

/// The inside branch of [`Grid::trilinear`] for four f32 channels (the
/// packed `[sigma, r, g, b]` grid): each corner's four channels are one
/// 16-byte load and the seven lerps run on the four channels at once
/// (glam `Vec4`: SSE2 on x86-64, which every x86-64 CPU has; scalar lanes
/// elsewhere). The same IEEE multiplies and adds in the same order as the
/// scalar loop, channel by channel, so the values are bit-identical
/// (`simd_cell_equals_the_scalar_lerps`). The weights are splat from the
/// three fractions one by one (`1 - f` per lane is the scalar `1 - f`): a
/// 16-byte load of weights stored as scalars stalls store forwarding.
#[inline(always)]
fn lerp_cell4(d: &[f32], b: usize, sy: usize, sz: usize, fx: f32, fy: f32, fz: f32) -> [f32; 4] {
    use glam::Vec4;
    let (x1, y1, z1) = (Vec4::splat(fx), Vec4::splat(fy), Vec4::splat(fz));
    let (x0, y0, z0) = (Vec4::ONE - x1, Vec4::ONE - y1, Vec4::ONE - z1);
    let row = |o: usize| {
        let r = &d[o..o + 8];
        Vec4::from_slice(&r[..4]) * x0 + Vec4::from_slice(&r[4..]) * x1
    };
    let (c00, c10, c01, c11) = (row(b), row(b + sy), row(b + sz), row(b + sz + sy));
    let c0 = c00 * y0 + c10 * y1;
    let c1 = c01 * y0 + c11 * y1;
    (c0 * z0 + c1 * z1).to_array()
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
    fn simd_cell_equals_the_scalar_lerps() {
        let n = [7usize, 6, 5];
        let data: Vec<f32> = (0..n[0] * n[1] * n[2] * 4)
            .map(|i| crate::rng::rand_f32(9, i as u32, 0, 0) * 40.0 - 3.0)
            .collect();
        let (sy, sz) = (4 * n[0], 4 * n[0] * n[1]);
        for q in 0..500u32 {
            let g0 = [0, 1, 2].map(|a| crate::rng::rand_f32(3, q, 1, a));
            let g = [1.0 - g0[0], g0[0], 1.0 - g0[1], g0[1], 1.0 - g0[2], g0[2]];
            let b = ((q as usize % 4) * n[1] + q as usize % 5) * n[0] * 4 + (q as usize % 6) * 4;
            let v = lerp_cell4(&data, b, sy, sz, g0[0], g0[1], g0[2]);
            for (c, vc) in v.iter().enumerate() {
                let at = |o: usize| data[b + o + c] * g[0] + data[b + o + 4 + c] * g[1];
                let c0 = at(0) * g[2] + at(sy) * g[3];
                let c1 = at(sz) * g[2] + at(sz + sy) * g[3];
                assert_eq!(vc.to_bits(), (c0 * g[4] + c1 * g[5]).to_bits(), "{q} {c}");
            }
        }
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
}
