// volume_diff.wgsl: f_diff, the emission-absorption backward pass (issue 19).
//   f_diff_ray   one thread per ray of an unfused batch: walks the ray's
//                persisted samples (f_samp_fill, f_int) back to front in the
//                log domain, scatters dL/dsigma and dL/dc into the grids (or
//                the constant/slab parameters and the constant colour), and
//                reduces dL/d(pose) over the workgroup in a fixed tree.
//                CPU twin: src/volume/diff/mod.rs `backward_ray` with
//                src/volume/diff/walk.rs `ray_grads` (same formulas, same
//                back-to-front order, Kahan sums where the CPU has them).
// Reductions into grid nodes are bit-deterministic: every value is a 64-bit
// two's-complement fixed-point number (two atomic<u32> words, carry by hand)
// scaled by a power of two chosen on the host from a bound of the sum, so
// integer addition makes the result independent of thread order. The fast
// path (D.float_atomic = 1) adds f32 by compare-exchange instead: its order,
// and so its rounding, varies from run to run; it is measured against the
// fixed-point path (src/gpu/volume_diff.rs). CPU twins of the encoding:
// src/gpu/volume_diff.rs `fx_split` and `fx_value`.
//   f_diff_hash  one thread per sample of a batch of a hash-grid + MLP field,
//                between two f_diff_ray passes (D.hash_stage 0: the walk
//                stores each sample's dL/d(sigma, rgb) in `sgrad`; 1: it reads
//                the sample's dL/dx back for the pose): back-propagates
//                through the network and the encoding, adds dL/d(parameters)
//                with the same fixed-point reduction (one value a parameter,
//                table entries and weights alike) and writes dL/dx.
//                CPU twin: src/volume/field/hash_grad.rs `HashMlp::backward`.
// Prepended: common.wgsl, volume.wgsl (fields, lattice, bindings 0-11),
// hash_mlp.wgsl (the network, bindings 17-18).
// Parity cases: TESTS/volume/manifest_gpu_diff.yaml `gpu_vol_grad_*`;
// f_diff_hash: TESTS/volume/manifest_gpu_hash.yaml `gpu_vol_hash_grad_*`.
// Host side: src/gpu/volume_diff.rs (struct `DiffParams`, keep in sync).

struct DiffParams {
    // Rows of the camera-to-world rotation and its centre (SCENES.md pose).
    pose_r0: vec4<f32>,
    pose_r1: vec4<f32>,
    pose_r2: vec4<f32>,
    pose_c: vec4<f32>,
    // The clip box, as f_ray clips (near in bmin.w, far in bmax.w).
    bmin: vec4<f32>,
    bmax: vec4<f32>,
    // Fixed-point scales (powers of two) of density and colour values.
    fx_sigma: f32,
    fx_color: f32,
    // Value offsets into `acc` (two words a value): density grid nodes,
    // colour grid nodes x 3, constant/slab parameters, constant colour x 3,
    // then one flag value (bit 0: a non-finite or overflowing gradient).
    off_sigma: u32,
    off_color: u32,
    off_param: u32,
    off_ccol: u32,
    off_flags: u32,
    float_atomic: u32,
    // Workgroup index of this batch's first workgroup in dcam_part.
    part_base: u32,
    // Hash field: value offset of its parameters, their scale, the stage.
    off_hash: u32,
    fx_hash: f32,
    hash_stage: u32,
}

@group(0) @binding(12) var<uniform> D: DiffParams;
// Upstream gradients, two per ray of the region: (dL/dr, dL/dg, dL/db,
// dL/d depth) and (dL/d opacity, 0, 0, 0).
@group(0) @binding(13) var<storage, read> up: array<vec4<f32>>;
@group(0) @binding(14) var<storage, read_write> acc: array<atomic<u32>>;
// Per workgroup: its rays' summed dL/d(rho, w) (6 of 8 slots).
@group(0) @binding(15) var<storage, read_write> dcam_part: array<f32>;
// Hash field, per sample of the batch: (dL/dsigma, dL/dc) after stage 0,
// (dL/dx, 0) after f_diff_hash.
@group(0) @binding(19) var<storage, read_write> sgrad: array<vec4<f32>>;

// ---- deterministic accumulation -------------------------------------------

const FX_LIMIT: f32 = 0x1p62f;

fn flag_bad() {
    atomicOr(&acc[2u * D.off_flags], 1u);
}

// Adds v * scale, truncated toward zero, to the 64-bit value in words
// (acc[w], acc[w + 1]) = (low, high). CPU twin: `fx_split`.
fn fx_add(w: u32, v: f32, scale: f32) {
    let a = v * scale;
    if (a == 0.0) {
        return;
    }
    let m = abs(a);
    if (!(m < FX_LIMIT)) {
        flag_bad();
        return;
    }
    let hi_m = floor(m * 0x1p-32f);
    var lo = u32(m - hi_m * 0x1p32f);
    var hi = u32(hi_m);
    if (a < 0.0) {
        hi = ~hi + select(0u, 1u, lo == 0u);
        lo = ~lo + 1u;
    }
    let old = atomicAdd(&acc[w], lo);
    let carry = select(0u, 1u, old + lo < old);
    atomicAdd(&acc[w + 1u], hi + carry);
}

// The fast path: f32 addition by compare-exchange on the low word.
fn f32_atomic_add(w: u32, v: f32) {
    if (v != v || abs(v) > 3.0e38) {
        flag_bad();
        return;
    }
    var old = atomicLoad(&acc[w]);
    loop {
        let r = atomicCompareExchangeWeak(&acc[w], old, bitcast<u32>(bitcast<f32>(old) + v));
        if (r.exchanged) {
            break;
        }
        old = r.old_value;
    }
}

fn grad_add(value: u32, v: f32, scale: f32) {
    if (D.float_atomic == 1u) {
        f32_atomic_add(2u * value, v);
    } else {
        fx_add(2u * value, v, scale);
    }
}

// ---- field derivatives (src/volume/diff/field_grad.rs) ----------------------

struct Cell {
    base: vec3<i32>,
    f: vec3<f32>,
    ds: vec3<f32>,
    ok: bool,
}

// The trilinear cell of x (`cell_of`): the same operations as `tri_setup`.
fn cell_of(x: vec3<f32>, bmin: vec3<f32>, scale: vec3<f32>, n: vec4<u32>) -> Cell {
    var c: Cell;
    c.ok = true;
    c.ds = scale;
    for (var a = 0u; a < 3u; a++) {
        let u = (x[a] - bmin[a]) * scale[a];
        let top = f32(n[a] - 1u);
        if (n.w == 1u) {
            let cl = min(max(u, 0.0), top);
            let fl = min(floor(cl), f32(n[a] - 2u));
            c.base[a] = i32(fl);
            c.f[a] = cl - fl;
            if (u < 0.0 || u > top) {
                c.ds[a] = 0.0;
            }
        } else {
            let fl = floor(u);
            if (fl < -1.0 || fl > top) {
                c.ok = false;
                return c;
            }
            c.f[a] = u - fl;
            c.base[a] = i32(fl);
        }
    }
    return c;
}

// Flat node of corner d (bit a = offset on axis a), -1 outside (`corner_node`).
fn corner_node(c: Cell, n: vec4<u32>, d: u32) -> i32 {
    let i = c.base.x + i32(d & 1u);
    let j = c.base.y + i32((d >> 1u) & 1u);
    let k = c.base.z + i32((d >> 2u) & 1u);
    if (i < 0 || j < 0 || k < 0 || i >= i32(n.x) || j >= i32(n.y) || k >= i32(n.z)) {
        return -1;
    }
    return (k * i32(n.y) + j) * i32(n.x) + i;
}

fn corner_weight(f: vec3<f32>, d: u32) -> f32 {
    let wx = select(1.0 - f.x, f.x, (d & 1u) == 1u);
    let wy = select(1.0 - f.y, f.y, ((d >> 1u) & 1u) == 1u);
    let wz = select(1.0 - f.z, f.z, ((d >> 2u) & 1u) == 1u);
    return wx * wy * wz;
}

// d(corner weight)/d(frac) along axis a, times ds[a] (`grid_grad`'s factor).
fn corner_dweight(c: Cell, d: u32, a: u32) -> f32 {
    var dw = select(-1.0, 1.0, ((d >> a) & 1u) == 1u);
    for (var b = 0u; b < 3u; b++) {
        if (b != a) {
            dw *= select(1.0 - c.f[b], c.f[b], ((d >> b) & 1u) == 1u);
        }
    }
    return dw * c.ds[a];
}

// grad of the density grid at the cell (`grid_grad::<_, 1>`), and the
// scatter of dsigma into its eight nodes.
fn sgrid_backward(c: Cell, dsigma: f32) -> vec3<f32> {
    let n = V.sg_n;
    var out = vec3<f32>(0.0);
    for (var d = 0u; d < 8u; d++) {
        let node = corner_node(c, n, d);
        if (node < 0) {
            continue;
        }
        let v = sgrid[node];
        for (var a = 0u; a < 3u; a++) {
            out[a] += v * corner_dweight(c, d, a);
        }
        grad_add(D.off_sigma + u32(node), corner_weight(c.f, d) * dsigma, D.fx_sigma);
    }
    return out;
}

// J_c^T dcolor of the colour grid (`grid_grad::<_, 3>`), and the scatter of
// dcolor into its eight nodes.
fn cgrid_backward(c: Cell, dcolor: vec3<f32>) -> vec3<f32> {
    let n = V.cg_n;
    var out = vec3<f32>(0.0);
    for (var d = 0u; d < 8u; d++) {
        let node = corner_node(c, n, d);
        if (node < 0) {
            continue;
        }
        let b = u32(node) * 3u;
        let v = dcolor.x * cgrid[b] + dcolor.y * cgrid[b + 1u] + dcolor.z * cgrid[b + 2u];
        for (var a = 0u; a < 3u; a++) {
            out[a] += v * corner_dweight(c, d, a);
        }
        let w = corner_weight(c.f, d);
        for (var ch = 0u; ch < 3u; ch++) {
            grad_add(D.off_color + b + ch, w * dcolor[ch], D.fx_color);
        }
    }
    return out;
}

// grad sigma of the analytic fields (`sigma_grad`); 0 where piecewise constant.
fn sigma_grad_analytic(x: vec3<f32>) -> vec3<f32> {
    switch V.field_kind {
        case FIELD_GAUSSIAN: {
            let dx = x - V.field_b.xyz;
            let s = V.field_a.x * exp(-(dx.x * dx.x + dx.y * dx.y + dx.z * dx.z) * V.field_a.y);
            return -2.0 * V.field_a.y * s * dx;
        }
        case FIELD_LINEAR: {
            if (V.field_a.x + V.field_b.x * x.x + V.field_b.y * x.y + V.field_b.z * x.z > 0.0) {
                return V.field_b.xyz;
            }
            return vec3<f32>(0.0);
        }
        default: {
            return vec3<f32>(0.0);
        }
    }
}

// Parameter of the constant / slab density at x (`param_index`), or -1.
fn param_index(x: vec3<f32>) -> i32 {
    if (V.field_kind == FIELD_CONSTANT) {
        return 0;
    }
    if (V.field_kind == FIELD_SLABS) {
        let v = x[V.slab_axis];
        let n = V.slab_n;
        for (var i = 0u; i < n; i++) {
            if (slabs[i] <= v && (v < slabs[i + 1u] || (i + 1u == n && v <= slabs[n]))) {
                return i32(i);
            }
        }
    }
    return -1;
}

// ---- camera (src/volume/diff/camera.rs) --------------------------------------

struct Planes {
    t0: f32,
    t1: f32,
    m0: vec3<bool>,
    m1: vec3<bool>,
}

// The active clip planes of t0 and t1 (`clip_planes`).
fn clip_planes(o: vec3<f32>, d: vec3<f32>) -> Planes {
    let near = D.bmin.w;
    let far = D.bmax.w;
    var lo = near;
    var hi = far;
    var e0 = vec3<f32>(0.0);
    var e1 = vec3<f32>(0.0);
    for (var a = 0u; a < 3u; a++) {
        if (d[a] == 0.0) {
            continue;
        }
        let inv = 1.0 / d[a];
        let ta = (D.bmin[a] - o[a]) * inv;
        let tb = (D.bmax[a] - o[a]) * inv;
        e0[a] = min(ta, tb);
        e1[a] = max(ta, tb);
        lo = max(lo, e0[a]);
        hi = min(hi, e1[a]);
    }
    var p: Planes;
    p.t0 = lo;
    p.t1 = hi;
    for (var a = 0u; a < 3u; a++) {
        p.m0[a] = d[a] != 0.0 && lo != near && e0[a] == lo;
        p.m1[a] = d[a] != 0.0 && hi != far && e1[a] == hi;
    }
    return p;
}

// R^T v.
fn pose_rt(v: vec3<f32>) -> vec3<f32> {
    return D.pose_r0.xyz * v.x + D.pose_r1.xyz * v.y + D.pose_r2.xyz * v.z;
}

fn count3(m: vec3<bool>) -> f32 {
    return f32(select(0u, 1u, m.x) + select(0u, 1u, m.y) + select(0u, 1u, m.z));
}

// ---- the per-ray walk ----------------------------------------------------------

struct CamGrad {
    rho: vec3<f32>,
    w: vec3<f32>,
}

// Ray j of the batch, back to front (`backward_ray` + `ray_grads`).
fn ray_grads(j: u32) -> CamGrad {
    let i = V.ray_base + j;
    let ray = camera_ray(C, i);
    let ro = ray_out[i];
    let u0 = up[2u * i];
    let g = u0.xyz;
    let gd = u0.w;
    let go = up[2u * i + 1u].x;
    let tn = trans_of_log(ro.log_trans);
    var s = vec2<f32>(tn * (g.x * V.background.x + g.y * V.background.y + g.z * V.background.z), 0.0);
    let got = go * tn;
    var lt_next = ro.log_trans;
    var gox = vec2<f32>(0.0);
    var goy = vec2<f32>(0.0);
    var goz = vec2<f32>(0.0);
    var gdx = vec2<f32>(0.0);
    var gdy = vec2<f32>(0.0);
    var gdz = vec2<f32>(0.0);
    var dl_t0 = vec2<f32>(0.0);
    var dl_t1 = vec2<f32>(0.0);
    let lo = off[j];
    for (var q = ro.n; q > 0u; q--) {
        let m = lo + q - 1u;
        let s0 = samp0[m];
        let s1 = samp1[m];
        let pe = persist[m];
        let t = s0.x;
        let dt = s0.y;
        let sigma = s0.z;
        let c = s1.xyz;
        let k = bitcast<u32>(s1.w);
        let t_next = trans_of_log(lt_next);
        let w = trans_of_log(pe.y) * pe.x;
        let e = g.x * c.x + g.y * c.y + g.z * c.z + gd * t;
        let dtau = t_next * e - s.x + got;
        let dsigma = dtau * dt;
        let dcolor = g * w;
        let x = ray.o + t * ray.d;
        var gs = vec3<f32>(0.0);
        var gc = vec3<f32>(0.0);
        if (V.field_kind == FIELD_HASH) {
            if (D.hash_stage == 0u) {
                sgrad[m] = vec4<f32>(dsigma, dcolor);
            } else {
                gc = sgrad[m].xyz;
            }
        } else if (V.field_kind == FIELD_GRID) {
            let cs = cell_of(x, V.sg_bmin.xyz, V.sg_scale.xyz, V.sg_n);
            if (cs.ok) {
                gs = sgrid_backward(cs, dsigma);
            }
        } else {
            gs = sigma_grad_analytic(x);
            let p = param_index(x);
            if (p >= 0) {
                grad_add(D.off_param + u32(p), dsigma, D.fx_sigma);
            }
        }
        if (V.color_grid == 1u) {
            let cc = cell_of(x, V.cg_bmin.xyz, V.cg_scale.xyz, V.cg_n);
            if (cc.ok) {
                gc = cgrid_backward(cc, dcolor);
            }
        } else if (V.field_kind != FIELD_HASH) {
            for (var ch = 0u; ch < 3u; ch++) {
                grad_add(D.off_ccol + ch, dcolor[ch], D.fx_color);
            }
        }
        let gx = dsigma * gs + gc;
        gox = kahan(gox, gx.x);
        goy = kahan(goy, gx.y);
        goz = kahan(goz, gx.z);
        gdx = kahan(gdx, t * gx.x);
        gdy = kahan(gdy, t * gx.y);
        gdz = kahan(gdz, t * gx.z);
        let dl_tpos = gx.x * ray.d.x + gx.y * ray.d.y + gx.z * ray.d.z + gd * w;
        let dl_dt = dtau * sigma;
        if (ray.t0 + f32(k + 1u) * V.dt > ray.t1) {
            var u = 0.5;
            if (V.stratified == 1u) {
                u = rand_f32(V.seed, ray.pixel, 0u, k);
            }
            dl_t0 = kahan(dl_t0, dl_tpos * (1.0 - u) - dl_dt);
            dl_t1 = kahan(dl_t1, dl_tpos * u + dl_dt);
        } else {
            dl_t0 = kahan(dl_t0, dl_tpos);
        }
        s = kahan(s, w * e);
        lt_next = pe.y;
    }
    var go_sum = vec3<f32>(gox.x, goy.x, goz.x);
    var gd_sum = vec3<f32>(gdx.x, gdy.x, gdz.x);
    if (ro.n > 0u) {
        let p = clip_planes(ray.o, ray.d);
        let n0 = count3(p.m0);
        let n1 = count3(p.m1);
        for (var a = 0u; a < 3u; a++) {
            if (p.m0[a]) {
                let share = dl_t0.x / n0;
                go_sum[a] -= share / ray.d[a];
                gd_sum[a] -= share * p.t0 / ray.d[a];
            }
            if (p.m1[a]) {
                let share = dl_t1.x / n1;
                go_sum[a] -= share / ray.d[a];
                gd_sum[a] -= share * p.t1 / ray.d[a];
            }
        }
    }
    var out: CamGrad;
    out.rho = pose_rt(go_sum);
    out.w = pose_rt(cross(ray.o - D.pose_c.xyz, go_sum) + cross(ray.d, gd_sum));
    return out;
}

var<workgroup> wg_cam: array<array<f32, 6>, 64>;

@compute @workgroup_size(64)
fn f_diff_ray(
    @builtin(global_invocation_id) gid: vec3<u32>,
    @builtin(num_workgroups) nwg: vec3<u32>,
    @builtin(local_invocation_index) lid: u32,
    @builtin(workgroup_id) wid: vec3<u32>,
) {
    let j = linear_id(gid, nwg, 64u);
    var cam = array<f32, 6>(0.0, 0.0, 0.0, 0.0, 0.0, 0.0);
    if (j < V.ray_count) {
        let r = ray_grads(j);
        cam = array<f32, 6>(r.rho.x, r.rho.y, r.rho.z, r.w.x, r.w.y, r.w.z);
    }
    wg_cam[lid] = cam;
    workgroupBarrier();
    for (var stride = 32u; stride > 0u; stride = stride >> 1u) {
        if (lid < stride) {
            for (var q = 0u; q < 6u; q++) {
                wg_cam[lid][q] += wg_cam[lid + stride][q];
            }
        }
        workgroupBarrier();
    }
    let w = wid.x + wid.y * nwg.x;
    if (lid == 0u && w * 64u < V.ray_count) {
        for (var q = 0u; q < 6u; q++) {
            dcam_part[8u * (D.part_base + w) + q] = wg_cam[0][q];
        }
    }
}

// ---- the hash-grid + MLP field ---------------------------------------------

fn hash_add(i: u32, v: f32) {
    grad_add(D.off_hash + i, v, D.fx_hash);
}

// Adds dL/d(parameters) of g = dL/d(sigma, rgb) at x; returns dL/dx.
// CPU twin: src/volume/field/hash_grad.rs `HashMlp::backward` (same loops,
// same order; rows whose dL/dz is 0 add nothing and are skipped).
fn hash_backward(x: vec3<f32>, g: vec4<f32>) -> vec3<f32> {
    var c = hash_corners(x);
    var h: array<f32, 64>;
    hash_encode(&c, &h);
    var z: array<array<f32, 64>, 4>;
    let o = hash_mlp(&h, &z);
    var dz: array<f32, 64>;
    if (H.misc.x == 1u) {
        dz[0] = select(0.0, g.x, o.x > 0.0);
    } else {
        dz[0] = g.x * hash_sigmoid(o.x);
    }
    for (var ch = 1u; ch < 4u; ch++) {
        let s = hash_sigmoid(o[ch]);
        dz[ch] = g[ch] * s * (1.0 - s);
    }
    var dh: array<f32, 64>;
    for (var qq = H.dims.w; qq > 0u; qq--) {
        let q = qq - 1u;
        let ly = H.layer[q];
        var a: array<f32, 64>;
        if (q == 0u) {
            a = h;
        } else {
            for (var i = 0u; i < ly.x; i++) {
                a[i] = max(z[q - 1u][i], 0.0);
            }
        }
        dh = array<f32, 64>();
        for (var r = 0u; r < ly.y; r++) {
            let d = dz[r];
            if (d == 0.0) {
                continue;
            }
            let row = ly.z + r * ly.x;
            for (var i = 0u; i < ly.x; i++) {
                hash_add(row + i, d * a[i]);
                dh[i] += hparams[row + i] * d;
            }
            hash_add(ly.w + r, d);
        }
        if (q > 0u) {
            dz = array<f32, 64>();
            for (var i = 0u; i < ly.x; i++) {
                if (z[q - 1u][i] > 0.0) {
                    dz[i] = dh[i];
                }
            }
        }
    }
    let nf = H.dims.y;
    var gx = vec3<f32>(0.0);
    for (var l = 0u; l < H.dims.x; l++) {
        let f = c.f[l];
        let n = H.level_n[l].x;
        for (var d = 0u; d < 8u; d++) {
            let row = c.rows[l][d] * nf;
            var v = 0.0;
            for (var q = 0u; q < nf; q++) {
                let dhq = dh[l * nf + q];
                hash_add(row + q, c.w[l][d] * dhq);
                v += hparams[row + q] * dhq;
            }
            for (var a = 0u; a < 3u; a++) {
                if (!c.free[a]) {
                    continue;
                }
                var dw = select(-1.0, 1.0, ((d >> a) & 1u) == 1u);
                for (var b = 0u; b < 3u; b++) {
                    if (b != a) {
                        dw *= select(1.0 - f[b], f[b], ((d >> b) & 1u) == 1u);
                    }
                }
                gx[a] += v * dw * n * H.inv_ext[a];
            }
        }
    }
    return gx;
}

@compute @workgroup_size(64)
fn f_diff_hash(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let m = linear_id(gid, nwg, 64u);
    if (m >= off[V.ray_count]) {
        return;
    }
    let g = sgrad[m];
    if (all(g == vec4<f32>(0.0))) {
        return;
    }
    let s0 = samp0[m];
    let ray = camera_ray(C, bitcast<u32>(s0.w));
    sgrad[m] = vec4<f32>(hash_backward(ray.o + s0.x * ray.d, g), 0.0);
}
