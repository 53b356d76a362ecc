//! Sparse voxel octrees and the Laine–Karras ESVO traversal (seeds 001, 003).
//! Operations of the `voxels` renderer.
//!
//! | op | what |
//! | --- | --- |
//! | `voxels.render` | build the octree (and the DAG with `structure: dag`), cast every ray: hit, t, leaf, normal, image, iters, leaf_key; build and cast metrics |
//! | `voxels.referee` | the exact f64 DDA over the scene predicate on the same rays, with tie flags |
//! | `voxels.sphere_bounds` | analytic entry distances of the spheres r -+ half a voxel diagonal (sphere scenes) |
//! | `voxels.bench` | Mrays/s of octree and referee, coherent and incoherent, build time, bytes per voxel |
//!
//! Ray sources (`params.rays`): `camera` (default: the scene's camera, tensors
//! shaped (H, W)), `hard` (`count` rays of each hard kind, shaped (N,), plus
//! `kind` (int32)), `incoherent` (`count` rays, origins uniform in the box,
//! uniform directions); `render --rays FILE` replays dumped rays (shape (N,)),
//! and `--dump-failing` adds `rays` (N, 9). `seed` defaults to the run seed. Rays are made in
//! the run's precision; the referee widens the same rays to f64, so it
//! judges exactly the rays the cast saw.

use std::time::Instant;

use super::{BackendKind, OpCtx, OpEntry, Support};
use crate::budget::bytes_for;
use crate::error::{Error, Result};
use crate::judge::measure::timed;
use crate::parallel::par_collect;
use crate::rays::{f_ray, RayGen, Rays};
use crate::real::Real;
use crate::scene::voxels::VoxelScene;
use crate::tensor::{Outputs, Tensor};
use crate::voxels::cast::{CastParams, CastReal};
use crate::voxels::contour::fit_all;
use crate::voxels::dag::{build_dag, Dag};
use crate::voxels::octree::{build, Octree};
use crate::voxels::attributes::{for_scene, Attributes};
use crate::voxels::outputs::{build_metrics, put_hits, put_hits_shaded};
use crate::voxels::raysets::{hard, incoherent, HARD_KINDS};
use crate::voxels::render::{cast_all, cast_all_contours, cast_all_dag, referee_all, Structure};
use crate::voxels::shape::Shape;

const RAY_PARAMS: &[&str] = &["rays", "count", "seed"];

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "voxels.render",
        doc: "ESVO cast of a voxels scene: hit, t, leaf, normal, image, iters; build_s, bytes_per_voxel, mrays_per_s",
        params: RAY_PARAMS,
        support: Support::CpuGpuF32,
        run: render,
    },
    OpEntry {
        name: "voxels.referee",
        doc: "exact f64 Amanatides-Woo DDA over the scene predicate: hit, t, leaf, normal, tie, near_tie, untied, clear",
        params: &["rays", "count", "seed", "near_margin"],
        support: Support::Any,
        run: referee_op,
    },
    OpEntry {
        name: "voxels.sphere_bounds",
        doc: "entry t of the spheres radius -+ half a voxel diagonal: t_outer, t_inner, meets_outer, meets_inner",
        params: &["rays", "count", "seed", "slack_rel"],
        support: Support::Any,
        run: sphere_bounds,
    },
    OpEntry {
        name: "voxels.bench",
        doc: "octree vs referee Mrays/s on coherent (size^2 camera) and incoherent (count) rays; build_s, bytes_per_voxel",
        params: &["count", "size", "seed", "referee_stride"],
        support: Support::Cpu,
        run: bench,
    },
];

pub(super) fn load(ctx: &OpCtx) -> Result<VoxelScene> {
    crate::scene::voxels::parse(ctx.scene()?)
}

/// A batch of rays in precision `F` and the shape of its per-ray tensors.
pub(super) struct Batch<F> {
    pub(super) o: Vec<[F; 3]>,
    pub(super) d: Vec<[F; 3]>,
    pub(super) shape: Vec<usize>,
    pub(super) near: f64,
    pub(super) far: f64,
    pub(super) kind: Option<Vec<i32>>,
}

pub(super) fn from64<F: Real>(rays: Vec<([f64; 3], [f64; 3])>) -> (Vec<[F; 3]>, Vec<[F; 3]>) {
    rays.into_iter()
        .map(|(o, d)| (o.map(F::of), d.map(F::of)))
        .unzip()
}

pub(super) fn camera_batch<F: Real>(
    ctx: &OpCtx,
    sc: &VoxelScene,
    size: Option<u32>,
) -> Result<Batch<F>> {
    let (cam, mut gen): (_, RayGen) = sc.view.build()?;
    let cam = match size {
        Some(s) => {
            gen.width = s;
            gen.height = s;
            gen.roi = None;
            sc.view.camera.build(s, s)?
        }
        None => cam,
    };
    let r = f_ray::<F>(&cam, &gen, &ctx.budget)?;
    let roi = gen.region();
    Ok(Batch {
        o: r.o,
        d: r.d,
        shape: vec![roi.height as usize, roi.width as usize],
        near: gen.near,
        far: gen.far,
        kind: None,
    })
}

pub(super) fn batch<F: Real>(ctx: &OpCtx, sc: &VoxelScene) -> Result<Batch<F>> {
    let src: String = ctx.param_or("rays", "camera".to_string())?;
    let seed: u32 = ctx.param_or("seed", ctx.seed)?;
    let count: u32 = ctx.param_or("count", 4096)?;
    let at = format!("{} params.rays", ctx.case_id);
    if let Some(t) = ctx.rays {
        // `render --rays FILE`: replay dumped rays (their t0/t1 columns are
        // ignored; the scene's near/far apply).
        let r = Rays::<F>::from_tensor(t, "--rays")?;
        let n = r.len();
        return Ok(Batch {
            o: r.o,
            d: r.d,
            shape: vec![n],
            near: sc.view.near,
            far: sc.view.far,
            kind: None,
        });
    }
    match src.as_str() {
        "camera" => camera_batch(ctx, sc, None),
        "hard" | "incoherent" => {
            let total = if src == "hard" {
                count as u64 * HARD_KINDS.len() as u64
            } else {
                count as u64
            };
            ctx.budget
                .check("voxel rays", bytes_for(total, 2 * 24 + 64))?;
            let (rays, kind) = if src == "hard" {
                let h = hard(&sc.shape, sc.depth, count, seed);
                let kind = h
                    .iter()
                    .map(|(_, k)| HARD_KINDS.iter().position(|x| x == k).unwrap_or(0) as i32)
                    .collect();
                (h.into_iter().map(|(r, _)| r).collect(), Some(kind))
            } else {
                (incoherent(count, seed), None)
            };
            let n = rays.len();
            let (o, d) = from64::<F>(rays);
            Ok(Batch {
                o,
                d,
                shape: vec![n],
                near: 0.0,
                far: f64::INFINITY,
                kind,
            })
        }
        other => Err(Error::invalid(
            at,
            format!("{other:?} is not camera, hard or incoherent"),
        )),
    }
}

/// The batch in the (N, 9) dump layout of `Rays::to_tensor` (`--dump-failing`;
/// `render --rays` replays it). An infinite far is written as 1e30.
pub(super) fn dump_rays<F: Real>(b: &Batch<F>) -> Result<Tensor> {
    let n = b.o.len();
    let far = if b.far.is_finite() { b.far } else { 1e30 };
    Rays {
        o: b.o.clone(),
        d: b.d.clone(),
        t0: vec![F::of(b.near); n],
        t1: vec![F::of(far); n],
        pixel: (0..n as u32).collect(),
    }
    .to_tensor()
}

fn render_in<F: CastReal>(
    ctx: &OpCtx,
    sc: &VoxelScene,
    tree: &Octree,
    dag: Option<&Dag>,
    contours: Option<&[u32]>,
    attrs: Option<&Attributes>,
) -> Result<Outputs> {
    let b = batch::<F>(ctx, sc)?;
    let n = b.o.len() as u64;
    ctx.budget.check(
        "voxels.render outputs",
        bytes_for(n, 12 * std::mem::size_of::<F>() as u64 + 32),
    )?;
    let p = CastParams {
        near: b.near,
        far: b.far,
        lod: sc.lod,
        max_iter: sc.max_iter,
    };
    let t0 = Instant::now();
    let h = match (dag, contours) {
        (Some(g), _) => cast_all_dag::<F>(g, &b.o, &b.d, &p),
        (None, Some(cs)) => cast_all_contours::<F>(tree, cs, &b.o, &b.d, &p).0,
        (None, None) => cast_all::<F>(tree, &b.o, &b.d, &p),
    };
    let s = t0.elapsed().as_secs_f64();
    let mut out = Outputs::default();
    if let Some(g) = dag {
        super::voxels_dag::dag_metrics(&mut out, g);
    }
    if ctx.dump {
        out.tensor("rays", dump_rays(&b)?);
    }
    out.metric("cast_s", s)
        .metric("mrays_per_s", n as f64 / s.max(1e-12) / 1e6);
    out.counter("rays", n)
        .counter("hits", h.hit.iter().map(|&x| x as u64).sum());
    let a = attrs.map(|a| (a, sc.attributes));
    match dag {
        Some(g) => put_hits_shaded(&mut out, h, &b.shape, sc.depth, a, |v| g.attr_index(v))?,
        None => put_hits_shaded(&mut out, h, &b.shape, sc.depth, a, |v| tree.attr_index(v))?,
    }
    if let Some(k) = b.kind {
        out.tensor("kind", Tensor::from_shape_vec(&b.shape, k)?);
    }
    build_metrics(&mut out, tree);
    Ok(out)
}

fn render(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let attrs = for_scene(&sc.shape, &tree, sc.attributes)?;
    if ctx.backend == BackendKind::Gpu {
        if sc.structure != Structure::Octree || sc.contours || attrs.is_some() {
            return Err(Error::NotSupported(format!(
                "{}: the GPU cast reads the octree without contours or attributes (structure: dag, contours and attributes run on the CPU)",
                ctx.case_id
            )));
        }
        return super::voxels_gpu::render_gpu(ctx, &sc, &tree);
    }
    let dag = match sc.structure {
        Structure::Octree => None,
        Structure::Dag => Some(build_dag(&tree, &ctx.budget)?),
    };
    let contours = if sc.contours {
        Some(fit_all(&sc.shape, &tree)?)
    } else {
        None
    };
    let (g, cs) = (dag.as_ref(), contours.as_deref());
    by_precision!(ctx, render_in(ctx, &sc, &tree, g, cs, attrs.as_ref()))
}

pub(super) fn widen<F: Real>(b: &Batch<F>) -> (Vec<[f64; 3]>, Vec<[f64; 3]>) {
    (
        b.o.iter().map(|v| v.map(|x| x.f64())).collect(),
        b.d.iter().map(|v| v.map(|x| x.f64())).collect(),
    )
}

fn referee_in<F: Real>(ctx: &OpCtx, sc: &VoxelScene) -> Result<Outputs> {
    let b = batch::<F>(ctx, sc)?;
    let margin: f64 = ctx.param_or("near_margin", 0.0)?;
    if !(margin >= 0.0 && margin.is_finite()) {
        return Err(Error::invalid(
            format!("{} params.near_margin", ctx.case_id),
            "must be finite and >= 0",
        ));
    }
    let (o, d) = widen(&b);
    let t0 = Instant::now();
    let r = referee_all(&sc.shape, sc.depth, &o, &d, b.near, b.far, margin);
    let s = t0.elapsed().as_secs_f64();
    let n = o.len();
    let mut out = Outputs::default();
    out.metric("time_s", s)
        .metric("mrays_per_s", n as f64 / s.max(1e-12) / 1e6);
    out.counter("rays", n as u64);
    out.counter("ties", r.tie.iter().map(|&x| x as u64).sum());
    out.counter("near_ties", r.near_tie.iter().map(|&x| x as u64).sum());
    let untied: Vec<u8> = r.tie.iter().map(|&x| 1 - x).collect();
    let clear: Vec<u8> = r.near_tie.iter().map(|&x| 1 - x).collect();
    out.tensor("tie", Tensor::from_shape_vec(&b.shape, r.tie)?);
    out.tensor("near_tie", Tensor::from_shape_vec(&b.shape, r.near_tie)?);
    out.tensor("untied", Tensor::from_shape_vec(&b.shape, untied)?);
    out.tensor("clear", Tensor::from_shape_vec(&b.shape, clear)?);
    put_hits(&mut out, r.hits, &b.shape, sc.depth, false)?;
    Ok(out)
}

fn referee_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    by_precision!(ctx, referee_in(ctx, &sc))
}

/// First t >= near at which `o + t d` (unit d) is inside the ball of
/// radius `r` about the origin, if any (closed form, f64).
pub(super) fn ball_entry(o: [f64; 3], d: [f64; 3], r: f64, near: f64) -> Option<f64> {
    let b = o[0] * d[0] + o[1] * d[1] + o[2] * d[2];
    let c = o[0] * o[0] + o[1] * o[1] + o[2] * o[2] - r * r;
    let disc = b * b - c;
    if disc < 0.0 {
        return None;
    }
    let q = disc.sqrt();
    let (t0, t1) = (-b - q, -b + q);
    if t1 < near {
        None
    } else {
        Some(t0.max(near))
    }
}

fn bounds_in<F: Real>(ctx: &OpCtx, sc: &VoxelScene, radius: f64) -> Result<Outputs> {
    let b = batch::<F>(ctx, sc)?;
    let slack: f64 = ctx.param_or("slack_rel", 1e-12)?;
    let (o, d) = widen(&b);
    let h = 3f64.sqrt() / (1u64 << sc.depth) as f64;
    let (r_out, r_in) = ((radius + h) * (1.0 + slack), (radius - h) * (1.0 - slack));
    let res = par_collect("voxels.sphere_bounds", o.len(), |i| {
        let l = (d[i][0] * d[i][0] + d[i][1] * d[i][1] + d[i][2] * d[i][2]).sqrt();
        let du = d[i].map(|x| x / l);
        let e = |r: f64| {
            ball_entry(o[i], du, r, b.near)
                .filter(|&t| t <= b.far)
                .map(|t| t / l)
        };
        (e(r_out), if r_in > 0.0 { e(r_in) } else { None })
    });
    let mut out = Outputs::default();
    let t_outer: Vec<f64> = res.iter().map(|r| r.0.unwrap_or(-1.0)).collect();
    let t_inner: Vec<f64> = res.iter().map(|r| r.1.unwrap_or(-1.0)).collect();
    out.tensor("t_outer", Tensor::from_shape_vec(&b.shape, t_outer)?);
    out.tensor("t_inner", Tensor::from_shape_vec(&b.shape, t_inner)?);
    out.tensor(
        "meets_outer",
        Tensor::from_shape_vec(&b.shape, res.iter().map(|r| r.0.is_some() as u8).collect())?,
    );
    out.tensor(
        "meets_inner",
        Tensor::from_shape_vec(&b.shape, res.iter().map(|r| r.1.is_some() as u8).collect())?,
    );
    Ok(out)
}

fn sphere_bounds(ctx: &OpCtx) -> Result<Outputs> {
    let sc = load(ctx)?;
    let Shape::Sphere { radius } = sc.shape else {
        return Err(Error::invalid(
            ctx.scene()?.at(),
            "voxels.sphere_bounds needs a `shape: {type: sphere}` scene",
        ));
    };
    by_precision!(ctx, bounds_in(ctx, &sc, radius))
}

fn bench_in<F: CastReal>(ctx: &OpCtx, sc: &VoxelScene, tree: &Octree) -> Result<Outputs> {
    let count: u32 = ctx.param_or("count", 1 << 20)?;
    let size: u32 = ctx.param_or("size", 1024)?;
    let seed: u32 = ctx.param_or("seed", ctx.seed)?;
    let stride: usize = ctx.param_or("referee_stride", 16usize)?.max(1);
    let threads = rayon::current_num_threads() as f64;
    let mut out = Outputs::default();
    out.metric("threads", threads);
    build_metrics(&mut out, tree);
    ctx.budget.check(
        "voxels.bench rays and results",
        bytes_for(count as u64 + size as u64 * size as u64, 160),
    )?;
    let coherent = camera_batch::<F>(ctx, sc, Some(size))?;
    let (io, id) = from64::<F>(incoherent(count, seed));
    let inc = Batch {
        o: io,
        d: id,
        shape: vec![count as usize],
        near: 0.0,
        far: f64::INFINITY,
        kind: None,
    };
    for (name, b) in [("coherent", &coherent), ("incoherent", &inc)] {
        let p = CastParams {
            near: b.near,
            far: b.far,
            lod: sc.lod,
            max_iter: sc.max_iter,
        };
        let (h, wall, cpu) = timed(|| cast_all::<F>(tree, &b.o, &b.d, &p));
        let n = b.o.len() as f64;
        let rate = n / wall.max(1e-12) / 1e6;
        out.metric(&format!("{name}_mrays_per_s"), rate);
        out.metric(&format!("{name}_mrays_per_s_per_core"), rate / threads);
        out.metric(
            &format!("{name}_mrays_per_cpu_s"),
            if cpu > 0.0 { n / cpu / 1e6 } else { 0.0 },
        );
        let hits = h.hit.iter().map(|&x| x as f64).sum::<f64>();
        out.metric(&format!("{name}_hit_fraction"), hits / n);
        out.metric(
            &format!("{name}_mean_iters"),
            h.iters.iter().map(|&x| x as f64).sum::<f64>() / n,
        );
        // The referee on every stride-th ray of the same set.
        let (o, d) = widen(b);
        let (o, d): (Vec<_>, Vec<_>) = o.into_iter().zip(d).step_by(stride).unzip();
        let (r, rwall, rcpu) =
            timed(|| referee_all(&sc.shape, sc.depth, &o, &d, b.near, b.far, 0.0));
        let m = r.tie.len() as f64;
        let rrate = m / rwall.max(1e-12) / 1e6;
        out.metric(&format!("referee_{name}_mrays_per_s"), rrate);
        out.metric(
            &format!("referee_{name}_mrays_per_cpu_s"),
            if rcpu > 0.0 { m / rcpu / 1e6 } else { 0.0 },
        );
        out.metric(
            &format!("{name}_speedup_vs_referee"),
            rate / rrate.max(1e-12),
        );
    }
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::budget::MemBudget;
    use crate::judge::ops::BackendKind;
    use crate::real::Precision;
    use crate::scene::SceneDoc;
    use serde_yaml::Value;

    const SPHERE: &str = "renderer: voxels\nshape: {type: sphere, radius: 0.8}\ndepth: 6\n\
        camera: {type: pinhole, position: [2.0, 1.5, 2.5], target: [0, 0, 0], fov_y: 45}\nwidth: 48\nheight: 40\n";

    fn run(op: &str, scene: &str, params: &str, precision: Precision) -> Outputs {
        let doc = SceneDoc {
            path: "t.yaml".into(),
            value: serde_yaml::from_str(scene).unwrap(),
        };
        let params: Value = serde_yaml::from_str(params).unwrap();
        let ctx = OpCtx {
            case_id: "t",
            scene: Some(&doc),
            params: &params,
            backend: BackendKind::Cpu,
            precision,
            seed: 1,
            budget: MemBudget::fixed(1 << 30),
            dump: false,
            rays: None,
            root: std::path::Path::new("."),
        };
        (super::super::find(op).unwrap().run)(&ctx).unwrap()
    }

    #[test]
    fn render_writes_scenes_outputs_with_their_shapes_and_dtypes() {
        let out = run("voxels.render", SPHERE, "{}", Precision::F32);
        let t = &out.tensors;
        assert_eq!(
            (t["hit"].dtype(), t["hit"].shape()),
            ("uint8", &[40usize, 48][..])
        );
        assert_eq!(
            (t["t"].dtype(), t["leaf"].dtype(), t["leaf"].shape()),
            ("float32", "int32", &[40usize, 48, 3][..])
        );
        assert_eq!(t["image"].shape(), &[40, 48, 3]);
        assert!(out.counters["hits"] > 300);
        let hit = t["hit"].to_f64_vec();
        let leaf = t["leaf"].to_f64_vec();
        let tt = t["t"].to_f64_vec();
        for i in 0..hit.len() {
            if hit[i] == 0.0 {
                assert_eq!((tt[i], leaf[3 * i]), (-1.0, -1.0));
            }
        }
    }

    #[test]
    fn render_and_referee_agree_on_untied_camera_and_hard_rays() {
        for params in ["{}", "{rays: hard, count: 60}"] {
            let a = run("voxels.render", SPHERE, params, Precision::F64);
            let r = run("voxels.referee", SPHERE, params, Precision::F64);
            let untied = r.tensors["untied"].to_f64_vec();
            for name in ["hit", "t", "normal", "leaf"] {
                let x = a.tensors[name].to_f64_vec();
                let y = r.tensors[name].to_f64_vec();
                let k = x.len() / untied.len();
                for i in 0..x.len() {
                    if untied[i / k] == 1.0 {
                        assert!(
                            (x[i] - y[i]).abs() <= 1e-12 * y[i].abs().max(1.0),
                            "{params} {name} {i}: {} {}",
                            x[i],
                            y[i]
                        );
                    }
                }
            }
        }
    }

    #[test]
    fn sphere_hits_lie_between_the_bounding_spheres() {
        let a = run("voxels.render", SPHERE, "{}", Precision::F64);
        let b = run("voxels.sphere_bounds", SPHERE, "{}", Precision::F64);
        let (hit, t) = (a.tensors["hit"].to_f64_vec(), a.tensors["t"].to_f64_vec());
        let (to, ti, mi) = (
            b.tensors["t_outer"].to_f64_vec(),
            b.tensors["t_inner"].to_f64_vec(),
            b.tensors["meets_inner"].to_f64_vec(),
        );
        for i in 0..hit.len() {
            if hit[i] == 1.0 {
                assert!(t[i] >= to[i] && to[i] >= 0.0);
            }
            if mi[i] == 1.0 {
                assert!(hit[i] == 1.0 && t[i] <= ti[i]);
            }
        }
    }
}
