// pathtrace.wgsl: the path tracer's GPU twin (SCENES.md "Cornell box with three spheres").
// Entry point `pt_render`: one invocation per pixel runs `P.samples` paths
// (samples P.sample0 ..) and folds them into the pixel's running mean and
// M2 (Welford), so a render is a sequence of short submits (progressive).
// CPU twin: src/pathtrace/integrator.rs `render` (per pixel: `pixel_sums`,
// per path: `trace`, light sampling: `sample_light`); materials
// src/pathtrace/bsdf.rs `Material::{eval, pdf, sample}`; shapes
// src/pathtrace/shapes.rs `sphere_t`, `quad_t`, `intersect`, `occluded`,
// `spawn_origin`. The same random numbers: src/pathtrace/sampler.rs
// (`P.sampler`: rand(seed, pixel, sample, dim) or the padded Sobol') with
// the dimensions of sampler.rs `dims`.
// Parity case: TESTS/pathtrace/manifest_gpu.yaml `pt_gpu_cpu_parity_cornell`
// (per-pixel z-test, Sidak), `pt_gpu_furnace_*`, `pt_gpu_rmse_ratio_*`,
// `pt_gpu_render_deterministic`, `pt_gpu_cpu_parity_sobol`.
// Host side: src/gpu/pathtrace.rs (structs `PtShape`, `PtMaterial`,
// `PtParams`, keep in sync).

// Shape kinds (src/pathtrace/shapes.rs `Shape`).
const SHAPE_SPHERE: u32 = 0u;
const SHAPE_QUAD: u32 = 1u;
// Material kinds (src/pathtrace/bsdf.rs `Material`).
const MAT_LAMBERTIAN: u32 = 0u;
const MAT_CONDUCTOR: u32 = 1u;
const MAT_DIELECTRIC: u32 = 2u;
const MAT_EMITTER: u32 = 3u;
// src/pathtrace/shapes.rs OFFSET_REL.
const OFFSET_REL: f32 = 2e-5;
const PI: f32 = 3.14159265358979323846;
const FRAC_1_PI: f32 = 0.318309886183790671538;
// src/pathtrace/sampler.rs `dims` (LIGHT_V = LIGHT_U + 1, BSDF_V = BSDF_U + 1:
// drawn as pairs by `rnd2`).
const DIM_FIRST_VERTEX: u32 = 2u;
const DIM_STRIDE: u32 = 8u;
const DIM_LIGHT_CHOICE: u32 = 0u;
const DIM_LIGHT_U: u32 = 1u;
const DIM_LOBE: u32 = 3u;
const DIM_BSDF_U: u32 = 4u;
const DIM_ROULETTE: u32 = 6u;

// 112 bytes. Sphere: a = (centre, radius). Quad: a = (corner, area), u, v
// edges, n the unit normal, ua / vb the dual edge vectors, axis 0..2 when
// the normal is +-e_axis (else 3).
struct PtShape {
    a: vec4<f32>,
    u: vec4<f32>,
    v: vec4<f32>,
    n: vec4<f32>,
    ua: vec4<f32>,
    vb: vec4<f32>,
    kind: u32,
    material: u32,
    axis: u32,
    _pad: u32,
}

// 32 bytes. c.rgb: albedo, reflectance or radiance; c.w: GGX alpha or IOR.
struct PtMaterial {
    c: vec4<f32>,
    kind: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

// 208 bytes.
struct PtParams {
    cam: CamParams,
    env: vec4<f32>,
    seed: u32,
    max_bounces: u32,
    rr_depth: u32,
    n_shapes: u32,
    n_lights: u32,
    sample0: u32,
    samples: u32,
    pixel0: u32,
    pixels: u32,
    // 0 = independent, 1 = Sobol' (src/pathtrace/sampler.rs `Sampler`).
    sampler: u32,
    // Russian roulette's survival q = min(rr_scale max(beta eta^2), rr_cap):
    // integrator.rs `survival`, its RR_SCALE and RR_CAP passed in.
    rr_scale: f32,
    rr_cap: f32,
}

@group(0) @binding(0) var<uniform> P: PtParams;
@group(0) @binding(1) var<storage, read> shapes: array<PtShape>;
@group(0) @binding(2) var<storage, read> materials: array<PtMaterial>;
@group(0) @binding(3) var<storage, read> lights: array<u32>;
// Per pixel two vec4: (running mean rgb, non-finite samples), (M2 rgb, 0).
@group(0) @binding(4) var<storage, read_write> accum: array<vec4<f32>>;

// ---- small helpers -----------------------------------------------------------

// x's sign bit applied to 1 (Rust f32::copysign(1.0, x)).
fn sign_bit1(x: f32) -> f32 {
    return select(1.0, -1.0, (bitcast<u32>(x) & 0x80000000u) != 0u);
}

// bsdf.rs `sign`: -1 for x < 0, else 1.
fn sgn(x: f32) -> f32 {
    return select(1.0, -1.0, x < 0.0);
}

fn finite(x: f32) -> bool {
    return (bitcast<u32>(x) & 0x7f800000u) != 0x7f800000u;
}

fn comp(v: vec3<f32>, k: u32) -> f32 {
    if (k == 0u) {
        return v.x;
    }
    if (k == 1u) {
        return v.y;
    }
    return v.z;
}

// sampler.rs `PathRng`: independent key = pcg(pk ^ sample), Sobol' pixel
// key pk = pcg(pcg(seed) ^ pixel) and the sample index.
struct Rng {
    key: u32,
    pk: u32,
    index: u32,
}

// sampler.rs `PathRng::f` for a 1-D dimension.
fn rnd(r: Rng, dim: u32) -> f32 {
    if (P.sampler == 1u) {
        return unit_f32(sobol1(r.pk, r.index, dim));
    }
    return unit_f32(pcg(r.key ^ dim));
}

// sampler.rs `PathRng::f2`: dimensions dim and dim + 1 (a Sobol' pair).
fn rnd2(r: Rng, dim: u32) -> vec2<f32> {
    if (P.sampler == 1u) {
        let w = sobol2(r.pk, r.index, dim);
        return vec2<f32>(unit_f32(w.x), unit_f32(w.y));
    }
    return vec2<f32>(unit_f32(pcg(r.key ^ dim)), unit_f32(pcg(r.key ^ (dim + 1u))));
}

// integrator.rs `power`.
fn power(a: f32, b: f32) -> f32 {
    let a2 = a * a;
    let b2 = b * b;
    if (a2 + b2 > 0.0) {
        return a2 / (a2 + b2);
    }
    return 0.0;
}

// ---- shapes (shapes.rs) ------------------------------------------------------

// shapes.rs `sphere_t`; -1 on a miss.
fn sphere_t(c: vec3<f32>, radius: f32, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> f32 {
    let f = o - c;
    let b = -dot(f, d);
    let r2 = radius * radius;
    let cc = dot(f, f) - r2;
    if (cc > 0.0 && b < 0.0) {
        return -1.0;
    }
    let l = f + b * d;
    let disc = r2 - dot(l, l);
    if (disc < 0.0) {
        return -1.0;
    }
    let q = b + sqrt(disc) * sign_bit1(b);
    var t0 = 0.0;
    var t1 = 0.0;
    if (q != 0.0) {
        t0 = cc / q;
        t1 = q;
    }
    let lo = min(t0, t1);
    let hi = max(t0, t1);
    if (lo > 0.0 && lo < tmax) {
        return lo;
    }
    if (hi > 0.0 && hi < tmax) {
        return hi;
    }
    return -1.0;
}

// shapes.rs `quad_t`; -1 on a miss.
fn quad_t(s: PtShape, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> f32 {
    var t: f32;
    if (s.axis < 3u) {
        let dk = comp(d, s.axis);
        if (dk == 0.0) {
            return -1.0;
        }
        t = (comp(s.a.xyz, s.axis) - comp(o, s.axis)) / dk;
    } else {
        let dn = dot(d, s.n.xyz);
        if (dn == 0.0) {
            return -1.0;
        }
        t = dot(s.a.xyz - o, s.n.xyz) / dn;
    }
    if (!(t > 0.0 && t < tmax)) {
        return -1.0;
    }
    let h = o + t * d - s.a.xyz;
    let a = dot(h, s.ua.xyz);
    let b = dot(h, s.vb.xyz);
    if (a >= 0.0 && a <= 1.0 && b >= 0.0 && b <= 1.0) {
        return t;
    }
    return -1.0;
}

fn hit_t(s: PtShape, o: vec3<f32>, d: vec3<f32>, tmax: f32) -> f32 {
    if (s.kind == SHAPE_SPHERE) {
        return sphere_t(s.a.xyz, s.a.w, o, d, tmax);
    }
    return quad_t(s, o, d, tmax);
}

struct Hit {
    t: f32,
    idx: i32,
}

// shapes.rs `intersect`: nearest hit in (0, tmax); idx -1 on a miss.
fn intersect(o: vec3<f32>, d: vec3<f32>, tmax: f32) -> Hit {
    var h = Hit(tmax, -1);
    for (var i = 0u; i < P.n_shapes; i++) {
        let t = hit_t(shapes[i], o, d, h.t);
        if (t > 0.0) {
            h = Hit(t, i32(i));
        }
    }
    return h;
}

// shapes.rs `occluded`.
fn occluded(o: vec3<f32>, d: vec3<f32>, tmax: f32) -> bool {
    for (var i = 0u; i < P.n_shapes; i++) {
        if (hit_t(shapes[i], o, d, tmax) > 0.0) {
            return true;
        }
    }
    return false;
}

// shapes.rs `spawn_origin`.
fn spawn_origin(p: vec3<f32>, n: vec3<f32>, w: vec3<f32>) -> vec3<f32> {
    let ap = abs(p);
    let eps = OFFSET_REL * (1.0 + max(ap.x, max(ap.y, ap.z)));
    if (dot(w, n) >= 0.0) {
        return p + eps * n;
    }
    return p - eps * n;
}

// ---- frame and materials (bsdf.rs) -------------------------------------------

struct Frame {
    t: vec3<f32>,
    b: vec3<f32>,
    n: vec3<f32>,
}

// bsdf.rs `Frame::new` (Duff et al. 2017).
fn make_frame(n: vec3<f32>) -> Frame {
    let s = sign_bit1(n.z);
    let a = -1.0 / (s + n.z);
    let b = n.x * n.y * a;
    return Frame(
        vec3<f32>(1.0 + s * n.x * n.x * a, s * b, -s * n.x),
        vec3<f32>(b, s + n.y * n.y * a, -n.y),
        n,
    );
}

fn to_local(f: Frame, v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(dot(v, f.t), dot(v, f.b), dot(v, f.n));
}

fn to_world(f: Frame, v: vec3<f32>) -> vec3<f32> {
    return v.x * f.t + v.y * f.b + v.z * f.n;
}

// bsdf.rs `ggx_d`.
fn ggx_d(cos_h: f32, alpha: f32) -> f32 {
    if (cos_h <= 0.0) {
        return 0.0;
    }
    let a2 = alpha * alpha;
    let k = cos_h * cos_h * (a2 - 1.0) + 1.0;
    return a2 / (PI * k * k);
}

// bsdf.rs `smith_g1`.
fn smith_g1(cos: f32, alpha: f32) -> f32 {
    let c = abs(cos);
    let a2 = alpha * alpha;
    return 2.0 * c / (c + sqrt(a2 + (1.0 - a2) * c * c));
}

// bsdf.rs `fresnel_dielectric`: (F, cos_t).
fn fresnel_dielectric(c: f32, eta: f32) -> vec2<f32> {
    let sin2_t = (1.0 - c * c) / (eta * eta);
    if (sin2_t >= 1.0) {
        return vec2<f32>(1.0, 0.0);
    }
    let ct = sqrt(1.0 - sin2_t);
    let rs = (c - eta * ct) / (c + eta * ct);
    let rp = (eta * c - ct) / (eta * c + ct);
    return vec2<f32>(0.5 * (rs * rs + rp * rp), ct);
}

// bsdf.rs `cosine_hemisphere`.
fn cosine_hemisphere(u0: f32, u1: f32) -> vec3<f32> {
    let r = sqrt(u0);
    let phi = 2.0 * PI * u1;
    return vec3<f32>(r * cos(phi), r * sin(phi), sqrt(max(1.0 - u0, 0.0)));
}

// bsdf.rs `sample_ggx_vndf` (Heitz 2018, listing 1).
fn sample_ggx_vndf(wo: vec3<f32>, alpha: f32, u0: f32, u1: f32) -> vec3<f32> {
    let vh = normalize(vec3<f32>(alpha * wo.x, alpha * wo.y, wo.z));
    let lensq = vh.x * vh.x + vh.y * vh.y;
    var t1 = vec3<f32>(1.0, 0.0, 0.0);
    if (lensq > 0.0) {
        t1 = vec3<f32>(-vh.y, vh.x, 0.0) / sqrt(lensq);
    }
    let t2 = cross(vh, t1);
    let r = sqrt(u0);
    let phi = 2.0 * PI * u1;
    let p1 = r * cos(phi);
    let s = 0.5 * (1.0 + vh.z);
    let p2 = (1.0 - s) * sqrt(max(1.0 - p1 * p1, 0.0)) + s * r * sin(phi);
    let nh = p1 * t1 + p2 * t2 + sqrt(max(1.0 - p1 * p1 - p2 * p2, 0.0)) * vh;
    return normalize(vec3<f32>(alpha * nh.x, alpha * nh.y, max(nh.z, 0.0)));
}

// bsdf.rs `Material::eval`.
fn mat_eval(m: PtMaterial, wo: vec3<f32>, wi: vec3<f32>) -> vec3<f32> {
    if (wo.z * wi.z <= 0.0) {
        return vec3<f32>(0.0);
    }
    if (m.kind == MAT_LAMBERTIAN) {
        return m.c.rgb * FRAC_1_PI;
    }
    if (m.kind == MAT_CONDUCTOR) {
        let o = abs(wo.z);
        let i = abs(wi.z);
        let hs = wo + wi;
        let h = normalize(vec3<f32>(hs.x, hs.y, abs(hs.z)));
        let alpha = m.c.w;
        return m.c.rgb * (ggx_d(h.z, alpha) * smith_g1(o, alpha) * smith_g1(i, alpha) / (4.0 * o * i));
    }
    return vec3<f32>(0.0);
}

// bsdf.rs `Material::pdf`.
fn mat_pdf(m: PtMaterial, wo: vec3<f32>, wi: vec3<f32>) -> f32 {
    if (m.kind == MAT_LAMBERTIAN) {
        if (wo.z * wi.z <= 0.0) {
            return 0.0;
        }
        return abs(wi.z) * FRAC_1_PI;
    }
    if (m.kind == MAT_CONDUCTOR) {
        let s = sgn(wo.z);
        let o = wo * s;
        let i = wi * s;
        let hs = o + i;
        if (o.z <= 0.0 || dot(hs, hs) == 0.0) {
            return 0.0;
        }
        let h = normalize(hs);
        if (h.z <= 0.0 || dot(o, h) <= 0.0) {
            return 0.0;
        }
        let alpha = m.c.w;
        return smith_g1(o.z, alpha) * ggx_d(h.z, alpha) / (4.0 * o.z);
    }
    return 0.0;
}

// bsdf.rs `BsdfSample`; ok = false where `sample` returns None.
struct BsdfSample {
    wi: vec3<f32>,
    weight: vec3<f32>,
    pdf: f32,
    delta: bool,
    eta2: f32,
    ok: bool,
}

// bsdf.rs `Material::sample`.
fn mat_sample(m: PtMaterial, wo: vec3<f32>, u_lobe: f32, u0: f32, u1: f32) -> BsdfSample {
    var r = BsdfSample(vec3<f32>(0.0), vec3<f32>(0.0), 0.0, false, 1.0, false);
    if (m.kind == MAT_LAMBERTIAN) {
        let l = cosine_hemisphere(u0, u1);
        r.wi = vec3<f32>(l.x, l.y, l.z * sgn(wo.z));
        r.weight = m.c.rgb;
        r.pdf = l.z * FRAC_1_PI;
        r.ok = true;
    } else if (m.kind == MAT_CONDUCTOR) {
        let s = sgn(wo.z);
        let o = wo * s;
        if (o.z <= 0.0) {
            return r;
        }
        let alpha = m.c.w;
        let h = sample_ggx_vndf(o, alpha, u0, u1);
        let i = 2.0 * dot(o, h) * h - o;
        if (i.z <= 0.0) {
            return r;
        }
        r.pdf = smith_g1(o.z, alpha) * ggx_d(h.z, alpha) / (4.0 * o.z);
        r.weight = m.c.rgb * smith_g1(i.z, alpha);
        r.wi = i * s;
        r.ok = true;
    } else if (m.kind == MAT_DIELECTRIC) {
        let c = abs(wo.z);
        var eta = 1.0 / m.c.w;
        if (wo.z > 0.0) {
            eta = m.c.w;
        }
        let fc = fresnel_dielectric(c, eta);
        r.delta = true;
        r.ok = true;
        if (u_lobe < fc.x) {
            r.wi = vec3<f32>(-wo.x, -wo.y, wo.z);
            r.weight = vec3<f32>(1.0);
        } else {
            r.wi = vec3<f32>(-wo.x / eta, -wo.y / eta, -sgn(wo.z) * fc.y);
            r.weight = vec3<f32>(1.0 / (eta * eta));
            r.eta2 = eta * eta;
        }
    }
    return r;
}

// ---- the integrator (integrator.rs) ------------------------------------------

// integrator.rs `sample_light`: f |cos_i| Le w_l / p_l (without beta).
fn sample_light(p: vec3<f32>, n: vec3<f32>, fr: Frame, wo: vec3<f32>, m: PtMaterial, key: Rng, base: u32) -> vec3<f32> {
    let nl = P.n_lights;
    let pick = min(u32(rnd(key, base + DIM_LIGHT_CHOICE) * f32(nl)), nl - 1u);
    let q = shapes[lights[pick]];
    if (q.kind != SHAPE_QUAD) {
        return vec3<f32>(0.0);
    }
    let em = materials[q.material];
    if (em.kind != MAT_EMITTER) {
        return vec3<f32>(0.0);
    }
    let uv = rnd2(key, base + DIM_LIGHT_U);
    let x = q.a.xyz + uv.x * q.u.xyz + uv.y * q.v.xyz;
    let to = x - p;
    let dist2 = dot(to, to);
    if (dist2 == 0.0) {
        return vec3<f32>(0.0);
    }
    let wi = to / sqrt(dist2);
    let cos_l = -dot(wi, q.n.xyz);
    if (cos_l <= 0.0) {
        return vec3<f32>(0.0);
    }
    let wl = to_local(fr, wi);
    let f = mat_eval(m, wo, wl);
    if (all(f == vec3<f32>(0.0))) {
        return vec3<f32>(0.0);
    }
    let o = spawn_origin(p, n, wi);
    if (occluded(o, wi, length(x - o) * (1.0 - 1e-4))) {
        return vec3<f32>(0.0);
    }
    let pl = dist2 / (cos_l * q.a.w * f32(nl));
    let w = power(pl, mat_pdf(m, wo, wl));
    return f * (abs(wl.z) * w / pl) * em.c.rgb;
}

// integrator.rs `trace`: radiance along the camera ray o + t d.
fn trace(o_in: vec3<f32>, d_in: vec3<f32>, key: Rng) -> vec3<f32> {
    var o = o_in;
    var d = d_in;
    var l = vec3<f32>(0.0);
    var beta = vec3<f32>(1.0);
    var eta2 = 1.0;
    var prev_pdf = 0.0;
    var prev_delta = true;
    var bounces = 0u;
    loop {
        let h = intersect(o, d, 3.0e38);
        if (h.idx < 0) {
            l += beta * P.env.rgb;
            break;
        }
        let sh = shapes[u32(h.idx)];
        let m = materials[sh.material];
        var p = o + h.t * d;
        var n = sh.n.xyz;
        if (sh.kind == SHAPE_SPHERE) {
            let rv = p - sh.a.xyz;
            n = rv / length(rv);
            p = sh.a.xyz + n * sh.a.w;
        }
        let fr = make_frame(n);
        let wo = to_local(fr, -d);
        if (m.kind == MAT_EMITTER) {
            if (wo.z > 0.0) {
                var w = 1.0;
                if (sh.kind == SHAPE_QUAD && !prev_delta) {
                    w = power(prev_pdf, h.t * h.t / (wo.z * sh.a.w * f32(P.n_lights)));
                }
                l += beta * m.c.rgb * w;
            }
            break;
        }
        if (bounces >= P.max_bounces) {
            break;
        }
        let base = DIM_FIRST_VERTEX + DIM_STRIDE * bounces;
        if (m.kind != MAT_DIELECTRIC && P.n_lights > 0u) {
            l += beta * sample_light(p, n, fr, wo, m, key, base);
        }
        let ub = rnd2(key, base + DIM_BSDF_U);
        let s = mat_sample(m, wo, rnd(key, base + DIM_LOBE), ub.x, ub.y);
        if (!s.ok) {
            break;
        }
        beta *= s.weight;
        eta2 *= s.eta2;
        prev_pdf = s.pdf;
        prev_delta = s.delta;
        d = normalize(to_world(fr, s.wi));
        o = spawn_origin(p, n, d);
        bounces += 1u;
        if (bounces >= P.rr_depth) {
            let be = beta * eta2;
            // CPU twin: integrator.rs `survival`.
            let q = min(P.rr_scale * max(be.x, max(be.y, be.z)), P.rr_cap);
            if (!(rnd(key, base + DIM_ROULETTE) < q)) {
                break;
            }
            beta /= q;
        }
    }
    return l;
}

// CPU twin: src/pathtrace/integrator.rs `render` / `pixel_sums` (f64 sums
// there; a Welford mean and M2 in f32 here). Parity cases: see the header.
@compute @workgroup_size(64)
fn pt_render(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let j = linear_id(gid, nwg, 64u);
    if (j >= P.pixels) {
        return;
    }
    let pixel = P.pixel0 + j;
    let a0 = accum[2u * pixel];
    var mean = a0.xyz;
    var bad = a0.w;
    var m2 = accum[2u * pixel + 1u].xyz;
    for (var k = 0u; k < P.samples; k++) {
        let s = P.sample0 + k;
        var c = P.cam;
        c.sample = s;
        let r = camera_ray(c, pixel);
        let pk = pcg(pcg(P.seed) ^ pixel);
        var l = trace(r.o, r.d, Rng(pcg(pk ^ s), pk, s));
        if (!(finite(l.x) && finite(l.y) && finite(l.z))) {
            bad += 1.0;
            l = vec3<f32>(0.0);
        }
        let delta = l - mean;
        mean += delta / f32(s + 1u);
        m2 += delta * (l - mean);
    }
    accum[2u * pixel] = vec4<f32>(mean, bad);
    accum[2u * pixel + 1u] = vec4<f32>(m2, 0.0);
}
