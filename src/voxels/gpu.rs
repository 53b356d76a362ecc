//! The voxel renderer's GPU backend: the cast's parameters rounded to the
//! kernel's f32 exactly as [`super::cast::cast::<f32>`] rounds them, the
//! contour decode table, and the kernel's per-ray results
//! (`crate::gpu::voxels`, `kernels/voxels.wgsl`) in the renderer's
//! [`VoxelHits`] conventions, and the attribute image with the decode on
//! the GPU ([`attr_image_gpu`]). [`super::through::Through::upload`] puts a
//! scene's structure on the GPU.

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::voxel_attrs::GpuAttrs;
use crate::gpu::voxels::{GpuCast, GpuCastParams, GpuOctree, GpuVoxelHit, CONTOUR_LUT_LEN};
use crate::gpu::GpuContext;
use crate::rays::thread_order::ThreadOrder;
use crate::rays::RayGen;

use super::attributes::{AttrForm, Attributes};
use super::batch::Batch;
use super::cast::CastParams;
use super::contour::decode;
use super::render::{attr_indices, shade_decoded, VoxelHits};

/// The kernel's contour decode table (`kernels/voxels.wgsl` `contour_lut`):
/// [`decode::<f32>`] of every 18-bit normal code (3 f32 each), then of the
/// 128 offset codes, then of the 128 thickness codes, so the kernel uses
/// the very f32 values the CPU cast computes in f64 and rounds.
pub fn contour_lut() -> Vec<f32> {
    let mut lut = Vec::with_capacity(CONTOUR_LUT_LEN);
    for code in 0u32..1 << 18 {
        lut.extend(decode::<f32>(code << 14).0);
    }
    lut.extend((0u32..128).map(|q| decode::<f32>(q << 7).1));
    lut.extend((0u32..128).map(|q| decode::<f32>(q).2));
    lut
}

/// The camera's rays cast on the GPU (generated there; read back into the
/// returned batch when `keep_rays`), over `gen`'s `[near, far]`, from the
/// beam starts when `beam` (where the adapter runs them).
pub fn cast_camera(
    g: &GpuOctree,
    (cam, gen): (&Camera, &RayGen),
    (p, beam): (&CastParams, bool),
    keep_rays: bool,
    budget: &MemBudget,
) -> Result<(GpuCast, Batch<f32>)> {
    let gp = GpuCastParams {
        beam,
        ..gpu_params(p)
    };
    let cast = g.cast_camera(cam, gen, &gp, keep_rays, budget)?;
    let (o, d) = cast
        .rays
        .iter()
        .map(|r| ([r[0], r[1], r[2]], [r[3], r[4], r[5]]))
        .unzip();
    let shape = gen.shape().to_vec();
    let b = Batch {
        o,
        d,
        shape,
        near: gen.near,
        far: gen.far,
        kind: None,
    };
    Ok((cast, b))
}

/// A batch's rays uploaded and cast on the GPU.
pub fn cast_batch(
    g: &GpuOctree,
    b: &Batch<f32>,
    p: &CastParams,
    budget: &MemBudget,
) -> Result<GpuCast> {
    let packed: Vec<[f32; 6]> =
        b.o.iter()
            .zip(&b.d)
            .map(|(o, d)| [o[0], o[1], o[2], d[0], d[1], d[2]])
            .collect();
    g.cast_rays(&packed, &gpu_params(p), budget)
}

/// `p` in the kernel's f32: near and far as `F::of` rounds them (far
/// clamped to `f32::MAX`, a bound no ray reaches in the unit box), the LOD
/// footprint halved after rounding, as the CPU cast does; camera rays in
/// [`ThreadOrder::Tiles`] from `near`: the beam pre-pass (`beam`, as the
/// CPU's beam path, [`super::beam`]) costs more than it saves on every
/// adapter measured (beam over plain: H200 0.34-0.57, lavapipe 0.87-0.95;
/// docs/PERF.md), so it runs only where asked.
pub fn gpu_params(p: &CastParams) -> GpuCastParams {
    GpuCastParams {
        near: p.near as f32,
        far: (p.far as f32).min(f32::MAX),
        lod: p
            .lod
            .map(|l| (l.orig_size as f32 * 0.5, l.dir_size as f32 * 0.5)),
        max_iter: p.max_iter,
        order: ThreadOrder::Tiles,
        beam: false,
        repeat: 1,
    }
}

/// The kernel's results as [`VoxelHits<f32>`] (a miss: t = -1, leaf = -1).
pub fn hits_from_gpu(h: &[GpuVoxelHit]) -> VoxelHits<f32> {
    let mut out = VoxelHits::default();
    for r in h {
        out.hit.push(r.hit() as u8);
        out.t.push(r.t);
        out.leaf.push(if r.hit() {
            r.voxel.map(|v| v as i32)
        } else {
            [-1; 3]
        });
        out.normal.push(r.normal().map(|v| v as f32));
        out.iters.push(r.iters as i32);
        out.capped += r.capped() as u64;
    }
    out
}

/// [`super::render::attr_image`] with the decode on the GPU
/// (`kernels/voxel_attrs.wgsl` `decode_attrs`): the same leaf indices
/// (`attr_index` of each hit voxel, as on the CPU), the same shading on
/// the host, so the image equals the CPU's wherever the decode does
/// (bit-identical on lavapipe: test in `crate::gpu::voxel_attrs`).
pub fn attr_image_gpu(
    ctx: &GpuContext,
    h: &VoxelHits<f32>,
    (attrs, form): (&Attributes, AttrForm),
    attr_index: impl Fn([u32; 3]) -> Option<u32> + Sync,
) -> Result<Vec<[f32; 3]>> {
    let idx = attr_indices(h, attr_index);
    let dec = GpuAttrs::new(ctx, attrs)?.decode(form, &idx)?;
    Ok(shade_decoded(h, |i| {
        (dec[i].valid == 1).then_some((dec[i].colour, dec[i].normal))
    }))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::gpu::voxels::GpuAddressing;
    use crate::rays::Roi;
    use crate::voxels::beam::{beam_nears, TILE};
    use crate::voxels::cast::{Absolute, Lod, Relative};
    use crate::voxels::dag::build_dag;
    use crate::voxels::octree::{build, Octree};
    use crate::voxels::shape::Shape;
    use crate::voxels::tiles::Tiling;

    /// The GPU context where kernels may use f64 (a note on stderr and
    /// `None` otherwise: the test is skipped).
    fn f64_gpu() -> Option<&'static GpuContext> {
        let Ok(ctx) = GpuContext::get() else {
            eprintln!("no GPU adapter: skipped");
            return None;
        };
        ctx.has_f64().then_some(ctx).or_else(|| {
            eprintln!("no SHADER_F64: skipped");
            None
        })
    }

    const SPONGE_DEPTH: u32 = 8;

    /// A level-5 Menger sponge at depth [`SPONGE_DEPTH`].
    fn sponge(budget: &MemBudget) -> Octree {
        build(&Shape::Menger { level: 5 }, SPONGE_DEPTH, budget).unwrap()
    }

    /// A `w` x `h` view of a Menger sponge (its rows `rows` only when
    /// given), its f32 camera rays and their cast parameters.
    fn sponge_view(
        budget: &MemBudget,
        (w, h): (u32, u32),
        rows: Option<(u32, u32)>,
    ) -> (Camera, RayGen, Batch<f32>, CastParams) {
        let cam = Camera::pinhole_look_at([2.0, 1.5, 2.5], [0.0; 3], [0.0, 1.0, 0.0], 45.0, w, h)
            .unwrap();
        let mut gen = RayGen::new(w, h);
        gen.roi = rows.map(|(y, height)| Roi {
            x: 0,
            y,
            width: w,
            height,
        });
        let b = Batch::<f32>::camera(&cam, &gen, budget).unwrap();
        let p = b.params(None, 1 << 16);
        (cam, gen, b, p)
    }

    /// The GPU's tile starts (kernels/voxel_beam.wgsl) against the CPU's
    /// (`beam_nears`, the f32 rays' tiles), octree and DAG, at 123 x 77
    /// (partial tiles at the right and bottom) and one row of a 300 x 300
    /// image (runs of 64):
    /// the same tiles meet nothing, the others start at the same f32
    /// distance (the GPU's f64 square root or division may round apart:
    /// within 2^-20 relative).
    #[test]
    fn gpu_beam_tiles_match_the_cpu_beam() {
        let Some(ctx) = f64_gpu() else { return };
        let budget = MemBudget::fixed(1 << 30);
        let (depth, t) = (SPONGE_DEPTH, sponge(&budget));
        let dag = build_dag(&t, &budget).unwrap();
        for (size, rows) in [((123, 77), None), ((300, 300), Some((150, 1)))] {
            let (cam, gen, b, p) = sponge_view(&budget, size, rows);
            let [h, w] = gen.shape();
            let tiles = Tiling::new(&b.shape, b.o.len(), TILE);
            let all = 0..tiles.bands();
            let cpu = [
                beam_nears::<f32, Relative>(&t.nodes, depth, &tiles, all.clone(), &b.o, &b.d, &p),
                beam_nears::<f32, Absolute>(&dag.nodes, depth, &tiles, all, &b.o, &b.d, &p),
            ];
            let uploads = [
                (&t.nodes, GpuAddressing::Relative),
                (&dag.nodes, GpuAddressing::Absolute),
            ];
            // Each GPU tile's first ray: 8x8 tiles row by row, or runs of 64.
            let (tw, th) = if h == 1 {
                (TILE * TILE, 1)
            } else {
                (TILE, TILE)
            };
            let across = w.div_ceil(tw);
            for ((nodes, addressing), cpu) in uploads.into_iter().zip(cpu) {
                let cpu = cpu.unwrap();
                let g = GpuOctree::with(ctx, nodes, depth, addressing, None).unwrap();
                let gpu = g.beam_tiles(&cam, &gen, &gpu_params(&p), &budget).unwrap();
                assert_eq!(gpu.len(), across * h.div_ceil(th));
                let (mut started, mut empty, mut equal) = (0, 0, 0);
                for (k, tile) in gpu.iter().enumerate() {
                    let want = cpu[(k / across) * th * w + (k % across) * tw];
                    if want == f64::INFINITY {
                        assert_eq!(tile.meets, 0, "tile {k}");
                        empty += 1;
                        continue;
                    }
                    assert_eq!(tile.meets, 1, "tile {k}");
                    let want = want as f32;
                    let diff = (tile.near - want).abs();
                    assert!(
                        diff <= 2f32.powi(-20) * want.abs(),
                        "tile {k}: {} against {want}",
                        tile.near
                    );
                    started += (want > p.near as f32) as u32;
                    equal += (tile.near.to_bits() == want.to_bits()) as u32;
                }
                if h > 1 {
                    assert!(started > 40 && empty > 10, "{started} {empty}");
                } else {
                    assert!(started >= 2, "{started}");
                }
                eprintln!(
                    "{w}x{h} {addressing:?}: {empty} of {} tiles empty, {equal} bit-equal",
                    gpu.len()
                );
            }
        }
    }

    /// Casts run back to back in one submission (`repeat`, for timing
    /// under sustained load) leave the last one's results: the same hits,
    /// camera and given rays.
    #[test]
    fn repeated_casts_leave_the_same_hits() {
        let Some(ctx) = f64_gpu() else { return };
        let budget = MemBudget::fixed(1 << 30);
        let (depth, t) = (SPONGE_DEPTH, sponge(&budget));
        let (cam, gen, b, p) = sponge_view(&budget, (40, 30), None);
        let g = GpuOctree::new(ctx, &t.nodes, depth).unwrap();
        let once = gpu_params(&p);
        let thrice = GpuCastParams { repeat: 3, ..once };
        let a = g.cast_camera(&cam, &gen, &once, false, &budget).unwrap();
        let c = g.cast_camera(&cam, &gen, &thrice, false, &budget).unwrap();
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&a.hits),
            bytemuck::cast_slice::<_, u8>(&c.hits)
        );
        let packed: Vec<[f32; 6]> = (b.o.iter().zip(&b.d))
            .map(|(o, d)| [o[0], o[1], o[2], d[0], d[1], d[2]])
            .collect();
        let a = g.cast_rays(&packed, &once, &budget).unwrap();
        let c = g.cast_rays(&packed, &thrice, &budget).unwrap();
        assert_eq!(
            bytemuck::cast_slice::<_, u8>(&a.hits),
            bytemuck::cast_slice::<_, u8>(&c.hits)
        );
        assert!(a.hits.iter().any(|h| h.hit()));
    }

    /// Camera casts from the GPU's beam starts: hit, t, voxel and normal
    /// of every ray equal the GPU cast from `near`, with fewer iterations;
    /// in both thread orders (the CPU cast is the parity cases' referee).
    #[test]
    fn gpu_beam_casts_equal_the_casts_from_near() {
        let Some(ctx) = f64_gpu() else { return };
        let budget = MemBudget::fixed(1 << 30);
        let (depth, t) = (SPONGE_DEPTH, sponge(&budget));
        let (cam, gen, _, p) = sponge_view(&budget, (123, 77), None);
        let g = GpuOctree::new(ctx, &t.nodes, depth).unwrap();
        let off = gpu_params(&p);
        let on = GpuCastParams { beam: true, ..off };
        let plain = g.cast_camera(&cam, &gen, &off, false, &budget).unwrap();
        assert!(!plain.beam);
        for order in [ThreadOrder::Tiles, ThreadOrder::Rows] {
            let beam = g
                .cast_camera(&cam, &gen, &GpuCastParams { order, ..on }, false, &budget)
                .unwrap();
            assert!(beam.beam);
            let (mut it_beam, mut it_plain) = (0u64, 0u64);
            for (i, (a, c)) in beam.hits.iter().zip(&plain.hits).enumerate() {
                assert_eq!(a.outcome(), c.outcome(), "ray {i}");
                (it_beam, it_plain) = (it_beam + a.iters as u64, it_plain + c.iters as u64);
            }
            // Few here: most of this view's rays enter the sponge at its
            // faces (the bench's scene cameras: 0.69-0.96x, docs/PERF.md).
            assert!(it_beam < it_plain, "{it_beam} {it_plain}");
        }
    }

    #[test]
    fn params_round_like_the_f32_cast_and_keep_far_finite() {
        let p = CastParams {
            near: 0.1,
            far: f64::INFINITY,
            lod: Some(Lod {
                orig_size: 0.3,
                dir_size: 0.02,
            }),
            max_iter: 77,
        };
        let g = gpu_params(&p);
        assert_eq!((g.near, g.far, g.max_iter), (0.1f32, f32::MAX, 77));
        assert_eq!(g.lod, Some((0.3f32 * 0.5, 0.02f32 * 0.5)));
    }

    #[test]
    fn contour_table_holds_the_cpu_decode_of_every_field() {
        let lut = contour_lut();
        assert_eq!(lut.len(), CONTOUR_LUT_LEN);
        for v in [
            0x1234_5678u32,
            0xFFFF_FFFF,
            0x8000_4081,
            7 << 26 | 3 << 7 | 100,
        ] {
            let (n, p, h) = decode::<f32>(v);
            let k = 3 * (v >> 14) as usize;
            assert_eq!(&lut[k..k + 3], &n[..]);
            assert_eq!(
                lut[3 << 18 | (v >> 7 & 0x7F) as usize].to_bits(),
                p.to_bits()
            );
            assert_eq!(
                lut[(3 << 18) + 128 + (v & 0x7F) as usize].to_bits(),
                h.to_bits()
            );
        }
    }

    #[test]
    fn misses_become_minus_one_leaves() {
        let h = [
            GpuVoxelHit {
                t: -1.0,
                normal: 0x010101,
                flags: 2,
                ..Default::default()
            },
            GpuVoxelHit {
                t: 2.5,
                voxel: [1, 2, 3],
                flags: 1 | 4 | (8 << 8),
                normal: 0x010100,
                iters: 9,
                ..Default::default()
            },
        ];
        let v = hits_from_gpu(&h);
        assert_eq!(v.hit, vec![0, 1]);
        assert_eq!(v.leaf, vec![[-1; 3], [1, 2, 3]]);
        assert_eq!(v.normal[1], [-1.0, 0.0, 0.0]);
        assert_eq!((v.capped, v.iters[1]), (1, 9));
    }
}
