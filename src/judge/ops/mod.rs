//! The judge's one table of operations. A manifest case names an operation
//! (`rays.generate`, `volume.forward`, ...); the worker looks it up here and
//! calls it with an [`OpCtx`] (`judge/op.rs`: what an operation is). Each
//! file below holds one renderer's rows in an `ops!` table and one short
//! function per row: scene and parameters in, a renderer, referee or
//! harness call, its `Outputs` back. Conversions to tensors live on the
//! renderers' result types, referees beside their renderer, timing in
//! `judge::measure`. Template: `rays.rs`.

/// `f::<f32>(args)` or `f::<f64>(args)` by the case's precision: the one
/// place an operation picks its float type.
macro_rules! by_precision {
    ($ctx:expr, $($f:ident)::+ ( $($arg:expr),* $(,)? )) => {
        match $ctx.precision {
            $crate::real::Precision::F32 => $($f)::+::<f32>($($arg),*),
            $crate::real::Precision::F64 => $($f)::+::<f64>($($arg),*),
        }
    };
}

/// An op file's table: one row per operation, `"name" Support run
/// ["param", ...] "doc";` (the columns of [`OpEntry`]).
macro_rules! ops {
    ($($name:literal $support:ident $run:ident [$($p:literal),*] $doc:literal;)*) => {
        pub const OPS: &[$crate::judge::ops::OpEntry] = &[$($crate::judge::ops::OpEntry {
            name: $name,
            doc: $doc,
            params: &[$($p),*],
            support: $crate::judge::ops::Support::$support,
            run: $run,
        }),*];
    };
}

mod pathtrace;
mod rays;
mod selftest;
mod transport;
mod volume;
mod volume_diff;
mod volume_fit;
mod volume_hash;
mod voxels;

pub use super::op::{BackendKind, OpCtx, OpEntry, Support};

/// Every operation, in table order.
pub fn table() -> impl Iterator<Item = &'static OpEntry> {
    [
        rays::OPS,
        volume::OPS,
        volume_diff::OPS,
        volume_hash::OPS,
        volume_fit::OPS,
        pathtrace::OPS,
        transport::OPS,
        voxels::OPS,
        selftest::OPS,
    ]
    .into_iter()
    .flatten()
}

/// Looks an operation up by name.
pub fn find(name: &str) -> Option<&'static OpEntry> {
    table().find(|e| e.name == name)
}

/// All operation names, for error messages.
pub fn names() -> Vec<&'static str> {
    table().map(|e| e.name).collect()
}
