//! Operations of the `pathtrace` renderer.

use super::OpEntry;

pub const OPS: &[OpEntry] = &[];
