//! Sparse voxel octrees and the Laine–Karras ESVO traversal (seeds 001, 003).
