//! The voxel cast on the GPU (`kernels/voxels.wgsl`, issue 15).
//!
//! | op | what |
//! | --- | --- |
//! | `voxels.render` with `backend: gpu` | the same outputs as the CPU row (octree, `structure: dag`, `contours: true`); camera rays are generated on the GPU |
//! | `voxels.gpu_parity` | GPU and CPU f32 casts of the same rays (the GPU's own camera rays read back), and the f64 referee's verdict on every ray where they differ |
//! | `voxels.gpu_bench` | CPU per-ray, CPU packet and GPU casts of the octree and the DAG in one run (perf scenarios) |
//!
//! `voxels.gpu_parity` casts through the scene's structure (octree, DAG,
//! contours) on both sides and outputs the GPU's `hit`, `t`, `leaf`, `normal`,
//! `iters`, `leaf_key`, the CPU's as `cpu_*`, and `excused` (uint8): 1 on a
//! ray whose GPU and CPU leaves differ and that the referee flags as a tie
//! or as within `ulp_margin` world units (default 2^-22, one f32 ulp of the
//! octree's [1, 2) coordinates) of a voxel boundary. Counters `differ`,
//! `excused`, `unexcused`; `identical_frac` (scalar tensor and metric):
//! the share of rays with identical leaves.

use std::time::Instant;

use super::voxels::{batch, camera_batch, dump_rays, from64, load, parts, Batch};
use super::voxels_dag::dag_metrics;
use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::budget::bytes_for;
use crate::error::{Error, Result};
use crate::gpu::voxels::GpuCast;
use crate::gpu::GpuContext;
use crate::judge::measure::timed;
use crate::rays::Rays;
use crate::real::Precision;
use crate::scene::voxels::VoxelScene;
use crate::tensor::{Outputs, Tensor};
use crate::voxels::cast::CastParams;
use crate::voxels::dag::build_dag;
use crate::voxels::gpu::{gpu_params, hits_from_gpu};
use crate::voxels::octree::{build, Octree};
use crate::voxels::outputs::{build_metrics, put_hits};
use crate::voxels::raysets::incoherent;
use crate::voxels::referee::referee;
use crate::voxels::render::VoxelHits;
use crate::voxels::through::{CastPath, Through};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "voxels.gpu_parity",
        doc: "GPU vs CPU f32 voxel cast on the same rays: both outputs, excused (referee ties / one-ulp near ties where they differ)",
        params: &["rays", "count", "seed", "ulp_margin"],
        support: Support::GpuF32,
        run: gpu_parity,
    },
    OpEntry {
        name: "voxels.gpu_bench",
        doc: "CPU per-ray, CPU packet and GPU casts of octree and DAG in one run, coherent (size^2 camera) and incoherent (count): Mrays/CPU-s, GPU Mrays/s, packet speedup, mean iterations, node bytes per ray",
        params: &["count", "size", "seed"],
        support: Support::GpuF32,
        run: gpu_bench,
    },
];

/// A GPU cast of the case's rays: the GPU's results, the rays (as the
/// kernel saw them), the per-ray tensor shape, the cast parameters and the
/// optional hard-ray kinds.
struct GpuRun {
    cast: GpuCast,
    o: Vec<[f32; 3]>,
    d: Vec<[f32; 3]>,
    shape: Vec<usize>,
    params: CastParams,
    kind: Option<Vec<i32>>,
}

fn cast_params(sc: &VoxelScene, near: f64, far: f64) -> CastParams {
    CastParams {
        near,
        far,
        lod: sc.lod,
        max_iter: sc.max_iter,
    }
}

/// Casts the case's rays on the GPU: camera rays are generated there (and
/// read back when `keep_rays`), other sources are uploaded.
fn gpu_run(ctx: &OpCtx, sc: &VoxelScene, through: Through, keep_rays: bool) -> Result<GpuRun> {
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU computes in f32 only",
            ctx.case_id
        )));
    }
    let gpu = GpuContext::get()?;
    let g = through.upload(gpu)?;
    let src: String = ctx.param_or("rays", "camera".to_string())?;
    if ctx.rays.is_none() && src == "camera" {
        let (cam, gen) = sc.view.build()?;
        let params = cast_params(sc, gen.near, gen.far);
        let cast = g.cast_camera(&cam, &gen, &gpu_params(&params), keep_rays, &ctx.budget)?;
        let roi = gen.region();
        let (o, d) = cast
            .rays
            .iter()
            .map(|r| ([r[0], r[1], r[2]], [r[3], r[4], r[5]]))
            .unzip();
        return Ok(GpuRun {
            cast,
            o,
            d,
            shape: vec![roi.height as usize, roi.width as usize],
            params,
            kind: None,
        });
    }
    let b: Batch<f32> = batch(ctx, sc)?;
    let params = cast_params(sc, b.near, b.far);
    let packed: Vec<[f32; 6]> =
        b.o.iter()
            .zip(&b.d)
            .map(|(o, d)| [o[0], o[1], o[2], d[0], d[1], d[2]])
            .collect();
    let cast = g.cast_rays(&packed, &gpu_params(&params), &ctx.budget)?;
    Ok(GpuRun {
        cast,
        o: b.o,
        d: b.d,
        shape: b.shape,
        params,
        kind: b.kind,
    })
}

/// `voxels.render` on the GPU (called by the CPU row for `backend: gpu`).
pub fn render_gpu(ctx: &OpCtx, sc: &VoxelScene, tree: &Octree, th: Through) -> Result<Outputs> {
    let t0 = Instant::now();
    let r = gpu_run(ctx, sc, th, ctx.dump)?;
    let wall = t0.elapsed().as_secs_f64();
    let n = r.cast.hits.len() as u64;
    let mut out = Outputs::default();
    if ctx.dump {
        let b = Batch {
            o: r.o,
            d: r.d,
            shape: r.shape.clone(),
            near: r.params.near,
            far: r.params.far,
            kind: None,
        };
        out.tensor("rays", dump_rays(&b)?);
    }
    let s = r.cast.gpu_s;
    out.metric("cast_s", s)
        .metric("wall_s", wall)
        .metric("mrays_per_s", n as f64 / s.max(1e-12) / 1e6);
    out.counter("rays", n)
        .counter(
            "hits",
            r.cast.hits.iter().filter(|h| h.hit()).count() as u64,
        )
        .counter("kernel_max_iter", r.cast.max_iter as u64);
    put_hits(
        &mut out,
        hits_from_gpu(&r.cast.hits),
        &r.shape,
        sc.depth,
        true,
    )?;
    if let Some(k) = r.kind {
        out.tensor("kind", Tensor::from_shape_vec(&r.shape, k)?);
    }
    build_metrics(&mut out, tree);
    if let Through::Dag(g) = th {
        dag_metrics(&mut out, g);
    }
    Ok(out)
}

/// Renames every tensor of `src` with `prefix` into `out`.
fn put_prefixed(out: &mut Outputs, src: Outputs, prefix: &str) {
    for (k, v) in src.tensors {
        out.tensor(&format!("{prefix}{k}"), v);
    }
}

fn hits_tensors(h: VoxelHits<f32>, shape: &[usize], depth: u32) -> Result<Outputs> {
    let mut o = Outputs::default();
    put_hits(&mut o, h, shape, depth, false)?;
    Ok(o)
}

/// Refuses the CPU backend for an operation that needs the GPU.
fn need_gpu(ctx: &OpCtx, op: &str) -> Result<()> {
    if ctx.backend != BackendKind::Gpu {
        return Err(Error::invalid(
            ctx.case_id,
            format!("{op} runs the GPU beside the CPU: give it `backends: [gpu]`"),
        ));
    }
    Ok(())
}

fn gpu_parity(ctx: &OpCtx) -> Result<Outputs> {
    need_gpu(ctx, "voxels.gpu_parity")?;
    let sc = load(ctx)?;
    let margin: f64 = ctx.param_or("ulp_margin", 2f64.powi(-22))?;
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(Error::invalid(
            format!("{} params.ulp_margin", ctx.case_id),
            "must be finite and >= 0",
        ));
    }
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let (dag, contours) = parts(ctx, &sc, &tree)?;
    let th = Through::pick(&tree, dag.as_ref(), contours.as_deref());
    let r = gpu_run(ctx, &sc, th, true)?;
    // The CPU cast runs with the kernel's iteration cap, so a capped ray is
    // capped on both.
    let p = CastParams {
        max_iter: r.cast.max_iter,
        ..r.params
    };
    let cpu = th.cast_all::<f32>(&r.o, &r.d, &p);
    let gpu = hits_from_gpu(&r.cast.hits);
    let n = gpu.hit.len();
    // The referee judges only the rays whose leaves differ.
    let differ: Vec<usize> = (0..n).filter(|&i| gpu.leaf[i] != cpu.leaf[i]).collect();
    let mut excused = vec![0u8; n];
    for &i in &differ {
        let w = |v: [f32; 3]| v.map(|x| x as f64);
        let f = referee(
            &sc.shape,
            sc.depth,
            w(r.o[i]),
            w(r.d[i]),
            p.near,
            p.far,
            margin,
        );
        excused[i] = (f.tie || f.near_tie) as u8;
        if excused[i] == 0 {
            eprintln!(
                "{}: ray {i} o={:?} d={:?}: gpu leaf {:?} cpu leaf {:?} (referee {:?})",
                ctx.case_id, r.o[i], r.d[i], gpu.leaf[i], cpu.leaf[i], f.voxel
            );
        }
    }
    let nex = excused.iter().map(|&x| x as u64).sum::<u64>();
    let mut out = Outputs::default();
    out.counter("rays", n as u64)
        .counter("differ", differ.len() as u64)
        .counter("excused", nex)
        .counter("unexcused", differ.len() as u64 - nex)
        .counter("gpu_capped", gpu.capped)
        .counter("cpu_capped", cpu.capped);
    let identical = 1.0 - differ.len() as f64 / n.max(1) as f64;
    out.metric("identical_frac", identical);
    out.tensor("identical_frac", Tensor::scalar(identical));
    let not_excused: Vec<u8> = excused.iter().map(|&x| 1 - x).collect();
    out.tensor("excused", Tensor::from_shape_vec(&r.shape, excused)?);
    out.tensor(
        "not_excused",
        Tensor::from_shape_vec(&r.shape, not_excused)?,
    );
    if ctx.dump {
        let rays = Rays {
            o: r.o.clone(),
            d: r.d.clone(),
            t0: vec![p.near as f32; n],
            t1: vec![(p.far as f32).min(1e30); n],
            pixel: (0..n as u32).collect(),
        };
        out.tensor("rays", rays.to_tensor()?);
    }
    put_prefixed(&mut out, hits_tensors(gpu, &r.shape, sc.depth)?, "");
    put_prefixed(&mut out, hits_tensors(cpu, &r.shape, sc.depth)?, "cpu_");
    Ok(out)
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// Per structure (octree, DAG): the CPU per-ray cast, the CPU packet cast
/// and the GPU cast of the same rays, in one run: coherent = the scene
/// camera at `size`^2 (the GPU generates its own camera rays), incoherent =
/// `count` seeded rays. Metrics `{structure}_{path}_{set}_mrays_per_cpu_s`
/// (CPU paths), `{structure}_gpu_{set}_mrays_per_s`,
/// `{structure}_{set}_packet_speedup` (per CPU-second, same run),
/// `{structure}_{set}_mean_iters`, `{structure}_{set}_node_bytes_per_ray`
/// (4 x node words the kernel read; the CPU casts read the same words).
fn gpu_bench(ctx: &OpCtx) -> Result<Outputs> {
    need_gpu(ctx, "voxels.gpu_bench")?;
    if ctx.precision != Precision::F32 {
        return Err(Error::NotSupported(format!(
            "{}: the GPU computes in f32 only",
            ctx.case_id
        )));
    }
    let count: u32 = ctx.param_or("count", 1 << 18)?;
    let size: u32 = ctx.param_or("size", 512)?;
    let seed: u32 = ctx.param_or("seed", ctx.seed)?;
    let sc = load(ctx)?;
    ctx.budget.check(
        "voxels.gpu_bench rays and results",
        bytes_for(count as u64 + size as u64 * size as u64, 200),
    )?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let dag = build_dag(&tree, &ctx.budget)?;
    let gpu = GpuContext::get()?;
    let mut out = Outputs::default();
    out.metric("threads", rayon::current_num_threads() as f64);
    build_metrics(&mut out, &tree);
    dag_metrics(&mut out, &dag);
    let coh: Batch<f32> = camera_batch(ctx, &sc, Some(size))?;
    let (io, id) = from64::<f32>(incoherent(count, seed));
    let (_, mut gen) = sc.view.build()?;
    (gen.width, gen.height, gen.roi) = (size, size, None);
    let cam = sc.view.camera.build(size, size)?;
    let p_coh = cast_params(&sc, gen.near, gen.far);
    let p_inc = cast_params(&sc, 0.0, f64::INFINITY);
    let packed: Vec<[f32; 6]> = (io.iter().zip(&id))
        .map(|(o, d)| [o[0], o[1], o[2], d[0], d[1], d[2]])
        .collect();
    for (sname, through) in [
        ("octree", Through::Octree(&tree)),
        ("dag", Through::Dag(&dag)),
    ] {
        let g = through.upload(gpu)?;
        // Warm-up: the first dispatch of each entry compiles it.
        g.cast_rays(
            &packed[..packed.len().min(64)],
            &gpu_params(&p_inc),
            &ctx.budget,
        )?;
        for (set, o, d, p) in [
            ("coherent", &coh.o[..], &coh.d[..], p_coh),
            ("incoherent", &io[..], &id[..], p_inc),
        ] {
            let n = o.len() as f64;
            let mut per_cpu_s = [0.0; 2];
            for (k, path) in [CastPath::PerRay, CastPath::Packet].into_iter().enumerate() {
                let (h, _, cpu) = timed(|| through.cast_by(path, o, d, &p));
                h?;
                per_cpu_s[k] = n / cpu.max(1e-3) / 1e6;
                out.metric(
                    &format!("{sname}_{}_{set}_mrays_per_cpu_s", ["per_ray", "packet"][k]),
                    per_cpu_s[k],
                );
            }
            out.metric(
                &format!("{sname}_{set}_packet_speedup"),
                per_cpu_s[1] / per_cpu_s[0],
            );
            let gc = if set == "coherent" {
                g.cast_camera(&cam, &gen, &gpu_params(&p), false, &ctx.budget)?
            } else {
                g.cast_rays(&packed, &gpu_params(&p), &ctx.budget)?
            };
            let m = gc.hits.len() as f64;
            out.metric(
                &format!("{sname}_gpu_{set}_mrays_per_s"),
                m / gc.gpu_s.max(1e-12) / 1e6,
            );
            out.metric(
                &format!("{sname}_{set}_mean_iters"),
                mean(gc.hits.iter().map(|h| h.iters as f64)),
            );
            out.metric(
                &format!("{sname}_{set}_node_bytes_per_ray"),
                4.0 * mean(gc.hits.iter().map(|h| h.loads() as f64)),
            );
        }
    }
    Ok(out)
}
