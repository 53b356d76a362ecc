//! Test fixtures shared by the voxel casts' bit-identity tests (per-ray vs
//! SSE, lanes, packets, node order): the scene list, the LOD parameters and
//! the ray sets, so every fast path is checked against the per-ray cast on
//! the same inputs.

use crate::rng::rand_f64;

use super::cast::{CastParams, CastReal, Lod};
use super::raysets::incoherent;
use super::shape::{Shape, VoxelBox};

/// Two boxes: a one-voxel column through the whole grid (depth 6: 64
/// voxels) and a thin slab.
pub fn two_boxes() -> Shape {
    Shape::Boxes {
        boxes: vec![
            VoxelBox {
                min: [9, 3, 0],
                max: [9, 3, 63],
            },
            VoxelBox {
                min: [1, 1, 1],
                max: [40, 50, 2],
            },
        ],
    }
}

/// The scenes the fast casts are compared on, with their depths: a sphere,
/// a Menger sponge, [`two_boxes`].
pub fn scenes() -> [(Shape, u32); 3] {
    [
        (Shape::Sphere { radius: 0.8 }, 7),
        (Shape::Menger { level: 4 }, 7),
        (two_boxes(), 6),
    ]
}

/// Default parameters with an LOD cut of `dir_size` (origin size 0).
pub fn lod(dir_size: f64) -> CastParams {
    CastParams {
        lod: Some(Lod {
            orig_size: 0.0,
            dir_size,
        }),
        ..CastParams::default()
    }
}

/// `n` hard f32 rays: origins in [-2.5, 2.5]^3 (outside and inside the
/// box), every sixth axis-parallel, diagonal (ties), in a coordinate plane
/// (grazing), or from one point (coherent); the rest random.
pub fn hard_rays(n: u32, seed: u32) -> (Vec<[f32; 3]>, Vec<[f32; 3]>) {
    (0..n)
        .map(|i| {
            let u = |k: u32| rand_f64(seed, i, 0, k);
            let mut o = [0, 1, 2].map(|k| (-2.5 + 5.0 * u(k)) as f32);
            let mut d = [0, 1, 2].map(|k| (-1.0 + 2.0 * u(3 + k)) as f32);
            match i % 6 {
                0 => d = [0.0, 0.0, -1.0],
                1 => d = [1.0, 1.0, 1.0],
                2 => d[0] = 0.0,
                3 => {
                    o = [0.3, 0.4, 2.5];
                    d[2] = -2.0;
                }
                _ => {}
            }
            let n = (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt().max(1e-6);
            (o, d.map(|x| x / n))
        })
        .unzip()
}

/// [`incoherent`] rays (`n`, `seed`) rounded to `F`, as origin and
/// direction arrays.
pub fn incoherent_in<F: CastReal>(n: u32, seed: u32) -> (Vec<[F; 3]>, Vec<[F; 3]>) {
    incoherent(n, seed)
        .into_iter()
        .map(|(o, d)| (o.map(F::of), d.map(F::of)))
        .unzip()
}
