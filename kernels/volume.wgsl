// volume.wgsl: the emission-absorption forward kernels.
//   f_fused        one thread per ray: ray, lattice, field query, integration.
//                  CPU twin: src/volume/fused.rs `march_ray` (+ `camera_ray`).
//   f_samp_count   lattice samples per ray (after occupancy skipping) and flags.
//   f_samp_fill    per-sample t, dt, sigma, colour into the packed buffers.
//                  CPU twin: src/volume/sample.rs `f_samp` / `walk_lattice`.
//   f_int          per-ray integration of the packed samples, persisting alpha
//                  and log T. CPU twin: src/volume/integrate.rs `integrate_ray`.
//   f_img          per-pixel image of the region from one camera ray a pixel
//                  (the session's frame, src/gpu/volume_session.rs).
//                  CPU twin: src/volume/compose.rs `f_img` (one ray a pixel).
// Fields: src/volume/field/mod.rs `Field::sigma`, `ColorField::color`,
// `Grid::trilinear` (lerp x, then y, then z); occupancy:
// src/volume/occupancy.rs `Occupancy::occupied`; integration state:
// src/volume/integrate.rs `RayAcc` (Kahan sums, same order).
// Parity case: TESTS/gpu/manifest.yaml `gpu_vol_*_parity` (GPU f32 vs CPU
// f64 per output), `gpu_vol_*_unfused_parity`, `gpu_vol_deterministic`.
// Parity case for f_img: TESTS/volume/manifest_gpu_diff.yaml
// `gpu_vol_session_frame_equals_stages` (memcmp against the host f_img).
// Host side: src/gpu/volume.rs (structs `VolParams`, `GpuRayOut`, `GpuPixel`, keep in sync).

// Field kind codes: src/volume/field/mod.rs `FieldKind`.
const FIELD_CONSTANT: u32 = 0u;
const FIELD_SLABS: u32 = 1u;
const FIELD_GAUSSIAN: u32 = 2u;
const FIELD_SHELL: u32 = 3u;
const FIELD_LINEAR: u32 = 4u;
const FIELD_GRID: u32 = 5u;
// The network runs in its own per-sample pass (kernels/hash_mlp.wgsl).
const FIELD_HASH: u32 = 6u;

// Ray flags: src/volume/sample.rs FLAG_*; FLAG_UNSTABLE is GPU-only (see below).
const FLAG_HIT: u32 = 1u;
const FLAG_STOPPED: u32 = 2u;
const FLAG_TRUNCATED: u32 = 4u;
// A decision of this ray sits within rounding of its threshold, so f32 and
// the f64 referee may legitimately take different branches: the early-stop
// test (T_k within 1e-3 relative of early_stop), the lattice end (a_K within
// 1e-5 of t1), an occupancy cell face between a set and a clear cell (within
// 1e-4 cell), a slab break or a shell radius (within 1e-5). Parity cases compare such rays loosely.
const FLAG_UNSTABLE: u32 = 8u;

struct VolParams {
    background: vec4<f32>,
    color_const: vec4<f32>,
    // constant: (s); gaussian: (amplitude, inv_two_var); shell: (r0, r1, s); linear: (a)
    field_a: vec4<f32>,
    // gaussian: mean; shell: centre; linear: g
    field_b: vec4<f32>,
    sg_bmin: vec4<f32>,
    sg_scale: vec4<f32>,
    cg_bmin: vec4<f32>,
    cg_scale: vec4<f32>,
    occ_bmin: vec4<f32>,
    occ_inv_cell: vec4<f32>,
    // (nx, ny, nz, oob: 0 zero, 1 clamp)
    sg_n: vec4<u32>,
    cg_n: vec4<u32>,
    dt: f32,
    early_stop: f32,
    max_steps: u32,
    stratified: u32,
    seed: u32,
    log_path: u32,
    field_kind: u32,
    color_grid: u32,
    slab_axis: u32,
    slab_n: u32,
    occ_res: u32,
    ray_base: u32,
    ray_count: u32,
    // Always 0 (see `kahan`).
    opaque_zero: u32,
    _pad1: u32,
    _pad2: u32,
}

struct RayOut {
    r: f32,
    g: f32,
    b: f32,
    trans: f32,
    log_trans: f32,
    depth: f32,
    opacity: f32,
    n: u32,
    saturated: u32,
    flags: u32,
    skipped: u32,
    pixel: u32,
}

@group(0) @binding(0) var<uniform> C: CamParams;
@group(0) @binding(1) var<uniform> V: VolParams;
// Slabs: breaks[0..=n] then sigma[0..n].
@group(0) @binding(2) var<storage, read> slabs: array<f32>;
@group(0) @binding(3) var<storage, read> sgrid: array<f32>;
@group(0) @binding(4) var<storage, read> cgrid: array<f32>;
@group(0) @binding(5) var<storage, read> occ: array<u32>;
@group(0) @binding(6) var<storage, read_write> ray_out: array<RayOut>;
// f_samp_count: (samples, flags, skipped, 0) per ray of the batch.
@group(0) @binding(7) var<storage, read_write> counts: array<vec4<u32>>;
// Sample offsets of the batch's rays (off[0] = 0), n + 1 entries.
@group(0) @binding(8) var<storage, read> off: array<u32>;
// Per sample: (t, dt, sigma, ray id as bits) and (r, g, b, lattice index k
// as bits; the backward's t0/t1 dependence, kernels/volume_diff.wgsl).
@group(0) @binding(9) var<storage, read_write> samp0: array<vec4<f32>>;
@group(0) @binding(10) var<storage, read_write> samp1: array<vec4<f32>>;
// Per sample: (alpha, log T before the sample).
@group(0) @binding(11) var<storage, read_write> persist: array<vec2<f32>>;
// f_img: one pixel of the region each.
@group(0) @binding(16) var<storage, read_write> image: array<Pixel>;

struct Pixel {
    r: f32,
    g: f32,
    b: f32,
    trans: f32,
    logtrans: f32,
    depth: f32,
    opacity: f32,
    nsamples: u32,
    hit: u32,
    _pad: u32,
}

// ---- fields ----------------------------------------------------------------

struct Tri {
    i0: vec3<i32>,
    f: vec3<f32>,
    inside: bool,
    zero: bool,
}

// Corner index and weights of a node-aligned trilinear lookup
// (src/volume/field/grid.rs `Grid::trilinear`, both OOB policies).
fn tri_setup(x: vec3<f32>, bmin: vec3<f32>, scale: vec3<f32>, n: vec4<u32>) -> Tri {
    var t: Tri;
    t.inside = true;
    t.zero = false;
    let u = (x - bmin) * scale;
    for (var a = 0u; a < 3u; a++) {
        let na = f32(n[a]);
        if (n.w == 1u) {
            let c = min(max(u[a], 0.0), na - 1.0);
            let fl = min(floor(c), na - 2.0);
            t.i0[a] = i32(fl);
            t.f[a] = c - fl;
        } else {
            let fl = floor(u[a]);
            if (fl < -1.0 || fl > na - 1.0) {
                t.zero = true;
                return t;
            }
            t.f[a] = u[a] - fl;
            if (fl < 0.0 || fl > na - 2.0) {
                t.inside = false;
            }
            t.i0[a] = i32(fl);
        }
    }
    return t;
}

// Flat node index of corner (di, dj, dk), or -1 when outside (OOB zero).
fn tri_corner(t: Tri, n: vec4<u32>, di: i32, dj: i32, dk: i32) -> i32 {
    let i = t.i0.x + di;
    let j = t.i0.y + dj;
    let k = t.i0.z + dk;
    let inr = i >= 0 && j >= 0 && k >= 0 && i < i32(n.x) && j < i32(n.y) && k < i32(n.z);
    if (t.inside || inr) {
        return (k * i32(n.y) + j) * i32(n.x) + i;
    }
    return -1;
}

fn sg_at(idx: i32) -> f32 {
    if (idx < 0) {
        return 0.0;
    }
    return sgrid[idx];
}

fn cg_at(idx: i32, c: u32) -> f32 {
    if (idx < 0) {
        return 0.0;
    }
    return cgrid[u32(idx) * 3u + c];
}

fn lerp3(v000: f32, v100: f32, v010: f32, v110: f32, v001: f32, v101: f32, v011: f32, v111: f32, f: vec3<f32>) -> f32 {
    let c00 = v000 * (1.0 - f.x) + v100 * f.x;
    let c10 = v010 * (1.0 - f.x) + v110 * f.x;
    let c01 = v001 * (1.0 - f.x) + v101 * f.x;
    let c11 = v011 * (1.0 - f.x) + v111 * f.x;
    let c0 = c00 * (1.0 - f.y) + c10 * f.y;
    let c1 = c01 * (1.0 - f.y) + c11 * f.y;
    return c0 * (1.0 - f.z) + c1 * f.z;
}

fn sigma_grid(x: vec3<f32>) -> f32 {
    let n = V.sg_n;
    let t = tri_setup(x, V.sg_bmin.xyz, V.sg_scale.xyz, n);
    if (t.zero) {
        return 0.0;
    }
    return lerp3(
        sg_at(tri_corner(t, n, 0, 0, 0)), sg_at(tri_corner(t, n, 1, 0, 0)),
        sg_at(tri_corner(t, n, 0, 1, 0)), sg_at(tri_corner(t, n, 1, 1, 0)),
        sg_at(tri_corner(t, n, 0, 0, 1)), sg_at(tri_corner(t, n, 1, 0, 1)),
        sg_at(tri_corner(t, n, 0, 1, 1)), sg_at(tri_corner(t, n, 1, 1, 1)),
        t.f,
    );
}

fn color_at(x: vec3<f32>) -> vec3<f32> {
    if (V.color_grid == 0u) {
        return V.color_const.xyz;
    }
    let n = V.cg_n;
    let t = tri_setup(x, V.cg_bmin.xyz, V.cg_scale.xyz, n);
    if (t.zero) {
        return vec3<f32>(0.0);
    }
    let i000 = tri_corner(t, n, 0, 0, 0);
    let i100 = tri_corner(t, n, 1, 0, 0);
    let i010 = tri_corner(t, n, 0, 1, 0);
    let i110 = tri_corner(t, n, 1, 1, 0);
    let i001 = tri_corner(t, n, 0, 0, 1);
    let i101 = tri_corner(t, n, 1, 0, 1);
    let i011 = tri_corner(t, n, 0, 1, 1);
    let i111 = tri_corner(t, n, 1, 1, 1);
    var out: vec3<f32>;
    for (var c = 0u; c < 3u; c++) {
        out[c] = lerp3(
            cg_at(i000, c), cg_at(i100, c), cg_at(i010, c), cg_at(i110, c),
            cg_at(i001, c), cg_at(i101, c), cg_at(i011, c), cg_at(i111, c),
            t.f,
        );
    }
    return out;
}

// sigma at x; sets *unstable when x is within rounding of a discontinuity.
fn sigma_at(x: vec3<f32>, unstable: ptr<function, bool>) -> f32 {
    switch V.field_kind {
        case FIELD_CONSTANT: {
            return V.field_a.x;
        }
        case FIELD_SLABS: {
            let v = x[V.slab_axis];
            let n = V.slab_n;
            for (var i = 0u; i <= n; i++) {
                if (abs(v - slabs[i]) < 1e-5) {
                    *unstable = true;
                }
            }
            for (var i = 0u; i < n; i++) {
                if (slabs[i] <= v && (v < slabs[i + 1u] || (i + 1u == n && v <= slabs[n]))) {
                    return slabs[n + 1u + i];
                }
            }
            return 0.0;
        }
        case FIELD_GAUSSIAN: {
            let dx = x.x - V.field_b.x;
            let dy = x.y - V.field_b.y;
            let dz = x.z - V.field_b.z;
            return V.field_a.x * exp(-(dx * dx + dy * dy + dz * dz) * V.field_a.y);
        }
        case FIELD_SHELL: {
            let dx = x.x - V.field_b.x;
            let dy = x.y - V.field_b.y;
            let dz = x.z - V.field_b.z;
            let r = sqrt(dx * dx + dy * dy + dz * dz);
            if (abs(r - V.field_a.x) < 1e-5 || abs(r - V.field_a.y) < 1e-5) {
                *unstable = true;
            }
            if (V.field_a.x <= r && r <= V.field_a.y) {
                return V.field_a.z;
            }
            return 0.0;
        }
        case FIELD_LINEAR: {
            return max(V.field_a.x + V.field_b.x * x.x + V.field_b.y * x.y + V.field_b.z * x.z, 0.0);
        }
        default: {
            return max(sigma_grid(x), 0.0);
        }
    }
}

// (sigma, rgb) at x. A hash field's values are 0 here: its network runs one
// thread per sample after f_samp_fill (kernels/hash_mlp.wgsl `f_hash_fill`).
fn medium_at(x: vec3<f32>, unstable: ptr<function, bool>) -> vec4<f32> {
    if (V.field_kind == FIELD_HASH) {
        return vec4<f32>(0.0);
    }
    let sigma = sigma_at(x, unstable);
    return vec4<f32>(sigma, color_at(x));
}

// ---- occupancy and lattice ----------------------------------------------------

fn occ_bit(c: vec3<u32>) -> bool {
    let b = (c.z * V.occ_res + c.y) * V.occ_res + c.x;
    return ((occ[b / 32u] >> (b % 32u)) & 1u) == 1u;
}

// Whether x's cell may have density (src/volume/occupancy.rs `occupied`);
// sets *unstable when x is within 1e-4 cell of a face whose neighbour cell
// has the other bit (f32 and f64 may then pick different cells).
fn occupied(x: vec3<f32>, unstable: ptr<function, bool>) -> bool {
    let top = f32(V.occ_res - 1u);
    var c: vec3<u32>;
    var w: vec3<f32>;
    for (var a = 0u; a < 3u; a++) {
        w[a] = (x[a] - V.occ_bmin[a]) * V.occ_inv_cell[a];
        c[a] = u32(min(max(floor(w[a]), 0.0), top));
    }
    let bit = occ_bit(c);
    for (var a = 0u; a < 3u; a++) {
        let face = round(w[a]);
        if (abs(w[a] - face) < 1e-4 && face >= 1.0 && face <= top) {
            var n = c;
            n[a] = u32(face) - select(0u, 1u, f32(c[a]) == face);
            if (occ_bit(n) != bit) {
                *unstable = true;
            }
        }
    }
    return bit;
}

struct Sample {
    ok: bool,
    t: f32,
    h: f32,
}

// Sample k of [t0, t1] (src/volume/sample.rs `sample_k`).
fn sample_k(t0: f32, t1: f32, k: u32, pixel: u32) -> Sample {
    var s: Sample;
    let a = t0 + f32(k) * V.dt;
    let b = min(t0 + f32(k + 1u) * V.dt, t1);
    s.ok = a < t1 && b > a;
    if (!s.ok) {
        return s;
    }
    s.h = b - a;
    if (V.stratified == 1u) {
        s.t = a + rand_f32(V.seed, pixel, 0u, k) * s.h;
    } else {
        s.t = (a + b) * 0.5;
    }
    return s;
}

// Whether the lattice end a_k sits within rounding of t1.
fn end_unstable(t0: f32, t1: f32, k: u32) -> bool {
    return abs(t0 + f32(k) * V.dt - t1) < 1e-5 * max(1.0, abs(t1));
}

// ---- integration state (src/volume/integrate.rs `RayAcc`) ----------------------

// A compensated (Kahan) sum's step: (sum, compensation) plus x. SPIR-V
// without NoContraction (naga writes none) lets a driver reassociate
// ((s + y) - s) - y to 0, and NVIDIA's does: on an H200 every log
// transmittance came back a plain sum (vol_tiny_optical_depth_alpha_f32:
// opacity 1.06e-6 high, bit for bit an emulation of the sum without its
// compensation). XOR with a uniform the host keeps 0 hides t = s + y from
// the compiler.
fn kahan(sc: vec2<f32>, x: f32) -> vec2<f32> {
    let y = x - sc.y;
    let t = bitcast<f32>(bitcast<u32>(sc.x + y) ^ V.opaque_zero);
    return vec2<f32>(t, (t - sc.x) - y);
}

struct Acc {
    trans: f32,
    log_t: vec2<f32>,
    r: vec2<f32>,
    g: vec2<f32>,
    b: vec2<f32>,
    depth: vec2<f32>,
    n: u32,
    saturated: u32,
}

fn acc_new() -> Acc {
    var a: Acc;
    a.trans = 1.0;
    return a;
}

fn acc_trans(a: Acc) -> f32 {
    if (V.log_path == 1u) {
        return trans_of_log(a.log_t.x);
    }
    return a.trans;
}

// One sample with transmittance tk; returns alpha.
fn acc_step(a: ptr<function, Acc>, tk: f32, sigma: f32, c: vec3<f32>, t: f32, h: f32) -> f32 {
    let tau = sigma * h;
    let alpha = -expm1_f32(-tau);
    let w = tk * alpha;
    (*a).r = kahan((*a).r, w * c.x);
    (*a).g = kahan((*a).g, w * c.y);
    (*a).b = kahan((*a).b, w * c.z);
    (*a).depth = kahan((*a).depth, w * t);
    (*a).log_t = kahan((*a).log_t, -tau);
    (*a).trans = (*a).trans * (1.0 - alpha);
    (*a).n += 1u;
    if (alpha == 1.0) {
        (*a).saturated += 1u;
    }
    return alpha;
}

fn early_unstable(tk: f32) -> bool {
    return V.early_stop > 0.0 && abs(tk - V.early_stop) <= 1e-3 * V.early_stop;
}

fn acc_finish(a: Acc, flags: u32, skipped: u32, pixel: u32) -> RayOut {
    let tn = acc_trans(a);
    var o: RayOut;
    o.r = a.r.x + tn * V.background.x;
    o.g = a.g.x + tn * V.background.y;
    o.b = a.b.x + tn * V.background.z;
    o.trans = tn;
    o.log_trans = a.log_t.x;
    o.depth = a.depth.x;
    o.opacity = -expm1_f32(a.log_t.x);
    o.n = a.n;
    o.saturated = a.saturated;
    o.flags = flags;
    o.skipped = skipped;
    o.pixel = pixel;
    return o;
}

// ---- f_fused --------------------------------------------------------------------

@compute @workgroup_size(64)
fn f_fused(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= C.n) {
        return;
    }
    let ray = camera_ray(C, i);
    var acc = acc_new();
    var flags = 0u;
    var skipped = 0u;
    var unstable = false;
    if (ray.t1 > ray.t0) {
        flags = FLAG_HIT;
        var k = 0u;
        var ended = false;
        loop {
            if (k >= V.max_steps) {
                break;
            }
            let s = sample_k(ray.t0, ray.t1, k, ray.pixel);
            if (!s.ok) {
                unstable = unstable || end_unstable(ray.t0, ray.t1, k);
                ended = true;
                break;
            }
            let x = ray.o + s.t * ray.d;
            if (V.occ_res > 0u && !occupied(x, &unstable)) {
                skipped += 1u;
                k += 1u;
                continue;
            }
            let tk = acc_trans(acc);
            unstable = unstable || early_unstable(tk);
            if (tk < V.early_stop) {
                flags |= FLAG_STOPPED;
                break;
            }
            let q = medium_at(x, &unstable);
            acc_step(&acc, tk, q.x, q.yzw, s.t, s.h);
            k += 1u;
        }
        if (!ended && sample_k(ray.t0, ray.t1, V.max_steps, ray.pixel).ok) {
            flags |= FLAG_TRUNCATED;
        }
    }
    if (unstable) {
        flags |= FLAG_UNSTABLE;
    }
    ray_out[i] = acc_finish(acc, flags, skipped, ray.pixel);
}

// ---- unfused: f_samp (count, fill) and f_int ----------------------------------
// Rays of the batch are V.ray_base .. V.ray_base + V.ray_count of the region;
// f_samp regenerates each camera ray (common.wgsl `camera_ray`, the f_ray twin).

@compute @workgroup_size(64)
fn f_samp_count(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg, 64u);
    if (j >= V.ray_count) {
        return;
    }
    let ray = camera_ray(C, V.ray_base + j);
    var count = 0u;
    var skipped = 0u;
    var flags = 0u;
    var unstable = false;
    if (ray.t1 > ray.t0) {
        flags = FLAG_HIT;
        var k = 0u;
        var ended = false;
        loop {
            if (k >= V.max_steps) {
                break;
            }
            let s = sample_k(ray.t0, ray.t1, k, ray.pixel);
            if (!s.ok) {
                unstable = unstable || end_unstable(ray.t0, ray.t1, k);
                ended = true;
                break;
            }
            let x = ray.o + s.t * ray.d;
            if (V.occ_res == 0u || occupied(x, &unstable)) {
                count += 1u;
            } else {
                skipped += 1u;
            }
            k += 1u;
        }
        if (!ended && sample_k(ray.t0, ray.t1, V.max_steps, ray.pixel).ok) {
            flags |= FLAG_TRUNCATED;
        }
    }
    if (unstable) {
        flags |= FLAG_UNSTABLE;
    }
    counts[j] = vec4<u32>(count, flags, skipped, 0u);
}

@compute @workgroup_size(64)
fn f_samp_fill(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg, 64u);
    if (j >= V.ray_count) {
        return;
    }
    let ray = camera_ray(C, V.ray_base + j);
    if (!(ray.t1 > ray.t0)) {
        return;
    }
    var m = off[j];
    let end = off[j + 1u];
    var unstable = false;
    for (var k = 0u; k < V.max_steps && m < end; k++) {
        let s = sample_k(ray.t0, ray.t1, k, ray.pixel);
        if (!s.ok) {
            break;
        }
        let x = ray.o + s.t * ray.d;
        if (V.occ_res > 0u && !occupied(x, &unstable)) {
            continue;
        }
        let q = medium_at(x, &unstable);
        samp0[m] = vec4<f32>(s.t, s.h, q.x, bitcast<f32>(V.ray_base + j));
        samp1[m] = vec4<f32>(q.yzw, bitcast<f32>(k));
        m += 1u;
    }
    if (unstable) {
        counts[j].y = counts[j].y | FLAG_UNSTABLE;
    }
}

@compute @workgroup_size(64)
fn f_int(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg, 64u);
    if (j >= V.ray_count) {
        return;
    }
    let lo = off[j];
    let hi = off[j + 1u];
    var flags = counts[j].y;
    var acc = acc_new();
    var unstable = false;
    for (var m = lo; m < hi; m++) {
        let tk = acc_trans(acc);
        unstable = unstable || early_unstable(tk);
        if (tk < V.early_stop) {
            flags |= FLAG_STOPPED;
            for (var r = m; r < hi; r++) {
                persist[r] = vec2<f32>(0.0, acc.log_t.x);
            }
            break;
        }
        let s0 = samp0[m];
        let log_before = acc.log_t.x;
        let alpha = acc_step(&acc, tk, s0.z, samp1[m].xyz, s0.x, s0.y);
        persist[m] = vec2<f32>(alpha, log_before);
    }
    if (unstable) {
        flags |= FLAG_UNSTABLE;
    }
    // Pixel ids are the region order's (the host knows them).
    ray_out[V.ray_base + j] = acc_finish(acc, flags, counts[j].z, 0u);
}

// ---- f_img ------------------------------------------------------------------------
// Camera rays: ray i of the region lands in pixel i of the region, so each
// pixel takes its one ray (src/volume/compose.rs `Image::add` with count 1).

@compute @workgroup_size(64)
fn f_img(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= C.n) {
        return;
    }
    let r = ray_out[i];
    var p: Pixel;
    p.r = r.r;
    p.g = r.g;
    p.b = r.b;
    p.trans = r.trans;
    p.logtrans = r.log_trans;
    p.depth = r.depth;
    p.opacity = r.opacity;
    p.nsamples = min(r.n, 2147483647u);
    p.hit = r.flags & FLAG_HIT;
    image[i] = p;
}
