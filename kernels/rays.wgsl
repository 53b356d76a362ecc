// rays.wgsl: f_ray, one camera ray per pixel of the region, clipped to the box.
// CPU twin: src/rays.rs `f_ray` (camera: src/camera.rs `RealCamera::ray`);
// the per-ray code is common.wgsl `camera_ray`.
// Parity case: TESTS/gpu/manifest.yaml `gpu_rays_pinhole_parity`,
// `gpu_rays_ortho_parity`, `gpu_rays_roi_jitter_parity` (against CPU f64).
// Host side: src/gpu/rays.rs (struct `RayParams` = common.wgsl `CamParams`).

@group(0) @binding(0) var<uniform> P: CamParams;
@group(0) @binding(1) var<storage, read_write> out_o: array<f32>;
@group(0) @binding(2) var<storage, read_write> out_d: array<f32>;
@group(0) @binding(3) var<storage, read_write> out_t0: array<f32>;
@group(0) @binding(4) var<storage, read_write> out_t1: array<f32>;
@group(0) @binding(5) var<storage, read_write> out_pixel: array<u32>;

@compute @workgroup_size(64)
fn f_ray(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= P.n) {
        return;
    }
    let r = camera_ray(P, i);
    out_o[3u * i] = r.o.x;
    out_o[3u * i + 1u] = r.o.y;
    out_o[3u * i + 2u] = r.o.z;
    out_d[3u * i] = r.d.x;
    out_d[3u * i + 1u] = r.d.y;
    out_d[3u * i + 2u] = r.d.z;
    out_t0[i] = r.t0;
    out_t1[i] = r.t1;
    out_pixel[i] = r.pixel;
}
