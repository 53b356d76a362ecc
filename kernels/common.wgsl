// common.wgsl: helpers prepended to every kernel in kernels/ by the registry
// (src/gpu/kernels.rs). Shared by all kernel families; keep each function's
// CPU twin named beside it.

// ---- launch geometry -------------------------------------------------------

// Linear item index of a 1-D launch laid out as a 2-D grid of workgroups
// (src/gpu/context.rs `plan_dispatch`): gid.x + gid.y * groups_x * wg.
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>, wg: u32) -> u32 {
    return gid.x + gid.y * nwg.x * wg;
}

// The camera ray (region order, n rays, w a row) that thread t casts, or n
// for none. order 0: ray t. order 1: 8x8 pixel tiles per 64 threads, the
// tile's pixels in Morton order (8 threads a 4x2 block, 32 an 8x4 block),
// so a lock-step thread group holds neighbouring rays.
// CPU twin: src/rays/thread_order.rs `thread_ray` (None = n).
fn thread_ray(order: u32, t: u32, w: u32, n: u32) -> u32 {
    var i = t;
    if (order == 1u) {
        let tile = t >> 6u;
        let l = t & 63u;
        let tiles_x = (w + 7u) / 8u;
        let x = (tile % tiles_x) * 8u + ((l & 1u) | ((l >> 1u) & 2u) | ((l >> 2u) & 4u));
        let y = (tile / tiles_x) * 8u + (((l >> 1u) & 1u) | ((l >> 2u) & 2u) | ((l >> 3u) & 4u));
        if (x >= w || y >= n / w) {
            return n;
        }
        i = y * w + x;
    }
    return min(i, n);
}

// ---- random numbers (SCENES.md "Random numbers") ---------------------------
// CPU twin: src/rng.rs `pcg`, `rand_u32`, `rand_f32`. Parity case:
// TESTS/gpu/manifest.yaml `gpu_rng_matches_cpu` (bit-exact).

fn pcg(v: u32) -> u32 {
    let s = v * 747796405u + 2891336453u;
    let w = ((s >> ((s >> 28u) + 4u)) ^ s) * 277803737u;
    return (w >> 22u) ^ w;
}

fn rand_u32(seed: u32, pixel: u32, sample: u32, dim: u32) -> u32 {
    return pcg(pcg(pcg(pcg(seed) ^ pixel) ^ sample) ^ dim);
}

// (rand >> 8) * 2^-24: exact in f32.
fn rand_f32(seed: u32, pixel: u32, sample: u32, dim: u32) -> f32 {
    return f32(rand_u32(seed, pixel, sample, dim) >> 8u) * 0x1p-24f;
}

// ---- padded 2-D Owen-scrambled Sobol' (Burley 2020) -------------------------
// CPU twin: src/rng/sobol.rs `lk`, `owen`, `zeta`, `sobol2`, `sobol1`,
// `unit_f32`; src/pathtrace/sampler.rs `sobol_pair` / `Sampler::table`
// (`sampler_u32`). Parity case: TESTS/gpu/manifest.yaml
// `gpu_sobol_matches_cpu` (bit-exact words and floats).

fn sobol_lk(x_in: u32, seed: u32) -> u32 {
    var x = x_in + seed;
    x ^= x * 0x6c50b47cu;
    x ^= x * 0xb82f1e52u;
    x ^= x * 0xc7afe638u;
    x ^= x * 0x8d22f6e6u;
    return x;
}

fn sobol_owen(v: u32, seed: u32) -> u32 {
    return reverseBits(sobol_lk(reverseBits(v), seed));
}

fn sobol_zeta(i: u32) -> u32 {
    var y = i;
    y ^= (y >> 1u) & 0x55555555u;
    y ^= (y >> 2u) & 0x33333333u;
    y ^= (y >> 4u) & 0x0f0f0f0fu;
    y ^= (y >> 8u) & 0x00ff00ffu;
    y ^= (y >> 16u) & 0x0000ffffu;
    return y;
}

// pk = pcg(pcg(seed) ^ pixel); the pair (dim, dim + 1) of sample `index`.
fn sobol2(pk: u32, index: u32, dim: u32) -> vec2<u32> {
    let h = pcg(pk ^ dim);
    let i = sobol_owen(index, h);
    return vec2<u32>(
        reverseBits(sobol_lk(i, h * 0x9e3779b9u)),
        reverseBits(sobol_lk(sobol_zeta(i), h * 0x85ebca6bu)),
    );
}

fn sobol1(pk: u32, index: u32, dim: u32) -> u32 {
    let h = pcg(pk ^ dim);
    return reverseBits(sobol_lk(sobol_owen(index, h), h * 0x9e3779b9u));
}

fn unit_f32(x: u32) -> f32 {
    return f32(x >> 8u) * 0x1p-24f;
}

// The path tracer's dimension `dim` (src/pathtrace/sampler.rs `dims`):
// sampler 0 = independent (rand_u32), 1 = Sobol' with the pairs (0, 1)
// and, per vertex (2 + 8 k), offsets (1, 2) and (4, 5); the rest 1-D.
fn sampler_u32(sampler: u32, seed: u32, pixel: u32, sample: u32, dim: u32) -> u32 {
    if (sampler == 0u) {
        return rand_u32(seed, pixel, sample, dim);
    }
    let pk = pcg(pcg(seed) ^ pixel);
    if (dim < 2u) {
        return sobol2(pk, sample, 0u)[dim];
    }
    let off = (dim - 2u) % 8u;
    if (off == 1u || off == 4u) {
        return sobol2(pk, sample, dim).x;
    }
    if (off == 2u || off == 5u) {
        return sobol2(pk, sample, dim - 1u).y;
    }
    return sobol1(pk, sample, dim);
}

// ---- exp / expm1 / log-domain transmittance --------------------------------
// CPU twin: f32::exp_m1 / f64::exp_m1 (libm). Parity case:
// TESTS/gpu/manifest.yaml `gpu_expm1_rel_err` (relative error against f64).

// expm1(x) = e^x - 1 keeping relative accuracy for small |x|: for
// |x| < 0.5 the Taylor series to x^9/9! in Horner form (truncation below
// 1.1e-8 relative at |x| = 0.5, i.e. under f32's 6e-8 rounding); elsewhere
// exp(x) - 1, where |e^x - 1| >= 0.39 so the subtraction loses nothing.
fn expm1_f32(x: f32) -> f32 {
    if (abs(x) < 0.5) {
        var p = 1.0 + x / 9.0;
        p = 1.0 + x / 8.0 * p;
        p = 1.0 + x / 7.0 * p;
        p = 1.0 + x / 6.0 * p;
        p = 1.0 + x / 5.0 * p;
        p = 1.0 + x / 4.0 * p;
        p = 1.0 + x / 3.0 * p;
        p = 1.0 + x / 2.0 * p;
        return x * p;
    }
    return exp(x) - 1.0;
}

// Below this log-transmittance exp() would be subnormal (f32 min normal is
// 2^-126 = e^-87.34): flush to exactly 0 on every driver alike, instead of
// leaving it to the driver's denormal mode (lavapipe flushes).
const LOG_T_FLUSH: f32 = -87.0;

// T = exp(log T), 0 below LOG_T_FLUSH. logT itself stays exact (it is the
// output `logtrans`), so a deep ray keeps its information.
fn trans_of_log(log_t: f32) -> f32 {
    if (log_t < LOG_T_FLUSH) {
        return 0.0;
    }
    return exp(log_t);
}

// Opacity of one interval: alpha = -expm1(-sigma dt), in [0, 1].
fn alpha_of(sigma_dt: f32) -> f32 {
    return clamp(-expm1_f32(-sigma_dt), 0.0, 1.0);
}

// ---- rays -----------------------------------------------------------------
// CPU twin: src/rays.rs `clip_aabb` (slab method, axis-parallel handled
// explicitly). `far` must be finite (callers pass min(far, f32::MAX)): WGSL
// lets implementations assume no infinities.

fn clip_aabb(o: vec3<f32>, d: vec3<f32>, bmin: vec3<f32>, bmax: vec3<f32>, near: f32, far: f32) -> vec2<f32> {
    var lo = near;
    var hi = far;
    for (var a = 0u; a < 3u; a++) {
        if (d[a] == 0.0) {
            if (o[a] < bmin[a] || o[a] > bmax[a]) {
                return vec2<f32>(near, near);
            }
            continue;
        }
        let inv = 1.0 / d[a];
        let ta = (bmin[a] - o[a]) * inv;
        let tb = (bmax[a] - o[a]) * inv;
        lo = max(lo, min(ta, tb));
        hi = min(hi, max(ta, tb));
    }
    if (hi > lo) {
        return vec2<f32>(lo, hi);
    }
    return vec2<f32>(near, near);
}

// Camera and ray-generator parameters, shared by f_ray (rays.wgsl) and the
// fused volume kernel. Host side: src/gpu/rays.rs `RayParams` (144 bytes,
// keep in sync).
struct CamParams {
    // Rows of the camera-to-world rotation; w holds the translation t[row].
    rot0: vec4<f32>,
    rot1: vec4<f32>,
    rot2: vec4<f32>,
    // Pinhole: (fx, fy, cx, cy). Orthographic: (hw, hh, W, H).
    model: vec4<f32>,
    // Box min and near (w); box max and far (w, finite).
    bmin_near: vec4<f32>,
    bmax_far: vec4<f32>,
    // 0 = pinhole, 1 = orthographic.
    kind: u32,
    width: u32,
    roi_x: u32,
    roi_y: u32,
    roi_w: u32,
    n: u32,
    // 1 = jittered pixel positions (seed, sample), 0 = pixel centres,
    // 2 = jittered by the path tracer's Sobol' pair 0 (sampler.rs).
    jitter: u32,
    seed: u32,
    sample: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

struct Ray {
    o: vec3<f32>,
    d: vec3<f32>,
    t0: f32,
    t1: f32,
    pixel: u32,
}

fn cam_rotate(c: CamParams, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        c.rot0.x * v.x + c.rot0.y * v.y + c.rot0.z * v.z,
        c.rot1.x * v.x + c.rot1.y * v.y + c.rot1.z * v.z,
        c.rot2.x * v.x + c.rot2.y * v.y + c.rot2.z * v.z,
    );
}

// Ray i of the region (row-major over the region), clipped to the box.
// CPU twin: src/rays.rs `f_ray` one_ray + src/camera.rs `RealCamera::ray`.
fn camera_ray(c: CamParams, i: u32) -> Ray {
    let u = c.roi_x + i % c.roi_w;
    let v = c.roi_y + i / c.roi_w;
    let pixel = v * c.width + u;
    var jx = 0.5;
    var jy = 0.5;
    if (c.jitter == 1u) {
        jx = rand_f32(c.seed, pixel, c.sample, 0u);
        jy = rand_f32(c.seed, pixel, c.sample, 1u);
    }
    if (c.jitter == 2u) {
        let j = sobol2(pcg(pcg(c.seed) ^ pixel), c.sample, 0u);
        jx = unit_f32(j.x);
        jy = unit_f32(j.y);
    }
    let px = f32(u) + jx;
    let py = f32(v) + jy;
    let t = vec3<f32>(c.rot0.w, c.rot1.w, c.rot2.w);
    var r: Ray;
    if (c.kind == 0u) {
        let dc = vec3<f32>((px - c.model.z) / c.model.x, -(py - c.model.w) / c.model.y, -1.0);
        let dw = cam_rotate(c, dc);
        let len = sqrt(dw.x * dw.x + dw.y * dw.y + dw.z * dw.z);
        r.o = t;
        r.d = dw / len;
    } else {
        let x = -c.model.x + 2.0 * c.model.x * px / c.model.z;
        let y = c.model.y - 2.0 * c.model.y * py / c.model.w;
        r.o = cam_rotate(c, vec3<f32>(x, y, 0.0)) + t;
        r.d = cam_rotate(c, vec3<f32>(0.0, 0.0, -1.0));
    }
    let tt = clip_aabb(r.o, r.d, c.bmin_near.xyz, c.bmax_far.xyz, c.bmin_near.w, c.bmax_far.w);
    r.t0 = tt.x;
    r.t1 = tt.y;
    r.pixel = pixel;
    return r;
}
