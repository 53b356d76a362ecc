//! Which camera ray a GPU thread casts. A GPU runs threads in lock-step
//! groups (warps of 32 on NVIDIA, 8-wide SIMD rows on lavapipe), and a group
//! runs until its slowest lane ends: a group whose rays are neighbours in
//! the image takes similar paths through the scene and wastes fewer lanes
//! than a group of one image row. [`ThreadOrder::Tiles`] gives each 64-thread
//! workgroup an 8x8 pixel tile, its threads the tile's pixels in Morton order
//! (threads 0-7 a 4x2 block, 0-15 a 4x4 block, 0-31 an 8x4 block).
//! Outputs stay in region order: only the thread that computes a ray moves.
//! GPU twin: `kernels/common.wgsl` `thread_ray` (used by
//! `kernels/voxels.wgsl` `cast_camera`).

/// How threads map onto the rays of an image region (`VoxParams.order`).
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ThreadOrder {
    /// Thread `t` casts ray `t` (region order): a warp is part of one row.
    Rows = 0,
    /// 8x8 tiles per 64-thread workgroup, Morton order inside a tile.
    Tiles = 1,
}

/// Side of a tile; a tile is one workgroup of `TILE * TILE` threads.
pub const TILE: u32 = 8;

/// Threads to dispatch for a `w` x `h` region (whole workgroups of 64).
pub fn thread_count(order: ThreadOrder, w: u32, h: u32) -> u64 {
    match order {
        ThreadOrder::Rows => w as u64 * h as u64,
        ThreadOrder::Tiles => {
            w.div_ceil(TILE) as u64 * h.div_ceil(TILE) as u64 * (TILE * TILE) as u64
        }
    }
}

/// The ray (region order, `n = w * h` rays) that thread `t` casts, `None`
/// for a thread of a partial tile past the region's edge.
pub fn thread_ray(order: ThreadOrder, t: u32, w: u32, n: u32) -> Option<u32> {
    let i = match order {
        ThreadOrder::Rows => t,
        ThreadOrder::Tiles => {
            let (tile, l) = (t / (TILE * TILE), t % (TILE * TILE));
            let tiles_x = w.div_ceil(TILE);
            let x = (tile % tiles_x) * TILE + ((l & 1) | ((l >> 1) & 2) | ((l >> 2) & 4));
            let y = (tile / tiles_x) * TILE + (((l >> 1) & 1) | ((l >> 2) & 2) | ((l >> 3) & 4));
            if x >= w {
                return None;
            }
            y.checked_mul(w)?.checked_add(x)?
        }
    };
    (i < n).then_some(i)
}

/// The fraction of lane-iterations that do work when the threads of
/// `order` run in lock-step groups of `warp` (consecutive thread ids) and a
/// group runs until its slowest lane ends; `iters[i]` is ray `i`'s loop
/// count (region order, `w` rays a row). 1 for no work at all.
pub fn warp_efficiency(iters: &[u32], order: ThreadOrder, w: u32, warp: u32) -> f64 {
    let n = iters.len() as u32;
    let h = n.checked_div(w).unwrap_or(0);
    let threads = thread_count(order, w, h);
    let (mut work, mut spent) = (0u64, 0u64);
    let mut t = 0u64;
    while t < threads {
        let end = (t + warp as u64).min(threads);
        let lanes = (t..end).filter_map(|k| thread_ray(order, k as u32, w, n));
        let (sum, max) = lanes.fold((0u64, 0u32), |(s, m), i| {
            let v = iters[i as usize];
            (s + v as u64, m.max(v))
        });
        work += sum;
        spent += (end - t) * max as u64;
        t = end;
    }
    if spent == 0 {
        1.0
    } else {
        work as f64 / spent as f64
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rays_of(order: ThreadOrder, w: u32, h: u32) -> Vec<u32> {
        (0..thread_count(order, w, h) as u32)
            .filter_map(|t| thread_ray(order, t, w, w * h))
            .collect()
    }

    #[test]
    fn every_ray_cast_by_exactly_one_thread() {
        for (w, h) in [
            (1, 1),
            (7, 3),
            (8, 8),
            (9, 17),
            (64, 5),
            (33, 40),
            (1920, 1080),
        ] {
            for order in [ThreadOrder::Rows, ThreadOrder::Tiles] {
                let mut seen = rays_of(order, w, h);
                assert_eq!(seen.len() as u32, w * h, "{order:?} {w}x{h}");
                seen.sort_unstable();
                assert!(
                    seen.iter().enumerate().all(|(k, &i)| k as u32 == i),
                    "{order:?} {w}x{h}"
                );
            }
        }
    }

    #[test]
    fn tile_threads_form_blocks() {
        // In a 24 x 16 region: threads 0-7 are the 4x2 block at the origin,
        // 0-31 the 8x4 block, 64-127 the next tile to the right.
        let w = 24;
        let xy = |t| {
            let i = thread_ray(ThreadOrder::Tiles, t, w, w * 16).unwrap();
            (i % w, i / w)
        };
        let block = |r: std::ops::Range<u32>| {
            let (xs, ys): (Vec<u32>, Vec<u32>) = r.map(xy).unzip();
            (
                *xs.iter().min().unwrap(),
                *xs.iter().max().unwrap(),
                *ys.iter().min().unwrap(),
                *ys.iter().max().unwrap(),
            )
        };
        assert_eq!(block(0..8), (0, 3, 0, 1));
        assert_eq!(block(0..32), (0, 7, 0, 3));
        assert_eq!(block(64..128), (8, 15, 0, 7));
        assert_eq!(block(192..256), (0, 7, 8, 15));
    }

    #[test]
    fn efficiency_counts_the_slowest_lane() {
        // 4 x 2 region, warps of 4: rows are (1,1,1,5) and (2,2,2,2).
        let iters = [1, 1, 1, 5, 2, 2, 2, 2];
        let e = warp_efficiency(&iters, ThreadOrder::Rows, 4, 4);
        assert!((e - 16.0 / 28.0).abs() < 1e-12, "{e}");
        // One 8x8 tile padded to 64 threads, warps of 32: Morton threads 0-7
        // cover the whole 4x2 region, the rest idle but for the block's max.
        let e = warp_efficiency(&iters, ThreadOrder::Tiles, 4, 32);
        assert!((e - 16.0 / (32.0 * 5.0)).abs() < 1e-12, "{e}");
        assert_eq!(warp_efficiency(&[0; 6], ThreadOrder::Rows, 3, 32), 1.0);
    }
}
