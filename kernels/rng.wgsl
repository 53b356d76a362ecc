// rng.wgsl: rand_u32 / rand_f32 over a list of keys (seed, pixel, sample, dim).
// CPU twin: src/rng.rs `rand_u32`, `rand_f32` (the WGSL functions are in
// common.wgsl). Parity case: TESTS/gpu/manifest.yaml `gpu_rng_matches_cpu`
// (memcmp: bit-identical words and floats).
// Host side: src/gpu/math.rs (struct `TableParams`, keep in sync).

struct TableParams {
    n: u32,
    _pad0: u32,
    _pad1: u32,
    _pad2: u32,
}

@group(0) @binding(0) var<uniform> P: TableParams;
@group(0) @binding(1) var<storage, read> keys: array<vec4<u32>>;
@group(0) @binding(2) var<storage, read_write> words: array<u32>;
@group(0) @binding(3) var<storage, read_write> floats: array<f32>;

@compute @workgroup_size(64)
fn rng_table(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let i = linear_id(gid, nwg, 64u);
    if (i >= P.n) {
        return;
    }
    let k = keys[i];
    words[i] = rand_u32(k.x, k.y, k.z, k.w);
    floats[i] = rand_f32(k.x, k.y, k.z, k.w);
}
