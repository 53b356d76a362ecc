//! Differentiable emission–absorption volume rendering (seed 000): fields,
//! `f_samp`, `f_int`, `f_img`, `f_fused` (forward, CPU, f32 or f64).
//!
//! | stage | file | in -> out |
//! | --- | --- | --- |
//! | fields | `field/` | analytic / dense grid descriptions -> `Field<F>`, `ColorField<F>` |
//! | `f_samp` | `sample.rs` | rays -> packed samples (`off`, `ray_id`, `t`, `dt`, `sigma`, `color`) |
//! | `f_int` | `integrate.rs` | samples -> per-ray results + persisted `alpha`, `log_t` |
//! | `f_img` | `compose.rs` | per-ray results -> image (sorted or scatter path) |
//! | `f_fused` | `fused.rs` | camera -> per-ray results, one pass, no sample buffers |
//! | skipping | `occupancy.rs` | field -> occupancy bitfield |
//! | loss, probes | `loss.rs` | the backward pass's loss weights and probe nodes |
//! | outputs | `grad_outputs.rs` | a backward pass as named tensors |
//! | inverse rendering | `fit.rs` | target views -> fitted dense grid or hash field (Adam + `f_diff`) |
//! | referees | `referee/` | quadrature, closed forms, finite differences, the hash encoding (never these stages) |
//!
//! [`render`] chains them (fused or unfused) for a typed [`VolumeParams`].

pub mod compose;
pub mod diff;
pub mod field;
pub mod fit;
pub mod fused;
pub mod fused_lanes;
pub mod gpu;
pub mod grad_outputs;
pub mod hash_kinks;
pub mod integrate;
pub mod loss;
pub mod occupancy;
pub mod outputs;
pub mod referee;
pub mod sample;
pub mod session;

use std::time::Instant;

use crate::budget::{bytes_for, MemBudget};
use crate::camera::Camera;
use crate::error::Result;
use crate::rays::{f_ray, RayGen};
use crate::real::Real;

use compose::{f_img, Compose, Image};
use field::{ColorDesc, FieldDesc};
use integrate::{f_int, Integrated, RayOut};
use occupancy::Occupancy;
use sample::{f_samp, March, Samples, Sampling, TransPath, FLAG_HIT, FLAG_STOPPED, FLAG_TRUNCATED};

/// Everything a volume render needs besides the camera and ray generator
/// (f64, rounded to the render precision at render time).
#[derive(Clone, Debug, PartialEq)]
pub struct VolumeParams {
    pub field: FieldDesc,
    pub color: ColorDesc,
    pub dt: f64,
    pub max_steps: u32,
    pub early_stop: f64,
    pub sampling: Sampling,
    pub path: TransPath,
    pub background: [f64; 3],
    /// Occupancy bitfield resolution per axis (0: no skipping).
    pub occupancy: u32,
}

impl VolumeParams {
    pub fn march<F: Real>(&self) -> March<F> {
        March {
            dt: F::of(self.dt),
            max_steps: self.max_steps,
            early_stop: F::of(self.early_stop),
            sampling: self.sampling,
            path: self.path,
            background: self.background.map(F::of),
        }
    }
}

/// Fused or unfused chain.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Chain {
    Fused,
    Unfused,
}

/// Counters of a render (seed D: rays, samples, early_stop, saturated_alpha).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct Counters {
    pub rays: u64,
    /// Rays that met the box.
    pub hits: u64,
    /// Samples integrated.
    pub samples: u64,
    /// Rays stopped by the early-stop test.
    pub early_stop: u64,
    /// Samples whose alpha rounded to exactly 1.
    pub saturated_alpha: u64,
    /// Rays whose lattice was cut by `max_steps`.
    pub max_steps: u64,
    /// Lattice points skipped by the occupancy bitfield.
    pub skipped: u64,
}

impl Counters {
    pub fn of<F: Real>(rays: &[RayOut<F>], skipped: u64) -> Counters {
        let mut c = Counters {
            rays: rays.len() as u64,
            skipped,
            ..Default::default()
        };
        for r in rays {
            c.hits += (r.flags & FLAG_HIT != 0) as u64;
            c.samples += r.n as u64;
            c.early_stop += (r.flags & FLAG_STOPPED != 0) as u64;
            c.max_steps += (r.flags & FLAG_TRUNCATED != 0) as u64;
            c.saturated_alpha += r.saturated as u64;
        }
        c
    }

    /// `(name, value)` pairs for reports.
    pub fn pairs(&self) -> [(&'static str, u64); 7] {
        [
            ("rays", self.rays),
            ("hits", self.hits),
            ("samples", self.samples),
            ("early_stop", self.early_stop),
            ("saturated_alpha", self.saturated_alpha),
            ("max_steps", self.max_steps),
            ("skipped", self.skipped),
        ]
    }
}

/// Wall-clock seconds per stage (0 for stages a chain does not run).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Timings {
    pub ray: f64,
    pub samp: f64,
    pub int: f64,
    pub img: f64,
    pub fused: f64,
    pub total: f64,
}

/// A finished render, with the unfused chain's buffers when it ran.
#[derive(Clone, Debug)]
pub struct Render<F> {
    pub image: Image<F>,
    pub counters: Counters,
    pub timings: Timings,
    pub samples: Option<Samples<F>>,
    pub integrated: Option<Integrated<F>>,
}

/// A render plan's fields and parameters in precision `F`, built once
/// (grid conversion, colour packing, occupancy bits) and reused by every
/// frame that renders it.
#[derive(Clone, Debug)]
pub struct Prepared<F> {
    pub medium: field::Medium<F>,
    pub occ: Option<Occupancy<F>>,
    pub march: March<F>,
}

/// Builds the [`Prepared`] plan of `params` for the world box `aabb`.
pub fn prepare<F: Real>(
    params: &VolumeParams,
    aabb: &crate::rays::Aabb,
    budget: &MemBudget,
) -> Result<Prepared<F>> {
    let march = params.march::<F>();
    march.validate()?;
    let occ = match params.occupancy {
        0 => None,
        r => Some(Occupancy::<F>::build(&params.field, aabb, r, budget)?),
    };
    Ok(Prepared {
        medium: field::Medium::<F>::new(&params.field, &params.color),
        occ,
        march,
    })
}

/// Renders `params` through `cam` / `gen` with the fused or unfused chain.
pub fn render<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    params: &VolumeParams,
    chain: Chain,
    compose: Compose,
    budget: &MemBudget,
) -> Result<Render<F>> {
    let t_all = Instant::now();
    let prep = prepare::<F>(params, &gen.aabb, budget)?;
    let mut r = render_prepared(cam, gen, &prep, chain, compose, budget)?;
    r.timings.total = t_all.elapsed().as_secs_f64();
    Ok(r)
}

/// Renders a [`Prepared`] plan (one frame).
pub fn render_prepared<F: Real>(
    cam: &Camera,
    gen: &RayGen,
    prep: &Prepared<F>,
    chain: Chain,
    compose: Compose,
    budget: &MemBudget,
) -> Result<Render<F>> {
    let t_all = Instant::now();
    let m = prep.march;
    let occ = prep.occ.as_ref();
    let roi = gen.region();
    let region = (roi.x, roi.y, roi.width, roi.height);
    let mut tm = Timings::default();
    let (rays_out, pixel, skipped, samples, integrated) = match chain {
        Chain::Fused => {
            let t = Instant::now();
            let f = fused::f_fused(cam, gen, &prep.medium, &m, occ, budget)?;
            tm.fused = t.elapsed().as_secs_f64();
            (f.rays, f.pixel, f.skipped, None, None)
        }
        Chain::Unfused => {
            let t = Instant::now();
            let rays = f_ray::<F>(cam, gen, budget)?;
            let ray_s = t.elapsed().as_secs_f64();
            let mut r = render_rays(&rays, gen, prep, compose, budget)?;
            r.timings.ray = ray_s;
            r.timings.total = t_all.elapsed().as_secs_f64();
            return Ok(r);
        }
    };
    let t = Instant::now();
    let image = f_img(&rays_out, &pixel, gen.width, region, m.background, compose)?;
    tm.img = t.elapsed().as_secs_f64();
    tm.total = t_all.elapsed().as_secs_f64();
    Ok(Render {
        counters: Counters::of(&rays_out, skipped),
        image,
        timings: tm,
        samples,
        integrated,
    })
}

/// The unfused chain on given rays (camera rays, or rays replayed from a
/// `--dump-failing` file): `f_samp` -> `f_int` -> `f_img` into the region of
/// `gen` (ray pixel ids index the full `gen.width`-wide image).
pub fn render_rays<F: Real>(
    rays: &crate::rays::Rays<F>,
    gen: &RayGen,
    prep: &Prepared<F>,
    compose: Compose,
    budget: &MemBudget,
) -> Result<Render<F>> {
    let t_all = Instant::now();
    let m = prep.march;
    let roi = gen.region();
    let mut tm = Timings::default();
    let t = Instant::now();
    let s = f_samp(rays, &prep.medium, &m, prep.occ.as_ref(), budget)?;
    tm.samp = t.elapsed().as_secs_f64();
    budget.check(
        "f_int buffers",
        bytes_for(s.len() as u64, Integrated::<F>::BYTES_PER_SAMPLE),
    )?;
    let t = Instant::now();
    let it = f_int(&s, &m);
    tm.int = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let region = (roi.x, roi.y, roi.width, roi.height);
    let image = f_img(
        &it.rays,
        &rays.pixel,
        gen.width,
        region,
        m.background,
        compose,
    )?;
    tm.img = t.elapsed().as_secs_f64();
    tm.total = t_all.elapsed().as_secs_f64();
    let counters = Counters::of(&it.rays, s.skipped);
    Ok(Render {
        image,
        counters,
        timings: tm,
        samples: Some(s),
        integrated: Some(it),
    })
}

#[cfg(test)]
mod tests {
    use super::field::{Analytic, GridDesc, Oob};
    use super::*;

    fn params(
        field: FieldDesc,
        occupancy: u32,
        sampling: Sampling,
        path: TransPath,
    ) -> VolumeParams {
        VolumeParams {
            field,
            color: ColorDesc::Constant([1.0, 0.5, 0.25]),
            dt: 0.01,
            max_steps: 1024,
            early_stop: 1e-4,
            sampling,
            path,
            background: [0.1, 0.2, 0.3],
            occupancy,
        }
    }

    fn cam() -> Camera {
        Camera::pinhole_look_at([0.0, 0.0, 3.0], [0.0; 3], [0.0, 1.0, 0.0], 40.0, 16, 12).unwrap()
    }

    fn both<F: Real>(p: &VolumeParams) -> (Render<F>, Render<F>) {
        let b = MemBudget::fixed(1 << 28);
        let gen = RayGen::new(16, 12);
        let f = render::<F>(&cam(), &gen, p, Chain::Fused, Compose::Sorted, &b).unwrap();
        let u = render::<F>(&cam(), &gen, p, Chain::Unfused, Compose::Scatter, &b).unwrap();
        (f, u)
    }

    #[test]
    fn fused_matches_unfused_bit_for_bit_f32_and_f64() {
        let gauss = FieldDesc::Analytic(Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.0; 3],
            std: 0.3,
        });
        let grid = FieldDesc::Grid(GridDesc::sample(
            [9, 10, 11],
            [-1.0; 3],
            [1.0; 3],
            Oob::Zero,
            |x| 5.0 + x[0],
        ));
        for f in [gauss, grid] {
            for (s, p) in [
                (Sampling::Fixed, TransPath::Product),
                (Sampling::Stratified { seed: 9 }, TransPath::Log),
            ] {
                let pr = params(f.clone(), 0, s, p);
                let (a, b) = both::<f32>(&pr);
                assert_eq!(a.image, b.image);
                assert_eq!(a.counters, b.counters);
                let (a, b) = both::<f64>(&pr);
                assert_eq!(a.image, b.image);
            }
        }
    }

    #[test]
    fn occupancy_skipping_keeps_the_image_and_takes_fewer_samples() {
        let shell = FieldDesc::Analytic(Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        });
        let (plain, _) = both::<f32>(&params(
            shell.clone(),
            0,
            Sampling::Fixed,
            TransPath::Product,
        ));
        let (skip, skip_u) = both::<f32>(&params(shell, 32, Sampling::Fixed, TransPath::Product));
        assert_eq!(plain.image.rgb, skip.image.rgb);
        assert_eq!(plain.image.trans, skip.image.trans);
        assert_eq!(skip.image, skip_u.image);
        assert!(
            skip.counters.samples < plain.counters.samples / 2,
            "{:?} {:?}",
            skip.counters,
            plain.counters
        );
        assert!(skip.counters.skipped > 0);
    }

    #[test]
    fn persisted_buffers_replay_the_transmittance() {
        let gauss = FieldDesc::Analytic(Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.0; 3],
            std: 0.3,
        });
        let (_, u) = both::<f64>(&params(gauss, 0, Sampling::Fixed, TransPath::Product));
        let (s, it) = (u.samples.unwrap(), u.integrated.unwrap());
        for r in 0..it.rays.len() {
            for k in s.off[r] as usize..s.off[r + 1] as usize {
                if it.alpha[k] > 0.0 {
                    let lt = it.log_t[k] - s.sigma[k] * s.dt[k];
                    let next = if k + 1 < s.off[r + 1] as usize {
                        it.log_t[k + 1]
                    } else {
                        it.rays[r].log_trans
                    };
                    assert!((lt - next).abs() < 1e-12);
                }
            }
        }
    }
}
