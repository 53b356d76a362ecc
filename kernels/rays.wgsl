// rays.wgsl: f_ray, one camera ray per pixel of the region, clipped to the box.
// CPU twin: src/rays.rs `f_ray` (camera: src/camera.rs `RealCamera::ray`).
// Parity case: TESTS/gpu/manifest.yaml `gpu_rays_pinhole_parity`,
// `gpu_rays_ortho_parity` (against the CPU f64 rays).
// Host side: src/gpu/rays.rs (struct `RayParams`, keep in sync).

struct RayParams {
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
    // 1 = jittered pixel positions (seed, sample), 0 = pixel centres.
    jitter: u32,
    seed: u32,
    sample: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> P: RayParams;
@group(0) @binding(1) var<storage, read_write> out_o: array<f32>;
@group(0) @binding(2) var<storage, read_write> out_d: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_t0: array<f32>;
@group(0) @binding(4) var<storage, read_write> out_t1: array<f32>;
@group(0) @binding(5) var<storage, read_write> out_pixel: array<u32>;

fn rotate(v: vec3<f32>) -> vec3<f32> {
    return vec3<f32>(
        P.rot0.x * v.x + P.rot0.y * v.y + P.rot0.z * v.z,
        P.rot1.x * v.x + P.rot1.y * v.y + P.rot1.z * v.z,
        P.rot2.x * v.x + P.rot2.y * v.y + P.rot2.z * v.z,
    );
}

const WG: u32 = 64u;

@compute @workgroup_size(64)
fn f_ray(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, WG);
    if (i >= P.n) {
        return;
    }
    let u = P.roi_x + i % P.roi_w;
    let v = P.roi_y + i / P.roi_w;
    let pixel = v * P.width + u;
    var jx = 0.5;
    var jy = 0.5;
    if (P.jitter == 1u) {
        jx = rand_f32(P.seed, pixel, P.sample, 0u);
        jy = rand_f32(P.seed, pixel, P.sample, 1u);
    }
    let px = f32(u) + jx;
    let py = f32(v) + jy;
    let t = vec3<f32>(P.rot0.w, P.rot1.w, P.rot2.w);
    var o: vec3<f32>;
    var d: vec3<f32>;
    if (P.kind == 0u) {
        let dc = vec3<f32>((px - P.model.z) / P.model.x, -(py - P.model.w) / P.model.y, -1.0);
        let dw = rotate(dc);
        let len = sqrt(dw.x * dw.x + dw.y * dw.y + dw.z * dw.z);
        o = t;
        d = dw / len;
    } else {
        let x = -P.model.x + 2.0 * P.model.x * px / P.model.z;
        let y = P.model.y - 2.0 * P.model.y * py / P.model.w;
        o = rotate(vec3<f32>(x, y, 0.0)) + t;
        d = rotate(vec3<f32>(0.0, 0.0, -1.0));
    }
    let tt = clip_aabb(o, d, P.bmin_near.xyz, P.bmax_far.xyz, P.bmin_near.w, P.bmax_far.w);
    out_o[3u * i] = o.x;
    out_o[3u * i + 1u] = o.y;
    out_o[3u * i + 2u] = o.z;
    out_d[3u * i] = d.x;
    out_d[3u * i + 1u] = d.y;
    out_d[3u * i + 2u] = d.z;
    out_t0[i] = tt.x;
    out_t1[i] = tt.y;
    out_pixel[i] = pixel;
}
