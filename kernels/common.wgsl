// common.wgsl: helpers prepended to every kernel in kernels/ by the registry
// (src/gpu/kernels.rs). Shared by all kernel families; keep each function's
// CPU twin named beside it.

// ---- launch geometry -------------------------------------------------------

// Linear item index of a 1-D launch laid out as a 2-D grid of workgroups
// (src/gpu/context.rs `plan_dispatch`): gid.x + gid.y * groups_x * wg.
fn linear_id(gid: vec3<u32>, nwg: vec3<u32>, wg: u32) -> u32 {
    return gid.x + gid.y * nwg.x * wg;
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
