//! Timing harnesses of the voxel casts: the octree against the referee,
//! the octree against the DAG, the CPU against the GPU, each on coherent
//! (camera) and incoherent ray sets in one run. Rates are Mrays per second
//! and per CPU second (the process CPU-time clock, [`super::process_cpu_s`]).

use super::timed;
use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::Result;
use crate::gpu::voxels::{GpuCast, GpuCastParams, GpuOctree};
use crate::gpu::GpuContext;
use crate::rays::thread_order::{warp_efficiency, ThreadOrder};
use crate::rays::RayGen;
use crate::real::Real;
use crate::scene::voxels::VoxelScene;
use crate::tensor::{Outputs, Tensor};
use crate::voxels::batch::Batch;
use crate::voxels::cast::{Absolute, CastReal, Relative};
use crate::voxels::cast_lanes::{cast_all_lanes_on, LaneIsa};
use crate::voxels::dag::{build_dag, Dag};
use crate::voxels::gpu::gpu_params;
use crate::voxels::node_order::breadth_first;
use crate::voxels::octree::Octree;
use crate::voxels::outputs::{build_metrics, dag_metrics};
use crate::voxels::render::{cast_all, cast_all_dag, referee_all, VoxelHits};
use crate::voxels::through::{CastPath, Through};

fn per_cpu_s(n: f64, cpu: f64) -> f64 {
    if cpu > 0.0 {
        n / cpu / 1e6
    } else {
        0.0
    }
}

fn mean(v: impl Iterator<Item = f64>) -> f64 {
    let (s, n) = v.fold((0.0, 0usize), |(s, n), x| (s + x, n + 1));
    s / n.max(1) as f64
}

/// A benchmark's ray sets: the camera (`size` x `size` pixels, the scene's
/// own size when `None`) and its rays, and `count` incoherent rays.
pub struct Sets<F> {
    cam: Camera,
    gen: RayGen,
    coh: Batch<F>,
    inc: Batch<F>,
}

impl<F: Real> Sets<F> {
    /// The sets after a budget check of `bytes_per_ray` per ray (`what`
    /// names the check).
    pub fn new(
        sc: &VoxelScene,
        (size, count, seed): (Option<u32>, u32, u32),
        (what, bytes_per_ray): (&str, u64),
        budget: &MemBudget,
    ) -> Result<Sets<F>> {
        let pixels = size.map_or(0, |s| s as u64 * s as u64);
        budget.check(what, bytes_for(count as u64 + pixels, bytes_per_ray))?;
        let (cam, gen) = sc.view_at(size)?;
        let coh = Batch::camera(&cam, &gen, budget)?;
        let inc = Batch::incoherent(count, seed);
        Ok(Sets { cam, gen, coh, inc })
    }

    fn named(&self) -> [(&'static str, &Batch<F>); 2] {
        [("coherent", &self.coh), ("incoherent", &self.inc)]
    }
}

/// `voxels.bench`: thread count, the octree's build metrics and
/// [`octree_vs_referee`] on `sets`.
pub fn bench<F: CastReal>(
    sc: &VoxelScene,
    tree: &Octree,
    sets: &Sets<F>,
    stride: usize,
    out: &mut Outputs,
) {
    out.metric("threads", rayon::current_num_threads() as f64);
    build_metrics(out, tree);
    octree_vs_referee(tree, sc, sets, stride, out);
}

/// `voxels.dag`: the DAG's metrics against the octree's (bytes ratio,
/// bytes per voxel, `nodes_per_level`), and with `sets`
/// [`octree_vs_dag`] over `repeats` rounds.
pub fn dag_bench<F: CastReal>(
    sc: &VoxelScene,
    tree: &Octree,
    sets: Option<(&Sets<F>, u32)>,
    budget: &MemBudget,
    out: &mut Outputs,
) -> Result<()> {
    let g = build_dag(tree, budget)?;
    dag_metrics(out, &g);
    let t = &tree.stats;
    out.metric(
        "octree_over_dag_bytes",
        t.bytes as f64 / g.stats.bytes as f64,
    );
    let per_voxel = if t.solid_voxels == 0 {
        0.0
    } else {
        g.stats.bytes as f64 / t.solid_voxels as f64
    };
    out.metric("dag_bytes_per_voxel", per_voxel);
    out.tensor("nodes_per_level", per_level(&g.stats.nodes_per_level)?);
    if let Some((sets, repeats)) = sets {
        octree_vs_dag(tree, &g, sc, sets, repeats, out);
    }
    Ok(())
}

/// Counts per octree level as a tensor.
pub fn per_level(v: &[u64]) -> Result<Tensor> {
    Tensor::from_shape_vec(&[v.len()], v.iter().map(|&x| x as f64).collect())
}

/// `voxels.gpu_bench`: thread count, octree and DAG metrics and
/// [`cpu_vs_gpu`] of both structures on `sets`, then [`differing_totals`]
/// as tensors a case can gate.
pub fn gpu_bench(
    sc: &VoxelScene,
    tree: &Octree,
    sets: &Sets<f32>,
    gpu: &GpuContext,
    budget: &MemBudget,
    out: &mut Outputs,
) -> Result<()> {
    let dag = build_dag(tree, budget)?;
    out.metric("threads", rayon::current_num_threads() as f64);
    build_metrics(out, tree);
    dag_metrics(out, &dag);
    let structures = [
        ("octree", Through::Octree(tree)),
        ("dag", Through::Dag(&dag)),
    ];
    cpu_vs_gpu(&structures, gpu, sc, sets, budget, out)?;
    lane_isas(tree, &dag, sc, sets, out);
    node_order(&dag, sc, sets, out)?;
    let (rays, comparisons) = differing_totals(out);
    out.tensor("differing_rays", Tensor::scalar(rays));
    out.tensor("differing_comparisons", Tensor::scalar(comparisons as f64));
    Ok(())
}

/// Every `*_differing_rays` figure of `out` (metric or counter: each path
/// against its referee path on the same rays) summed, and how many there
/// are: a bench whose paths all agree reads 0 over a count that is not.
fn differing_totals(out: &Outputs) -> (f64, usize) {
    let is = |k: &String| k.ends_with("_differing_rays");
    let m = out.metrics.iter().filter(|(k, _)| is(k)).map(|(_, &v)| v);
    let c = out
        .counters
        .iter()
        .filter(|(k, _)| is(k))
        .map(|(_, &v)| v as f64);
    m.chain(c).fold((0.0, 0), |(sum, n), v| (sum + v, n + 1))
}

/// The lane cast compiled for each [`LaneIsa`] from AVX2 up that this CPU
/// has, in [`ROUNDS`] interleaved rounds per structure and set:
/// `{structure}_lanes_{isa}_{set}_mrays_per_cpu_s` and `..._mrays_per_s`
/// (wall), and for the ISAs above AVX2 `{structure}_{set}_lanes_{isa}_over_avx2`
/// (per CPU-second, same run) and `{structure}_{set}_lanes_{isa}_differing_rays`
/// (against AVX2).
pub fn lane_isas(tree: &Octree, dag: &Dag, sc: &VoxelScene, sets: &Sets<f32>, out: &mut Outputs) {
    let isas: Vec<LaneIsa> = LaneIsa::available(tree.nodes.len().max(dag.nodes.len()))
        .into_iter()
        .filter(|&i| i >= LaneIsa::Avx2)
        .collect();
    for (sname, dag_path) in [("octree", false), ("dag", true)] {
        for (set, b) in sets.named() {
            let p = b.params(sc.lod, sc.max_iter);
            let cast = |isa| {
                if dag_path {
                    cast_all_lanes_on::<Absolute>(isa, &dag.nodes, dag.depth, &b.o, &b.d, &p)
                } else {
                    cast_all_lanes_on::<Relative>(isa, &tree.nodes, tree.depth, &b.o, &b.d, &p)
                }
            };
            let mut acc = vec![(0.0, 0.0); isas.len()];
            let mut res = vec![VoxelHits::default(); isas.len()];
            for _ in 0..ROUNDS {
                for (k, &isa) in isas.iter().enumerate() {
                    let (h, wall, cpu) = timed(|| cast(isa));
                    res[k] = h;
                    acc[k] = (acc[k].0 + wall, acc[k].1 + cpu);
                }
            }
            let n = b.o.len() as f64 * ROUNDS as f64;
            for (k, isa) in isas.iter().enumerate() {
                let name = format!("{isa:?}").to_lowercase();
                let rate = per_cpu_s(n, acc[k].1);
                out.metric(&format!("{sname}_lanes_{name}_{set}_mrays_per_cpu_s"), rate);
                out.metric(
                    &format!("{sname}_lanes_{name}_{set}_mrays_per_s"),
                    n / acc[k].0.max(1e-12) / 1e6,
                );
                if k == 0 {
                    continue;
                }
                out.metric(
                    &format!("{sname}_{set}_lanes_{name}_over_avx2"),
                    rate / per_cpu_s(n, acc[0].1).max(1e-12),
                );
                out.metric(
                    &format!("{sname}_{set}_lanes_{name}_differing_rays"),
                    differing(&res[0], &res[k]) as f64,
                );
            }
        }
    }
}

/// The lane cast through the DAG and through its breadth-first copy
/// ([`breadth_first`]) in [`ROUNDS`] interleaved rounds, per set:
/// `dag_bfs_lanes_{set}_mrays_per_cpu_s`, `dag_bfs_{set}_lanes_speedup` (over
/// the DAG's order, per CPU-second, same run), `dag_bfs_{set}_differing_rays`
/// (hit, t, leaf or normal bits against the DAG's); `dag_bfs_bytes`.
pub fn node_order(dag: &Dag, sc: &VoxelScene, sets: &Sets<f32>, out: &mut Outputs) -> Result<()> {
    let bfs = breadth_first(dag);
    out.metric("dag_bfs_bytes", bfs.stats.bytes as f64);
    let pair = [Through::Dag(dag), Through::Dag(&bfs)];
    for (set, b) in sets.named() {
        let p = b.params(sc.lod, sc.max_iter);
        let (mut cpu, mut res) = ([0.0; 2], [VoxelHits::default(), VoxelHits::default()]);
        for _ in 0..ROUNDS {
            for (k, through) in pair.iter().enumerate() {
                let (h, _, c) =
                    timed(|| through.cast_by(CastPath::Lanes, &b.shape, &b.o, &b.d, &p));
                (res[k], cpu[k]) = (h?, cpu[k] + c);
            }
        }
        let n = b.o.len() as f64 * ROUNDS as f64;
        let rate = per_cpu_s(n, cpu[1]);
        out.metric(&format!("dag_bfs_lanes_{set}_mrays_per_cpu_s"), rate);
        out.metric(
            &format!("dag_bfs_{set}_lanes_speedup"),
            rate / per_cpu_s(n, cpu[0]).max(1e-12),
        );
        out.metric(
            &format!("dag_bfs_{set}_differing_rays"),
            differing(&res[0], &res[1]) as f64,
        );
    }
    Ok(())
}

/// The octree cast and the referee (on every `stride`-th ray of the same
/// set) per named batch: `<name>_mrays_per_s` (and per core, per CPU
/// second), hit fraction, mean iterations, `referee_<name>_*` and
/// `<name>_speedup_vs_referee`.
pub fn octree_vs_referee<F: CastReal>(
    tree: &Octree,
    sc: &VoxelScene,
    sets: &Sets<F>,
    stride: usize,
    out: &mut Outputs,
) {
    let threads = rayon::current_num_threads() as f64;
    let (shape, depth) = (&sc.shape, sc.depth);
    for (name, b) in sets.named() {
        let p = b.params(sc.lod, sc.max_iter);
        let (h, wall, cpu) = timed(|| cast_all::<F>(tree, &b.o, &b.d, &p));
        let n = b.o.len() as f64;
        let rate = n / wall.max(1e-12) / 1e6;
        out.metric(&format!("{name}_mrays_per_s"), rate);
        out.metric(&format!("{name}_mrays_per_s_per_core"), rate / threads);
        out.metric(&format!("{name}_mrays_per_cpu_s"), per_cpu_s(n, cpu));
        let hits = h.hit.iter().map(|&x| x as f64).sum::<f64>();
        out.metric(&format!("{name}_hit_fraction"), hits / n);
        out.metric(
            &format!("{name}_mean_iters"),
            h.iters.iter().map(|&x| x as f64).sum::<f64>() / n,
        );
        let (o, d) = b.widen();
        let (o, d): (Vec<_>, Vec<_>) = o.into_iter().zip(d).step_by(stride).unzip();
        let (r, rwall, rcpu) = timed(|| referee_all(shape, depth, &o, &d, b.near, b.far, 0.0));
        let m = r.tie.len() as f64;
        let rrate = m / rwall.max(1e-12) / 1e6;
        out.metric(&format!("referee_{name}_mrays_per_s"), rrate);
        out.metric(
            &format!("referee_{name}_mrays_per_cpu_s"),
            per_cpu_s(m, rcpu),
        );
        out.metric(
            &format!("{name}_speedup_vs_referee"),
            rate / rrate.max(1e-12),
        );
    }
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

/// The GPU camera cast in three variants ([`VARIANTS`]: both
/// [`ThreadOrder`]s from `near`, and tiles from beam starts), per variant:
/// seconds a cast (submit to readback of one cast alone; per cast of a
/// sustained submission, [`warm_repeat`]); the fraction of lane-iterations
/// 32-lane warps spend on work in either order ([`warp_efficiency`] of the
/// tiled cast's own iteration counts); the rays whose results differ between the orders
/// (none: only the thread moves) and between the beam and `near` starts
/// other than in iterations and node words read (none: the beam start never
/// passes a hit); whether the beam ran (the adapter has f64).
struct CameraCasts {
    /// Submit to readback of one cast alone.
    gpu_s: [f64; 3],
    /// Per cast of a sustained submission: the kernels' clock where the
    /// adapter has timestamps (`kernel_clock`), else the submission's wall.
    sustained_s: [f64; 3],
    kernel_clock: bool,
    warp32: [f64; 2],
    order_differing: u64,
    beam_differing: u64,
    beam_iters: f64,
    beam_ran: bool,
    rays: f64,
}

/// The variants [`camera_casts`] casts: rows from `near`, tiles from
/// `near` (the default, [`gpu_params`]), tiles from the beam starts.
const VARIANTS: [(ThreadOrder, bool); 3] = [
    (ThreadOrder::Rows, false),
    (ThreadOrder::Tiles, false),
    (ThreadOrder::Tiles, true),
];

impl CameraCasts {
    /// `{s}_gpu_coherent_rows_kernel_mrays_per_s` and
    /// `{s}_gpu_coherent_beam_kernel_mrays_per_s` (`..._mrays_per_s`
    /// without timestamps; the tiled figures from `near` are the scenario's
    /// `{s}_gpu_coherent_*`), `{s}_gpu_coherent_tiles_over_rows` and
    /// `{s}_gpu_coherent_beam_over_plain` (speed ratios, kernels' clock
    /// where there is one), `{s}_coherent_warp32_efficiency_{rows,tiles}`,
    /// `{s}_gpu_coherent_order_differing_rays`,
    /// `{s}_gpu_coherent_beam_differing_rays`,
    /// `{s}_gpu_coherent_beam_mean_iters`, `{s}_gpu_coherent_beam_ran`.
    fn report(&self, s: &str, out: &mut Outputs) {
        let secs = |k: usize| self.sustained_s[k];
        let clock = if self.kernel_clock { "kernel_" } else { "" };
        for (k, name) in [(0, "rows"), (2, "beam")] {
            out.metric(
                &format!("{s}_gpu_coherent_{name}_{clock}mrays_per_s"),
                self.rays / secs(k).max(1e-12) / 1e6,
            );
        }
        for (k, name) in ["rows", "tiles"].into_iter().enumerate() {
            out.metric(
                &format!("{s}_coherent_warp32_efficiency_{name}"),
                self.warp32[k],
            );
        }
        out.metric(
            &format!("{s}_gpu_coherent_tiles_over_rows"),
            secs(0) / secs(1).max(1e-12),
        );
        out.metric(
            &format!("{s}_gpu_coherent_beam_over_plain"),
            secs(1) / secs(2).max(1e-12),
        );
        out.metric(
            &format!("{s}_gpu_coherent_order_differing_rays"),
            self.order_differing as f64,
        );
        out.metric(
            &format!("{s}_gpu_coherent_beam_differing_rays"),
            self.beam_differing as f64,
        );
        out.metric(
            &format!("{s}_gpu_coherent_beam_mean_iters"),
            self.beam_iters,
        );
        out.metric(
            &format!("{s}_gpu_coherent_beam_ran"),
            self.beam_ran as u32 as f64,
        );
    }
}

/// [`ROUNDS`] interleaved rounds of the camera cast in the three
/// [`VARIANTS`] (which goes first rotates; `p.order`, `p.beam` and
/// `p.repeat` are ignored), each timed over submissions of
/// [`warm_repeat`] casts; seconds a cast averaged over the rounds, and the
/// last tiled cast from `near`.
fn camera_casts(
    g: &GpuOctree,
    (cam, gen): (&Camera, &RayGen),
    p: &GpuCastParams,
    budget: &MemBudget,
) -> Result<(CameraCasts, GpuCast)> {
    let mut cc = CameraCasts {
        gpu_s: [0.0; 3],
        sustained_s: [0.0; 3],
        kernel_clock: true,
        warp32: [0.0; 2],
        order_differing: 0,
        beam_differing: 0,
        beam_iters: 0.0,
        beam_ran: false,
        rays: 0.0,
    };
    let cast = |(order, beam): (ThreadOrder, bool), repeat: u32| {
        let q = GpuCastParams {
            order,
            beam,
            repeat,
            ..*p
        };
        g.cast_camera(cam, gen, &q, false, budget)
    };
    let mut reps = [1; VARIANTS.len()];
    for (k, v) in VARIANTS.into_iter().enumerate() {
        reps[k] = warm_repeat(|n| cast(v, n))?;
    }
    tracing::info!(
        ?reps,
        "gpu camera casts per timed submission (rows, tiles, beam)"
    );
    let mut last: [Option<GpuCast>; 3] = [None, None, None];
    for round in 0..ROUNDS as usize {
        for j in 0..VARIANTS.len() {
            let k = (round + j) % VARIANTS.len();
            cc.gpu_s[k] += cast(VARIANTS[k], 1)?.gpu_s;
            let c = cast(VARIANTS[k], reps[k])?;
            cc.sustained_s[k] += per_cast(&c);
            cc.kernel_clock &= c.kernel_s.is_some();
            last[k] = Some(c);
        }
    }
    let [Some(rows), Some(tiles), Some(beam)] = last else {
        unreachable!("ROUNDS > 0")
    };
    let r = ROUNDS as f64;
    cc.gpu_s = cc.gpu_s.map(|s| s / r);
    cc.sustained_s = cc.sustained_s.map(|s| s / r);
    let iters: Vec<u32> = tiles.hits.iter().map(|h| h.iters).collect();
    cc.rays = iters.len() as f64;
    cc.beam_iters = mean(beam.hits.iter().map(|h| h.iters as f64));
    cc.beam_ran = beam.beam;
    let w = gen.region().width;
    cc.warp32 = [ThreadOrder::Rows, ThreadOrder::Tiles].map(|o| warp_efficiency(&iters, o, w, 32));
    cc.order_differing = (rows.hits.iter().zip(&tiles.hits))
        .filter(|(a, b)| bytemuck::bytes_of(*a) != bytemuck::bytes_of(*b))
        .count() as u64;
    cc.beam_differing = (beam.hits.iter().zip(&tiles.hits))
        .filter(|(a, b)| a.outcome() != b.outcome())
        .count() as u64;
    Ok((cc, tiles))
}

/// Wall seconds of GPU casts run before a timed one: the first dispatch of
/// an entry may compile it, and a GPU left idle while the CPU paths ran may
/// run its first millisecond-long casts at idle clocks (a boost clock is
/// reached over milliseconds to tens of milliseconds).
const WARM_S: f64 = 0.25;

/// GPU seconds one timed submission of casts keeps the GPU busy for
/// ([`GpuCastParams::repeat`] casts back to back). Fed one cast of a
/// millisecond or so at a time with a readback between, an H200's SM clock
/// read its idle 345 MHz (boost 1980) through every voxel measurement of
/// the twenty-fourth session (nvidia-smi every 100 ms: 3-10% busy).
const SUSTAIN_S: f64 = 0.05;

/// Most casts in one submission.
const MAX_REPEAT: u32 = 256;

/// Casts of `secs` each (one cast timed alone) that fill a submission of
/// [`SUSTAIN_S`]: at least 1, at most [`MAX_REPEAT`].
fn sustained(secs: f64) -> u32 {
    let n = (SUSTAIN_S / secs).ceil();
    if n >= MAX_REPEAT as f64 {
        MAX_REPEAT
    } else if n >= 1.0 {
        n as u32
    } else {
        1
    }
}

/// A cast's seconds: the kernels' clock where there is one, else submit to
/// readback (per cast of its submission).
fn per_cast(c: &GpuCast) -> f64 {
    c.kernel_s.unwrap_or(c.gpu_s)
}

/// The casts a timed submission of `cast(n)` (n casts back to back) holds
/// to keep the GPU busy for [`SUSTAIN_S`]: sized from one cast, warmed at
/// that size ([`warm_up`]), sized again (a cold GPU's casts may run at its
/// idle clock, so fewer of the warm ones would fill the span).
fn warm_repeat(mut cast: impl FnMut(u32) -> Result<GpuCast>) -> Result<u32> {
    let reps = sustained(per_cast(&cast(1)?));
    warm_up(|| cast(reps).map(drop))?;
    Ok(sustained(per_cast(&cast(reps)?)))
}

/// Runs `cast` at least once and until [`WARM_S`] have passed.
fn warm_up(mut cast: impl FnMut() -> Result<()>) -> Result<()> {
    let t = std::time::Instant::now();
    loop {
        cast()?;
        if t.elapsed().as_secs_f64() >= WARM_S {
            return Ok(());
        }
    }
}

/// Octree against DAG casts of the same rays in `repeats` alternating
/// rounds (both see the same machine load): `<name>_octree_mrays_per_cpu_s`,
/// `<name>_dag_mrays_per_cpu_s`, `<name>_dag_over_octree`, counter
/// `<name>_differing_rays`.
pub fn octree_vs_dag<F: CastReal>(
    tree: &Octree,
    g: &Dag,
    sc: &VoxelScene,
    sets: &Sets<F>,
    repeats: u32,
    out: &mut Outputs,
) {
    for (name, b) in sets.named() {
        let p = b.params(sc.lod, sc.max_iter);
        let (mut a, mut c) = (VoxelHits::default(), VoxelHits::default());
        let (mut ca, mut cb) = (0.0, 0.0);
        for _ in 0..repeats {
            let (h, _, t) = timed(|| cast_all::<F>(tree, &b.o, &b.d, &p));
            (a, ca) = (h, ca + t);
            let (h, _, t) = timed(|| cast_all_dag::<F>(g, &b.o, &b.d, &p));
            (c, cb) = (h, cb + t);
        }
        let n = b.o.len() as f64 * repeats as f64;
        out.metric(&format!("{name}_octree_mrays_per_cpu_s"), per_cpu_s(n, ca));
        out.metric(&format!("{name}_dag_mrays_per_cpu_s"), per_cpu_s(n, cb));
        out.metric(
            &format!("{name}_dag_over_octree"),
            if cb > 0.0 { ca / cb } else { 0.0 },
        );
        out.counter(&format!("{name}_differing_rays"), differing(&a, &c));
    }
}

/// Interleaved rounds of the CPU paths in [`cpu_vs_gpu`].
pub const ROUNDS: u32 = 3;

/// Per structure (`octree`, `dag`, ...): every CPU cast path
/// ([`CastPath::ALL`]) and the GPU cast of the same rays in one run, coherent
/// (the camera `coh`; the GPU generates its own camera rays) and incoherent
/// (`inc`). The CPU paths run in [`ROUNDS`] interleaved rounds (all see the
/// same machine load). Metrics `{structure}_{path}_{set}_mrays_per_cpu_s`
/// and `..._mrays_per_s` (wall), `{structure}_{set}_{path}_speedup` (over
/// per-ray, per CPU-second, same run),
/// `{structure}_{set}_{path}_differing_rays` (hit, t, leaf or normal bits
/// against per-ray), `{structure}_gpu_{set}_mrays_per_s`,
/// the coherent GPU figures in [`ThreadOrder::Tiles`] with the
/// [`CameraCasts`] metrics beside them ([`camera_casts`]),
/// `{structure}_{set}_mean_iters` (per-ray; the GPU's are the same),
/// `{structure}_{set}_{path}_mean_iters` (fewer on the beam path),
/// `{structure}_{set}_node_bytes_per_ray` (4 x node words the kernel read;
/// the per-ray CPU cast reads the same words).
pub fn cpu_vs_gpu(
    structures: &[(&str, Through)],
    gpu: &GpuContext,
    sc: &VoxelScene,
    sets: &Sets<f32>,
    budget: &MemBudget,
    out: &mut Outputs,
) -> Result<()> {
    let (cam, gen, coh, inc) = (&sets.cam, &sets.gen, &sets.coh, &sets.inc);
    let params = |b: &Batch<f32>| b.params(sc.lod, sc.max_iter);
    let (p_coh, p_inc) = (params(coh), params(inc));
    let packed: Vec<[f32; 6]> = (inc.o.iter().zip(&inc.d))
        .map(|(o, d)| [o[0], o[1], o[2], d[0], d[1], d[2]])
        .collect();
    for (sname, through) in structures {
        let g = through.upload(gpu)?;
        for (set, b, p) in [("coherent", coh, p_coh), ("incoherent", inc, p_inc)] {
            let n = b.o.len() as f64 * ROUNDS as f64;
            let mut acc = [(0.0, 0.0); CastPath::ALL.len()];
            let mut res: Vec<VoxelHits<f32>> = vec![VoxelHits::default(); acc.len()];
            for _ in 0..ROUNDS {
                for (k, path) in CastPath::ALL.into_iter().enumerate() {
                    let (h, wall, cpu) = timed(|| through.cast_by(path, &b.shape, &b.o, &b.d, &p));
                    res[k] = h?;
                    acc[k] = (acc[k].0 + wall, acc[k].1 + cpu);
                }
            }
            let base = per_cpu_s(n, acc[0].1);
            for (k, path) in CastPath::ALL.into_iter().enumerate() {
                let (pname, rate) = (path.name(), per_cpu_s(n, acc[k].1));
                out.metric(&format!("{sname}_{pname}_{set}_mrays_per_cpu_s"), rate);
                out.metric(
                    &format!("{sname}_{pname}_{set}_mrays_per_s"),
                    n / acc[k].0.max(1e-12) / 1e6,
                );
                if k > 0 {
                    out.metric(
                        &format!("{sname}_{set}_{pname}_speedup"),
                        rate / base.max(1e-12),
                    );
                    out.metric(
                        &format!("{sname}_{set}_{pname}_differing_rays"),
                        differing(&res[0], &res[k]) as f64,
                    );
                    out.metric(
                        &format!("{sname}_{set}_{pname}_mean_iters"),
                        mean(res[k].iters.iter().map(|&i| i as f64)),
                    );
                }
            }
            out.metric(
                &format!("{sname}_{set}_mean_iters"),
                mean(res[0].iters.iter().map(|&i| i as f64)),
            );
            // `gc`: the cast whose node words are reported (from `near`, as
            // the per-ray CPU cast reads them).
            let (gpu_s, kernel_s, gc) = if set == "coherent" {
                let (cc, tiles) = camera_casts(&g, (cam, gen), &gpu_params(&p), budget)?;
                cc.report(sname, out);
                let kernel_s = cc.kernel_clock.then_some(cc.sustained_s[1]);
                (cc.gpu_s[1], kernel_s, tiles)
            } else {
                // Timed over sustained submissions ([`warm_repeat`]);
                // submit to readback from one cast alone.
                let once = gpu_params(&p);
                let cast = |repeat| g.cast_rays(&packed, &GpuCastParams { repeat, ..once }, budget);
                let reps = warm_repeat(cast)?;
                let single = cast(1)?;
                let gc = cast(reps)?;
                (single.gpu_s, gc.kernel_s, gc)
            };
            let m = gc.hits.len() as f64;
            out.metric(
                &format!("{sname}_gpu_{set}_mrays_per_s"),
                m / gpu_s.max(1e-12) / 1e6,
            );
            if let Some(k) = kernel_s {
                out.metric(
                    &format!("{sname}_gpu_{set}_kernel_mrays_per_s"),
                    m / k.max(1e-12) / 1e6,
                );
            }
            out.metric(
                &format!("{sname}_{set}_node_bytes_per_ray"),
                4.0 * mean(gc.hits.iter().map(|h| h.loads() as f64)),
            );
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn differing_totals_add_every_differing_figure_and_count_them() {
        let mut out = Outputs::default();
        out.metric("octree_coherent_lanes_differing_rays", 0.0);
        out.metric("dag_incoherent_beam_differing_rays", 3.0);
        out.metric("octree_coherent_lanes_speedup", 7.0);
        out.counter("dag_bfs_coherent_differing_rays", 2);
        out.counter("rays", 9);
        assert_eq!(differing_totals(&out), (5.0, 3));
        assert_eq!(differing_totals(&Outputs::default()), (0.0, 0));
    }

    #[test]
    fn sustained_submissions_fill_the_gpu_for_their_span() {
        assert_eq!(sustained(1e-3), 50);
        assert_eq!(sustained(0.02), 3);
        assert_eq!(sustained(0.2), 1);
        assert_eq!(sustained(1e-7), MAX_REPEAT);
        assert_eq!(sustained(0.0), MAX_REPEAT);
        assert_eq!(sustained(f64::NAN), 1);
    }
}
