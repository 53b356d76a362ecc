// voxel_attrs.wgsl: decode of the per-leaf voxel attributes (colour and unit
// normal) stored by src/voxels/attributes.rs, one invocation per ray, f32.
// CPU twin: src/voxels/attributes.rs `Attributes::decode` (entry
// `decode_attrs`; helpers twin `decode_plain`, src/voxels/dxt.rs
// `decode_colour`, `decode_normal`, `oct_decode`, `from_frame`,
// `channel_value`, `get_bits`), operation for operation.
// Parity case: src/gpu/voxel_attrs.rs test
// `gpu_attribute_decode_equals_the_cpu_decode_on_every_leaf` (plain and
// DXT, every leaf of a depth-8 sphere: the bound it allows, for a driver
// that contracts a * b + c into an FMA, is stated there).
// Host side: src/gpu/voxel_attrs.rs (`AttrParams` = `AttrParams` here,
// `GpuAttr` = `Attr`).
//
// Layout on the GPU: plain attribute i = words 2i (bits 0..32 of the CPU's
// 48-bit value) and 2i + 1 (bits 32..48); DXT block b = colour words 2b,
// 2b + 1 and normal words 5b .. 5b + 5, as in src/voxels/dxt.rs. An index
// at or past `leaves` (a coarse LOD stop, the DAG's u32::MAX) decodes to
// `valid = 0` and zeros.

// Keep in sync with src/gpu/voxel_attrs.rs `AttrParams` (16 bytes).
struct AttrParams {
    n: u32,
    // 1: plain, 2: DXT (src/voxels/attributes.rs `AttrForm`).
    form: u32,
    leaves: u32,
    _pad: u32,
}

// Keep in sync with src/gpu/voxel_attrs.rs `GpuAttr` (32 bytes).
struct Attr {
    colour: vec3<f32>,
    valid: u32,
    normal: vec3<f32>,
    _pad: u32,
}

@group(0) @binding(0) var<uniform> P: AttrParams;
@group(0) @binding(1) var<storage, read> attr_idx: array<u32>;
@group(0) @binding(2) var<storage, read> plain: array<u32>;
@group(0) @binding(3) var<storage, read> dxt_colour: array<u32>;
@group(0) @binding(4) var<storage, read> dxt_normal: array<u32>;
@group(0) @binding(5) var<storage, read_write> out_attrs: array<Attr>;

fn sgn1(x: f32) -> f32 {
    if x < 0.0 {
        return -1.0;
    }
    return 1.0;
}

fn oct_decode(e: vec2<f32>) -> vec3<f32> {
    let z = 1.0 - abs(e.x) - abs(e.y);
    var x = e.x;
    var y = e.y;
    if z < 0.0 {
        x = (1.0 - abs(e.y)) * sgn1(e.x);
        y = (1.0 - abs(e.x)) * sgn1(e.y);
    }
    let l = sqrt(x * x + y * y + z * z);
    return vec3<f32>(x / l, y / l, z / l);
}

fn decode_plain(i: u32) -> Attr {
    let lo = plain[2u * i];
    let hi = plain[2u * i + 1u];
    var a: Attr;
    a.colour = vec3<f32>(f32(lo & 0xFFu), f32((lo >> 8u) & 0xFFu), f32((lo >> 16u) & 0xFFu)) / 255.0;
    let u = (lo >> 24u) | ((hi & 0xFu) << 8u);
    let v = (hi >> 4u) & 0xFFFu;
    a.normal = oct_decode(vec2<f32>(f32(u) / 4095.0 * 2.0 - 1.0, f32(v) / 4095.0 * 2.0 - 1.0));
    return a;
}

fn expand565(c: u32) -> vec3<f32> {
    return vec3<f32>(f32((c >> 11u) & 31u) / 31.0, f32((c >> 5u) & 63u) / 63.0, f32(c & 31u) / 31.0);
}

fn decode_colour(b: u32, s: u32) -> vec3<f32> {
    let w0 = dxt_colour[2u * b];
    let k = (dxt_colour[2u * b + 1u] >> (2u * s)) & 3u;
    let a = expand565(w0 & 0xFFFFu);
    let c = expand565(w0 >> 16u);
    switch k {
        case 0u: { return a; }
        case 1u: { return c; }
        case 2u: { return (2.0 * a + 1.0 * c) / 3.0; }
        default: { return (1.0 * a + 2.0 * c) / 3.0; }
    }
}

// Bits at .. at + n (n <= 12) of block b's 160-bit normal string.
fn get_bits(b: u32, at: u32, n: u32) -> u32 {
    let w = 5u * b + at / 32u;
    let s = at % 32u;
    var v = dxt_normal[w] >> s;
    if s + n > 32u {
        v = v | (dxt_normal[w + 1u] << (32u - s));
    }
    return v & ((1u << n) - 1u);
}

fn endpoint(e: u32) -> f32 {
    return f32(e) / 4095.0 * 2.0 - 1.0;
}

fn channel_value(b: u32, at: u32, s: u32) -> f32 {
    let e0 = endpoint(get_bits(b, at, 12u));
    let e1 = endpoint(get_bits(b, at + 12u, 12u));
    let k = f32(get_bits(b, at + 24u + 3u * s, 3u));
    return e0 + (e1 - e0) * k / 7.0;
}

fn from_frame(m: vec3<f32>, f: u32) -> vec3<f32> {
    let a = f % 3u;
    var s = 1.0;
    if f >= 3u {
        s = -1.0;
    }
    var n = vec3<f32>(0.0);
    n[(a + 1u) % 3u] = m.x;
    n[(a + 2u) % 3u] = m.y;
    n[a] = s * m.z;
    return n;
}

fn decode_normal(b: u32, s: u32) -> vec3<f32> {
    let f = get_bits(b, 0u, 3u);
    let m = oct_decode(vec2<f32>(channel_value(b, 3u, s), channel_value(b, 75u, s)));
    return from_frame(m, f);
}

@compute @workgroup_size(64)
fn decode_attrs(@builtin(global_invocation_id) gid: vec3<u32>, @builtin(num_workgroups) nwg: vec3<u32>) {
    let r = linear_id(gid, nwg, 64u);
    if r >= P.n {
        return;
    }
    let i = attr_idx[r];
    var a: Attr;
    a.colour = vec3<f32>(0.0);
    a.normal = vec3<f32>(0.0);
    a.valid = 0u;
    if i < P.leaves {
        if P.form == 1u {
            a = decode_plain(i);
        } else {
            let b = i / 16u;
            let s = i % 16u;
            a.colour = decode_colour(b, s);
            a.normal = decode_normal(b, s);
        }
        a.valid = 1u;
    }
    a._pad = 0u;
    out_attrs[r] = a;
}
