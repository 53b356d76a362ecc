// hash_mlp.wgsl: the hash-grid + MLP field on the GPU (issue 19; the
// Instant-NGP multiresolution hash encoding of src/volume/field/hash.rs).
//   f_hash_fill  one thread per sample of an unfused batch: the sample's
//                point from its ray (common.wgsl `camera_ray`) and t, then
//                sigma and rgb from one network evaluation into the packed
//                sample buffers (f_samp_fill leaves them for this pass).
//                CPU twin: src/volume/field/hash.rs `HashMlp::query`
//                (`corners`, `encode`, `mlp`, `head`: the same primes, the
//                same dense-coarse-level rule, corners summed d = 0..8,
//                weights x*y*z, each output b + W_0 h_0 + W_1 h_1 + ... in
//                index order, ReLU hidden, softplus | relu density, sigmoid rgb).
// The network runs one thread per sample, not per ray: a ray of ~100
// samples times ~800 loop back-edges per evaluation would pass Mesa
// llvmpipe's 65535 back-edges per invocation (src/gpu/context.rs
// `max_loop_iterations`); src/gpu/volume_hash.rs bounds one evaluation.
// Parity case: TESTS/volume/manifest_gpu_hash.yaml `gpu_vol_hash_render_parity`
// (GPU f32 vs CPU f64 image), `gpu_vol_hash_encoding_planted_*` in its doc.
// Prepended: common.wgsl, volume.wgsl (bindings 0-11, FIELD_HASH).
// Host side: src/gpu/volume_hash.rs (struct `HashParams`, keep in sync).

const HASH_P1: u32 = 2654435761u;
const HASH_P2: u32 = 805459861u;

struct HashParams {
    bmin: vec4<f32>,
    // 1 / (max - min) per axis.
    inv_ext: vec4<f32>,
    // (levels L, features F, table size T, layers)
    dims: vec4<u32>,
    // (density: 0 softplus, 1 relu; 0, 0, 0)
    misc: vec4<u32>,
    // Level l: N_l as f32 in .x.
    level_n: array<vec4<f32>, 16>,
    // Level l: (N_l - 1, N_l + 1, dense 0 | 1, 0).
    level_u: array<vec4<u32>, 16>,
    // Layer q: (in, out, offset of W, offset of b) in `hparams`.
    layer: array<vec4<u32>, 4>,
}

@group(0) @binding(17) var<uniform> H: HashParams;
// Every parameter, the flat order of HashMlpDesc::flat: tables (L, T, F),
// then per layer W (out, in) row-major and b.
@group(0) @binding(18) var<storage, read> hparams: array<f32>;

// Corner rows and weights of a point on every level (CPU `Corners`).
struct HashCorners {
    rows: array<array<u32, 8>, 16>,
    w: array<array<f32, 8>, 16>,
    f: array<vec3<f32>, 16>,
    // Per axis: the point is inside the box (else its dx is 0).
    free: vec3<bool>,
}

// CPU twin: `HashMlp::corners`.
fn hash_corners(x: vec3<f32>) -> HashCorners {
    var c: HashCorners;
    var p: vec3<f32>;
    for (var a = 0u; a < 3u; a++) {
        let v = (x[a] - H.bmin[a]) * H.inv_ext[a];
        c.free[a] = v >= 0.0 && v <= 1.0;
        p[a] = min(max(v, 0.0), 1.0);
    }
    let tmask = H.dims.z - 1u;
    for (var l = 0u; l < H.dims.x; l++) {
        let n = H.level_n[l].x;
        let lu = H.level_u[l];
        var i0: vec3<u32>;
        for (var a = 0u; a < 3u; a++) {
            let u = p[a] * n;
            let b = min(u32(max(floor(u), 0.0)), lu.x);
            i0[a] = b;
            c.f[l][a] = u - f32(b);
        }
        let f = c.f[l];
        let base = l * H.dims.z;
        for (var d = 0u; d < 8u; d++) {
            let o = vec3<u32>(d & 1u, (d >> 1u) & 1u, (d >> 2u) & 1u);
            let ci = i0 + o;
            var e: u32;
            if (lu.z == 1u) {
                e = ci.x + lu.y * (ci.y + lu.y * ci.z);
            } else {
                e = (ci.x ^ (ci.y * HASH_P1) ^ (ci.z * HASH_P2)) & tmask;
            }
            c.rows[l][d] = base + e;
            let wx = select(1.0 - f.x, f.x, o.x == 1u);
            let wy = select(1.0 - f.y, f.y, o.y == 1u);
            let wz = select(1.0 - f.z, f.z, o.z == 1u);
            c.w[l][d] = wx * wy * wz;
        }
    }
    return c;
}

// The encoding h[l F + q] (CPU twin: `HashMlp::encode`).
fn hash_encode(c: ptr<function, HashCorners>, h: ptr<function, array<f32, 64>>) {
    let nf = H.dims.y;
    for (var l = 0u; l < H.dims.x; l++) {
        for (var q = 0u; q < nf; q++) {
            var s = 0.0;
            for (var d = 0u; d < 8u; d++) {
                s += (*c).w[l][d] * hparams[(*c).rows[l][d] * nf + q];
            }
            (*h)[l * nf + q] = s;
        }
    }
}

// The network on h, keeping every layer's pre-activation in z[q]; the four
// raw outputs (CPU twin: `HashMlp::mlp`).
fn hash_mlp(h: ptr<function, array<f32, 64>>, z: ptr<function, array<array<f32, 64>, 4>>) -> vec4<f32> {
    var cur = *h;
    let nl = H.dims.w;
    for (var q = 0u; q < nl; q++) {
        let ly = H.layer[q];
        for (var o = 0u; o < ly.y; o++) {
            let row = ly.z + o * ly.x;
            var s = hparams[ly.w + o];
            for (var i = 0u; i < ly.x; i++) {
                s += hparams[row + i] * cur[i];
            }
            (*z)[q][o] = s;
        }
        if (q + 1u < nl) {
            for (var o = 0u; o < ly.y; o++) {
                cur[o] = max((*z)[q][o], 0.0);
            }
        }
    }
    let zl = (*z)[nl - 1u];
    return vec4<f32>(zl[0], zl[1], zl[2], zl[3]);
}

// ln(1 + x) for x in [0, 1] to f32 rounding (no WGSL builtin).
fn log1p_f32(x: f32) -> f32 {
    let u = 1.0 + x;
    if (u == 1.0) {
        return x;
    }
    return log(u) * (x / (u - 1.0));
}

fn hash_sigmoid(x: f32) -> f32 {
    return 1.0 / (1.0 + exp(-x));
}

// (sigma, rgb) of the raw outputs (CPU twin: `HashMlp::head`).
fn hash_head(o: vec4<f32>) -> vec4<f32> {
    var sigma: f32;
    if (H.misc.x == 1u) {
        sigma = max(o.x, 0.0);
    } else {
        sigma = max(o.x, 0.0) + log1p_f32(exp(-abs(o.x)));
    }
    return vec4<f32>(sigma, hash_sigmoid(o.y), hash_sigmoid(o.z), hash_sigmoid(o.w));
}

// (sigma, rgb) at x (CPU twin: `HashMlp::query`).
fn hash_query(x: vec3<f32>) -> vec4<f32> {
    var c = hash_corners(x);
    var h: array<f32, 64>;
    hash_encode(&c, &h);
    var z: array<array<f32, 64>, 4>;
    return hash_head(hash_mlp(&h, &z));
}

@compute @workgroup_size(64)
fn f_hash_fill(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let m = linear_id(gid, nwg, 64u);
    if (m >= off[V.ray_count]) {
        return;
    }
    let s0 = samp0[m];
    let ray = camera_ray(C, bitcast<u32>(s0.w));
    let v = hash_query(ray.o + s0.x * ray.d);
    samp0[m].z = v.x;
    samp1[m] = vec4<f32>(v.yzw, samp1[m].w);
}
