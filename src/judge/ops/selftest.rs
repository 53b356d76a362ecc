//! Planted wrong outputs the judge must fail (STYLE.md "The judge tests
//! itself"). Used only by `TESTS/selftest/manifest.yaml`.

use super::OpEntry;

pub const OPS: &[OpEntry] = &[];
