//! Field derivatives for `f_diff`: the closed enums of `field/`,
//! differentiated (trilinear cells, grid gradients, parameter indices).

use crate::real::Real;

use super::super::field::{ColorField, Field, Grid, Oob};

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
        let top = F::of((n[a] - 1) as f64);
        match g.oob {
            Oob::Clamp => {
                let cl = u.max(F::zero()).min(top);
                let fl = cl.floor().min(F::of((n[a] - 2) as f64));
                c.base[a] = fl.to_i64().unwrap_or(0);
                c.f[a] = cl - fl;
                if u < F::zero() || u > top {
                    c.ds[a] = F::zero();
                }
            }
            Oob::Zero => {
                let fl = u.floor();
                if fl < -F::one() || fl > top {
                    return None;
                }
                c.f[a] = u - fl;
                c.base[a] = fl.to_i64().unwrap_or(-1);
            }
        }
    }
    Some(c)
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

/// `sum_ch gout[ch] grad value_ch(x)` of a `C`-channel grid.
#[inline]
pub(super) fn grid_grad<F: Real, const C: usize>(g: &Grid<F>, c: &Cell<F>, gout: [F; C]) -> [F; 3] {
    let one = F::one();
    let mut out = [F::zero(); 3];
    for d in 0..8 {
        let Some(node) = corner_node(g, c.base, d) else {
            continue;
        };
        let mut v = F::zero();
        for (ch, go) in gout.iter().enumerate() {
            v += *go * g.data[node * g.ch + ch];
        }
        for (a, o) in out.iter_mut().enumerate() {
            let mut dw = if d >> a & 1 == 1 { one } else { -one };
            for b in 0..3 {
                if b != a {
                    dw *= if d >> b & 1 == 1 {
                        c.f[b]
                    } else {
                        one - c.f[b]
                    };
                }
            }
            *o += v * dw * c.ds[a];
        }
    }
    out
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
