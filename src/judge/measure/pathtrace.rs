//! Sweeps of the path tracer over samples per pixel: RMSE convergence and
//! speed against error. `render(spp, seed)` renders the case's scene on its
//! backend and returns the image and its seconds.

use crate::error::Result;
use crate::judge::plot::{self, Chart, Series};
use crate::pathtrace::Image;
use crate::stats::image::{mean_variance, mse};
use crate::stats::summary::loglog_slope;
use crate::tensor::{Outputs, Tensor};

/// RMSE against a `ref_spp` render (seed `2^31`, independent of the test
/// seeds) at each spp, MSE averaged over `seeds` (correlated samples across
/// spp or seeds would bend the slope away from -0.5); with `clamp: false`
/// the reference's own noise is subtracted from each MSE. Returns the RMSE
/// per spp (`rmse`), `spp`, the log-log `slope` and `time_s`.
pub fn convergence(
    spps: &[u32],
    seeds: &[u32],
    (ref_spp, clamp): (u32, bool),
    render: impl Fn(u32, u32) -> Result<(Image, f64)>,
) -> Result<Outputs> {
    let t = std::time::Instant::now();
    let (reference, _) = render(ref_spp, 1 << 31)?;
    let noise = if clamp {
        0.0
    } else {
        mean_variance(&reference.variance)
    };
    let mut rmse = Vec::with_capacity(spps.len());
    for &spp in spps {
        let mut acc = 0.0;
        for &seed in seeds {
            let (img, _) = render(spp, seed)?;
            acc += (mse(&img.rgb, &reference.rgb, clamp) - noise).max(0.0);
        }
        rmse.push((acc / seeds.len() as f64).sqrt());
    }
    let x: Vec<f64> = spps.iter().map(|&v| v as f64).collect();
    let slope = loglog_slope(&x, &rmse);
    let mut out = Outputs::default();
    out.tensor("spp", Tensor::real(&[x.len()], x)?);
    out.tensor("rmse", Tensor::real(&[rmse.len()], rmse)?);
    out.tensor("slope", Tensor::scalar(slope));
    out.metric("time_s", t.elapsed().as_secs_f64());
    Ok(out)
}

/// Speed against error, one render per spp (seed `seed`): `seconds`, `rmse`
/// of linear radiance clamped to [0, 1] against `reference` (as the
/// acceptance measures) and `rmse_raw` with the reference's own noise
/// `noise` subtracted; `spp`; metrics `time_s_<spp>`; `plot_image` draws
/// log RMSE against log seconds with the ideal Monte Carlo rate (slope -1/2
/// through the first point) as a guide.
pub fn speed_error(
    spps: &[u32],
    seed: u32,
    (reference, noise): (&Image, f64),
    render: impl Fn(u32, u32) -> Result<(Image, f64)>,
    out: &mut Outputs,
) -> Result<()> {
    let (mut secs, mut rmse, mut raw) = (vec![], vec![], vec![]);
    for &spp in spps {
        let (img, t) = render(spp, seed)?;
        secs.push(t);
        rmse.push(mse(&img.rgb, &reference.rgb, true).sqrt());
        raw.push(
            (mse(&img.rgb, &reference.rgb, false) - noise)
                .max(0.0)
                .sqrt(),
        );
        out.metric(&format!("time_s_{spp}"), t);
    }
    let ideal = secs
        .iter()
        .map(|t| rmse[0] * (t / secs[0]).powf(-0.5))
        .collect();
    let series = vec![
        Series::new("RMSE", secs.clone(), rmse.clone()),
        Series::guide("ideal t^-1/2", secs.clone(), ideal),
    ];
    let chart = Chart::loglog(
        "path tracer: speed against error",
        "seconds",
        "RMSE vs reference",
        series,
    );
    out.tensor("plot_image", plot::render(&chart)?);
    let k = [spps.len()];
    out.tensor(
        "spp",
        Tensor::real(&k, spps.iter().map(|&v| v as f64).collect())?,
    );
    out.tensor("seconds", Tensor::real(&k, secs)?);
    out.tensor("rmse", Tensor::real(&k, rmse)?);
    out.tensor("rmse_raw", Tensor::real(&k, raw)?);
    Ok(())
}
