// transport.wgsl: curved rays, one thread per ray (seed 002, issue 17).
//   trace   integrates one ray of Hamilton's equations from its start state
//           (at most `chunk` step attempts per dispatch, state kept in
//           `rays`; the host dispatches until every ray is done)
//           until an event fires (located by Illinois), max_steps accepted
//           steps, or a non-finite state; writes the final state, affine
//           parameter, end code, step counts, max |H| and the summed
//           embedded error estimate.
//           CPU twin: src/transport/integrate.rs `trace` (with `rk4_step`,
//           `dopri5_step`, `fixed_step`, `locate`, `Event::g`).
// Systems (`SYS_*`, if-chains on the override constant `SYSTEM`; no
// `switch`, which SPIR-V-to-NIR turns into a loop: see "Loops" below): GRIN media, CPU twin
// src/transport/grin.rs `Medium::n2_grad` / `Hamiltonian for Medium`;
// static spherical spacetimes, CPU twin src/transport/metric.rs
// `Spacetime::radial` / `Hamiltonian for Spacetime`; Kerr in Kerr–Schild
// Cartesian coordinates, CPU twin src/transport/kerr.rs `kerr_rhs`,
// `kerr_h`, `Hamiltonian for Kerr`, with the thin-disk continuation and the
// constants-of-motion certificate of src/transport/kerr_trace.rs
// `trace_kerr`. The state is always
// 8 floats: GRIN rays use slots 0..6 (x, p) and keep 6, 7 at zero.
// Tiers: rk4, dopri5_fixed (Dormand-Prince 5th-order solution, fixed law),
// dopri5 (adaptive 5(4), the CPU controller). f32 only.
// Parity case: TESTS/transport/manifest_gpu.yaml `trgpu_*` (closed forms per tier in
// f32, CPU f32 agreement, determinism; Kerr and Ellis images `trgpu_img_*`
// against the f64 CPU render and Bardeen's curve); contract docs/transport_gpu.md.
// Host side: src/gpu/transport.rs (structs `TraceParams` = `Params`,
// `GpuTrace` = `TraceOut`, `GpuRayState` = `RayState`; keep in sync).

const SYS_MINKOWSKI: u32 = 0u;
const SYS_SCHWARZSCHILD: u32 = 1u;
const SYS_ELLIS: u32 = 2u;
const SYS_KERR: u32 = 3u;
const SYS_LUNEBURG: u32 = 10u;
const SYS_LUNEBURG_CORE: u32 = 11u;
const SYS_FISH_EYE: u32 = 12u;
const SYS_FIBRE: u32 = 13u;
const SYS_SECH: u32 = 14u;

const TIER_RK4: u32 = 0u;
const TIER_DP5_FIXED: u32 = 1u;
const TIER_DP45: u32 = 2u;

const LAW_FIXED: u32 = 0u;

const EV_COORD: u32 = 0u;
const EV_SPHERE: u32 = 1u;
const EV_APPROACH: u32 = 2u;
const EV_KS_RADIUS: u32 = 3u;

// Most equatorial crossings a Kerr disk ray makes outside the disk before
// it ends there (src/transport/kerr_trace.rs `MAX_CROSSINGS`).
const MAX_CROSSINGS: u32 = 64u;

// End codes: src/transport/integrate.rs `End::code`.
const END_MAX_STEPS: i32 = -1;
const END_NON_FINITE: i32 = -2;
const END_STEP_UNDERFLOW: i32 = -3;
// GPU-only: the ray is still running (more dispatches to come).
const END_RUNNING: i32 = -6;

const PHASE_FRESH: u32 = 0u;
const PHASE_RUNNING: u32 = 1u;
const PHASE_DONE: u32 = 2u;

const EPS: f32 = 1.1920929e-7;

// The system and tier are pipeline-overridable constants (one specialised
// pipeline per pair, src/gpu/transport.rs `TracePipeline`): the driver
// drops the branches of the other systems and tiers, which keeps the
// compile small (every call site of rhs is inlined).
override SYSTEM: u32 = 0u;
override TIER: u32 = 0u;

struct Params {
    // sys.x: mass / b0 / radius / n0; sys.y: radius / alpha / Kerr spin a;
    // Kerr: sys.z, sys.w the disk's r_in, r_out (r_out = 0: no disk).
    sys: vec4<f32>,
    // law: h (fixed) or eta, h_min, h_max, 0.
    law: vec4<f32>,
    // Controller (dopri5): rtol, eta cap, atol, h0.
    ctl: vec4<f32>,
    // Controller h_min, h_max.
    ctl2: vec4<f32>,
    // Per event: coordinate value or sphere radius.
    ev_val: vec4<f32>,
    // Per event: the approach point.
    ev_pt: array<vec4<f32>, 4>,
    pad_system: u32,
    pad_tier: u32,
    law_kind: u32,
    project: u32,
    max_steps: u32,
    // Step attempts (accepted + rejected) per dispatch.
    chunk: u32,
    n: u32,
    n_dim: u32,
    n_events: u32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
    ev_kind: vec4<u32>,
    ev_index: vec4<u32>,
    ev_rising: vec4<u32>,
}

struct TraceOut {
    y: array<f32, 8>,
    lambda: f32,
    end_code: i32,
    steps: u32,
    rejected: u32,
    h_drift: f32,
    err_est: f32,
    // Kerr: max relative drift of E, L_z, Carter Q (0 elsewhere).
    e_drift: f32,
    l_drift: f32,
    q_drift: f32,
    pad0: u32,
    pad1: u32,
    pad2: u32,
}

// A ray between dispatches: its result so far and the loop's own state.
struct RayState {
    t: TraceOut,
    k1: array<f32, 8>,
    gs: vec4<f32>,
    // Kerr: (E, L_z, Q) of the start state.
    c0: vec4<f32>,
    h_ctl: f32,
    just_rejected: u32,
    phase: u32,
    // Kerr disk: crossings of z = 0 outside the disk so far.
    crossings: u32,
}

alias State = array<f32, 8>;

@group(0) @binding(0) var<uniform> P: Params;
@group(0) @binding(1) var<storage, read_write> rays: array<RayState>;

// Finite test on the bits: WGSL lets a compiler assume no NaN or infinity
// in float comparisons, so `x == x` could be folded away.
fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

// Loops: Mesa llvmpipe breaks out of every loop once an invocation has
// taken 65535 back-edges in total (and the results are then wrong, not
// flagged). So one dispatch makes at most `chunk` step attempts per ray and
// keeps the loop's state in `rays`; the host dispatches again until every
// ray is done. The per-step code is written without loops (slots and
// events spelled out, if-chains instead of `switch`, which SPIR-V-to-NIR
// turns into a loop); measured on llvmpipe: 3 back-edges per RK4 step.

fn all_finite(y: State) -> bool {
    return finite(y[0]) && finite(y[1]) && finite(y[2]) && finite(y[3]) && finite(y[4]) && finite(y[5]) && finite(y[6]) && finite(y[7]);
}

// (sin x, cos x) to about 1 ulp for |x| up to ~1e4. WGSL allows its
// builtin sin/cos an absolute error of 2^-11, which would move an
// equatorial photon's sin^2(theta) by 1e-3; this Cody-Waite reduction by
// pi/2 (three-part constant) plus the Cephes single-precision minimax
// polynomials on [-pi/4, pi/4] does not depend on the driver.
// CPU twin: f32::sin_cos (libm). Parity case: TESTS/transport/manifest_gpu.yaml
// `trgpu_schw_deflection_dp45` (equatorial rays would drift off theta).
fn sin_cos_f32(x: f32) -> vec2<f32> {
    let j = round(x * 0.63661977236758134);
    let r = ((x - j * 1.5703125) - j * 4.837512969970703125e-4) - j * 7.549789954891485e-8;
    let z = r * r;
    let s = r + r * z * (-1.6666654611e-1 + z * (8.3321608736e-3 + z * -1.9515295891e-4));
    let c = 1.0 - 0.5 * z + z * z * (4.166664568298827e-2 + z * (-1.388731625493765e-3 + z * 2.443315711809948e-5));
    let q = i32(j) & 3;
    if (q == 0) {
        return vec2<f32>(s, c);
    }
    if (q == 1) {
        return vec2<f32>(c, -s);
    }
    if (q == 2) {
        return vec2<f32>(-s, -c);
    }
    return vec2<f32>(-c, s);
}

// tanh(u) / u, exact at 0; tanh through expm1 (no cancellation for small u).
// CPU twin: src/transport/grin.rs `tanhc`.
fn tanhc(u: f32) -> f32 {
    if (abs(u) < 1e-4) {
        return 1.0 - u * u / 3.0;
    }
    let e = expm1_f32(2.0 * u);
    return e / (e + 2.0) / u;
}

// ---- GRIN media -----------------------------------------------------------
// n^2 and grad n^2 as (n2, gx, gy, gz).
// CPU twin: src/transport/grin.rs `Medium::n2_grad` (Grid media stay on the CPU).
fn n2_grad(x: vec3<f32>) -> vec4<f32> {
    let a = P.sys.x;
    let b = P.sys.y;
    if (SYSTEM == SYS_LUNEBURG || SYSTEM == SYS_LUNEBURG_CORE) {
        let r2 = x.x * x.x + x.y * x.y + x.z * x.z;
        let rr = a * a;
        if (SYSTEM == SYS_LUNEBURG && !(r2 < rr)) {
            return vec4<f32>(1.0, 0.0, 0.0, 0.0);
        }
        return vec4<f32>(2.0 - r2 / rr, -2.0 * x.x / rr, -2.0 * x.y / rr, -2.0 * x.z / rr);
    } else if (SYSTEM == SYS_FISH_EYE) {
        // a = n0, b = radius.
        let q = (x.x * x.x + x.y * x.y + x.z * x.z) / (b * b);
        let d = 1.0 + q;
        let n2 = a * a / (d * d);
        let k = -4.0 * a * a / (b * b * d * d * d);
        return vec4<f32>(n2, k * x.x, k * x.y, k * x.z);
    } else if (SYSTEM == SYS_FIBRE) {
        // a = n0, b = alpha.
        let a2 = b * b;
        let k = a * a;
        return vec4<f32>(k * (1.0 - a2 * (x.y * x.y + x.z * x.z)), 0.0, -2.0 * k * a2 * x.y, -2.0 * k * a2 * x.z);
    } else {
        // SYS_SECH: a = n0, b = alpha.
        let rho = sqrt(x.y * x.y + x.z * x.z);
        let u = b * rho;
        let sech = 1.0 / cosh(u);
        let n2 = a * a * sech * sech;
        let k = -2.0 * b * b * n2 * tanhc(u);
        return vec4<f32>(n2, 0.0, k * x.y, k * x.z);
    }
}

// ---- spacetimes -----------------------------------------------------------

struct Radial {
    a: f32,
    da: f32,
    b: f32,
    db: f32,
    r2: f32,
    dr2: f32,
}

// A, dA/dr, B, dB/dr, R2, dR2/dr. CPU twin: src/transport/metric.rs
// `Spacetime::radial`.
fn radial(r: f32) -> Radial {
    if (SYSTEM == SYS_SCHWARZSCHILD) {
        let m = P.sys.x;
        let f = 1.0 - 2.0 * m / r;
        let df = 2.0 * m / (r * r);
        return Radial(1.0 / f, -df / (f * f), f, df, r * r, 2.0 * r);
    } else if (SYSTEM == SYS_ELLIS) {
        let b0 = P.sys.x;
        return Radial(1.0, 0.0, 1.0, 0.0, b0 * b0 + r * r, 2.0 * r);
    } else {
        return Radial(1.0, 0.0, 1.0, 0.0, r * r, 2.0 * r);
    }
}

// ---- Kerr (Kerr–Schild) ------------------------------------------------------
// M = P.sys.x, a = P.sys.y (the spin of the spacetime the backward ray is
// integrated in: src/transport/observer.rs `reversed`).

// Boyer–Lindquist radius of a Kerr–Schild point. CPU twin:
// src/transport/kerr.rs `ks_radius`.
fn ks_radius(a: f32, x: f32, y: f32, z: f32) -> f32 {
    let a2z2 = a * a * z * z;
    let w = x * x + y * y + z * z - a * a;
    let s = sqrt(w * w + 4.0 * a2z2);
    if (w >= 0.0) {
        return sqrt(0.5 * (w + s));
    }
    return sqrt(2.0 * a2z2 / (s - w));
}

// (r, f, l . p) at a state: the Boyer–Lindquist radius, the Kerr–Schild
// potential f = 2 M r^3 / (r^4 + a^2 z^2) and the spatial part of l_mu p^mu
// (CPU twins: the first lines of `kerr_h` and `project`).
fn kerr_flp(y: State) -> vec3<f32> {
    let m = P.sys.x;
    let a = P.sys.y;
    let r = ks_radius(a, y[1], y[2], y[3]);
    let r2 = r * r;
    let a2 = a * a;
    let f = 2.0 * m * r2 * r / (r2 * r2 + a2 * y[3] * y[3]);
    let lp = ((r * y[1] + a * y[2]) * y[5] + (r * y[2] - a * y[1]) * y[6]) / (r2 + a2) + y[3] / r * y[7];
    return vec3<f32>(r, f, lp);
}

// H. CPU twin: src/transport/kerr.rs `kerr_h`.
fn kerr_h(y: State) -> f32 {
    let g = kerr_flp(y);
    let l = -y[4] + g.z;
    return 0.5 * (-y[4] * y[4] + y[5] * y[5] + y[6] * y[6] + y[7] * y[7] - g.y * l * l);
}

// Hamilton's equations, line by line as the CPU twin
// src/transport/kerr.rs `kerr_rhs`.
fn kerr_rhs(y: State) -> State {
    let m = P.sys.x;
    let a = P.sys.y;
    let x = y[1];
    let yy = y[2];
    let z = y[3];
    let pt = y[4];
    let px = y[5];
    let py = y[6];
    let pz = y[7];
    let r = ks_radius(a, x, yy, z);
    let r2 = r * r;
    let a2 = a * a;
    let ra2 = r2 + a2;
    let n = r2 * r2 + a2 * z * z;
    let f = 2.0 * m * r2 * r / n;
    let lx = (r * x + a * yy) / ra2;
    let ly = (r * yy - a * x) / ra2;
    let lz = z / r;
    let lpxy = lx * px + ly * py;
    let big_l = -pt + lpxy + lz * pz;
    let r3n = r2 * r / n;
    let rx = x * r3n;
    let ry = yy * r3n;
    let rz = z * r * ra2 / n;
    let k4 = 4.0 * r2 * r / n;
    let fx = f * (3.0 / r - k4) * rx;
    let fy = f * (3.0 / r - k4) * ry;
    let fz = f * ((3.0 / r - k4) * rz - 2.0 * a2 * z / n);
    let q = x * px + yy * py;
    let c = (q - 2.0 * r * lpxy) / ra2 - pz * z / r2;
    let gx = rx * c + (r * px - a * py) / ra2;
    let gy = ry * c + (r * py + a * px) / ra2;
    let gz = rz * c + pz / r;
    let half_l2 = 0.5 * big_l * big_l;
    let fl = f * big_l;
    return State(-pt + fl, px - fl * lx, py - fl * ly, pz - fl * lz, 0.0, half_l2 * fx + fl * gx, half_l2 * fy + fl * gy, half_l2 * fz + fl * gz);
}

// Scales the spatial momenta onto H = 0 keeping E. CPU twin:
// `Hamiltonian for Kerr`, `project`.
fn kerr_project(y: State) -> State {
    var o = y;
    let g = kerr_flp(y);
    let f = g.y;
    let lp = g.z;
    let pt = y[4];
    let qa = y[5] * y[5] + y[6] * y[6] + y[7] * y[7] - f * lp * lp;
    let qb = 2.0 * f * pt * lp;
    let qc = -pt * pt * (1.0 + f);
    let disc = qb * qb - 4.0 * qa * qc;
    if (qa > 0.0 && disc >= 0.0) {
        let k = (-qb + sqrt(disc)) / (2.0 * qa);
        if (k > 0.0 && finite(k)) {
            o[5] = y[5] * k;
            o[6] = y[6] * k;
            o[7] = y[7] * k;
        }
    }
    return o;
}

// (E, L_z, Carter Q) of a state. CPU twin: src/transport/kerr.rs
// `Kerr::constants`.
fn kerr_constants(y: State) -> vec4<f32> {
    let a = P.sys.y;
    let x = y[1];
    let yy = y[2];
    let r = ks_radius(a, x, yy, y[3]);
    let e = -y[4];
    let lz = x * y[6] - yy * y[5];
    let cos_t = y[3] / r;
    let rho = sqrt(x * x + yy * yy);
    let sin_t = rho / sqrt(r * r + a * a);
    var q: f32;
    if (rho > 0.0) {
        let p_th = cos_t / sin_t * (x * y[5] + yy * y[6]) - r * sin_t * y[7];
        q = p_th * p_th + cos_t * cos_t * (lz * lz / (sin_t * sin_t) - a * a * e * e);
    } else {
        let p_th = -r * sin_t * y[7];
        q = p_th * p_th - cos_t * cos_t * a * a * e * e;
    }
    return vec4<f32>(e, lz, q, 0.0);
}

// The certificate update at an accepted state: max |X - X0| / max(|X0|, 1)
// (CPU twin: the `on_step` closure of `trace_kerr`).
fn kerr_drift(o: TraceOut, c0: vec4<f32>, y: State) -> TraceOut {
    var t = o;
    let d = abs(kerr_constants(y) - c0) / max(abs(c0), vec4<f32>(1.0));
    t.e_drift = max(t.e_drift, d.x);
    t.l_drift = max(t.l_drift, d.y);
    t.q_drift = max(t.q_drift, d.z);
    return t;
}

fn is_grin() -> bool {
    return SYSTEM >= SYS_LUNEBURG;
}

// dy/dlambda. CPU twins: src/transport/grin.rs `Medium::rhs`,
// src/transport/metric.rs `Spacetime::rhs`.
fn rhs(y: State) -> State {
    var o: State;
    if (is_grin()) {
        let g = n2_grad(vec3<f32>(y[0], y[1], y[2]));
        o[0] = y[3];
        o[1] = y[4];
        o[2] = y[5];
        o[3] = 0.5 * g.y;
        o[4] = 0.5 * g.z;
        o[5] = 0.5 * g.w;
        return o;
    }
    if (SYSTEM == SYS_KERR) {
        return kerr_rhs(y);
    }
    let c = radial(y[1]);
    let sc = sin_cos_f32(y[2]);
    let s2 = sc.x * sc.x;
    let ang = y[6] * y[6] + y[7] * y[7] / s2;
    let dpr = -0.5 * (-c.da * y[4] * y[4] + c.db * y[5] * y[5]) + 0.5 * c.dr2 * ang / (c.r2 * c.r2);
    let dpth = y[7] * y[7] * sc.y / (c.r2 * s2 * sc.x);
    o[0] = -c.a * y[4];
    o[1] = c.b * y[5];
    o[2] = y[6] / c.r2;
    o[3] = y[7] / (c.r2 * s2);
    o[5] = dpr;
    o[6] = dpth;
    return o;
}

// H(y). CPU twins: `Medium::h`, `Spacetime::h`.
fn ham(y: State) -> f32 {
    if (is_grin()) {
        let g = n2_grad(vec3<f32>(y[0], y[1], y[2]));
        return (y[3] * y[3] + y[4] * y[4] + y[5] * y[5] - g.x) * 0.5;
    }
    if (SYSTEM == SYS_KERR) {
        return kerr_h(y);
    }
    let c = radial(y[1]);
    let s = sin_cos_f32(y[2]).x;
    let ang = (y[6] * y[6] + y[7] * y[7] / (s * s)) / c.r2;
    return (-c.a * y[4] * y[4] + c.b * y[5] * y[5] + ang) * 0.5;
}

// Step-law scale. CPU twins: `Medium::scale` (1), `Spacetime::scale`.
fn scale(y: State) -> f32 {
    if (SYSTEM == SYS_MINKOWSKI) {
        return abs(y[1]);
    } else if (SYSTEM == SYS_SCHWARZSCHILD) {
        return y[1] - 2.0 * P.sys.x;
    } else if (SYSTEM == SYS_ELLIS) {
        return sqrt(P.sys.x * P.sys.x + y[1] * y[1]);
    } else if (SYSTEM == SYS_KERR) {
        return ks_radius(P.sys.y, y[1], y[2], y[3]);
    } else {
        return 1.0;
    }
}

// Back onto H = 0. CPU twins: `Medium::project`, `Spacetime::project`.
fn project(y: State) -> State {
    var o = y;
    if (is_grin()) {
        let n2 = n2_grad(vec3<f32>(y[0], y[1], y[2])).x;
        let p2 = y[3] * y[3] + y[4] * y[4] + y[5] * y[5];
        if (p2 > 0.0 && n2 > 0.0) {
            let s = sqrt(n2 / p2);
            o[3] = y[3] * s;
            o[4] = y[4] * s;
            o[5] = y[5] * s;
        }
        return o;
    }
    if (SYSTEM == SYS_KERR) {
        return kerr_project(y);
    }
    let c = radial(y[1]);
    let s = sin_cos_f32(y[2]).x;
    let spatial = c.b * y[5] * y[5] + (y[6] * y[6] + y[7] * y[7] / (s * s)) / c.r2;
    let time = c.a * y[4] * y[4];
    if (spatial > 0.0 && time > 0.0) {
        let k = sqrt(time / spatial);
        o[5] = y[5] * k;
        o[6] = y[6] * k;
        o[7] = y[7] * k;
    }
    return o;
}

// ---- tiers ------------------------------------------------------------------

// Dormand-Prince 5(4) (src/transport/integrate.rs constants A*, B*, E*).
const A21: f32 = 1.0 / 5.0;
const A31: f32 = 3.0 / 40.0;
const A32: f32 = 9.0 / 40.0;
const A41: f32 = 44.0 / 45.0;
const A42: f32 = -56.0 / 15.0;
const A43: f32 = 32.0 / 9.0;
const A51: f32 = 19372.0 / 6561.0;
const A52: f32 = -25360.0 / 2187.0;
const A53: f32 = 64448.0 / 6561.0;
const A54: f32 = -212.0 / 729.0;
const A61: f32 = 9017.0 / 3168.0;
const A62: f32 = -355.0 / 33.0;
const A63: f32 = 46732.0 / 5247.0;
const A64: f32 = 49.0 / 176.0;
const A65: f32 = -5103.0 / 18656.0;
const B1: f32 = 35.0 / 384.0;
const B3: f32 = 500.0 / 1113.0;
const B4: f32 = 125.0 / 192.0;
const B5: f32 = -2187.0 / 6784.0;
const B6: f32 = 11.0 / 84.0;
const E1: f32 = 71.0 / 57600.0;
const E3: f32 = -71.0 / 16695.0;
const E4: f32 = 71.0 / 1920.0;
const E5: f32 = -17253.0 / 339200.0;
const E6: f32 = 22.0 / 525.0;
const E7: f32 = -1.0 / 40.0;

// y + (c * h) k, slot by slot (CPU twin: `axpy` / one term of `lin`).
fn axpy(y: State, s: f32, k: State) -> State {
    return State(y[0] + s * k[0], y[1] + s * k[1], y[2] + s * k[2], y[3] + s * k[3], y[4] + s * k[4], y[5] + s * k[5], y[6] + s * k[6], y[7] + s * k[7]);
}

fn max_abs(e: State) -> f32 {
    return max(max(max(abs(e[0]), abs(e[1])), max(abs(e[2]), abs(e[3]))), max(max(abs(e[4]), abs(e[5])), max(abs(e[6]), abs(e[7]))));
}

// One classical RK4 step. CPU twin: src/transport/integrate.rs `rk4_step`.
fn rk4_step(y: State, h: f32) -> State {
    let half = 0.5 * h;
    let k1 = rhs(y);
    let k2 = rhs(axpy(y, half, k1));
    let k3 = rhs(axpy(y, half, k2));
    let k4 = rhs(axpy(y, h, k3));
    var o = axpy(y, h / 6.0, k1);
    o = axpy(o, h / 3.0, k2);
    o = axpy(o, h / 3.0, k3);
    return axpy(o, h / 6.0, k4);
}

struct Dp {
    y5: State,
    err: State,
    k7: State,
}

// One Dormand-Prince step from y with k1 = rhs(y): the 5th-order solution,
// the embedded error y5 - y4 and rhs(y5). CPU twin: `dopri5_step`.
fn dopri5_step(y: State, k1: State, h: f32) -> Dp {
    let k2 = rhs(axpy(y, A21 * h, k1));
    let k3 = rhs(axpy(axpy(y, A31 * h, k1), A32 * h, k2));
    let k4 = rhs(axpy(axpy(axpy(y, A41 * h, k1), A42 * h, k2), A43 * h, k3));
    let k5 = rhs(axpy(axpy(axpy(axpy(y, A51 * h, k1), A52 * h, k2), A53 * h, k3), A54 * h, k4));
    let k6 = rhs(axpy(axpy(axpy(axpy(axpy(y, A61 * h, k1), A62 * h, k2), A63 * h, k3), A64 * h, k4), A65 * h, k5));
    let y5 = axpy(axpy(axpy(axpy(axpy(y, B1 * h, k1), B3 * h, k3), B4 * h, k4), B5 * h, k5), B6 * h, k6);
    let k7 = rhs(y5);
    var z: State;
    let err = axpy(axpy(axpy(axpy(axpy(axpy(z, E1 * h, k1), E3 * h, k3), E4 * h, k4), E5 * h, k5), E6 * h, k6), E7 * h, k7);
    return Dp(y5, err, k7);
}

struct Stepped {
    y: State,
    err: f32,
}

// A fixed-law step of the ray's tier (dopri5 tiers: the 5th-order solution
// and its max-norm error estimate). CPU twin: `fixed_step`.
fn fixed_step(y: State, h: f32) -> Stepped {
    if (TIER == TIER_RK4) {
        return Stepped(rk4_step(y, h), 0.0);
    }
    let d = dopri5_step(y, rhs(y), h);
    return Stepped(d.y5, max_abs(d.err));
}

fn law_h(s: f32) -> f32 {
    if (P.law_kind == LAW_FIXED) {
        return P.law.x;
    }
    return min(max(P.law.x * s, P.law.y), P.law.z);
}

// ---- events -----------------------------------------------------------------

// g of event e. CPU twin: src/transport/integrate.rs `Event::g`.
fn ev_g(e: u32, y: State) -> f32 {
    let v = P.ev_val[e];
    if (P.ev_kind[e] == EV_COORD) {
        return y[P.ev_index[e]] - v;
    } else if (P.ev_kind[e] == EV_SPHERE) {
        return y[0] * y[0] + y[1] * y[1] + y[2] * y[2] - v * v;
    } else if (P.ev_kind[e] == EV_KS_RADIUS) {
        return ks_radius(P.sys.y, y[1], y[2], y[3]) - v;
    } else {
        let p = P.ev_pt[e];
        return (y[0] - p.x) * y[3] + (y[1] - p.y) * y[4] + (y[2] - p.z) * y[5];
    }
}

// CPU twin: `Event::fires`.
fn fires(e: u32, g0: f32, g1: f32) -> bool {
    if (P.ev_rising[e] != 0u) {
        return g0 < 0.0 && g1 >= 0.0;
    }
    return g0 > 0.0 && g1 <= 0.0;
}

struct Located {
    theta: f32,
    y: State,
}

// theta in (0, 1] with g(step(y0, theta h)) = 0 by Illinois, given g0, g1 of
// opposite signs. CPU twin: src/transport/integrate.rs `locate`.
fn locate(e: u32, y0: State, h: f32, g0: f32, g1: f32) -> Located {
    let tol = 8.0 * EPS;
    var a = 0.0;
    var fa = g0;
    var b = 1.0;
    var fb = g1;
    var best = Located(1.0, y0);
    for (var it = 0u; it < 100u; it++) {
        var c = b - fb * (b - a) / (fb - fa);
        let lo = min(a, b);
        let hi = max(a, b);
        if (!(c > lo && c < hi) || !finite(c)) {
            c = 0.5 * (a + b);
        }
        var yc = fixed_step(y0, c * h).y;
        if (P.project != 0u) {
            yc = project(yc);
        }
        let fc = ev_g(e, yc);
        best = Located(c, yc);
        if (fc == 0.0 || abs(b - a) <= tol) {
            break;
        }
        if ((fc < 0.0) != (fb < 0.0)) {
            a = b;
            fa = fb;
        } else {
            fa = fa * 0.5;
        }
        b = c;
        fb = fc;
    }
    return best;
}

// ---- the per-ray loop ---------------------------------------------------------

// Squared error of slot k of a DP45 step, scaled (CPU twin: the controller
// sum in `trace`).
fn err_sq(e: f32, y0: f32, y1: f32, rtol: f32) -> f32 {
    let q = e / (P.ctl.z + rtol * max(abs(y0), abs(y1)));
    return q * q;
}

fn gs_of(y: State) -> vec4<f32> {
    return vec4<f32>(ev_g(0u, y), ev_g(1u, y), ev_g(2u, y), ev_g(3u, y));
}

// CPU twin: src/transport/integrate.rs `trace` (no polylines: dumps stay on
// the CPU).
@compute @workgroup_size(64)
fn trace(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= P.n) {
        return;
    }
    var s = rays[i];
    if (s.phase == PHASE_DONE) {
        return;
    }
    var o = s.t;
    var y = o.y;
    if (s.phase == PHASE_FRESH) {
        o.lambda = 0.0;
        o.end_code = END_RUNNING;
        o.steps = 0u;
        o.rejected = 0u;
        o.h_drift = abs(ham(y));
        o.err_est = 0.0;
        o.e_drift = 0.0;
        o.l_drift = 0.0;
        o.q_drift = 0.0;
        s.crossings = 0u;
        if (SYSTEM == SYS_KERR) {
            s.c0 = kerr_constants(y);
        }
        s.gs = gs_of(y);
        if (!all_finite(y)) {
            o.end_code = END_NON_FINITE;
            s.t = o;
            s.phase = PHASE_DONE;
            rays[i] = s;
            return;
        }
        s.h_ctl = 0.0;
        if (TIER == TIER_DP45) {
            s.h_ctl = max(min(P.ctl.w, P.ctl2.y), P.ctl2.x);
        }
        s.k1 = rhs(y);
        s.just_rejected = 0u;
        s.phase = PHASE_RUNNING;
    }
    var gs = s.gs;
    var h_ctl = s.h_ctl;
    var k1 = s.k1;
    var just_rejected = s.just_rejected != 0u;
    var crossings = s.crossings;
    let c0 = s.c0;
    var done = false;
    for (var it = 0u; it < P.chunk; it++) {
        if (o.steps >= P.max_steps) {
            o.end_code = END_MAX_STEPS;
            done = true;
            break;
        }
        var h: f32;
        var y1: State;
        var local_err: f32;
        if (TIER == TIER_DP45) {
            h = max(min(h_ctl, P.ctl.y * scale(y)), P.ctl2.x);
            let rtol = max(P.ctl.x, 8.0 * EPS);
            let d = dopri5_step(y, k1, h);
            var acc = err_sq(d.err[0], y[0], d.y5[0], rtol) + err_sq(d.err[1], y[1], d.y5[1], rtol)
                + err_sq(d.err[2], y[2], d.y5[2], rtol) + err_sq(d.err[3], y[3], d.y5[3], rtol)
                + err_sq(d.err[4], y[4], d.y5[4], rtol) + err_sq(d.err[5], y[5], d.y5[5], rtol);
            if (P.n_dim == 8u) {
                acc += err_sq(d.err[6], y[6], d.y5[6], rtol) + err_sq(d.err[7], y[7], d.y5[7], rtol);
            }
            let err = sqrt(acc / f32(P.n_dim));
            if (!finite(err) || err > 1.0) {
                var f = 0.2;
                if (finite(err)) {
                    f = max(0.9 * pow(err, -0.2), 0.2);
                }
                h_ctl = h * f;
                o.rejected += 1u;
                just_rejected = true;
                if (h_ctl < P.ctl2.x) {
                    o.end_code = END_STEP_UNDERFLOW;
                    done = true;
                    break;
                }
                continue;
            }
            var grow = 5.0;
            if (just_rejected) {
                grow = 1.0;
            }
            var f = grow;
            if (err > 0.0) {
                f = min(max(0.9 * pow(err, -0.2), 0.2), grow);
            }
            h_ctl = max(min(h * f, P.ctl2.y), P.ctl2.x);
            just_rejected = false;
            k1 = d.k7;
            y1 = d.y5;
            local_err = max_abs(d.err);
        } else {
            h = law_h(scale(y));
            let s = fixed_step(y, h);
            y1 = s.y;
            local_err = s.err;
        }
        if (!all_finite(y1)) {
            o.end_code = END_NON_FINITE;
            done = true;
            break;
        }
        if (P.project != 0u) {
            y1 = project(y1);
            if (TIER == TIER_DP45) {
                k1 = rhs(y1);
            }
        }
        o.steps += 1u;
        o.err_est += local_err;
        let g1 = gs_of(y1);
        let fired = vec4<bool>(fires(0u, gs.x, g1.x), fires(1u, gs.y, g1.y), fires(2u, gs.z, g1.z), fires(3u, gs.w, g1.w))
            & (vec4<u32>(0u, 1u, 2u, 3u) < vec4<u32>(P.n_events));
        if (any(fired)) {
            // Earliest event crossed in this step, located (the ray ends
            // here, so this loop runs once per ray).
            var hit = -1;
            var hit_theta = 0.0;
            var hit_y: State;
            for (var e = 0u; e < 4u; e++) {
                if (fired[e]) {
                    let l = locate(e, y, h, gs[e], g1[e]);
                    if (hit < 0 || l.theta < hit_theta) {
                        hit = i32(e);
                        hit_theta = l.theta;
                        hit_y = l.y;
                    }
                }
            }
            y = hit_y;
            o.lambda += hit_theta * h;
            o.h_drift = max(o.h_drift, abs(ham(hit_y)));
            if (SYSTEM == SYS_KERR) {
                o = kerr_drift(o, c0, y);
                // A crossing of z = 0 (events 2, 3) outside the disk: the
                // ray goes on from the plane itself, a fresh trace as on
                // the CPU (controller and events restarted).
                let r = ks_radius(P.sys.y, y[1], y[2], y[3]);
                if (P.sys.w > 0.0 && hit >= 2 && !(r >= P.sys.z && r <= P.sys.w) && crossings < MAX_CROSSINGS) {
                    crossings += 1u;
                    y[3] = 0.0;
                    o.h_drift = max(o.h_drift, abs(ham(y)));
                    o = kerr_drift(o, c0, y);
                    gs = gs_of(y);
                    if (TIER == TIER_DP45) {
                        h_ctl = max(min(P.ctl.w, P.ctl2.y), P.ctl2.x);
                    }
                    k1 = rhs(y);
                    just_rejected = false;
                    continue;
                }
            }
            o.end_code = hit;
            done = true;
            break;
        }
        gs = g1;
        y = y1;
        o.lambda += h;
        o.h_drift = max(o.h_drift, abs(ham(y1)));
        if (SYSTEM == SYS_KERR) {
            o = kerr_drift(o, c0, y1);
        }
    }
    o.y = y;
    s.t = o;
    s.gs = gs;
    s.h_ctl = h_ctl;
    s.k1 = k1;
    s.just_rejected = u32(just_rejected);
    s.crossings = crossings;
    if (done) {
        s.phase = PHASE_DONE;
    }
    rays[i] = s;
}
