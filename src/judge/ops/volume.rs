//! Operations of the `volume` renderer.

use super::OpEntry;

pub const OPS: &[OpEntry] = &[];
