//! Operations of the `transport` renderer.

use super::OpEntry;

pub const OPS: &[OpEntry] = &[];
