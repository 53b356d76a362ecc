//! Sparse voxel octrees: voxelisation ([`octree::build`] of a
//! [`shape::Shape`]), the ESVO node layout ([`octree`]), the Laine–Karras
//! traversal ([`cast`]) and its independent referee, an exact
//! Amanatides–Woo DDA over the scene predicate ([`referee`]); [`outputs`]
//! names their tensors. Seeds 001 and
//! 003; SCENES.md "Sparse voxels" fixes voxel indexing and outputs.

pub mod attributes;
pub mod batch;
pub mod beam;
pub mod cast;
pub mod cast_lanes;
pub mod cast_real;
pub mod cast_sse;
pub mod checks;
pub mod contour;
pub mod dag;
pub mod dxt;
#[cfg(test)]
pub mod fixtures;
pub mod gpu;
pub mod hits;
pub mod mesh;
pub mod node_order;
pub mod octree;
pub mod outputs;
pub mod packet;
pub mod raysets;
pub mod referee;
pub mod referee_bounds;
pub mod referee_contour;
pub mod referee_dag;
pub mod referee_mesh;
pub mod render;
pub mod set_bits;
pub mod shape;
pub mod through;
pub mod tiles;
pub mod voxelise;

#[cfg(test)]
mod tests {
    use crate::budget::MemBudget;
    use crate::rng::rand_f64;

    use super::cast::{cast, CastParams, CastReal};
    use super::fixtures::two_boxes;
    use super::octree::build;
    use super::referee::referee;
    use super::shape::Shape;

    /// Random rays: origins in [-1.6, 1.6]^3, uniform directions.
    fn rays(n: u32, seed: u32) -> Vec<([f64; 3], [f64; 3])> {
        (0..n)
            .map(|i| {
                let u = |k: u32| rand_f64(seed, i, 0, k);
                let o = [0, 1, 2].map(|k| -1.6 + 3.2 * u(k));
                let z = 1.0 - 2.0 * u(3);
                let r = (1.0 - z * z).max(0.0).sqrt();
                let ph = 2.0 * std::f64::consts::PI * u(4);
                (o, [r * ph.cos(), r * ph.sin(), z])
            })
            .collect()
    }

    /// (mismatches outside flagged rays, flagged rays) for casts in `F`.
    fn compare<F: CastReal>(s: &Shape, depth: u32, margin: f64, rtol: f64) -> (usize, usize) {
        let t = build(s, depth, &MemBudget::fixed(1 << 30)).unwrap();
        let (mut bad, mut flagged) = (0, 0);
        for (o, d) in rays(20_000, depth) {
            let (of, df) = (o.map(F::of), d.map(F::of));
            let (o64, d64) = (of.map(|x| x.f64()), df.map(|x| x.f64()));
            let r = referee(s, depth, o64, d64, 0.0, f64::INFINITY, margin);
            let h = cast::<F>(&t.nodes, depth, of, df, &CastParams::default());
            let flag = if margin > 0.0 { r.near_tie } else { r.tie };
            if flag {
                flagged += 1;
                continue;
            }
            let t_ok = !r.hit || (h.t.f64() - r.t).abs() <= rtol * r.t.abs().max(1e-3);
            if h.hit != r.hit || (r.hit && (h.voxel != r.voxel || h.normal != r.normal || !t_ok)) {
                bad += 1;
                if bad < 4 {
                    eprintln!("{s:?} o={o64:?} d={d64:?}\n  cast {h:?}\n  ref  {r:?}");
                }
            }
        }
        (bad, flagged)
    }

    fn shapes() -> Vec<(Shape, u32)> {
        vec![
            (Shape::Sphere { radius: 0.8 }, 6),
            (Shape::Menger { level: 3 }, 5),
            (Shape::Menger { level: 4 }, 7),
            (two_boxes(), 6),
        ]
    }

    #[test]
    fn f64_cast_equals_the_exact_referee_on_every_untied_ray() {
        for (s, depth) in shapes() {
            let (bad, flagged) = compare::<f64>(&s, depth, 0.0, 1e-12);
            assert_eq!(bad, 0, "{s:?}: {bad} mismatches ({flagged} ties)");
        }
    }

    #[test]
    fn f32_cast_equals_the_referee_away_from_near_ties() {
        for (s, depth) in shapes() {
            let (bad, flagged) = compare::<f32>(&s, depth, 1e-5, 1e-5);
            assert_eq!(bad, 0, "{s:?}: {bad} mismatches ({flagged} near ties)");
            assert!(flagged < 200, "{s:?}: {flagged} near ties of 20000");
        }
    }
}
