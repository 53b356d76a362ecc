//! DAG operations of the `voxels` renderer (issue 14): wiring only.
//!
//! | op | what |
//! | --- | --- |
//! | `voxels.dag` | octree and DAG of the scene: `nodes_per_level`, node, slot and byte counts of both; with `count` > 0, octree vs DAG cast Mrays per CPU-second on the scene's camera rays and `count` incoherent rays, in one run (`repeats` alternating rounds, default 3; CPU time from /proc in 10 ms ticks) |
//! | `voxels.dag_referee` | distinct non-uniform cube contents per level from the scene predicate (`nodes_per_level`, depth <= 7) |

use super::{OpCtx, OpEntry, Support};
use crate::error::Result;
use crate::judge::measure::timed;
use crate::rays::f_ray;
use crate::real::{Precision, Real};
use crate::tensor::{Outputs, Tensor};
use crate::voxels::cast::{CastParams, CastReal};
use crate::voxels::dag::{build_dag, Dag};
use crate::voxels::octree::{build, Octree};
use crate::voxels::outputs::build_metrics;
use crate::voxels::raysets::incoherent;
use crate::voxels::referee_dag::distinct_nodes_per_level;
use crate::voxels::render::{cast_all, cast_all_dag, VoxelHits};

pub const OPS: &[OpEntry] = &[
    OpEntry {
        name: "voxels.dag",
        doc: "octree vs DAG: nodes_per_level, nodes/slots/bytes of both; with count > 0 cast Mrays per CPU-second of both on the same rays",
        params: &["count", "seed", "repeats"],
        support: Support::Cpu,
        run: dag_op,
    },
    OpEntry {
        name: "voxels.dag_referee",
        doc: "distinct non-uniform cube contents per level from the scene predicate (nodes_per_level; depth <= 7)",
        params: &[],
        support: Support::Any,
        run: dag_referee,
    },
];

/// The DAG's counters and build time, beside an octree's.
pub(super) fn dag_metrics(out: &mut Outputs, g: &Dag) {
    let s = &g.stats;
    out.counter("dag_nodes", s.nodes)
        .counter("dag_slots", s.slots)
        .counter("dag_bytes", s.bytes);
    out.metric("dag_build_s", s.build_s);
}

fn per_level(v: &[u64]) -> Result<Tensor> {
    Tensor::from_shape_vec(&[v.len()], v.iter().map(|&x| x as f64).collect())
}

/// Rays that differ between two casts in hit, t, leaf or normal (bitwise).
fn differing<F: Real>(a: &VoxelHits<F>, b: &VoxelHits<F>) -> u64 {
    (0..a.hit.len())
        .filter(|&i| {
            a.hit[i] != b.hit[i]
                || a.t[i].f64().to_bits() != b.t[i].f64().to_bits()
                || a.leaf[i] != b.leaf[i]
                || a.normal[i] != b.normal[i]
        })
        .count() as u64
}

fn bench_in<F: CastReal>(
    ctx: &OpCtx,
    sc: &crate::scene::voxels::VoxelScene,
    tree: &Octree,
    g: &Dag,
    out: &mut Outputs,
) -> Result<()> {
    let count: u32 = ctx.param_or("count", 0)?;
    if count == 0 {
        return Ok(());
    }
    let seed: u32 = ctx.param_or("seed", ctx.seed)?;
    let repeats: u32 = ctx.param_or("repeats", 3u32)?.max(1);
    let (cam, gen) = sc.view.build()?;
    let cam_rays = f_ray::<F>(&cam, &gen, &ctx.budget)?;
    let (io, id): (Vec<[F; 3]>, Vec<[F; 3]>) = incoherent(count, seed)
        .into_iter()
        .map(|(o, d)| (o.map(F::of), d.map(F::of)))
        .unzip();
    let sets = [
        ("coherent", &cam_rays.o, &cam_rays.d, gen.near, gen.far),
        ("incoherent", &io, &id, 0.0, f64::INFINITY),
    ];
    for (name, o, d, near, far) in sets {
        let p = CastParams {
            near,
            far,
            lod: sc.lod,
            max_iter: sc.max_iter,
        };
        let n = o.len() as f64;
        // Alternating repeats, so both see the same machine load.
        let (mut a, mut b) = (VoxelHits::default(), VoxelHits::default());
        let (mut ca, mut cb) = (0.0, 0.0);
        for _ in 0..repeats {
            let (h, _, c) = timed(|| cast_all::<F>(tree, o, d, &p));
            (a, ca) = (h, ca + c);
            let (h, _, c) = timed(|| cast_all_dag::<F>(g, o, d, &p));
            (b, cb) = (h, cb + c);
        }
        let n = n * repeats as f64;
        let rate = |c: f64| if c > 0.0 { n / c / 1e6 } else { 0.0 };
        out.metric(&format!("{name}_octree_mrays_per_cpu_s"), rate(ca));
        out.metric(&format!("{name}_dag_mrays_per_cpu_s"), rate(cb));
        out.metric(
            &format!("{name}_dag_over_octree"),
            if cb > 0.0 { ca / cb } else { 0.0 },
        );
        out.counter(&format!("{name}_differing_rays"), differing(&a, &b));
    }
    Ok(())
}

fn dag_op(ctx: &OpCtx) -> Result<Outputs> {
    let sc = crate::scene::voxels::parse(ctx.scene()?)?;
    let tree = build(&sc.shape, sc.depth, &ctx.budget)?;
    let g = build_dag(&tree, &ctx.budget)?;
    let mut out = Outputs::default();
    build_metrics(&mut out, &tree);
    dag_metrics(&mut out, &g);
    let t = &tree.stats;
    out.metric(
        "octree_over_dag_bytes",
        t.bytes as f64 / g.stats.bytes as f64,
    )
    .metric(
        "dag_bytes_per_voxel",
        if t.solid_voxels == 0 {
            0.0
        } else {
            g.stats.bytes as f64 / t.solid_voxels as f64
        },
    );
    out.tensor("nodes_per_level", per_level(&g.stats.nodes_per_level)?);
    match ctx.precision {
        Precision::F32 => bench_in::<f32>(ctx, &sc, &tree, &g, &mut out)?,
        Precision::F64 => bench_in::<f64>(ctx, &sc, &tree, &g, &mut out)?,
    }
    Ok(out)
}

fn dag_referee(ctx: &OpCtx) -> Result<Outputs> {
    let sc = crate::scene::voxels::parse(ctx.scene()?)?;
    let counts = distinct_nodes_per_level(&sc.shape, sc.depth)?;
    let mut out = Outputs::default();
    out.counter("nodes", counts.iter().sum());
    out.tensor("nodes_per_level", per_level(&counts)?);
    Ok(out)
}
