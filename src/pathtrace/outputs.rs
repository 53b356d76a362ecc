//! The path tracer's image as named tensors, and image-level measures of
//! it: the furnace z-score and the mean radiance of world-space regions.
//! The judge's pathtrace ops return these; statistics come from
//! `crate::stats::image`.

use std::collections::BTreeMap;
use std::path::Path;

use crate::error::{Error, Result};
use crate::stats::image::image_mean;
use crate::stats::ztest::z_test;
use crate::tensor::{Outputs, Tensor};

use super::checks::{region_sum, Region};
use super::Image;

impl Image {
    /// `image` (H, W, 3 linear f32), `variance` (of the pixel mean); metrics
    /// `time_s` (= `secs`), `paths_per_s`; counters `paths`, `nonfinite_samples`.
    pub fn to_outputs(&self, secs: f64, spp: u32, out: &mut Outputs) -> Result<()> {
        let shape = [self.height as usize, self.width as usize];
        out.tensor("image", Tensor::real3(&shape, &self.rgb)?);
        out.tensor("variance", Tensor::real3(&shape, &self.variance)?);
        let paths = self.rgb.len() as f64 * spp as f64;
        out.metric("time_s", secs)
            .metric("paths_per_s", paths / secs.max(1e-9));
        out.counter("paths", paths as u64)
            .counter("nonfinite_samples", self.nonfinite);
        Ok(())
    }

    /// An (H, W, 3) float32 `.npy` image of `w` x `h` pixels, finite, with
    /// zero variance (a saved reference).
    pub fn read_npy(path: &Path, w: usize, h: usize) -> Result<Image> {
        let t = Tensor::read_npy_checked(path, &["float32"], &[Some(h), Some(w), Some(3)])?;
        let v = t.to_f64_vec();
        if v.iter().any(|x| !x.is_finite()) {
            return Err(Error::invalid(
                path.display().to_string(),
                "reference has NaN or Inf",
            ));
        }
        let rgb = v
            .chunks_exact(3)
            .map(|c| [c[0] as f32, c[1] as f32, c[2] as f32])
            .collect();
        Ok(Image {
            width: w as u32,
            height: h as u32,
            rgb,
            variance: vec![[0.0; 3]; w * h],
            nonfinite: 0,
        })
    }

    /// Parity with an independent CPU render `cpu` (another seed): per pixel
    /// and channel a two-sample z-test (`stats::ztest`, Sidak at `alpha`),
    /// both images, `nonfinite_samples` of both.
    pub fn parity_outputs(&self, cpu: &Image, alpha: f64, out: &mut Outputs) -> Result<()> {
        let flat =
            |v: &[[f32; 3]]| -> Vec<f64> { v.iter().flat_map(|p| p.map(f64::from)).collect() };
        let z = z_test(
            &flat(&self.rgb),
            &flat(&self.variance),
            &flat(&cpu.rgb),
            &flat(&cpu.variance),
        );
        let shape = [self.height as usize, self.width as usize];
        out.tensor("image", Tensor::real3(&shape, &self.rgb)?);
        out.tensor("cpu_image", Tensor::real3(&shape, &cpu.rgb)?);
        z.to_outputs(alpha, out);
        out.counter("nonfinite_samples", self.nonfinite + cpu.nonfinite);
        Ok(())
    }

    /// The furnace test against radiance `expect`: `mean` (3,), `z` (3,) the
    /// z-score of the image mean by its standard error, `pixel_err` the
    /// largest |pixel - expect|.
    pub fn furnace_outputs(&self, expect: [f64; 3], out: &mut Outputs) -> Result<()> {
        let (mean, se) = image_mean(&self.rgb, &self.variance);
        let z: Vec<f64> = (0..3)
            .map(|c| (mean[c] - expect[c]) / se[c].max(1e-7))
            .collect();
        let err = self
            .rgb
            .iter()
            .flat_map(|p| (0..3).map(move |c| (p[c] as f64 - expect[c]).abs()))
            .fold(0.0, f64::max);
        out.tensor("mean", Tensor::real(&[3], mean.to_vec())?);
        out.tensor("z", Tensor::real(&[3], z)?);
        out.tensor("pixel_err", Tensor::scalar(err));
        Ok(())
    }

    /// Per region (`regions`, over the first hits `hits` and the shape
    /// `names`): `<name>` mean rgb (3,), `<name>_lum` its luminance,
    /// `<name>_r_over_g` red over green; counter `<name>_pixels`. `at` names
    /// the regions for errors (an unknown shape, a region with no pixel).
    pub fn region_outputs(
        &self,
        hits: &[(i32, [f32; 3])],
        names: &[String],
        regions: &BTreeMap<String, Region>,
        at: &str,
        out: &mut Outputs,
    ) -> Result<()> {
        for (name, r) in regions {
            let at = format!("{at}.{name}");
            let k = names
                .iter()
                .position(|n| *n == r.shape)
                .ok_or_else(|| Error::invalid(&at, format!("no shape named {:?}", r.shape)))?;
            let (sum, count) = region_sum(&self.rgb, hits, k, r);
            if count == 0 {
                return Err(Error::invalid(
                    at,
                    "the region covers no pixel at this image size",
                ));
            }
            let m = sum.map(|x| x / count as f64);
            out.tensor(name, Tensor::real(&[3], m.to_vec())?);
            let lum = 0.2126 * m[0] + 0.7152 * m[1] + 0.0722 * m[2];
            out.tensor(&format!("{name}_lum"), Tensor::scalar(lum));
            out.tensor(
                &format!("{name}_r_over_g"),
                Tensor::scalar(m[0] / m[1].max(1e-12)),
            );
            out.counter(&format!("{name}_pixels"), count);
        }
        Ok(())
    }
}
