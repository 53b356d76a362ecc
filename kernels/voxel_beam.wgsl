// voxel_beam.wgsl: the beam pre-pass of the GPU camera cast (Laine & Karras
// 2010, "beam optimization", made conservative), one workgroup of 64 per
// 8x8 pixel tile of the region, in f64 (the adapter's SHADER_F64; the host runs
// the cast from `near` without it). Extends voxels.wgsl (its parameters,
// nodes and `BeamTile`); entry `cast_camera` there reads the result.
// CPU twin: src/voxels/beam.rs `beam_nears` (one tile: `band_cones`'
// `ConeAcc` over the tile's rays, `start_distance_scalar`, `tile_near`), the
// same operations in the same order on the same f32 rays; a GPU's f64
// division and square root may round differently (the starts agree to
// about 1e-15 relative, far inside `MARGIN`).
// Parity cases: TESTS/voxels/manifest_gpu.yaml `voxel_gpu_*` (every camera
// cast there starts from these tiles: identical leaf to the CPU's cast from
// its own beam starts, contours to the CPU's from `near`), and
// src/gpu/voxels.rs `beam_tiles` against `beam_nears` (unit test
// src/voxels/gpu.rs `gpu_beam_tiles_match_the_cpu_beam`).
//
// Why the start is safe: see src/voxels/beam.rs (the start never passes a
// hit, and the cast from it makes the same decisions as from `near`). Two
// things the CPU argument does not cover hold here too: with contours a
// leaf's solid slab lies inside its box, so the nearest box still bounds
// the hit; and this module's `camera_ray` may round a ray differently from
// voxels.wgsl's if the driver fuses multiply-adds differently, a change of
// an f32 ulp or so that the cone's `slack` (twice the cast's rounding
// bound, about 1e-6 of the distance or more) and `MARGIN` absorb. Where
// the CPU checks that a ray's |d|^2 is finite and the axis's length too,
// this kernel does not: f32 camera rays cannot overflow in f64.
// WGSL's f64 has no trigonometric functions: the cone's half-angle is kept
// as its cosine and sine (src/voxels/beam.rs `ConeAcc::finish` does the
// same), and no infinity: `NO_BOX` stands for it.

const MARGIN: f64 = 1e-5lf;
const COS_MAX_HALF_ANGLE: f64 = 0.8775825618903728lf;
const WIDEN: f64 = 1e-9lf;
const SQRT3: f64 = 1.7320508075688772lf;
const NO_BOX: f64 = 1e300lf;
// Stack entries: one pop pushes at most 8, so at most 1 + 7 * 22.
const BEAM_STACK: u32 = 155u;

@group(0) @binding(9) var<storage, read_write> beam_out: array<BeamTile>;

// One tile's workgroup (`beam_nears`): lane i's ray terms for the cone
// (`flag` 0: no ray), the cone, whether the tile
// walks, the best distance found so far (`tile_bound`) and each lane's.
var<workgroup> lane_terms: array<RayTerms, 64>;
var<workgroup> tile_cone: Cone;
var<workgroup> tile_walks: u32;
var<workgroup> bound_bits: atomic<u32>;
var<workgroup> lane_best: array<f64, 64>;

struct Cone {
    o: vec3<f64>,
    axis: vec3<f64>,
    cos2_half: f64,
    sin_half: f64,
    tan_half: f64,
    slack: f64,
    time_error: f64,
    len_max: f64,
}

fn dot64(a: vec3<f64>, b: vec3<f64>) -> f64 {
    return a.x * b.x + a.y * b.y + a.z * b.z;
}

fn less64(a: f64, b: f64) -> f64 {
    return select(b, a, a < b);
}

// CPU twin: src/voxels/beam.rs `plane_time_error::<f32>`.
fn plane_time_error(o: vec3<f32>, d: vec3<f64>) -> f64 {
    let eps = f64(exp2i(-23));
    var e = 0.0lf;
    for (var a = 0u; a < 3u; a++) {
        let dir = max(0.5lf * abs(d[a]), eps);
        e = max(e, 4.0lf * eps / dir * (abs(0.5lf * f64(o[a]) + 1.5lf) + 5.0lf));
    }
    return e;
}

// CPU twin: src/voxels/beam.rs `Cone::meets_sphere`.
fn meets_sphere(k: Cone, v: vec3<f64>, r0: f64) -> bool {
    let r = r0 + k.slack;
    let l2 = dot64(v, v);
    if (l2 <= r * r) {
        return true;
    }
    let lhs = dot64(v, k.axis) + k.sin_half * r + 1e-9lf * (1.0lf + l2);
    return lhs >= 0.0lf && lhs * lhs >= k.cos2_half * (l2 - r * r);
}

// CPU twin: src/voxels/beam.rs `box_distance2`.
fn box_distance2(o: vec3<f64>, lo: vec3<f64>, hi: vec3<f64>) -> f64 {
    let g = max(max(lo - o, o - hi), vec3<f64>(0.0lf));
    return dot64(g, g);
}

// The slot of child c (CPU twin: src/voxels/cast.rs `Addressing::child`).
fn child_slot(slot: u32, desc: u32, c: u32) -> u32 {
    if (ADDRESSING == 1u) {
        return nodes[2u * slot + 1u] + c;
    }
    var ofs = desc >> 17u;
    if ((desc & 0x10000u) != 0u) {
        ofs = nodes[2u * (slot + ofs)];
    }
    return slot + ofs + countOneBits((desc << (7u - c)) & 0x7Fu);
}

// An upper bound of `x` >= 0 as f32 bits (for `tile_bound`).
fn f32_bits_above(x: f64) -> u32 {
    let f = f32(x);
    return bitcast<u32>(f) + select(0u, 1u, f64(f) < x);
}

// The best distance any lane of the tile has found so far, rounded up to an
// f32: a box at least this far cannot lower the tile's start, so every lane
// prunes by it (pruning never changes the start: see `start_distance`).
fn tile_bound() -> f64 {
    return f64(bitcast<f32>(atomicLoad(&bound_bits)));
}

// The squared distance from the cone's origin to the nearest non-empty node
// box that meets the cone, below the node `slot` (corner and level `kl`,
// at squared distance `d2`), `NO_BOX` for none; with `pooled`, offers each
// better distance to the tile's lanes and prunes by theirs (`bound_bits`).
// CPU twin: src/voxels/beam.rs `start_distance_scalar` (from the root).
// The start is the least distance over the boxes the walk stops at (leaves,
// boxes at the depth, boxes under the cone's width), a set that does not
// depend on the order of the walk, and pruning drops only boxes no nearer
// than a box already found; so a tile's lanes, each walking its share of
// the tree (`lane_start_distance`) and pruning by each other's finds, agree
// with the CPU's one walk bit for bit.
fn start_distance(k: Cone, d2_0: f64, slot0: u32, kl0: vec4<u32>, pooled: bool) -> f64 {
    let tan2 = k.tan_half * k.tan_half;
    var best = NO_BOX;
    // An entry: squared distance, slot, and the node's low corner as whole
    // multiples of its edge 2^(1 - level) (xyz) with the level (w): the
    // CPU's f64 corner exactly (dyadic), in 28 bytes instead of 48.
    var st_d2: array<f64, BEAM_STACK>;
    var st_slot: array<u32, BEAM_STACK>;
    var st_kl: array<vec4<u32>, BEAM_STACK>;
    st_d2[0] = d2_0;
    st_slot[0] = slot0;
    st_kl[0] = kl0;
    var sp = 1u;
    while (sp > 0u) {
        sp -= 1u;
        let dist2 = st_d2[sp];
        let slot = st_slot[sp];
        let kl = st_kl[sp];
        let level = kl.w;
        var bound = best;
        if (pooled) {
            bound = less64(best, tile_bound());
        }
        if (dist2 >= bound) {
            continue;
        }
        let desc = nodes[2u * slot];
        let nonleaf = desc & 0xFFu;
        let valid = (desc >> 8u) & 0xFFu;
        // The children's edge, 2 / 2^(level + 1), exact in f32 and f64.
        let size = f64(exp2i(-i32(level)));
        let lo = vec3<f64>(kl.xyz) * (2.0lf * size) - 1.0lf;
        let radius = 0.5lf * SQRT3 * size;
        let last = nonleaf == 0u || level + 1u >= V.depth;
        let base = sp;
        for (var c = 0u; c < 8u; c++) {
            if (((valid >> c) & 1u) == 0u) {
                continue;
            }
            let cb = vec3<u32>(c, c >> 1u, c >> 2u) & vec3<u32>(1u);
            let wlo = lo + vec3<f64>(cb) * size;
            let whi = wlo + size;
            let d2 = box_distance2(k.o, wlo, whi);
            if (d2 >= less64(best, bound)) {
                continue;
            }
            let v = wlo + 0.5lf * size - k.o;
            if (!meets_sphere(k, v, radius)) {
                continue;
            }
            let fine = size * size <= 4.0lf * d2 * tan2;
            if (last || ((nonleaf >> c) & 1u) == 0u || fine) {
                best = d2;
                if (pooled) {
                    atomicMin(&bound_bits, f32_bits_above(d2));
                }
            } else if (sp < BEAM_STACK) {
                // Pushed among the entries above base, nearest on top
                // (CPU twin: `push_nearest_last`).
                var i = sp;
                while (i > base && st_d2[i - 1u] < d2) {
                    st_d2[i] = st_d2[i - 1u];
                    st_slot[i] = st_slot[i - 1u];
                    st_kl[i] = st_kl[i - 1u];
                    i -= 1u;
                }
                st_d2[i] = d2;
                st_slot[i] = child_slot(slot, desc, c);
                st_kl[i] = vec4<u32>(2u * kl.xyz + cb, level + 1u);
                sp += 1u;
            } else {
                // No room (not reached with depth <= 22): stop here, nearer.
                best = d2;
                if (pooled) {
                    atomicMin(&bound_bits, f32_bits_above(d2));
                }
            }
        }
    }
    return best;
}

// Lane `lane`'s share of the tile's walk: the subtree of the root's child
// lane / 8's child lane % 8, by the same tests as `start_distance`. Where
// the root's child is itself a box the walk stops at, lane % 8 = 0 answers
// it and its other lanes nothing; `NO_BOX` for none.
fn lane_start_distance(k: Cone, lane: u32) -> f64 {
    let tan2 = k.tan_half * k.tan_half;
    var slot = 0u;
    var kl = vec4<u32>(0u);
    var d2 = 0.0lf;
    for (var step = 0u; step < 2u; step++) {
        let c = select(lane & 7u, lane >> 3u, step == 0u);
        let desc = nodes[2u * slot];
        if (((desc >> (8u + c)) & 1u) == 0u) {
            return NO_BOX;
        }
        let nonleaf = desc & 0xFFu;
        let level = kl.w;
        let size = f64(exp2i(-i32(level)));
        let lo = vec3<f64>(kl.xyz) * (2.0lf * size) - 1.0lf;
        let cb = vec3<u32>(c, c >> 1u, c >> 2u) & vec3<u32>(1u);
        let wlo = lo + vec3<f64>(cb) * size;
        d2 = box_distance2(k.o, wlo, wlo + size);
        if (!meets_sphere(k, wlo + 0.5lf * size - k.o, 0.5lf * SQRT3 * size)) {
            return NO_BOX;
        }
        let last = nonleaf == 0u || level + 1u >= V.depth;
        let fine = size * size <= 4.0lf * d2 * tan2;
        if (last || ((nonleaf >> c) & 1u) == 0u || fine) {
            return select(NO_BOX, d2, step == 1u || (lane & 7u) == 0u);
        }
        slot = child_slot(slot, desc, c);
        kl = vec4<u32>(2u * kl.xyz + cb, level + 1u);
    }
    return start_distance(k, d2, slot, kl, true);
}

// One ray's terms of the tile's cone (ConeAcc::add): cos^2 of its angle to
// the axis, |d| per axis, |d|^2, and `flag` 1 (it fits a cone) or 2 (it
// spoils it: another origin, a direction at or past 90 degrees, zero).
struct RayTerms {
    c2: f64,
    dabs: vec3<f64>,
    l2: f64,
    flag: u32,
}

fn ray_terms(r: Ray, o: vec3<f32>, axis: vec3<f64>) -> RayTerms {
    let d = vec3<f64>(r.d);
    let c = dot64(d, axis);
    let l2 = dot64(d, d);
    let ok = all(r.o == o) && c > 0.0lf && l2 > 0.0lf;
    return RayTerms(c * c / l2, abs(d), l2, select(2u, 1u, ok));
}

// ConeAcc: the running fold of a tile's `RayTerms` in memory order.
struct ConeAcc {
    ok: bool,
    cos2_min: f64,
    dmin: vec3<f64>,
    len2_max: f64,
}

fn cone_acc() -> ConeAcc {
    return ConeAcc(true, 1.0lf, vec3<f64>(NO_BOX), 0.0lf);
}

fn cone_add(a: ConeAcc, t: RayTerms) -> ConeAcc {
    let dmin = vec3<f64>(less64(t.dabs.x, a.dmin.x), less64(t.dabs.y, a.dmin.y), less64(t.dabs.z, a.dmin.z));
    return ConeAcc(a.ok && t.flag == 1u, less64(t.c2, a.cos2_min), dmin, -less64(-t.l2, -a.len2_max));
}

// ConeAcc::finish: the cone about `axis` from `o` holding the tile's rays,
// and whether the tile walks (its rays fit a cone no wider than
// `COS_MAX_HALF_ANGLE`).
fn cone_finish(a: ConeAcc, o: vec3<f32>, axis: vec3<f64>) -> Cone {
    let c2 = clamp(a.cos2_min, 0.0lf, 1.0lf);
    let cc = sqrt(c2);
    let ss = sqrt(1.0lf - c2);
    let cos_half = cc - ss * WIDEN;
    let sin_half = ss + cc * WIDEN;
    var k: Cone;
    k.o = vec3<f64>(o);
    k.axis = axis;
    k.time_error = plane_time_error(o, a.dmin);
    k.len_max = sqrt(a.len2_max);
    k.slack = 2.0lf * k.time_error * k.len_max;
    k.cos2_half = cos_half * cos_half;
    k.sin_half = sin_half;
    k.tan_half = sin_half / cos_half;
    return k;
}

fn cone_walks(a: ConeAcc) -> bool {
    let c2 = clamp(a.cos2_min, 0.0lf, 1.0lf);
    let cos_half = sqrt(c2) - sqrt(1.0lf - c2) * WIDEN;
    return a.ok && a.len2_max != 0.0lf && cos_half >= COS_MAX_HALF_ANGLE;
}

// tile_near: the tile's entry from the walk's `best` (`walks` false: from `near`).
fn tile_out(walks: bool, k: Cone, best: f64) -> BeamTile {
    var out: BeamTile;
    out.near = V.near;
    out.meets = 1u;
    if (walks) {
        if (best >= NO_BOX) {
            out.meets = 0u;
        } else {
            let s = sqrt(best) / k.len_max * (1.0lf - MARGIN) - k.time_error;
            if (s > f64(V.near)) {
                out.near = f32(s);
            }
        }
    }
    return out;
}

// A tile's corners and axis: pixels [x0, x1) x [y0, y1) of the region, the
// first ray's origin, the unit sum of the first and last directions, and
// whether it has one (no LOD cut, a nonzero sum).
struct TileFrame {
    x0: u32,
    y0: u32,
    x1: u32,
    y1: u32,
    // The tile's width in the region's layout (`beam_tile_size`).
    sx: u32,
    o: vec3<f32>,
    axis: vec3<f64>,
    coned: bool,
}

fn tile_frame(t: u32) -> TileFrame {
    let w = C.roi_w;
    let h = V.n / w;
    let s = beam_tile_size(h);
    let tiles_x = beam_tiles_x(w, h);
    var f: TileFrame;
    f.x0 = (t % tiles_x) * s.x;
    f.y0 = (t / tiles_x) * s.y;
    f.x1 = min(f.x0 + s.x, w);
    f.y1 = min(f.y0 + s.y, h);
    f.sx = s.x;
    let first = camera_ray(C, f.y0 * w + f.x0);
    let last = camera_ray(C, (f.y1 - 1u) * w + f.x1 - 1u);
    // ConeAcc::new: the axis made unit.
    let ax = vec3<f64>(first.d) + vec3<f64>(last.d);
    let al = sqrt(dot64(ax, ax));
    f.o = first.o;
    f.axis = ax / al;
    f.coned = V.lod_on != 1u && al > 0.0lf;
    return f;
}

fn tile_count() -> u32 {
    let h = V.n / C.roi_w;
    return beam_tiles_x(C.roi_w, h) * ((h + beam_tile_size(h).y - 1u) / beam_tile_size(h).y);
}

// One tile's start (`beam_tile_size`: 8x8, or 64x1 in a region one row
// high), one workgroup a tile, lane i holding the tile's ray i (memory
// order): the tile's rays (the f32 camera rays `cast_camera` casts) bound by
// a cone about the sum of its first and last directions, the walk shared
// among the lanes (`lane_start_distance`), the pull-back. `meets` 0: no
// non-empty box meets the cone (every ray a miss); a tile without a cone
// (rays from differing origins, one too wide, an LOD cut) starts at
// `V.near`. For GPUs: one invocation walking a tile alone
// (`beam_nears_by_thread`) left an H200 one thread a tile, each waiting on
// its own memory, and the pre-pass 2.6-2.8x slower than the cast it was to
// shorten (docs/PERF.md).
// CPU twin: src/voxels/beam.rs `beam_nears` (one tile).
@compute @workgroup_size(64)
fn beam_nears(
    @builtin(workgroup_id) wid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lane: u32,
) {
    let t = wid.x + wid.y * nwg.x;
    if (t >= tile_count()) {
        return;
    }
    let f = tile_frame(t);
    let x = f.x0 + lane % f.sx;
    let y = f.y0 + lane / f.sx;
    var terms = RayTerms(0.0lf, vec3<f64>(0.0lf), 0.0lf, 0u);
    if (f.coned && x < f.x1 && y < f.y1) {
        terms = ray_terms(camera_ray(C, y * C.roi_w + x), f.o, f.axis);
    }
    lane_terms[lane] = terms;
    if (lane == 0u) {
        atomicStore(&bound_bits, 0x7F7FFFFFu);
    }
    workgroupBarrier();
    if (lane == 0u) {
        var a = cone_acc();
        for (var i = 0u; i < 64u; i++) {
            if (lane_terms[i].flag != 0u) {
                a = cone_add(a, lane_terms[i]);
            }
        }
        tile_cone = cone_finish(a, f.o, f.axis);
        tile_walks = select(0u, 1u, cone_walks(a));
    }
    let walks = workgroupUniformLoad(&tile_walks) == 1u;
    var best = NO_BOX;
    if (walks) {
        best = lane_start_distance(tile_cone, lane);
    }
    lane_best[lane] = best;
    workgroupBarrier();
    if (lane == 0u) {
        for (var i = 1u; i < 64u; i++) {
            best = less64(lane_best[i], best);
        }
        beam_out[t] = tile_out(walks, tile_cone, best);
    }
}

// The same tiles one invocation each, walking alone: the schedule of the
// CPU twin, for CPU adapters (lavapipe), whose SIMD lanes would run a
// workgroup's diverging walks one after another (Menger d10 512^2 on
// lavapipe: beam over plain 0.22-0.24 by workgroup, 0.93-0.95 by thread).
// CPU twin: src/voxels/beam.rs `beam_nears` (one tile).
@compute @workgroup_size(64)
fn beam_nears_by_thread(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let t = linear_id(gid, nwg, 64u);
    if (t >= tile_count()) {
        return;
    }
    let f = tile_frame(t);
    var a = cone_acc();
    if (f.coned) {
        for (var y = f.y0; y < f.y1; y++) {
            for (var x = f.x0; x < f.x1; x++) {
                a = cone_add(a, ray_terms(camera_ray(C, y * C.roi_w + x), f.o, f.axis));
            }
        }
    }
    let walks = f.coned && cone_walks(a);
    let k = cone_finish(a, f.o, f.axis);
    var best = NO_BOX;
    if (walks) {
        best = start_distance(k, 0.0lf, 0u, vec4<u32>(0u), false);
    }
    beam_out[t] = tile_out(walks, k, best);
}
