//! Operations of the `voxels` renderer.

use super::OpEntry;

pub const OPS: &[OpEntry] = &[];
