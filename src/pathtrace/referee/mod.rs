//! Referees of the path tracer: independent references that never call the
//! stages they check (a test below holds every file here to that).
//!
//! | file | what |
//! | --- | --- |
//! | `geometry.rs` | f64 first hits of listed rays: geometric sphere test, Cramer's rule for quads |
//! | `bsdf.rs` | Fresnel reflectance by the angle forms |
//!
//! BSDF quadrature and chi-square live in `crate::stats`; the harnesses that
//! run the renderer's stages against these are in `pathtrace::checks`.

pub mod bsdf;
pub mod geometry;

#[cfg(test)]
mod tests {
    use crate::independence::foreign_paths;

    /// What a pathtrace referee may name: descriptions and shared maths.
    const ALLOWED: &[&str] = &[
        "crate::pathtrace::listed",
        "crate::pathtrace::referee",
        "crate::stats",
        "crate::error",
        "crate::tensor",
    ];

    #[test]
    fn referees_never_use_the_stages_they_check() {
        for (file, src) in [
            ("geometry.rs", include_str!("geometry.rs")),
            ("bsdf.rs", include_str!("bsdf.rs")),
        ] {
            assert_eq!(
                foreign_paths(src, ALLOWED),
                Vec::<String>::new(),
                "{file} uses renderer code"
            );
        }
    }
}
