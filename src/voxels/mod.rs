//! Sparse voxel octrees: voxelisation ([`octree::build`] of a
//! [`shape::Shape`]), the ESVO node layout ([`octree`]), the Laine–Karras
//! traversal ([`cast`]) and its independent referee, an exact
//! Amanatides–Woo DDA over the scene predicate ([`referee`]). Seeds 001 and
//! 003; SCENES.md "Sparse voxels" fixes voxel indexing and outputs.

pub mod cast;
pub mod octree;
pub mod shape;
