//! Operations of the `voxels` renderer (sparse voxel octrees, DAGs,
//! contours; the ESVO cast on the CPU, or `kernels/voxels.wgsl` under
//! `backend: gpu`), its referees (`voxels::referee`, `referee_dag`,
//! `referee_bounds`), harnesses (`voxels::checks`) and timings
//! (`judge::measure::voxels`).
//!
//! Ray sources (`params.rays`) are documented in `voxels::batch`.
//! `voxels.render` casts through the scene's structure (`voxels::through`:
//! octree, `structure: dag`, `contours: true`) on either backend; `cast`:
//! `per_ray` (default), `packet`, `sse` or `beam` (`voxels::through::CastPath`; identical
//! outputs, `beam` with fewer `iters`).
//!
//! Scene key `attributes: plain | dxt` shades `voxels.render`'s image from
//! the hit leaves' decoded colours and normals (on the GPU backend decoded
//! by `kernels/voxel_attrs.wgsl`);
//! `voxels.attributes` and `voxels.mesh_referee` wire `voxels::checks`.

use super::{BackendKind, OpCtx};
use crate::budget::bytes_for;
use crate::error::{Error, Result};
use crate::gpu::voxels::GpuCast;
use crate::gpu::GpuContext;
use crate::judge::measure::voxels::{self as measure, Sets};
use crate::judge::measure::{peak_rss_bytes, timed};
use crate::rays::Rays;
use crate::real::Real;
use crate::scene::voxels::VoxelScene;
use crate::tensor::Outputs;
use crate::voxels::attributes::for_scene;
use crate::voxels::batch::{Batch, RaySource};
use crate::voxels::cast::{CastParams, CastReal};
use crate::voxels::checks::{attribute_quality, contour_error, mesh_referee};
use crate::voxels::contour::fit_all;
use crate::voxels::gpu::{cast_batch, cast_camera};
use crate::voxels::octree::{build, Octree};
use crate::voxels::outputs::{build_metrics, dag_metrics, gpu_cast_outputs};
use crate::voxels::referee_bounds::sphere_bounds;
use crate::voxels::referee_dag::distinct_nodes_per_level;
use crate::voxels::render::{attr_image, referee_all};
use crate::voxels::shape::Shape;
use crate::voxels::through::{CastPath, Through};

ops! {
    "voxels.render" CpuGpuF32 render ["rays", "count", "seed", "cast", "beam"]
        "ESVO cast of a voxels scene: hit, t, leaf, normal, image, iters; build_s, bytes_per_voxel, mrays_per_s (CPU: param cast picks the path, default per_ray; GPU: param beam, camera rays from the beam pre-pass, default false: slower than casts from near on the H200 and lavapipe; each refused on the other backend)";
    "voxels.referee" Any referee_op ["rays", "count", "seed", "near_margin"]
        "exact f64 Amanatides-Woo DDA over the scene predicate: hit, t, leaf, normal, tie, near_tie, untied, clear";
    "voxels.sphere_bounds" Any sphere_bounds_op ["rays", "count", "seed", "slack_rel"]
        "entry t of the spheres radius -+ half a voxel diagonal: t_outer, t_inner, meets_outer, meets_inner";
    "voxels.bench" Cpu bench ["count", "size", "seed", "referee_stride"]
        "octree vs referee Mrays/s on coherent (size^2 camera) and incoherent (count) rays; build_s, bytes_per_voxel";
    "voxels.dag" Cpu dag_op ["count", "seed", "repeats"]
        "octree vs DAG: nodes_per_level, nodes/slots/bytes of both; with count > 0 cast Mrays per CPU-second of both on the same rays";
    "voxels.dag_referee" Any dag_referee []
        "distinct non-uniform cube contents per level from the scene predicate (nodes_per_level; depth <= 7)";
    "voxels.contour_error" Cpu contour_op []
        "t error of cubes vs contours against the analytic sphere (max, p99); per ray box_excess and slab_excess of contour hits";
    "voxels.gpu_parity" GpuF32 gpu_parity ["rays", "count", "seed", "ulp_margin", "beam"]
        "GPU vs CPU f32 voxel cast on the same rays (GPU camera rays from its beam pre-pass unless param beam is false: the parity cases keep it checked): both outputs (and with scene attributes both attribute images, image / cpu_image), excused (referee ties / one-ulp near ties where leaves differ, and in contour casts slab ties at the leaf one cast passed), normal_not_excused (also normal ties where normals differ), t_not_excused (also t at normal ties and at contour slab entries within the plane's rounding)";
    "voxels.gpu_bench" GpuF32 gpu_bench ["count", "size", "seed"]
        "CPU per-ray, CPU packet and GPU casts of octree and DAG in one run, coherent (size^2 camera; size 0: the scene's width x height) and incoherent (count): Mrays/CPU-s, GPU Mrays/s (submit to readback of one cast; `*_kernel_*` the kernels alone on the GPU clock where the adapter has timestamps, per cast of submissions of back-to-back casts filling about 50 ms, at most 256), packet speedup, mean iterations, node bytes per ray; tensors differing_rays (every *_differing_rays figure summed) and differing_comparisons (how many)";
    "voxels.attributes" Cpu attributes_op []
        "plain and DXT per-leaf colour/normal: {plain,dxt}_colour_psnr_db, _normal_{mean,p99,max}_deg, _bytes_per_voxel";
    "voxels.mesh_referee" Cpu mesh_referee_op ["tri_stride", "leaf_stride", "margin"]
        "separating-axis referee of the mesh voxelisation: missing, untouched, ties; voxelise_s, build_s, peak_rss_bytes";
}

fn load(ctx: &OpCtx) -> Result<VoxelScene> {
    crate::scene::voxels::parse(ctx.scene()?)
}

/// The case's rays (module doc).
fn batch<F: Real>(ctx: &OpCtx, sc: &VoxelScene) -> Result<Batch<F>> {
    if let Some(t) = ctx.rays {
        let r = Rays::<F>::from_tensor(t, "--rays")?;
        return Ok(Batch::replay(r, sc.view.near, sc.view.far));
    }
    let src = ctx.param_or("rays", RaySource::Camera)?;
    let (count, seed) = (
        ctx.param_or("count", 4096)?,
        ctx.param_or("seed", ctx.seed)?,
    );
    sc.batch(src, count, seed, &ctx.budget)
}

fn render_in<F: CastReal>(
    ctx: &OpCtx,
    sc: &VoxelScene,
    th: Through,
    tree: &Octree,
) -> Result<Outputs> {
    let attrs = for_scene(&sc.shape, tree, sc.attributes)?;
    let b = batch::<F>(ctx, sc)?;
    let bytes = bytes_for(b.o.len() as u64, 12 * std::mem::size_of::<F>() as u64 + 32);
    ctx.budget.check("voxels.render outputs", bytes)?;
    let p = b.params(sc.lod, sc.max_iter);
    let path: CastPath = ctx.param_or("cast", CastPath::PerRay)?;
    let (h, secs, _) = timed(|| th.cast_by::<F>(path, &b.shape, &b.o, &b.d, &p));
    let h = h?;
    let mut out = Outputs::default();
    let hits = h.hit.iter().map(|&x| x as u64).sum();
    let img = attrs.map(|a| attr_image(&h, &a, sc.attributes, |v| th.attr_index(v)));
    b.cast_outputs((h, img), (secs, hits), sc.depth, ctx.dump, &mut out)?;
    Ok(out)
}

fn render(ctx: &OpCtx) -> Result<Outputs> {
    // Each backend has its own switch; the other's is refused, not ignored.
    let (other, why) = if ctx.backend == BackendKind::Cpu {
        (
            "beam",
            "the GPU's switch: the CPU's path is param cast (e.g. cast: beam)",
        )
    } else {
        (
            "cast",
            "the CPU's switch: the GPU casts one way, its beam pre-pass is param beam",
        )
    };
    if ctx.param::<serde_yaml::Value>(other)?.is_some() {
        return Err(ctx.bad(other, why));
    }
    let sc = load(ctx)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let (dag, cs) = sc.extras(&tree, &ctx.budget)?;
    let th = Through::pick(&tree, dag.as_ref(), cs.as_deref());
    let mut out = if ctx.backend == BackendKind::Cpu {
        by_precision!(ctx, render_in(ctx, &sc, th, &tree))?
    } else {
        let (r, wall, _) = timed(|| gpu_run(ctx, &sc, (th, false), ctx.dump));
        let (cast, b, _) = r?;
        let a = for_scene(&sc.shape, &tree, sc.attributes)?;
        let mut out = Outputs::default();
        let at = (a.as_ref(), sc.attributes, th);
        gpu_cast_outputs(&cast, b, at, (wall, sc.depth, ctx.dump), &mut out)?;
        out
    };
    if let Some(g) = &dag {
        dag_metrics(&mut out, g);
    }
    build_metrics(&mut out, &tree);
    Ok(out)
}

fn referee_in<F: Real>(ctx: &OpCtx, sc: &VoxelScene) -> Result<Outputs> {
    let b = batch::<F>(ctx, sc)?;
    let margin: f64 = ctx.param_or("near_margin", 0.0)?;
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(ctx.bad("near_margin", "must be finite and >= 0"));
    }
    let (o, d) = b.widen();
    let t0 = std::time::Instant::now();
    let r = referee_all(&sc.shape, sc.depth, &o, &d, b.near, b.far, margin);
    let s = t0.elapsed().as_secs_f64();
    let mut out = Outputs::default();
    out.metric("time_s", s)
        .metric("mrays_per_s", o.len() as f64 / s.max(1e-12) / 1e6);
    out.counter("rays", o.len() as u64);
    r.to_outputs(&b.shape, sc.depth, &mut out)?;
    Ok(out)
}

fn referee_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    by_precision!(ctx, referee_in(ctx, &sc))
}

/// The radius of a sphere scene, or an error naming `op`.
fn sphere_radius(ctx: &OpCtx, sc: &VoxelScene, op: &str) -> Result<f64> {
    let Shape::Sphere { radius } = sc.shape else {
        return Err(Error::invalid(
            ctx.scene()?.at(),
            format!("{op} needs a `shape: {{type: sphere}}` scene"),
        ));
    };
    Ok(radius)
}

fn bounds_in<F: Real>(ctx: &OpCtx, sc: &VoxelScene, radius: f64) -> Result<Outputs> {
    let b = batch::<F>(ctx, sc)?;
    let slack: f64 = ctx.param_or("slack_rel", 1e-12)?;
    let (o, d) = b.widen();
    sphere_bounds(&o, &d, (b.near, b.far), radius, sc.depth, slack, &b.shape)
}

fn sphere_bounds_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let radius = sphere_radius(ctx, &sc, "voxels.sphere_bounds")?;
    by_precision!(ctx, bounds_in(ctx, &sc, radius))
}

fn bench_in<F: CastReal>(ctx: &OpCtx, sc: &VoxelScene, tree: &Octree) -> Result<Outputs> {
    let size = Some(ctx.param_or("size", 1024)?);
    let (count, seed) = (
        ctx.param_or("count", 1 << 20)?,
        ctx.param_or("seed", ctx.seed)?,
    );
    let stride: usize = ctx.param_or("referee_stride", 16usize)?.max(1);
    let what = ("voxels.bench rays and results", 160);
    let sets = Sets::<F>::new(sc, (size, count, seed), what, &ctx.budget)?;
    let mut out = Outputs::default();
    measure::bench(sc, tree, &sets, stride, &mut out);
    Ok(out)
}

fn bench(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let (tree, _, build_cpu) = timed(|| build(&sc.shape, sc.depth, &ctx.budget));
    let tree = tree?;
    let mut out = by_precision!(ctx, bench_in(ctx, &sc, &tree))?;
    out.metric("build_cpu_s", build_cpu);
    Ok(out)
}

fn dag_in<F: CastReal>(
    ctx: &OpCtx,
    sc: &VoxelScene,
    tree: &Octree,
    out: &mut Outputs,
) -> Result<()> {
    let count: u32 = ctx.param_or("count", 0)?;
    let sets = match count {
        0 => None,
        _ => Some(Sets::<F>::new(
            sc,
            (None, count, ctx.param_or("seed", ctx.seed)?),
            ("voxels.dag rays", 0),
            &ctx.budget,
        )?),
    };
    let repeats: u32 = ctx.param_or("repeats", 3u32)?.max(1);
    measure::dag_bench(
        sc,
        tree,
        sets.as_ref().map(|s| (s, repeats)),
        &ctx.budget,
        out,
    )
}

fn dag_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let mut out = Outputs::default();
    build_metrics(&mut out, &tree);
    by_precision!(ctx, dag_in(ctx, &sc, &tree, &mut out))?;
    Ok(out)
}

fn dag_referee(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let counts = distinct_nodes_per_level(&sc.shape, sc.depth)?;
    let mut out = Outputs::default();
    out.counter("nodes", counts.iter().sum());
    out.tensor("nodes_per_level", measure::per_level(&counts)?);
    Ok(out)
}

fn contour_in<F: CastReal>(ctx: &OpCtx, sc: &VoxelScene, radius: f64) -> Result<Outputs> {
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let cs = fit_all(&sc.shape, &tree)?;
    let b = sc.batch::<F>(RaySource::Camera, 0, 0, &ctx.budget)?;
    let p = b.params(None, sc.max_iter);
    contour_error(&tree, &cs, &b, &p, radius, sc.depth)
}

fn contour_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let radius = sphere_radius(ctx, &sc, "voxels.contour_error")?;
    by_precision!(ctx, contour_in(ctx, &sc, radius))
}

/// Casts the case's rays on the GPU: camera rays are generated there (and
/// read back when `keep`) and cast from the GPU's beam starts where param
/// `beam` (when the case gives none, the caller's `beam`) is true, other
/// sources are uploaded. The cast, the rays as the kernel saw them, the
/// cast parameters.
fn gpu_run(
    ctx: &OpCtx,
    sc: &VoxelScene,
    (th, beam): (Through, bool),
    keep: bool,
) -> Result<(GpuCast, Batch<f32>, CastParams)> {
    let g = th.upload(GpuContext::get()?)?;
    if ctx.rays.is_some() || ctx.param_or("rays", RaySource::Camera)? != RaySource::Camera {
        let b: Batch<f32> = batch(ctx, sc)?;
        let p = b.params(sc.lod, sc.max_iter);
        return Ok((cast_batch(&g, &b, &p, &ctx.budget)?, b, p));
    }
    let (cam, gen) = sc.view_at(None)?;
    let (near, far, lod, max_iter) = (gen.near, gen.far, sc.lod, sc.max_iter);
    let p = CastParams {
        near,
        far,
        lod,
        max_iter,
    };
    let beam = ctx.param_or("beam", beam)?;
    let (cast, b) = cast_camera(&g, (&cam, &gen), (&p, beam), keep, &ctx.budget)?;
    Ok((cast, b, p))
}

fn gpu_parity(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let margin: f64 = ctx.param_or("ulp_margin", 2f64.powi(-22))?;
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(ctx.bad("ulp_margin", "must be finite and >= 0"));
    }
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let (dag, cs) = sc.extras(&tree, &ctx.budget)?;
    let th = Through::pick(&tree, dag.as_ref(), cs.as_deref());
    let (cast, b, p) = gpu_run(ctx, &sc, (th, true), true)?;
    let scene = (&sc.shape, sc.depth);
    let a = for_scene(&sc.shape, &tree, sc.attributes)?;
    let at = (margin, a.as_ref().map(|a| (a, sc.attributes)));
    crate::voxels::checks::gpu_parity(th, &cast, &b, &p, scene, at, ctx.case_id, ctx.dump)
}

fn gpu_bench(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    // `size: 0`: the scene's own width x height (1920x1080 for the H100 goal).
    let size = Some(ctx.param_or("size", 512)?).filter(|&s: &u32| s != 0);
    let (count, seed) = (
        ctx.param_or("count", 1 << 18)?,
        ctx.param_or("seed", ctx.seed)?,
    );
    let what = ("voxels.gpu_bench rays and results", 200);
    let sets = Sets::<f32>::new(&sc, (size, count, seed), what, &ctx.budget)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let mut out = Outputs::default();
    measure::gpu_bench(&sc, &tree, &sets, GpuContext::get()?, &ctx.budget, &mut out)?;
    Ok(out)
}

fn attributes_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    attribute_quality(&sc.shape, &build(&sc.shape, sc.depth, &ctx.budget)?)
}

fn mesh_referee_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let Shape::Mesh(m) = &sc.shape else {
        let why = "voxels.mesh_referee needs a `shape: {type: mesh}` scene";
        return Err(Error::invalid(ctx.scene()?.at(), why));
    };
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let strides = (
        ctx.param_or("tri_stride", 1)?,
        ctx.param_or("leaf_stride", 1)?,
    );
    let mut out = mesh_referee(m, &tree, strides, ctx.param_or("margin", 1e-9)?);
    out.metric("peak_rss_bytes", peak_rss_bytes());
    Ok(out)
}
