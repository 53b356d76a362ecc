//! The volume renderer's GPU backend: [`render_gpu`] takes what
//! [`super::render`] takes and returns the same [`Render<f32>`], computed by
//! `kernels/volume.wgsl` through `crate::gpu::volume` (issue 5).
//!
//! The fields are rounded to f32 here exactly as the CPU f32 render rounds
//! them (`FieldDesc::to_real::<f32>`, `Occupancy::<f32>::build`), then handed
//! to the GPU layer as its own typed inputs. Composition (`f_img`) runs on
//! the host over the GPU's per-ray results: it is a placement of one result
//! per pixel for camera rays. A hash-grid + MLP field always runs the
//! unfused chain (its network runs one thread a sample, `f_hash_fill`).

use crate::budget::MemBudget;
use crate::camera::Camera;
use crate::error::{Error, Result};
use crate::gpu::volume::{self as gv, GpuField, GpuGrid, GpuOccupancy, GpuRayOut, VolumeInput};
use crate::gpu::volume_hash::{GpuHash, GpuLevel};
use crate::gpu::GpuContext;
use crate::rays::RayGen;

use super::compose::{f_img, Compose};
use super::field::hash::{DensityAct, HashMlp};
use super::field::{ColorField, Field, Grid, Oob};
use super::integrate::RayOut;
use super::occupancy::Occupancy;
use super::sample::{March, Sampling, TransPath};
use super::{Chain, Counters, Render, Timings, VolumeParams};

fn gpu_grid<'a>(g: &'a Grid<f32>, ch: usize, what: &str) -> Result<GpuGrid<'a>> {
    if g.ch != ch {
        return Err(Error::NotSupported(format!(
            "GPU {what}: {} channels, the kernel reads {ch}",
            g.ch
        )));
    }
    let n = |v: usize| {
        u32::try_from(v).map_err(|_| Error::NotSupported(format!("GPU {what}: side {v} too large")))
    };
    Ok(GpuGrid {
        n: [n(g.nx)?, n(g.ny)?, n(g.nz)?],
        data: &g.data,
        clamp: g.oob == Oob::Clamp,
        bmin: g.bmin,
        scale: g.scale,
    })
}

/// A GPU render and, per pixel of the region (row-major), 1 where every
/// decision of its ray was clear of its threshold by more than rounding
/// (`crate::gpu::volume::FLAG_UNSTABLE` unset), 0 where f32 and the f64
/// referee may legitimately differ by one sample.
pub struct GpuRender {
    pub render: Render<f32>,
    pub stable: Vec<u8>,
}

/// A scene's fields rounded to f32 as the CPU f32 render rounds them, and
/// its march: what [`GpuScene::input`] lends the GPU layer.
pub(super) struct GpuScene {
    pub field: Field<f32>,
    pub color: ColorField<f32>,
    pub occ: Option<Occupancy<f32>>,
    pub m: March<f32>,
    /// A hash field's levels, layer shapes and flat parameters (f32).
    hash: Option<(Vec<GpuLevel>, Vec<[u32; 2]>, Vec<f32>)>,
}

/// What [`GpuHash`] borrows of a hash field, in the kernels' layout.
fn hash_host(h: &HashMlp<f32>) -> (Vec<GpuLevel>, Vec<[u32; 2]>, Vec<f32>) {
    let levels = h
        .levels
        .iter()
        .map(|l| GpuLevel {
            n: l.n,
            top: l.top,
            n1: l.n1,
            dense: l.dense,
        })
        .collect();
    let layers = h
        .layers
        .iter()
        .map(|l| [l.inp as u32, l.out as u32])
        .collect();
    let mut flat = h.table.clone();
    for l in &h.layers {
        flat.extend_from_slice(&l.w);
        flat.extend_from_slice(&l.b);
    }
    (levels, layers, flat)
}

impl GpuScene {
    pub(super) fn new(params: &VolumeParams, gen: &RayGen, budget: &MemBudget) -> Result<GpuScene> {
        let m = params.march::<f32>();
        m.validate()?;
        let field = params.field.to_real::<f32>();
        let hash = match &field {
            Field::HashMlp(h) => Some(hash_host(h)),
            _ => None,
        };
        Ok(GpuScene {
            hash,
            field,
            color: params.color.to_real::<f32>(),
            occ: match params.occupancy {
                0 => None,
                r => Some(Occupancy::<f32>::build(
                    &params.field,
                    &gen.aabb,
                    r,
                    budget,
                )?),
            },
            m,
        })
    }

    /// Whether the field is a hash grid + MLP.
    pub(super) fn is_hash(&self) -> bool {
        self.hash.is_some()
    }

    /// The GPU layer's typed input (refused where no kernel reads the field).
    pub(super) fn input(&self) -> Result<VolumeInput<'_>> {
        let gfield = match &self.field {
            Field::Constant { s } => GpuField::Constant { s: *s },
            Field::Slabs {
                axis,
                breaks,
                sigma,
            } => GpuField::Slabs {
                axis: *axis as u32,
                breaks,
                sigma,
            },
            Field::Gaussian {
                amplitude,
                mean,
                inv_two_var,
            } => GpuField::Gaussian {
                amplitude: *amplitude,
                mean: *mean,
                inv_two_var: *inv_two_var,
            },
            Field::Shell { centre, r0, r1, s } => GpuField::Shell {
                centre: *centre,
                r0: *r0,
                r1: *r1,
                s: *s,
            },
            Field::Linear { a, g } => GpuField::Linear { a: *a, g: *g },
            Field::Grid(g) => GpuField::Grid(gpu_grid(g, 1, "density grid")?),
            Field::HashMlp(h) => {
                let Some((levels, layers, params)) = &self.hash else {
                    return Err(Error::invalid("gpu scene", "hash field without its layout"));
                };
                GpuField::Hash(GpuHash {
                    levels,
                    features: h.features as u32,
                    tsize: h.tsize as u32,
                    relu: h.density == DensityAct::Relu,
                    bmin: h.bmin,
                    inv_ext: h.inv_ext,
                    layers,
                    params,
                })
            }
        };
        let (cconst, cgrid) = match &self.color {
            ColorField::Constant(c) => (*c, None),
            ColorField::Grid(g) => ([0.0; 3], Some(gpu_grid(g, 3, "colour grid")?)),
            ColorField::Mlp => ([0.0; 3], None),
        };
        let m = &self.m;
        Ok(VolumeInput {
            field: gfield,
            color: cconst,
            color_grid: cgrid,
            dt: m.dt,
            max_steps: m.max_steps,
            early_stop: m.early_stop,
            stratified: match m.sampling {
                Sampling::Fixed => None,
                Sampling::Stratified { seed } => Some(seed),
            },
            log_path: m.path == TransPath::Log,
            background: m.background,
            occupancy: self.occ.as_ref().map(|o| GpuOccupancy {
                res: o.res,
                bits: &o.bits,
                bmin: o.bmin,
                inv_cell: o.inv_cell,
            }),
        })
    }
}

/// Renders `params` on the GPU with the fused or unfused chain.
pub fn render_gpu(
    ctx: &GpuContext,
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    chain: Chain,
    compose: Compose,
    budget: &MemBudget,
) -> Result<GpuRender> {
    let scene = GpuScene::new(params, gen, budget)?;
    let input = scene.input()?;
    let m = &scene.m;
    let mut tm = Timings::default();
    let chain = if scene.is_hash() {
        Chain::Unfused
    } else {
        chain
    };
    let out: Vec<GpuRayOut> = match chain {
        Chain::Fused => {
            let (out, s) = gv::f_fused(ctx, cam, gen, &input, budget)?;
            tm.fused = s;
            out
        }
        Chain::Unfused => {
            let u = gv::unfused(ctx, cam, gen, &input, budget, false)?;
            (tm.samp, tm.int) = (u.times.samp, u.times.int);
            u.rays
        }
    };
    let roi = gen.region();
    let pixel: Vec<u32> = (0..out.len() as u32)
        .map(|i| (roi.y + i / roi.width) * gen.width + roi.x + i % roi.width)
        .collect();
    let rays: Vec<RayOut<f32>> = out
        .iter()
        .map(|r| RayOut {
            rgb: r.rgb,
            trans: r.trans,
            log_trans: r.log_trans,
            depth: r.depth,
            opacity: r.opacity,
            n: r.n,
            saturated: r.saturated,
            flags: (r.flags & 7) as u8,
        })
        .collect();
    let skipped = out.iter().map(|r| r.skipped as u64).sum();
    let image = f_img(
        &rays,
        &pixel,
        gen.width,
        (roi.x, roi.y, roi.width, roi.height),
        m.background,
        compose,
    )?;
    tm.total = tm.fused + tm.samp + tm.int;
    let stable = out
        .iter()
        .map(|r| (r.flags & gv::FLAG_UNSTABLE == 0) as u8)
        .collect();
    Ok(GpuRender {
        render: Render {
            counters: Counters::of(&rays, skipped),
            image,
            timings: tm,
            samples: None,
            integrated: None,
        },
        stable,
    })
}
