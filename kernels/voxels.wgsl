// voxels.wgsl: the Laine-Karras ESVO ray cast (seed 003) through the octree
// of src/voxels/octree.rs or the DAG of src/voxels/dag.rs, one invocation
// per ray, in f32.
// CPU twin: src/voxels/cast.rs `cast_with` (the f32 instance): with
// ADDRESSING = 0 `cast::<f32>` (octree, `Relative`), ADDRESSING = 1
// `cast_dag::<f32>` (DAG, `Absolute`), CONTOURS = 1 `cast_contours::<f32>`.
// The two override constants pick the policy per pipeline, as the CPU's
// generic `A: Addressing` does per instance: one loop, two addressing policies.
// Entry `cast_camera` also runs common.wgsl `camera_ray` (CPU twin
// src/rays.rs `f_ray`), from the beam starts of voxel_beam.wgsl where the
// host ran it; entry `cast_rays` reads given rays.
// Parity cases: TESTS/voxels/manifest_gpu.yaml `voxel_gpu_*_parity` (GPU vs
// CPU f32 on the same rays: identical leaf except referee-flagged near ties;
// `voxel_gpu_dag_*` for the DAG, `voxel_gpu_*_contour_*` for contours)
// and `voxel_gpu_*_deterministic` (two GPU runs, memcmp).
// Host side: src/gpu/voxels.rs (struct `VoxParams` = `VoxParams` here,
// `GpuVoxelHit` = `VoxHit`).
//
// The loop is `cast::<f32>` operation for operation: the same world ->
// [1, 2]^3 map, the same direction epsilon 2^-23 with its sign, the same
// reciprocal `-1 / |d|`, the same t = x * coef - bias recipe, comparisons in
// the same order. Per-axis loops of the CPU are vec3 operations here (the
// same per-component roundings) so that Mesa llvmpipe's loop-iteration cap
// counts only the main loop. POP takes `firstLeadingBit` of the 32-bit
// difference where the CPU takes `63 - leading_zeros` of it widened to 64
// bits: the same number. WGSL has no f64 and no 64-bit integers; nothing
// here needs them (the CPU's u64 bit patterns are f32 bits for f32).
// Differences from the CPU: the kernel's iteration cap is the scene's cap
// clamped by the host to the driver's loop cap (src/gpu/voxels.rs); a
// driver whose division is not correctly rounded (WGSL allows 2.5 ulp) can
// move a ray across a near tie; lavapipe divides exactly.
// Contours: the 32-bit code is unpacked here; its normal (18 bits), offset
// and thickness (7 bits each) index `contour_lut`, a table the host fills
// with src/voxels/contour.rs `decode::<f32>` of every code (f64 math
// rounded to f32: WGSL has no f64), so both sides use the same f32 values.

const S_MAX: i32 = 23;
// 0: octree (relative child addressing), 1: DAG (absolute: child c at childPtr + c).
override ADDRESSING: u32 = 0u;
// 1: cut finest-level leaves to their contour slab (octree only, as on the CPU).
override CONTOURS: u32 = 0u;
// contour_lut layout: normals (3 f32 per 18-bit code), then 128 offsets, then 128 thicknesses.
const LUT_P: u32 = 786432u;
const LUT_H: u32 = 786560u;

struct VoxParams {
    near: f32,
    far: f32,
    // LOD footprint in octree units (world / 2), used when lod_on = 1.
    lod_orig: f32,
    lod_dir: f32,
    lod_on: u32,
    depth: u32,
    max_iter: u32,
    n: u32,
    // cast_camera: 1 = write the generated rays to out_rays.
    write_rays: u32,
    // cast_camera: which ray a thread casts (common.wgsl `thread_ray`).
    order: u32,
    // cast_camera: 1 = each ray starts at its 8x8 tile's `beam` entry.
    beam: u32,
    _pad2: u32,
}

// One 8x8 pixel tile's beam start (voxel_beam.wgsl `beam_nears`): meets 0
// when no non-empty node box meets the tile's cone (every ray a miss, not
// cast), else every ray of the tile is cast from `near`.
struct BeamTile {
    near: f32,
    meets: u32,
}

const BEAM_TILE: u32 = 8u;

// A beam tile's width and height in a region h rows high: 8x8 pixels, runs
// of 64 in a region one row high. CPU twin: src/voxels/tiles.rs `Tiling::new`.
fn beam_tile_size(h: u32) -> vec2<u32> {
    return select(vec2<u32>(BEAM_TILE), vec2<u32>(BEAM_TILE * BEAM_TILE, 1u), h == 1u);
}

// The beam tiles across a region w pixels wide.
fn beam_tiles_x(w: u32, h: u32) -> u32 {
    let s = beam_tile_size(h);
    return (w + s.x - 1u) / s.x;
}

// One ray's result (32 bytes). flags: bit 0 hit, bit 1 capped, bit 2 solid
// leaf (0: LOD cut at an inner node), bits 8..16 level, bits 16..32 node
// words read (descriptors, far pointers, the attribute base; saturating at
// 65535), for the bytes-per-ray figure. normal: byte a holds normal[a] + 1.
struct VoxHit {
    t: f32,
    vx: u32,
    vy: u32,
    vz: u32,
    iters: u32,
    flags: u32,
    normal: u32,
    attr: u32,
}

@group(0) @binding(0) var<uniform> C: CamParams;
@group(0) @binding(1) var<uniform> V: VoxParams;
@group(0) @binding(2) var<storage, read> nodes: array<u32>;
@group(0) @binding(3) var<storage, read> in_rays: array<f32>;
@group(0) @binding(4) var<storage, read_write> out_hits: array<VoxHit>;
@group(0) @binding(5) var<storage, read_write> out_rays: array<f32>;
// Contour per attribute index (0: none) and the decode table; CONTOURS = 1 only.
@group(0) @binding(6) var<storage, read> contours: array<u32>;
@group(0) @binding(7) var<storage, read> contour_lut: array<f32>;
// The beam starts of cast_camera's tiles (V.beam = 1 only).
@group(0) @binding(8) var<storage, read> beam: array<BeamTile>;

fn exp2i(k: i32) -> f32 {
    return bitcast<f32>(u32(k + 127) << 23u);
}

fn min3(a: vec3<f32>) -> f32 {
    return min(min(a.x, a.y), a.z);
}

fn max3(a: vec3<f32>) -> f32 {
    return max(max(a.x, a.y), a.z);
}

// 2^-19 (16 f32 epsilons) of a face's product term: how far the recomputed
// entry time may fall below the loop's t_min and still name the entered face
// (a driver may fuse the multiply-adds differently at the two sites).
// CPU twin: src/voxels/cast.rs `entry_slack`.
fn entry_slack(product: f32) -> f32 {
    return 1.9073486328125e-6 * abs(product);
}

fn bits3(m: vec3<bool>) -> u32 {
    return select(0u, 1u, m.x) | select(0u, 2u, m.y) | select(0u, 4u, m.z);
}

fn fmin(a: f32, b: f32) -> f32 {
    return select(b, a, a < b);
}

fn fmax(a: f32, b: f32) -> f32 {
    return select(b, a, a > b);
}

// The t interval in which o + t d is inside the slab of contour v of the
// voxel with centre c and edge s, (t0, t1), empty when t0 > t1.
// CPU twin: src/voxels/contour.rs `slab_interval` (infinities are the
// largest finite f32 here: the caller clamps them to the voxel's interval).
fn slab_interval(v: u32, c: vec3<f32>, s: f32, o: vec3<f32>, d: vec3<f32>) -> vec2<f32> {
    let k = 3u * (v >> 14u);
    let n = vec3<f32>(contour_lut[k], contour_lut[k + 1u], contour_lut[k + 2u]);
    let p = contour_lut[LUT_P + ((v >> 7u) & 0x7Fu)];
    let h = contour_lut[LUT_H + (v & 0x7Fu)];
    let s0 = n.x * (o.x - c.x) + n.y * (o.y - c.y) + n.z * (o.z - c.z) - p * s;
    let nd = n.x * d.x + n.y * d.y + n.z * d.z;
    let th = h * s;
    let big = 3.4028235e38;
    if (nd == 0.0) {
        if (abs(s0) <= th) {
            return vec2<f32>(-big, big);
        }
        return vec2<f32>(big, -big);
    }
    let a = (-th - s0) / nd;
    let b = (th - s0) / nd;
    if (a < b) {
        return vec2<f32>(a, b);
    }
    return vec2<f32>(b, a);
}

fn miss(iters: u32, loads: u32, capped: bool) -> VoxHit {
    var h: VoxHit;
    h.t = -1.0;
    h.iters = iters;
    h.flags = select(0u, 2u, capped) | (min(loads, 0xFFFFu) << 16u);
    h.normal = 0x010101u;
    h.attr = 0xFFFFFFFFu;
    return h;
}

// The cast of ray o + t d, t in [near, V.far]. CPU twin: src/voxels/cast.rs `cast`.
fn esvo_cast(o: vec3<f32>, d: vec3<f32>, near: f32) -> VoxHit {
    let eps = exp2i(-23);
    var dir = d * 0.5;
    let orig = o * 0.5 + 1.5;
    let dneg = (bitcast<vec3<u32>>(dir) & vec3<u32>(0x80000000u)) != vec3<u32>(0u);
    dir = select(dir, select(vec3<f32>(eps), vec3<f32>(-eps), dneg), abs(dir) < vec3<f32>(eps));
    let coef = -1.0 / abs(dir);
    let pos_dir = dir > vec3<f32>(0.0);
    let b0 = coef * orig;
    let bias = select(b0, 3.0 * coef - b0, pos_dir);
    let octant = 7u ^ bits3(pos_dir);
    let oct_set = (vec3<u32>(octant) & vec3<u32>(1u, 2u, 4u)) != vec3<u32>(0u);
    var t_min = max3(2.0 * coef - bias);
    var t_max = min3(coef - bias);
    var h = t_max;
    t_min = max(t_min, near);
    t_max = min(t_max, V.far);
    if (t_min > t_max) {
        return miss(0u, 0u, false);
    }
    var stack_node: array<u32, 24>;
    var stack_tmax: array<f32, 24>;
    var parent = 0u;
    var desc = 0u;
    var pos = vec3<f32>(1.0);
    var scale = S_MAX - 1;
    var scale_exp2 = 0.5;
    let m0 = 1.5 * coef - bias > vec3<f32>(t_min);
    var idx = bits3(m0);
    pos = select(pos, vec3<f32>(1.5), m0);
    var iters = 0u;
    var loads = 0u;
    // 0: no voxel (miss), 1: solid leaf, 2: LOD cut at an inner node.
    var stop = 0u;
    // The contour slab's t at the stopping leaf, when it has one.
    var has_contour = false;
    var t_contour = 0.0;
    loop {
        if (scale >= S_MAX) {
            break;
        }
        iters += 1u;
        if (iters > V.max_iter) {
            return miss(iters - 1u, loads, true);
        }
        if (desc == 0u) {
            desc = nodes[2u * parent];
            loads += 1u;
        }
        let tc = pos * coef - bias;
        let tc_max = min3(tc);
        let child_shift = idx ^ octant;
        let child_masks = desc << child_shift;
        if ((child_masks & 0x8000u) != 0u && t_min <= t_max) {
            if (V.lod_on == 1u && tc_max * V.lod_dir + V.lod_orig >= scale_exp2) {
                stop = select(2u, 1u, (child_masks & 0x80u) == 0u);
                break;
            }
            // INTERSECT
            let tv_max = min(t_max, tc_max);
            let halfs = scale_exp2 * 0.5;
            let tcen = halfs * coef + tc;
            if (t_min <= tv_max && (child_masks & 0x80u) == 0u) {
                // A leaf: the hit, unless its contour's slab misses the ray.
                var empty = false;
                if (CONTOURS == 1u && S_MAX - scale == i32(V.depth)) {
                    let c = child_shift ^ 7u;
                    let leafmask = (desc >> 8u) & ~desc & 0xFFu;
                    let at = nodes[2u * parent + 1u] + countOneBits(leafmask & ((1u << c) - 1u));
                    loads += 1u;
                    var v = 0u;
                    if (at < arrayLength(&contours)) {
                        v = contours[at];
                    }
                    if (v != 0u) {
                        let lo = select(3.0 - scale_exp2 - pos, pos, oct_set);
                        let cen = 2.0 * lo + scale_exp2 - 3.0;
                        let ab = slab_interval(v, cen, 2.0 * scale_exp2, o, d);
                        let ta = fmax(t_min, ab.x);
                        empty = ta > fmin(tv_max, ab.y);
                        has_contour = !empty;
                        t_contour = ta;
                    }
                }
                if (!empty) {
                    stop = 1u;
                    break;
                }
            } else if (t_min <= tv_max) {
                // PUSH
                if (tc_max < h) {
                    stack_node[scale] = parent;
                    stack_tmax[scale] = t_max;
                }
                h = tc_max;
                if (ADDRESSING == 1u) {
                    parent = nodes[2u * parent + 1u] + (child_shift ^ 7u);
                    loads += 1u;
                } else {
                    var ofs = desc >> 17u;
                    if ((desc & 0x10000u) != 0u) {
                        ofs = nodes[2u * (parent + ofs)];
                        loads += 1u;
                    }
                    ofs += countOneBits(child_masks & 0x7Fu);
                    parent += ofs;
                }
                scale -= 1;
                scale_exp2 = halfs;
                let m = tcen > vec3<f32>(t_min);
                idx = bits3(m);
                pos = select(pos, pos + scale_exp2, m);
                t_max = tv_max;
                desc = 0u;
                continue;
            }
        }
        // ADVANCE
        let ms = tc <= vec3<f32>(tc_max);
        let step = bits3(ms);
        pos = select(pos, pos - scale_exp2, ms);
        t_min = tc_max;
        idx ^= step;
        if ((idx & step) != 0u) {
            // POP: the highest bit in which the positions before and after differ.
            let flip = bitcast<vec3<u32>>(pos) ^ bitcast<vec3<u32>>(pos + scale_exp2);
            let dv = select(vec3<u32>(0u), flip, ms);
            let diff = dv.x | dv.y | dv.z;
            scale = i32(firstLeadingBit(diff));
            if (scale >= S_MAX) {
                break;
            }
            scale_exp2 = exp2i(scale - S_MAX);
            parent = stack_node[scale];
            t_max = stack_tmax[scale];
            let sh = bitcast<vec3<u32>>(pos) >> vec3<u32>(u32(scale));
            pos = bitcast<vec3<f32>>(sh << vec3<u32>(u32(scale)));
            let odd = (sh & vec3<u32>(1u)) != vec3<u32>(0u);
            idx = bits3(odd);
            h = 0.0;
            desc = 0u;
        }
    }
    if (stop == 0u) {
        return miss(iters, loads, false);
    }

    // Entry times of the voxel's faces (its mirrored high corner).
    let tent = (pos + scale_exp2) * coef - bias;
    let te = max3(tent);
    var ea = 0;
    if (tent.x == te) {
        ea = 0;
    } else if (tent.y == te) {
        ea = 1;
    } else if (tent.z == te) {
        ea = 2;
    }
    var entered = -1;
    if (te >= t_min - entry_slack((pos[ea] + scale_exp2) * coef[ea])) {
        entered = ea;
    }
    let level = u32(S_MAX - scale);
    var attr = 0xFFFFFFFFu;
    if (stop == 1u && ADDRESSING == 0u) {
        let c = (idx ^ octant) ^ 7u;
        let leafmask = (desc >> 8u) & ~desc & 0xFFu;
        attr = nodes[2u * parent + 1u] + countOneBits(leafmask & ((1u << c) - 1u));
        loads += 1u;
    }
    var shift_fine = 0u;
    if (V.depth > level) {
        shift_fine = V.depth - level;
    }
    let grid = exp2i(i32(V.depth) - 1);
    // Undo the mirroring to get the voxel's low corner in [1, 2).
    let lo_oct = select(3.0 - scale_exp2 - pos, pos, oct_set);
    var t = t_min;
    if (entered >= 0 && d[entered] != 0.0) {
        let a = entered;
        var face = lo_oct[a] + scale_exp2;
        if (dir[a] > 0.0) {
            face = lo_oct[a];
        }
        let x = 2.0 * face - 3.0;
        t = max((x - o[a]) / d[a], near);
    }
    if (has_contour) {
        t = t_contour;
    }
    let hitp = o + t * d;
    let box_idx = vec3<u32>((lo_oct - 1.0) * exp2i(i32(level)));
    let lo = box_idx << vec3<u32>(shift_fine);
    let hi = lo + vec3<u32>((1u << shift_fine) - 1u);
    let g = vec3<i32>(floor((hitp + 1.0) * grid));
    var vox = vec3<u32>(clamp(g, vec3<i32>(lo), vec3<i32>(hi)));
    var normal = vec3<i32>(0);
    if (entered >= 0) {
        let a = entered;
        if (dir[a] > 0.0) {
            vox[a] = lo[a];
            normal[a] = -1;
        } else {
            vox[a] = hi[a];
            normal[a] = 1;
        }
    }
    var r: VoxHit;
    r.t = t;
    r.vx = vox.x;
    r.vy = vox.y;
    r.vz = vox.z;
    r.iters = iters;
    r.flags = 1u | select(0u, 4u, stop == 1u) | (level << 8u) | (min(loads, 0xFFFFu) << 16u);
    let nb = vec3<u32>(normal + 1);
    r.normal = nb.x | (nb.y << 8u) | (nb.z << 16u);
    r.attr = attr;
    return r;
}

// Camera rays generated here (common.wgsl `camera_ray`, region order), then cast;
// thread t casts ray `thread_ray(V.order, t, ..)` and writes it at its region index.
// With V.beam = 1 a ray starts at its tile's beam start (voxel_beam.wgsl),
// and the rays of a tile that meets nothing are misses without a cast.
// CPU twin: src/voxels/cast.rs `cast` on src/rays.rs `f_ray::<f32>` rays
// (with the beam: src/voxels/beam.rs `cast_all_beam`).
@compute @workgroup_size(64)
fn cast_camera(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = thread_ray(V.order, linear_id(gid, nwg, 64u), C.roi_w, V.n);
    if (i >= V.n) {
        return;
    }
    let ray = camera_ray(C, i);
    var near = V.near;
    var meets = 1u;
    if (V.beam == 1u) {
        let w = C.roi_w;
        let s = beam_tile_size(V.n / w);
        let b = beam[(i / w / s.y) * beam_tiles_x(w, V.n / w) + (i % w) / s.x];
        near = b.near;
        meets = b.meets;
    }
    if (meets == 1u) {
        out_hits[i] = esvo_cast(ray.o, ray.d, near);
    } else {
        out_hits[i] = miss(0u, 0u, false);
    }
    if (V.write_rays == 1u) {
        out_rays[6u * i] = ray.o.x;
        out_rays[6u * i + 1u] = ray.o.y;
        out_rays[6u * i + 2u] = ray.o.z;
        out_rays[6u * i + 3u] = ray.d.x;
        out_rays[6u * i + 4u] = ray.d.y;
        out_rays[6u * i + 5u] = ray.d.z;
    }
}

// Given rays (ox, oy, oz, dx, dy, dz per ray), cast.
// CPU twin: src/voxels/cast.rs `cast` (via src/voxels/render.rs `cast_all`).
@compute @workgroup_size(64)
fn cast_rays(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= V.n) {
        return;
    }
    let b = 6u * i;
    let o = vec3<f32>(in_rays[b], in_rays[b + 1u], in_rays[b + 2u]);
    let d = vec3<f32>(in_rays[b + 3u], in_rays[b + 4u], in_rays[b + 5u]);
    out_hits[i] = esvo_cast(o, d, V.near);
}
