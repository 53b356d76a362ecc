//! Which rays form a beam ([`super::beam`]): tiles of a camera image, or
//! runs of consecutive rays, walked a band (one row of tiles) at a time in
//! memory order.

use std::ops::Range;

/// The beam tiles of `n` rays shaped `shape`: `tile` x `tile` pixels of an
/// (H, W) image in row order, else runs of `tile^2` consecutive rays (one
/// row of tiles one ray high). A band (one row of tiles) is a contiguous
/// range of rays.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Tiling {
    n: usize,
    /// Rays per image row.
    width: usize,
    /// A tile's width and height.
    tw: usize,
    th: usize,
}

impl Tiling {
    pub fn new(shape: &[usize], n: usize, tile: usize) -> Tiling {
        let t = tile.max(1);
        match *shape {
            [h, w] if h > 1 && h * w == n => Tiling {
                n,
                width: w,
                tw: t,
                th: t,
            },
            _ => Tiling {
                n,
                width: t * t,
                tw: t * t,
                th: 1,
            },
        }
    }

    /// How many bands there are.
    pub fn bands(&self) -> usize {
        self.n.div_ceil(self.width * self.th)
    }

    /// The rays of band `b`.
    pub fn band(&self, b: usize) -> Range<usize> {
        let len = self.width * self.th;
        b * len..((b + 1) * len).min(self.n)
    }

    /// The columns of each tile across a band.
    fn columns(&self) -> Vec<Range<usize>> {
        (0..self.across())
            .map(|j| j * self.tw..((j + 1) * self.tw).min(self.width))
            .collect()
    }

    /// The first ray of each image row of band `b`.
    fn rows(&self, b: usize) -> impl Iterator<Item = usize> {
        let band = self.band(b);
        (band.start..band.end).step_by(self.width)
    }

    /// How many tiles a band has.
    pub fn across(&self) -> usize {
        self.width.div_ceil(self.tw)
    }

    /// Calls `f(j, row_part)` for each row of each tile of band `b`, in
    /// memory order: `row_part` the rays of tile `j` in that row.
    pub fn each_part(&self, b: usize, mut f: impl FnMut(usize, Range<usize>)) {
        let cols = self.columns();
        for row in self.rows(b) {
            for (j, c) in cols.iter().enumerate() {
                let part = (row + c.start).min(self.n)..(row + c.end).min(self.n);
                if !part.is_empty() {
                    f(j, part);
                }
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The rays of band `b`'s tile `j` (counted across), in order.
    fn rays(t: &Tiling, b: usize, j: usize) -> Vec<usize> {
        let cols = t.columns().get(j).cloned().unwrap_or(0..0);
        t.rows(b)
            .flat_map(|row| cols.clone().map(move |x| row + x))
            .filter(|&i| i < t.n)
            .collect()
    }

    #[test]
    fn tiles_cover_every_ray_once() {
        for (shape, tile) in [(vec![10, 13], 4), (vec![16, 16], 8), (vec![37], 3)] {
            let n = shape.iter().product::<usize>();
            let t = Tiling::new(&shape, n, tile);
            let mut seen = vec![0; n];
            let mut order = Vec::new();
            for b in 0..t.bands() {
                let mut of = vec![usize::MAX; n];
                for j in 0..t.across() {
                    for i in rays(&t, b, j) {
                        assert!(t.band(b).contains(&i), "{shape:?} tile {j} ray {i}");
                        seen[i] += 1;
                        of[i] = j;
                    }
                }
                t.each_part(b, |j, part| {
                    for i in part {
                        assert_eq!(of[i], j, "{shape:?} ray {i}");
                        order.push(i);
                    }
                });
            }
            assert!(seen.iter().all(|&c| c == 1), "{shape:?}");
            assert_eq!(order, (0..n).collect::<Vec<_>>(), "{shape:?}");
        }
        // A 4x4 tile of a 13-wide image holds rows of 4 pixels.
        assert_eq!(
            rays(&Tiling::new(&[10, 13], 130, 4), 0, 1)[..5],
            [4, 5, 6, 7, 17]
        );
    }
}
