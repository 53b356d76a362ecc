// expm1.wgsl: expm1_f32 (common.wgsl) and alpha_of over a list of arguments.
// CPU twin: f32::exp_m1 / f64::exp_m1 (libm), used by the volume
// integrator's alpha = -expm1(-sigma dt). Parity case:
// TESTS/gpu/manifest.yaml `gpu_expm1_rel_err` (relative error against f64).
// Host side: src/gpu/math.rs (struct `TableParams`, keep in sync).

struct TableParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> P: TableParams;
@group(0) @binding(1) var<storage, read> xs: array<f32>;
@group(0) @binding(2) var<storage, read_write> ys: array<f32>;

@compute @workgroup_size(64)
fn expm1_table(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= P.n) {
        return;
    }
    ys[i] = expm1_f32(xs[i]);
}
