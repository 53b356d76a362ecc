//! Block compression of per-leaf attributes (seed 003's DXT attributes).
//!
//! # Blocks
//!
//! Leaves are grouped by attribute index: block `b` holds leaves
//! `16 b .. 16 b + 16`, slot `i % 16`. The octree numbers leaves in
//! pre-order, so consecutive indices are spatial neighbours (siblings, then
//! cousins), as in ESVO's attachment blocks. This is the block scheme
//! instead of 4x4x4 spatial blocks because a surface voxelisation fills
//! about a quarter of a 4^3 cube: spatial blocks would spend index bits on
//! empty voxels or need an occupancy mask per block, and a leaf finds its
//! block with one shift from the index the cast already returns.
//!
//! # Colour: 64 bits per 16 leaves (DXT1 / BC1 opaque mode)
//!
//! `w[0]` = endpoint c0 (RGB565: r in bits 11..16, g 5..11, b 0..5) |
//! c1 << 16; `w[1]` bits `2s .. 2s + 2` = slot s's index k. Endpoints expand
//! as `r5 / 31`, `g6 / 63`, `b5 / 31`; the palette is always the four
//! colours `c0, c1, (2 c0 + c1) / 3, (c0 + 2 c1) / 3` (no 3-colour mode),
//! computed in f32.
//!
//! # Normal: 160 bits per 16 leaves (BC5-like, in a per-block frame)
//!
//! A 160-bit little-endian bit string over `w[0..5]` (bit `b` is bit
//! `b % 32` of word `b / 32`): bits 0..3 the frame `f` (axis `f % 3` and
//! its sign, `-` when `f >= 3`, is the block's "up": the axis of the
//! largest mean component), then two channels (u at bit 3, v at bit 75) of
//! 72 bits each: endpoints e0, e1 (12 bits each, value `e / 4095 * 2 - 1`)
//! and 16 3-bit indices k (value `e0 + (e1 - e0) k / 7`). (u, v) is the
//! octahedral encoding ([`oct_encode`]) of the normal written in the frame
//! (up = +z'), so the normals of a block sit in the continuous upper half of
//! the octahedral square, away from its folds. Decoding is pure arithmetic
//! on the words ([`decode_colour`], [`decode_normal`]): the GPU twin is a
//! transcription.

/// Leaves per block.
pub const BLOCK: usize = 16;
/// Words of a colour block and of a normal block.
pub const COLOUR_WORDS: usize = 2;
pub const NORMAL_WORDS: usize = 5;

/// Octahedral encoding of a unit vector: (u, v) in [-1, 1]^2.
pub fn oct_encode(n: [f64; 3]) -> [f64; 2] {
    let s = n[0].abs() + n[1].abs() + n[2].abs();
    if s == 0.0 {
        return [0.0, 0.0];
    }
    let p = n.map(|x| x / s);
    let sg = |x: f64| if x < 0.0 { -1.0 } else { 1.0 };
    if p[2] >= 0.0 {
        [p[0], p[1]]
    } else {
        [(1.0 - p[1].abs()) * sg(p[0]), (1.0 - p[0].abs()) * sg(p[1])]
    }
}

/// Inverse of [`oct_encode`] (normalised).
pub fn oct_decode(e: [f32; 2]) -> [f32; 3] {
    let z = 1.0 - e[0].abs() - e[1].abs();
    let sg = |x: f32| if x < 0.0 { -1.0 } else { 1.0 };
    let (x, y) = if z < 0.0 {
        ((1.0 - e[1].abs()) * sg(e[0]), (1.0 - e[0].abs()) * sg(e[1]))
    } else {
        (e[0], e[1])
    };
    let l = (x * x + y * y + z * z).sqrt();
    [x / l, y / l, z / l]
}

fn expand565(c: u32) -> [f32; 3] {
    [
        (c >> 11 & 31) as f32 / 31.0,
        (c >> 5 & 63) as f32 / 63.0,
        (c & 31) as f32 / 31.0,
    ]
}

fn pack565(c: [f64; 3]) -> u32 {
    let q = |x: f64, m: f64| (x.clamp(0.0, 1.0) * m).round() as u32;
    q(c[0], 31.0) << 11 | q(c[1], 63.0) << 5 | q(c[2], 31.0)
}

fn palette(w0: u32) -> [[f32; 3]; 4] {
    let (a, b) = (expand565(w0 & 0xFFFF), expand565(w0 >> 16));
    let mix = |s: f32, t: f32| [0, 1, 2].map(|i| (s * a[i] + t * b[i]) / 3.0);
    [a, b, mix(2.0, 1.0), mix(1.0, 2.0)]
}

/// Colour of slot `s` of a colour block.
pub fn decode_colour(w: &[u32], s: usize) -> [f32; 3] {
    palette(w[0])[(w[1] >> (2 * s) & 3) as usize]
}

fn sq(a: [f32; 3], b: [f64; 3]) -> f64 {
    (0..3).map(|i| (a[i] as f64 - b[i]).powi(2)).sum()
}

/// Best indices for endpoints `w0` and their squared error.
fn fit_indices(w0: u32, cs: &[[f64; 3]]) -> (u32, f64) {
    let p = palette(w0);
    let (mut idx, mut err) = (0u32, 0.0);
    for (s, c) in cs.iter().enumerate() {
        let (k, e) = (0..4)
            .map(|k| (k, sq(p[k], *c)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
            .unwrap_or((0, 0.0));
        idx |= (k as u32) << (2 * s);
        err += e;
    }
    (idx, err)
}

/// Least-squares endpoints for fixed indices (weights of c0: 1, 0, 2/3, 1/3).
fn refit(idx: u32, cs: &[[f64; 3]]) -> Option<([f64; 3], [f64; 3])> {
    let wa = [1.0, 0.0, 2.0 / 3.0, 1.0 / 3.0];
    let (mut aa, mut ab, mut bb) = (0.0, 0.0, 0.0);
    let (mut ax, mut bx) = ([0.0; 3], [0.0; 3]);
    for (s, c) in cs.iter().enumerate() {
        let a = wa[(idx >> (2 * s) & 3) as usize];
        let b = 1.0 - a;
        aa += a * a;
        ab += a * b;
        bb += b * b;
        for i in 0..3 {
            ax[i] += a * c[i];
            bx[i] += b * c[i];
        }
    }
    let det = aa * bb - ab * ab;
    if det.abs() < 1e-12 {
        return None;
    }
    let c0 = [0, 1, 2].map(|i| (bb * ax[i] - ab * bx[i]) / det);
    let c1 = [0, 1, 2].map(|i| (aa * bx[i] - ab * ax[i]) / det);
    Some((c0, c1))
}

/// Compresses up to 16 colours (components in [0, 1]): endpoints from the
/// extremes along the principal axis, then two least-squares refits; the
/// candidate with the least squared error wins.
pub fn encode_colour(cs: &[[f64; 3]]) -> [u32; 2] {
    let n = cs.len().max(1) as f64;
    let mean = [0, 1, 2].map(|i| cs.iter().map(|c| c[i]).sum::<f64>() / n);
    let mut cov = [[0.0; 3]; 3];
    for c in cs {
        for i in 0..3 {
            for j in 0..3 {
                cov[i][j] += (c[i] - mean[i]) * (c[j] - mean[j]);
            }
        }
    }
    let mut axis = [1.0, 1.0, 1.0];
    for _ in 0..8 {
        let v = [0, 1, 2].map(|i| (0..3).map(|j| cov[i][j] * axis[j]).sum::<f64>());
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        if l < 1e-300 {
            break;
        }
        axis = v.map(|x| x / l);
    }
    let proj = |c: &[f64; 3]| (0..3).map(|i| (c[i] - mean[i]) * axis[i]).sum::<f64>();
    let lo = cs.iter().map(proj).fold(0.0, f64::min);
    let hi = cs.iter().map(proj).fold(0.0, f64::max);
    let at = |t: f64| [0, 1, 2].map(|i| mean[i] + t * axis[i]);
    let mut w0 = pack565(at(hi)) | pack565(at(lo)) << 16;
    let (mut idx, mut err) = fit_indices(w0, cs);
    for _ in 0..2 {
        let Some((c0, c1)) = refit(idx, cs) else {
            break;
        };
        let cand = pack565(c0) | pack565(c1) << 16;
        let (i2, e2) = fit_indices(cand, cs);
        if e2 >= err {
            break;
        }
        (w0, idx, err) = (cand, i2, e2);
    }
    [w0, idx]
}

fn get_bits(w: &[u32], at: usize, n: usize) -> u32 {
    let lo = w[at / 32] as u64 | (*w.get(at / 32 + 1).unwrap_or(&0) as u64) << 32;
    ((lo >> (at % 32)) & ((1u64 << n) - 1)) as u32
}

fn put_bits(w: &mut [u32], at: usize, n: usize, v: u32) {
    for b in 0..n {
        if v >> b & 1 == 1 {
            w[(at + b) / 32] |= 1 << ((at + b) % 32);
        }
    }
}

/// Writes vector `n` in frame `f` (up = axis f % 3, negated when f >= 3) and back.
fn to_frame(n: [f64; 3], f: u32) -> [f64; 3] {
    let a = (f % 3) as usize;
    let s = if f >= 3 { -1.0 } else { 1.0 };
    [n[(a + 1) % 3], n[(a + 2) % 3], s * n[a]]
}

fn from_frame(m: [f32; 3], f: u32) -> [f32; 3] {
    let a = (f % 3) as usize;
    let s = if f >= 3 { -1.0 } else { 1.0 };
    let mut n = [0.0; 3];
    n[(a + 1) % 3] = m[0];
    n[(a + 2) % 3] = m[1];
    n[a] = s * m[2];
    n
}

fn endpoint(e: u32) -> f32 {
    e as f32 / 4095.0 * 2.0 - 1.0
}

fn channel_value(w: &[u32], at: usize, s: usize) -> f32 {
    let (e0, e1) = (
        endpoint(get_bits(w, at, 12)),
        endpoint(get_bits(w, at + 12, 12)),
    );
    let k = get_bits(w, at + 24 + 3 * s, 3) as f32;
    e0 + (e1 - e0) * k / 7.0
}

/// Unit normal of slot `s` of a normal block.
pub fn decode_normal(w: &[u32], s: usize) -> [f32; 3] {
    let f = get_bits(w, 0, 3);
    let m = oct_decode([channel_value(w, 3, s), channel_value(w, 75, s)]);
    from_frame(m, f)
}

/// One channel: endpoints bracketing the values (and their neighbours one
/// step in), nearest indices; the pair with the least squared error.
fn encode_channel(w: &mut [u32], at: usize, vals: &[f64]) {
    let q = |x: f64| (x + 1.0) / 2.0 * 4095.0;
    let lo = vals.iter().copied().fold(f64::INFINITY, f64::min);
    let hi = vals.iter().copied().fold(f64::NEG_INFINITY, f64::max);
    let (l0, h0) = (q(lo).floor() as i64, q(hi).ceil() as i64);
    let mut best = (f64::INFINITY, 0u32, 0u32, 0u64);
    for e0 in [l0, l0 + 1] {
        for e1 in [h0 - 1, h0] {
            let (e0, e1) = (e0.clamp(0, 4095) as u32, e1.clamp(0, 4095) as u32);
            let (a, b) = (endpoint(e0) as f64, endpoint(e1) as f64);
            let (mut idx, mut err) = (0u64, 0.0);
            for (s, &v) in vals.iter().enumerate() {
                let k = if b == a {
                    0.0
                } else {
                    ((v - a) / (b - a) * 7.0).round().clamp(0.0, 7.0)
                };
                err += (a + (b - a) * k / 7.0 - v).powi(2);
                idx |= (k as u64) << (3 * s);
            }
            if err < best.0 {
                best = (err, e0, e1, idx);
            }
        }
    }
    put_bits(w, at, 12, best.1);
    put_bits(w, at + 12, 12, best.2);
    put_bits(w, at + 24, 24, best.3 as u32 & 0xFF_FFFF);
    put_bits(w, at + 48, 24, (best.3 >> 24) as u32);
}

/// Compresses up to 16 unit normals (zero vectors encode as anything).
pub fn encode_normals(ns: &[[f64; 3]]) -> [u32; NORMAL_WORDS] {
    let sum = [0, 1, 2].map(|i| ns.iter().map(|n| n[i]).sum::<f64>());
    let a = (0..3)
        .max_by(|&x, &y| sum[x].abs().total_cmp(&sum[y].abs()))
        .unwrap_or(2);
    let f = a as u32 + if sum[a] < 0.0 { 3 } else { 0 };
    let uv: Vec<[f64; 2]> = ns.iter().map(|&n| oct_encode(to_frame(n, f))).collect();
    let mut w = [0u32; NORMAL_WORDS];
    put_bits(&mut w, 0, 3, f);
    encode_channel(&mut w, 3, &uv.iter().map(|e| e[0]).collect::<Vec<_>>());
    encode_channel(&mut w, 75, &uv.iter().map(|e| e[1]).collect::<Vec<_>>());
    w
}

#[cfg(test)]
mod tests {
    use super::*;

    fn unit(v: [f64; 3]) -> [f64; 3] {
        let l = (v[0] * v[0] + v[1] * v[1] + v[2] * v[2]).sqrt();
        v.map(|x| x / l)
    }

    fn angle(a: [f32; 3], b: [f64; 3]) -> f64 {
        let d: f64 = (0..3).map(|i| a[i] as f64 * b[i]).sum();
        d.clamp(-1.0, 1.0).acos().to_degrees()
    }

    #[test]
    fn octahedral_round_trip_is_exact_up_to_rounding_on_both_hemispheres() {
        for n in [
            [0.3, -0.5, 0.8],
            [0.3, -0.5, -0.8],
            [0.0, 0.0, -1.0],
            [-1.0, 0.0, 0.0],
        ] {
            let n = unit(n);
            let e = oct_encode(n);
            assert!(
                angle(oct_decode([e[0] as f32, e[1] as f32]), n) < 1e-3,
                "{n:?}"
            );
        }
    }

    #[test]
    fn a_two_colour_block_decodes_exactly_at_its_endpoints() {
        let a = [31.0 / 31.0, 0.0, 16.0 / 31.0];
        let b = [0.0, 63.0 / 63.0, 0.0];
        let cs: Vec<[f64; 3]> = (0..16).map(|i| if i % 3 == 0 { a } else { b }).collect();
        let w = encode_colour(&cs);
        for (s, c) in cs.iter().enumerate() {
            assert!(sq(decode_colour(&w, s), *c) < 1e-10, "slot {s}");
        }
    }

    /// Four palette entries over a 16-step ramp: the error is at most half
    /// a palette step, a sixth of the span (0.05 in r, 0.025 in b: 0.056).
    #[test]
    fn a_colour_ramp_decodes_within_half_a_palette_step() {
        let cs: Vec<[f64; 3]> = (0..16)
            .map(|i| [0.2 + 0.02 * i as f64, 0.5, 0.7 - 0.01 * i as f64])
            .collect();
        let w = encode_colour(&cs);
        let worst = (0..16)
            .map(|s| sq(decode_colour(&w, s), cs[s]).sqrt())
            .fold(0.0, f64::max);
        assert!(worst < 0.06, "{worst}");
    }

    /// A 4x4 cap of normals spanning 0.15 rad per axis: 8 levels per
    /// channel keep every normal within 1.5 degrees (measured 1.06).
    #[test]
    fn normal_blocks_keep_the_frame_and_stay_within_a_cap_tolerance() {
        for up in [[0.0f64, 0.0, -1.0], [1.0, 0.0, 0.0], [0.0, -1.0, 0.0]] {
            let ns: Vec<[f64; 3]> = (0..16)
                .map(|i| {
                    let (a, b) = ((i % 4) as f64 * 0.05, (i / 4) as f64 * 0.05);
                    unit([0, 1, 2].map(|k| up[k] + [a, b, a - b][k] * (1.0 - up[k].abs())))
                })
                .collect();
            let w = encode_normals(&ns);
            for (s, n) in ns.iter().enumerate() {
                let e = angle(decode_normal(&w, s), *n);
                assert!(e < 1.5, "up {up:?} slot {s}: {e} degrees");
            }
        }
    }

    #[test]
    fn bit_strings_round_trip_across_word_boundaries() {
        let mut w = [0u32; NORMAL_WORDS];
        put_bits(&mut w, 27, 12, 0xABC);
        put_bits(&mut w, 150, 10, 0x3FF);
        assert_eq!(get_bits(&w, 27, 12), 0xABC);
        assert_eq!(get_bits(&w, 150, 10), 0x3FF);
        assert_eq!(get_bits(&w, 39, 12), 0);
    }
}
