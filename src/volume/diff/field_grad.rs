//! Field derivatives for `f_diff`: the closed enums of `field/`,
//! differentiated (trilinear cells, grid gradients, parameter indices).

use crate::real::Real;

use super::super::field::{floor_i64, fmax, fmin, ColorField, Field, Grid, Oob};

/// The trilinear cell of a point: base corner, fractions, and d(frac)/dx
/// per axis (0 where a clamp holds the coordinate). Mirrors
/// `Grid::trilinear` operation for operation.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Cell<F> {
    pub base: [i64; 3],
    pub f: [F; 3],
    pub ds: [F; 3],
}

/// The cell of `x`, or `None` where every corner is outside (value 0).
/// `floor` by truncation ([`floor_i64`]), as the forward query takes it.
#[inline]
pub fn cell_of<F: Real>(g: &Grid<F>, x: [F; 3]) -> Option<Cell<F>> {
    let n = [g.nx, g.ny, g.nz];
    let mut c = Cell {
        base: [0; 3],
        f: [F::zero(); 3],
        ds: g.scale,
    };
    for a in 0..3 {
        let u = (x[a] - g.bmin[a]) * g.scale[a];
        let top = (n[a] - 1) as i64;
        match g.oob {
            Oob::Clamp => {
                let cl = fmin(fmax(u, F::zero()), F::of(top as f64));
                let (mut fl, mut ff) = floor_i64(cl);
                if fl > top - 1 {
                    (fl, ff) = (top - 1, F::of((top - 1) as f64));
                }
                c.base[a] = fl;
                c.f[a] = cl - ff;
                if u < F::zero() || u > F::of(top as f64) {
                    c.ds[a] = F::zero();
                }
            }
            Oob::Zero => {
                let (fl, ff) = floor_i64(u);
                if fl < -1 || fl > top {
                    return None;
                }
                c.f[a] = u - ff;
                c.base[a] = fl;
            }
        }
    }
    Some(c)
}

/// Whether all eight corners of `base` are grid nodes.
#[inline(always)]
pub(super) fn cell_inside<F>(g: &Grid<F>, base: [i64; 3]) -> bool {
    let n = [g.nx, g.ny, g.nz];
    (0..3).all(|a| base[a] >= 0 && base[a] + 1 < n[a] as i64)
}

/// Flat node offsets of corners 0..8 from the base corner (bit a = +1 on axis a).
#[inline(always)]
pub(super) fn corner_offsets<F>(g: &Grid<F>) -> [usize; 8] {
    let (sy, sz) = (g.nx, g.nx * g.ny);
    [0, 1, sy, sy + 1, sz, sz + 1, sz + sy, sz + sy + 1]
}

/// Trilinear weight of corner `d` (bit a = offset on axis a).
#[inline]
pub(super) fn corner_weight<F: Real>(f: [F; 3], d: usize) -> F {
    let one = F::one();
    let p = |a: usize| if d >> a & 1 == 1 { f[a] } else { one - f[a] };
    p(0) * p(1) * p(2)
}

/// Flat node index of corner `d` of `base`, `None` outside the grid.
#[inline]
pub(super) fn corner_node<F>(g: &Grid<F>, base: [i64; 3], d: usize) -> Option<usize> {
    let i = base[0] + (d & 1) as i64;
    let j = base[1] + (d >> 1 & 1) as i64;
    let k = base[2] + (d >> 2 & 1) as i64;
    if i < 0 || j < 0 || k < 0 || i >= g.nx as i64 || j >= g.ny as i64 || k >= g.nz as i64 {
        return None;
    }
    Some((k as usize * g.ny + j as usize) * g.nx + i as usize)
}

/// `sum_ch gout[ch] grad value_ch(x)` of a `C`-channel grid, in closed
/// form: with `v_d = sum_ch gout[ch] value_ch(corner d)` (0 outside the
/// grid), `d/dfx = ((v1 - v0)(1 - fy) + (v3 - v2) fy)(1 - fz) + ((v5 - v4)(1 - fy)
/// + (v7 - v6) fy) fz` and likewise for y and z, times `ds` per axis.
#[inline]
pub(super) fn grid_grad<F: Real, const C: usize>(g: &Grid<F>, c: &Cell<F>, gout: [F; C]) -> [F; 3] {
    debug_assert_eq!(g.ch, C);
    let dot = |node: usize| {
        let mut v = F::zero();
        for (ch, go) in gout.iter().enumerate() {
            v += *go * g.data[node * C + ch];
        }
        v
    };
    let mut v = [F::zero(); 8];
    if cell_inside(g, c.base) {
        let b = (c.base[2] as usize * g.ny + c.base[1] as usize) * g.nx + c.base[0] as usize;
        for (vd, o) in v.iter_mut().zip(corner_offsets(g)) {
            *vd = dot(b + o);
        }
    } else {
        for (d, vd) in v.iter_mut().enumerate() {
            if let Some(node) = corner_node(g, c.base, d) {
                *vd = dot(node);
            }
        }
    }
    let one = F::one();
    let [fx, fy, fz] = c.f;
    let (ex, ey, ez) = (one - fx, one - fy, one - fz);
    let dx = ((v[1] - v[0]) * ey + (v[3] - v[2]) * fy) * ez
        + ((v[5] - v[4]) * ey + (v[7] - v[6]) * fy) * fz;
    let dy = ((v[2] - v[0]) * ex + (v[3] - v[1]) * fx) * ez
        + ((v[6] - v[4]) * ex + (v[7] - v[5]) * fx) * fz;
    let dz = ((v[4] - v[0]) * ex + (v[5] - v[1]) * fx) * ey
        + ((v[6] - v[2]) * ex + (v[7] - v[3]) * fx) * fy;
    [dx * c.ds[0], dy * c.ds[1], dz * c.ds[2]]
}

/// grad sigma at `x` (0 where sigma is piecewise constant).
#[inline]
pub fn sigma_grad<F: Real>(field: &Field<F>, x: [F; 3]) -> [F; 3] {
    match field {
        Field::Constant { .. } | Field::Slabs { .. } | Field::Shell { .. } => [F::zero(); 3],
        Field::Gaussian {
            amplitude,
            mean,
            inv_two_var,
        } => {
            let dx = [x[0] - mean[0], x[1] - mean[1], x[2] - mean[2]];
            let s = *amplitude
                * (-(dx[0] * dx[0] + dx[1] * dx[1] + dx[2] * dx[2]) * *inv_two_var).exp();
            let k = -F::of(2.0) * *inv_two_var * s;
            [k * dx[0], k * dx[1], k * dx[2]]
        }
        Field::Linear { a, g } => {
            if *a + g[0] * x[0] + g[1] * x[1] + g[2] * x[2] > F::zero() {
                *g
            } else {
                [F::zero(); 3]
            }
        }
        Field::Grid(g) => match cell_of(g, x) {
            Some(c) => grid_grad::<F, 1>(g, &c, [F::one()]),
            None => [F::zero(); 3],
        },
        Field::HashMlp(h) => h.backward(x, [F::one(), F::zero(), F::zero(), F::zero()], None),
    }
}

/// `J_c(x)^T gc` of the colour field.
#[inline]
pub(super) fn color_grad<F: Real>(color: &ColorField<F>, x: [F; 3], gc: [F; 3]) -> [F; 3] {
    match color {
        // The hash field's colour head is differentiated with its density.
        ColorField::Constant(_) | ColorField::Mlp => [F::zero(); 3],
        ColorField::Grid(g) => match cell_of(g, x) {
            Some(c) => grid_grad::<F, 3>(g, &c, gc),
            None => [F::zero(); 3],
        },
    }
}

/// Parameter index of the constant / slab density at `x` (as `Field::sigma`
/// chooses the slab); `None` for other fields or outside every slab.
#[inline]
pub(super) fn param_index<F: Real>(field: &Field<F>, x: [F; 3]) -> Option<usize> {
    match field {
        Field::Constant { .. } => Some(0),
        Field::Slabs {
            axis,
            breaks,
            sigma,
        } => {
            let v = x[*axis];
            let n = sigma.len();
            (0..n)
                .find(|&i| breaks[i] <= v && (v < breaks[i + 1] || (i + 1 == n && v <= breaks[n])))
        }
        _ => None,
    }
}

pub(super) fn param_count<F>(field: &Field<F>) -> usize {
    match field {
        Field::Constant { .. } => 1,
        Field::Slabs { sigma, .. } => sigma.len(),
        _ => 0,
    }
}

#[cfg(test)]
mod tests {
    use super::super::super::field::GridDesc;
    use super::*;

    /// The per-corner derivative of the trilinear weights (the referee of
    /// the closed form).
    fn per_corner<const C: usize>(g: &Grid<f64>, c: &Cell<f64>, gout: [f64; C]) -> [f64; 3] {
        let mut out = [0.0; 3];
        for d in 0..8 {
            let Some(node) = corner_node(g, c.base, d) else {
                continue;
            };
            let v: f64 = (0..C).map(|ch| gout[ch] * g.data[node * C + ch]).sum();
            for (a, o) in out.iter_mut().enumerate() {
                let mut dw = if d >> a & 1 == 1 { 1.0 } else { -1.0 };
                for b in (0..3).filter(|&b| b != a) {
                    dw *= if d >> b & 1 == 1 {
                        c.f[b]
                    } else {
                        1.0 - c.f[b]
                    };
                }
                *o += v * dw * c.ds[a];
            }
        }
        out
    }

    #[test]
    fn closed_form_grid_gradient_matches_the_per_corner_sum_and_fd() {
        let b0 = [-1.0; 3];
        let b1 = [1.0, 0.8, 1.2];
        for oob in [Oob::Zero, Oob::Clamp] {
            let mut d = GridDesc::sample([5, 6, 7], b0, b1, oob, |_| 0.0);
            d.ch = 4;
            d.data = (0..5 * 6 * 7 * 4)
                .map(|i| crate::rng::rand_f64(4, i, 0, 0) * 3.0)
                .collect();
            let g: Grid<f64> = Grid::from_desc(&d);
            let gout = [0.7, -0.4, 1.3, 0.2];
            let val = |x: [f64; 3]| {
                let v = g.trilinear::<4>(x);
                (0..4).map(|c| gout[c] * v[c]).sum::<f64>()
            };
            for q in 0..400u32 {
                let x = [0, 1, 2].map(|a| crate::rng::rand_f64(7, q, 0, a) * 2.6 - 1.3);
                let Some(c) = cell_of(&g, x) else {
                    continue;
                };
                let ours = grid_grad::<f64, 4>(&g, &c, gout);
                let refr = per_corner::<4>(&g, &c, gout);
                for a in 0..3 {
                    assert!((ours[a] - refr[a]).abs() < 1e-12, "{x:?} {a}");
                    let h = 1e-6;
                    let (mut xp, mut xm) = (x, x);
                    xp[a] += h;
                    xm[a] -= h;
                    let fd = (val(xp) - val(xm)) / (2.0 * h);
                    // Kinks at cell faces: skip points within h of one.
                    if cell_of(&g, xp).map(|p| p.base) == cell_of(&g, xm).map(|m| m.base) {
                        assert!((ours[a] - fd).abs() < 1e-6 * (1.0 + fd.abs()), "{x:?} {a}");
                    }
                }
            }
        }
    }
}
