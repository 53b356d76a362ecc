// voxel_beam.wgsl: the beam pre-pass of the GPU camera cast (Laine & Karras
// 2010, "beam optimization", made conservative), one invocation per 8x8
// pixel tile of the region, in f64 (the adapter's SHADER_F64; the host runs
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

// The squared distance from the cone's origin to the nearest non-empty node
// box that meets the cone, `NO_BOX` for none.
// CPU twin: src/voxels/beam.rs `start_distance_scalar`.
fn start_distance(k: Cone) -> f64 {
    let tan2 = k.tan_half * k.tan_half;
    var best = NO_BOX;
    // An entry: squared distance, slot, and the node's low corner as whole
    // multiples of its edge 2^(1 - level) (xyz) with the level (w): the
    // CPU's f64 corner exactly (dyadic), in 28 bytes instead of 48 (the
    // stack's size is most of the walk's cost on a CPU driver).
    var st_d2: array<f64, BEAM_STACK>;
    var st_slot: array<u32, BEAM_STACK>;
    var st_kl: array<vec4<u32>, BEAM_STACK>;
    st_d2[0] = 0.0lf;
    st_slot[0] = 0u;
    st_kl[0] = vec4<u32>(0u);
    var sp = 1u;
    while (sp > 0u) {
        sp -= 1u;
        let dist2 = st_d2[sp];
        let slot = st_slot[sp];
        let kl = st_kl[sp];
        let level = kl.w;
        if (dist2 >= best) {
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
            if (d2 >= best) {
                continue;
            }
            let v = wlo + 0.5lf * size - k.o;
            if (!meets_sphere(k, v, radius)) {
                continue;
            }
            let fine = size * size <= 4.0lf * d2 * tan2;
            if (last || ((nonleaf >> c) & 1u) == 0u || fine) {
                best = d2;
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
            }
        }
    }
    return best;
}

// One tile's start (`beam_tile_size`: 8x8, or 64x1 in a region one row
// high): the tile's rays (the f32 camera rays `cast_camera` casts) bound by a cone about the sum of its first and last directions, the
// walk, the pull-back. `meets` 0: no non-empty box meets the cone (every ray
// a miss); a tile without a cone (rays from differing origins, one too wide,
// an LOD cut) starts at `V.near`.
// CPU twin: src/voxels/beam.rs `beam_nears` (one tile).
@compute @workgroup_size(64)
fn beam_nears(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let w = C.roi_w;
    let h = V.n / w;
    let s = beam_tile_size(h);
    let tiles_x = beam_tiles_x(w, h);
    let t = linear_id(gid, nwg, 64u);
    if (t >= tiles_x * ((h + s.y - 1u) / s.y)) {
        return;
    }
    let x0 = (t % tiles_x) * s.x;
    let y0 = (t / tiles_x) * s.y;
    let x1 = min(x0 + s.x, w);
    let y1 = min(y0 + s.y, h);
    var out: BeamTile;
    out.near = V.near;
    out.meets = 1u;
    let first = camera_ray(C, y0 * w + x0);
    let last = camera_ray(C, (y1 - 1u) * w + x1 - 1u);
    // ConeAcc::new: the axis made unit.
    let ax = vec3<f64>(first.d) + vec3<f64>(last.d);
    let al = sqrt(dot64(ax, ax));
    if (V.lod_on == 1u || !(al > 0.0lf)) {
        beam_out[t] = out;
        return;
    }
    let axis = ax / al;
    // ConeAcc::add over the tile's rays in memory order.
    var ok = true;
    var cos2_min = 1.0lf;
    var dmin = vec3<f64>(NO_BOX);
    var len2_max = 0.0lf;
    for (var y = y0; y < y1; y++) {
        for (var x = x0; x < x1; x++) {
            let r = camera_ray(C, y * w + x);
            let d = vec3<f64>(r.d);
            let c = dot64(d, axis);
            let l2 = dot64(d, d);
            ok = ok && all(r.o == first.o) && c > 0.0lf && l2 > 0.0lf;
            cos2_min = less64(c * c / l2, cos2_min);
            dmin = vec3<f64>(less64(abs(d.x), dmin.x), less64(abs(d.y), dmin.y), less64(abs(d.z), dmin.z));
            len2_max = -less64(-l2, -len2_max);
        }
    }
    // ConeAcc::finish.
    let c2 = clamp(cos2_min, 0.0lf, 1.0lf);
    let cc = sqrt(c2);
    let ss = sqrt(1.0lf - c2);
    let cos_half = cc - ss * WIDEN;
    let sin_half = ss + cc * WIDEN;
    if (!ok || len2_max == 0.0lf || !(cos_half >= COS_MAX_HALF_ANGLE)) {
        beam_out[t] = out;
        return;
    }
    var k: Cone;
    k.o = vec3<f64>(first.o);
    k.axis = axis;
    k.time_error = plane_time_error(first.o, dmin);
    k.len_max = sqrt(len2_max);
    k.slack = 2.0lf * k.time_error * k.len_max;
    k.cos2_half = cos_half * cos_half;
    k.sin_half = sin_half;
    k.tan_half = sin_half / cos_half;
    let best = start_distance(k);
    // tile_near.
    if (best >= NO_BOX) {
        out.meets = 0u;
    } else {
        let s = sqrt(best) / k.len_max * (1.0lf - MARGIN) - k.time_error;
        if (s > f64(V.near)) {
            out.near = f32(s);
        }
    }
    beam_out[t] = out;
}
