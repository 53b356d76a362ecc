// rng.wgsl: the sampler's words and floats over a list of keys (seed, pixel,
// sample, dim): `sampler` 0 = rand_u32 / rand_f32, 1 = the path tracer's
// Sobol' (common.wgsl `sampler_u32`). CPU twin: src/rng.rs `rand_u32`,
// `rand_f32`; src/pathtrace/sampler.rs `Sampler::table`. Parity cases:
// TESTS/gpu/manifest.yaml `gpu_rng_matches_cpu`, `gpu_sobol_matches_cpu`
// (memcmp: bit-identical words and floats).
// Host side: src/gpu/math.rs (struct `TableParams`, keep in sync).

struct TableParams {
    n: u32,
    sampler: u32,
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
    let w = sampler_u32(P.sampler, k.x, k.y, k.z, k.w);
    words[i] = w;
    floats[i] = unit_f32(w);
}
