//! Reductions of per-sample grid gradients into nodes: the canonical sorted
//! gather and the fixed-chunk dense scatter (module doc of `diff`).

use crate::real::Real;

use super::super::field::Grid;
use super::field_grad::{cell_inside, corner_node, corner_offsets, corner_weight, Cell};
use super::Ksum;

// Reductions.

/// One sample's record for the sorted reduction.
#[derive(Clone, Copy, Debug)]
pub(super) struct GridRec<F, const C: usize> {
    pub(super) key: u32,
    pub(super) f: [F; 3],
    pub(super) g: [F; C],
}

/// Cell key of a base corner: `(base + 1)` per axis in a `(n+1)^3` lattice.
pub(super) fn cell_key<F>(g: &Grid<F>, base: [i64; 3]) -> u32 {
    let (i, j, k) = (
        (base[0] + 1) as usize,
        (base[1] + 1) as usize,
        (base[2] + 1) as usize,
    );
    ((k * (g.ny + 1) + j) * (g.nx + 1) + i) as u32
}

pub(super) fn push_rec<F: Real, const C: usize>(
    g: &Grid<F>,
    cell: Option<Cell<F>>,
    v: [F; C],
    out: &mut Vec<GridRec<F, C>>,
) {
    if let Some(c) = cell {
        out.push(GridRec {
            key: cell_key(g, c.base),
            f: c.f,
            g: v,
        });
    }
}

/// A unit's dense gradient grid (chunked reduction) and the x-rows of
/// nodes it touched: [`sum_chunks`] skips untouched rows (all zeros, their
/// pages never faulted in), which leaves every sum's bits unchanged (a sum
/// that starts at +0 is never -0, so adding +0 changes nothing).
pub(super) struct Dense<F> {
    pub(super) data: Vec<F>,
    rows: Vec<bool>,
    /// Elements per row.
    row: usize,
}

impl<F: Real> Dense<F> {
    /// `len` zeros in rows of `row` elements, none touched yet.
    pub(super) fn new(len: usize, row: usize) -> Self {
        let row = row.max(1);
        Dense {
            data: vec![F::zero(); len],
            rows: vec![false; len.div_ceil(row)],
            row,
        }
    }

    /// For a grid of `C` channels per node: one row per x-row of nodes.
    pub(super) fn grid<const C: usize>(g: &Grid<F>) -> Self {
        Self::new(g.data.len(), g.nx * C)
    }

    /// Marks every row (a sink written element by element elsewhere).
    pub(super) fn touch_all(&mut self) {
        self.rows.fill(true);
    }

    /// Marks row `q` touched; its first touch writes its zeros, so the
    /// pages of the (lazily zeroed) buffer fault in once, on a write,
    /// rather than twice (a read maps the shared zero page, the first `+=`
    /// then copies it and flushes every core's TLB).
    #[inline(always)]
    pub(super) fn touch(&mut self, q: usize) {
        if !self.rows[q] {
            self.rows[q] = true;
            let end = ((q + 1) * self.row).min(self.data.len());
            self.data[q * self.row..end].fill(F::zero());
        }
    }

    /// [`Dense::touch`] of the four x-rows of nodes of the cell at
    /// `base` (all eight corners inside `g`).
    #[inline(always)]
    pub(super) fn touch_cell(&mut self, g: &Grid<F>, base: [i64; 3]) {
        let r = base[2] as usize * g.ny + base[1] as usize;
        for q in [r, r + 1, r + g.ny, r + g.ny + 1] {
            self.touch(q);
        }
    }
}

pub(super) fn scatter_dense<F: Real, const C: usize>(
    g: &Grid<F>,
    cell: Option<Cell<F>>,
    v: [F; C],
    out: &mut Dense<F>,
) {
    let Some(c) = cell else {
        return;
    };
    if cell_inside(g, c.base) {
        let b = (c.base[2] as usize * g.ny + c.base[1] as usize) * g.nx + c.base[0] as usize;
        out.touch_cell(g, c.base);
        for (d, o) in corner_offsets(g).into_iter().enumerate() {
            let w = corner_weight(c.f, d);
            let slot = &mut out.data[(b + o) * C..(b + o + 1) * C];
            for ch in 0..C {
                slot[ch] += w * v[ch];
            }
        }
        return;
    }
    for d in 0..8 {
        if let Some(node) = corner_node(g, c.base, d) {
            out.touch(node / g.nx);
            let w = corner_weight(c.f, d);
            for ch in 0..C {
                out.data[node * C + ch] += w * v[ch];
            }
        }
    }
}

/// Canonical reduction: the records (units in order, each in (ray, sample)
/// order) placed by a stable counting sort on their cell, then each node
/// sums its eight neighbouring cells (corner order 0..8, records in sorted
/// order). The order depends on the rays only, never on threads.
pub(super) fn reduce_sorted<F: Real, const C: usize>(
    g: &Grid<F>,
    parts: Vec<Vec<GridRec<F, C>>>,
) -> Vec<F> {
    let ncell = (g.nx + 1) * (g.ny + 1) * (g.nz + 1);
    let mut start = vec![0u32; ncell + 1];
    for r in parts.iter().flatten() {
        start[r.key as usize + 1] += 1;
    }
    for i in 0..ncell {
        start[i + 1] += start[i];
    }
    let nodes = g.nx * g.ny * g.nz;
    let mut out = vec![F::zero(); nodes * C];
    let Some(first) = parts.iter().flatten().next().copied() else {
        return out;
    };
    let mut recs = vec![first; start[ncell] as usize];
    let mut pos = start.clone();
    for r in parts.iter().flatten() {
        let p = &mut pos[r.key as usize];
        recs[*p as usize] = *r;
        *p += 1;
    }
    drop(parts);
    crate::parallel::par_chunks("f_diff_gather", &mut out, 4096 * C, |ci, chunk| {
        let first = ci * 4096;
        for (q, slot) in chunk.chunks_mut(C).enumerate() {
            let node = first + q;
            let (i, j, k) = (node % g.nx, node / g.nx % g.ny, node / (g.nx * g.ny));
            let mut acc = [Ksum::<F>::default(); C];
            for d in 0..8 {
                let base = [
                    i as i64 - (d & 1) as i64,
                    j as i64 - (d >> 1 & 1) as i64,
                    k as i64 - (d >> 2 & 1) as i64,
                ];
                let key = cell_key(g, base) as usize;
                for r in &recs[start[key] as usize..start[key + 1] as usize] {
                    let w = corner_weight(r.f, d);
                    for (a, g) in acc.iter_mut().zip(&r.g) {
                        a.add(w * *g);
                    }
                }
            }
            for (o, a) in slot.iter_mut().zip(&acc) {
                *o = a.s;
            }
        }
    });
    out
}

/// Sums per-chunk dense grids in chunk order, skipping untouched rows
/// ([`Dense`]).
pub(super) fn sum_chunks<F: Real>(parts: &[&Dense<F>], len: usize) -> Vec<F> {
    let mut out = vec![F::zero(); len];
    crate::parallel::par_chunks("f_diff_chunk_sum", &mut out, 1 << 14, |ci, chunk| {
        sum_range(parts, ci << 14, chunk)
    });
    out
}

/// `out[i] = sum of the parts' elements first + i` in part order, skipping
/// untouched rows.
fn sum_range<F: Real>(parts: &[&Dense<F>], first: usize, out: &mut [F]) {
    let end = first + out.len();
    // A write first: one page fault per page, no copy-on-write (`Dense::touch`).
    out.fill(F::zero());
    for p in parts {
        let mut e = first;
        while e < end {
            let r = e / p.row;
            let stop = ((r + 1) * p.row).min(end);
            if p.rows[r] {
                for (o, v) in out[e - first..stop - first]
                    .iter_mut()
                    .zip(&p.data[e..stop])
                {
                    *o += *v;
                }
            }
            e = stop;
        }
    }
}

/// [`sum_chunks`] of packed `[sigma, r, g, b]` grids of `nodes` nodes,
/// split as it goes into `dsigma` (one per node) and `dcolor` (three per
/// node): the same sums, without a packed total.
pub(super) fn sum_chunks_split<F: Real>(parts: &[&Dense<F>], nodes: usize) -> (Vec<F>, Vec<F>) {
    const NODES: usize = 1 << 12;
    let mut sig = vec![F::zero(); nodes];
    let mut col = vec![F::zero(); 3 * nodes];
    let (a, b) = ((&mut sig[..], NODES), (&mut col[..], 3 * NODES));
    crate::parallel::par_chunks2("f_diff_chunk_sum", a, b, |ci, s, c| {
        let mut pk = vec![F::zero(); 4 * s.len()];
        sum_range(parts, 4 * ci * NODES, &mut pk);
        for ((s, c), v) in s
            .iter_mut()
            .zip(c.chunks_exact_mut(3))
            .zip(pk.chunks_exact(4))
        {
            *s = v[0];
            c.copy_from_slice(&v[1..]);
        }
    });
    (sig, col)
}

/// The packed `[sigma, r, g, b]` node gradients split into `dsigma` (one
/// per node) and `dcolor` (three per node), in parallel.
pub(super) fn split_packed<F: Real>(pk: &[F]) -> (Vec<F>, Vec<F>) {
    const NODES: usize = 1 << 14;
    let n = pk.len() / 4;
    let mut sig = vec![F::zero(); n];
    let mut col = vec![F::zero(); 3 * n];
    crate::parallel::par_chunks2(
        "f_diff_split",
        (&mut sig[..], NODES),
        (&mut col[..], 3 * NODES),
        |ci, s, c| {
            for ((s, c), v) in s
                .iter_mut()
                .zip(c.chunks_exact_mut(3))
                .zip(pk[4 * ci * NODES..].chunks_exact(4))
            {
                *s = v[0];
                c.copy_from_slice(&v[1..]);
            }
        },
    );
    (sig, col)
}

/// What one unit of rays (a contiguous range) produced.
pub(super) struct Unit<F> {
    pub(super) cam: Vec<[f64; 6]>,
    pub(super) param: Vec<Ksum<F>>,
    pub(super) color_const: [Ksum<F>; 3],
    pub(super) sig_recs: Vec<GridRec<F, 1>>,
    pub(super) col_recs: Vec<GridRec<F, 3>>,
    /// Packed `[sigma, r, g, b]` records / dense grid (shared geometry).
    pub(super) pk_recs: Vec<GridRec<F, 4>>,
    pub(super) sig_dense: Dense<F>,
    pub(super) col_dense: Dense<F>,
    pub(super) pk_dense: Dense<F>,
    /// dL/dparams of a hash field (flat order), dense per unit.
    pub(super) hash_dense: Dense<F>,
    pub(super) per_sample: Vec<(F, [F; 3])>,
    pub(super) samples: u64,
}

/// Rays per unit of the sorted reduction.
pub(super) const UNIT_RAYS: usize = 256;
