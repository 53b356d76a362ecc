//! Codes the CPU and the GPU share, defined once here. The WGSL kernels
//! spell them as constants (`FIELD_*`, `FLAG_*` in `kernels/volume.wgsl`);
//! a test below reads the kernel text and holds every constant equal to its
//! Rust value, so a code changed on one side only fails `cargo test`.

/// Density field kind: the `switch` value of `kernels/volume.wgsl`
/// (`FIELD_*`) and `src/gpu/volume.rs` `VolParams::field_kind`.
#[repr(u32)]
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum FieldKind {
    Constant = 0,
    Slabs = 1,
    Gaussian = 2,
    Shell = 3,
    Linear = 4,
    Grid = 5,
    /// Its network runs in `kernels/hash_mlp.wgsl` (one thread a sample).
    HashMlp = 6,
}

impl FieldKind {
    /// Every kind the kernels know, with its WGSL constant name.
    pub const ALL: [(FieldKind, &'static str); 7] = [
        (FieldKind::Constant, "FIELD_CONSTANT"),
        (FieldKind::Slabs, "FIELD_SLABS"),
        (FieldKind::Gaussian, "FIELD_GAUSSIAN"),
        (FieldKind::Shell, "FIELD_SHELL"),
        (FieldKind::Linear, "FIELD_LINEAR"),
        (FieldKind::Grid, "FIELD_GRID"),
        (FieldKind::HashMlp, "FIELD_HASH"),
    ];
}

/// Ray flags of the volume sampler (`src/volume/sample.rs` `FLAG_*`, per
/// ray) and the kernels' `FLAG_*`.
pub const FLAG_HIT: u32 = 1;
pub const FLAG_STOPPED: u32 = 2;
pub const FLAG_TRUNCATED: u32 = 4;
/// GPU-only: a decision of this ray (early stop, lattice end, occupancy
/// face, field discontinuity) sits within rounding of its threshold.
pub const FLAG_UNSTABLE: u32 = 8;

/// Every flag with its WGSL constant name.
pub const FLAGS: [(u32, &str); 4] = [
    (FLAG_HIT, "FLAG_HIT"),
    (FLAG_STOPPED, "FLAG_STOPPED"),
    (FLAG_TRUNCATED, "FLAG_TRUNCATED"),
    (FLAG_UNSTABLE, "FLAG_UNSTABLE"),
];

/// The value of `const NAME: u32 = Vu;` in WGSL `text`, if declared once.
pub fn wgsl_u32_const(text: &str, name: &str) -> Option<u32> {
    let decl = format!("const {name}: u32 = ");
    let mut found = text.lines().filter_map(|l| {
        let v = l.trim().strip_prefix(&decl)?;
        v.trim_end_matches(';').trim_end_matches('u').parse().ok()
    });
    let v = found.next()?;
    found.next().is_none().then_some(v)
}

#[cfg(test)]
mod tests {
    use super::*;

    const VOLUME_WGSL: &str = include_str!("../../kernels/volume.wgsl");

    #[test]
    fn wgsl_field_kinds_equal_the_rust_codes() {
        for (k, name) in FieldKind::ALL {
            assert_eq!(wgsl_u32_const(VOLUME_WGSL, name), Some(k as u32), "{name}");
        }
    }

    #[test]
    fn wgsl_ray_flags_equal_the_rust_codes() {
        for (v, name) in FLAGS {
            assert_eq!(wgsl_u32_const(VOLUME_WGSL, name), Some(v), "{name}");
        }
    }

    #[test]
    fn a_changed_constant_is_seen() {
        let text = "const FIELD_SHELL: u32 = 7u;\n";
        assert_eq!(wgsl_u32_const(text, "FIELD_SHELL"), Some(7));
        assert_ne!(
            wgsl_u32_const(text, "FIELD_SHELL"),
            Some(FieldKind::Shell as u32)
        );
        assert_eq!(wgsl_u32_const(text, "FIELD_GRID"), None);
    }
}
