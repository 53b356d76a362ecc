//! Referees of the volume renderer: independent f64 references that never
//! call the stages they check (the tests below hold each file to that).
//!
//! | file | what | may use |
//! | --- | --- | --- |
//! | `quadrature.rs` | the forward pass by a plain per-pixel loop; trilinear lookups | descriptions only |
//! | `closed_form.rs` | optical depths of the analytic fields; closed-form gradients | descriptions only |
//! | `finite_diff.rs` | central differences of the forward render (checks `f_diff`) | the forward render, never `diff` |
//! | `hash.rs` | the hash-grid encoding and MLP written directly in f64 (checks `field/hash.rs`) | the hash field's description |
//! | `hash_probes.rs` | probe points and parameters of the hash cases; the referee's encoding with collisions; central differences of `hash.rs` and of the render | `hash.rs`, `finite_diff.rs`, descriptions |
//!
//! Descriptions are the parameter types (`VolumeParams`, `FieldDesc`,
//! `Analytic`, `ColorDesc`, `GridDesc`, `Sampling`, ...), the rays, the RNG
//! and the loss and probes of `volume::loss`.

pub mod closed_form;
pub mod finite_diff;
pub mod hash;
pub mod hash_probes;
pub mod quadrature;

#[cfg(test)]
mod tests {
    use crate::independence::foreign_paths;

    /// Descriptions a volume referee may name.
    const DESCRIPTIONS: &[&str] = &[
        "crate::volume::field::Analytic",
        "crate::volume::field::ColorDesc",
        "crate::volume::field::FieldDesc",
        "crate::volume::field::GridDesc",
        "crate::volume::field::Oob",
        "crate::volume::sample::Sampling",
        "crate::volume::sample::TransPath",
        "crate::volume::VolumeParams",
        "crate::volume::loss",
        "crate::rays::Rays",
        "crate::rays::RayGen",
        "crate::rng",
        "crate::error",
        "crate::tensor",
    ];

    #[test]
    fn quadrature_and_closed_forms_use_descriptions_only() {
        for (file, src) in [
            ("quadrature.rs", include_str!("quadrature.rs")),
            ("closed_form.rs", include_str!("closed_form.rs")),
        ] {
            assert_eq!(
                foreign_paths(src, DESCRIPTIONS),
                Vec::<String>::new(),
                "{file} uses renderer stages"
            );
        }
    }

    #[test]
    fn hash_referee_uses_the_description_only() {
        let mut allowed = DESCRIPTIONS.to_vec();
        allowed.extend([
            "crate::volume::field::hash::DensityAct",
            "crate::volume::field::hash::HashMlpDesc",
        ]);
        assert_eq!(
            foreign_paths(include_str!("hash.rs"), &allowed),
            Vec::<String>::new()
        );
    }

    #[test]
    fn hash_probes_use_the_referees_beside_them_and_descriptions_only() {
        let mut allowed = DESCRIPTIONS.to_vec();
        allowed.extend([
            "crate::volume::field::hash::HashMlpDesc",
            "crate::camera::Camera",
            "crate::budget::MemBudget",
            "crate::parallel::par_collect",
        ]);
        assert_eq!(
            foreign_paths(include_str!("hash_probes.rs"), &allowed),
            Vec::<String>::new()
        );
    }

    #[test]
    fn finite_differences_use_the_forward_render_but_never_diff() {
        let mut allowed = DESCRIPTIONS.to_vec();
        allowed.extend([
            "crate::volume::render",
            "crate::volume::Chain",
            "crate::volume::compose::Compose",
            "crate::camera::Camera",
            "crate::budget::MemBudget",
        ]);
        assert_eq!(
            foreign_paths(include_str!("finite_diff.rs"), &allowed),
            Vec::<String>::new()
        );
    }
}
