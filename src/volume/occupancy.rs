//! Occupancy bitfield for empty-space skipping (seed 000, section 9).
//!
//! The world box is cut into `res^3` cells; a cell's bit is set when the
//! density may be non-zero anywhere in the cell grown by a margin (1/64 of a
//! cell plus 1e-6 of the box on every side), so a sample whose cell index is
//! off by one through rounding still finds a conservative bit. A sample in a
//! clear cell has sigma = 0 exactly, hence alpha = 0 and no effect on any
//! accumulator: skipping it keeps the sample lattice and leaves the image
//! bit-identical while fewer samples are taken.

use crate::budget::{bytes_for, MemBudget};
use crate::error::{Error, Result};
use crate::rays::Aabb;
use crate::real::Real;

use super::field::{fmax, fmin, FieldDesc};

/// Bits of occupied cells, x fastest: cell (k, j, i) is bit `(k res + j) res + i`.
#[derive(Clone, Debug, PartialEq)]
pub struct Occupancy<F> {
    pub res: u32,
    pub bits: Vec<u32>,
    pub bmin: [F; 3],
    /// Cells per world unit, per axis.
    pub inv_cell: [F; 3],
}

/// Largest resolution accepted.
pub const MAX_RES: u32 = 512;

impl<F: Real> Occupancy<F> {
    /// Builds the bitfield of `field` over `aabb` at `res^3` cells.
    pub fn build(
        field: &FieldDesc,
        aabb: &Aabb,
        res: u32,
        budget: &MemBudget,
    ) -> Result<Occupancy<F>> {
        if res == 0 || res > MAX_RES {
            return Err(Error::invalid(
                "occupancy",
                format!("resolution {res} is not in 1..={MAX_RES}"),
            ));
        }
        let n = (res as u64).pow(3);
        budget.check("occupancy bits", bytes_for(n.div_ceil(32), 4))?;
        let r = res as usize;
        let size: [f64; 3] = [0, 1, 2].map(|a| aabb.max[a] - aabb.min[a]);
        let cell: [f64; 3] = size.map(|s| s / res as f64);
        let bits_per_z: Vec<Vec<bool>> = crate::parallel::par_collect("occupancy_build", r, |k| {
            let mut v = Vec::with_capacity(r * r);
            for j in 0..r {
                for i in 0..r {
                    let idx = [i, j, k];
                    let lo = [0, 1, 2].map(|a| {
                        aabb.min[a] + idx[a] as f64 * cell[a] - cell[a] / 64.0 - 1e-6 * size[a]
                    });
                    let hi = [0, 1, 2].map(|a| {
                        aabb.min[a]
                            + (idx[a] + 1) as f64 * cell[a]
                            + cell[a] / 64.0
                            + 1e-6 * size[a]
                    });
                    v.push(field.may_be_nonzero(lo, hi));
                }
            }
            v
        });
        let mut bits = vec![0u32; (n as usize).div_ceil(32)];
        for (b, on) in bits_per_z.into_iter().flatten().enumerate() {
            if on {
                bits[b / 32] |= 1 << (b % 32);
            }
        }
        Ok(Occupancy {
            res,
            bits,
            bmin: aabb.min.map(F::of),
            inv_cell: [0, 1, 2].map(|a| F::of(res as f64 / size[a])),
        })
    }

    /// Whether the cell holding `x` may have density (points outside the
    /// box use the nearest cell).
    #[inline]
    pub fn occupied(&self, x: [F; 3]) -> bool {
        let top = F::of((self.res - 1) as f64);
        let mut c = [0u32; 3];
        for a in 0..3 {
            // Clamped to [0, res - 1] first, so truncation is floor.
            let u = fmin(
                fmax((x[a] - self.bmin[a]) * self.inv_cell[a], F::zero()),
                top,
            );
            c[a] = u.to_u32().unwrap_or(0);
        }
        let b = ((c[2] * self.res + c[1]) * self.res + c[0]) as usize;
        self.bits[b / 32] >> (b % 32) & 1 == 1
    }

    /// Number of occupied cells.
    pub fn count(&self) -> u64 {
        self.bits.iter().map(|b| b.count_ones() as u64).sum()
    }
}

#[cfg(test)]
mod tests {
    use super::super::field::Analytic;
    use super::*;

    #[test]
    fn shell_occupancy_clears_the_core_and_corners_only() {
        let shell = FieldDesc::Analytic(Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        });
        let o =
            Occupancy::<f32>::build(&shell, &Aabb::UNIT, 16, &MemBudget::fixed(1 << 20)).unwrap();
        assert!(!o.occupied([0.0, 0.0, 0.0]));
        assert!(!o.occupied([0.95, 0.95, 0.95]));
        assert!(o.occupied([0.65, 0.0, 0.0]));
        assert!(o.count() > 0 && o.count() < 16 * 16 * 16 / 2);
    }

    #[test]
    fn every_point_with_density_is_in_an_occupied_cell() {
        let shell = Analytic::Shell {
            centre: [0.1, 0.0, -0.2],
            r0: 0.3,
            r1: 0.35,
            s: 1.0,
        };
        let fd = FieldDesc::Analytic(shell.clone());
        let o = Occupancy::<f32>::build(&fd, &Aabb::UNIT, 8, &MemBudget::fixed(1 << 20)).unwrap();
        let f: super::super::field::Field<f32> = fd.to_real();
        for i in 0..20_000u32 {
            let x = [0, 1, 2].map(|d| crate::rng::rand_f32(1, i, 0, d) * 2.0 - 1.0);
            if f.sigma(x) > 0.0 {
                assert!(o.occupied(x), "{x:?}");
            }
        }
    }
}
