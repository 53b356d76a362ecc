//! Sweeps of the path tracer over samples per pixel: RMSE convergence and
//! speed against error. `render(spp, seed)` renders the case's scene on its
//! backend and returns the image and its seconds.

use crate::budget::MemBudget;
use crate::error::Result;
use crate::judge::plot::{self, Chart, Series};
use crate::pathtrace::integrator::Tracer;
use crate::pathtrace::Image;
use crate::pathtrace::RenderParams;
use crate::scene::pathtrace::PathtraceScene;
use crate::stats::image::{mean_variance, mse};
use crate::stats::summary::{loglog_slope, median};
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

/// One backend's render for [`speed_error`]: `(spp, seed) -> (image, seconds)`.
pub type Render<'a> = &'a dyn Fn(u32, u32) -> Result<(Image, f64)>;

/// Speed against error, one render per spp (seed `seed`) on each backend
/// of `renders` (label, render): `seconds`, `rmse` of linear radiance
/// clamped to [0, 1] against `reference` (as the acceptance measures) and
/// `rmse_raw` with the reference's own noise `noise` subtracted; `spp`;
/// metrics `time_s_<spp>` and `rmse_<spp>`. With more than one backend
/// every name is prefixed `<label>_`. `plot_image` draws log RMSE against
/// log seconds, one series per backend, with the ideal Monte Carlo rate
/// (slope -1/2 through the first point) as a guide.
pub fn speed_error(
    spps: &[u32],
    seed: u32,
    (reference, noise): (&Image, f64),
    renders: &[(&str, Render)],
    out: &mut Outputs,
) -> Result<()> {
    let mut series = vec![];
    let k = [spps.len()];
    for &(label, render) in renders {
        let pre = if renders.len() > 1 {
            format!("{label}_")
        } else {
            String::new()
        };
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
            out.metric(&format!("{pre}time_s_{spp}"), t);
            out.metric(&format!("{pre}rmse_{spp}"), rmse[rmse.len() - 1]);
        }
        let ideal = secs
            .iter()
            .map(|t| rmse[0] * (t / secs[0]).powf(-0.5))
            .collect();
        let name = |what: &str| format!("{label} {what}").trim().to_string();
        series.push(Series::new(&name("RMSE"), secs.clone(), rmse.clone()));
        series.push(Series::guide(&name("ideal t^-1/2"), secs.clone(), ideal));
        out.tensor(&format!("{pre}seconds"), Tensor::real(&k, secs)?);
        out.tensor(&format!("{pre}rmse"), Tensor::real(&k, rmse)?);
        out.tensor(&format!("{pre}rmse_raw"), Tensor::real(&k, raw)?);
    }
    let chart = Chart::loglog(
        "path tracer: speed against error",
        "seconds",
        "RMSE vs reference",
        series,
    );
    out.tensor("plot_image", plot::render(&chart)?);
    out.tensor(
        "spp",
        Tensor::real(&k, spps.iter().map(|&v| v as f64).collect())?,
    );
    Ok(())
}

/// The CPU paths ([`Tracer`]) on the same render of `s`, interleaved
/// `repeats` times (CPU seconds of this process by [`super::timed`]): per
/// tracer the median `<tracer>_cpu_s` and `<tracer>_paths_per_cpu_s`, the speed-ups
/// `wavefront_over_scalar` and `wavefront_over_packet` (CPU-time ratios,
/// > 1 = wavefront faster), and `same_image` (1 when the three images are
/// bit-identical, else 0).
pub fn tracers(s: &PathtraceScene, repeats: usize, budget: &MemBudget) -> Result<Outputs> {
    let p = s.params;
    let cam = s.camera.to_real::<f32>(p.width, p.height);
    let paths = p.width as f64 * p.height as f64 * p.spp as f64;
    let render =
        |tracer| crate::pathtrace::render(&s.scene, &cam, &RenderParams { tracer, ..p }, budget);
    let mut out = Outputs::default();
    let all = [Tracer::Scalar, Tracer::Packet, Tracer::Wavefront];
    let mut cpu = [vec![], vec![], vec![]];
    let mut images: Vec<Option<Image>> = vec![None, None, None];
    for _ in 0..repeats.max(1) {
        for (i, &t) in all.iter().enumerate() {
            let (img, _, c) = super::timed(|| render(t));
            cpu[i].push(c);
            images[i] = Some(img?);
        }
    }
    let med: Vec<f64> = cpu.iter_mut().map(|v| median(v)).collect();
    for (i, name) in ["scalar", "packet", "wavefront"].iter().enumerate() {
        out.metric(&format!("{name}_cpu_s"), med[i]);
        out.metric(&format!("{name}_paths_per_cpu_s"), paths / med[i]);
    }
    out.metric("wavefront_over_scalar", med[0] / med[2]);
    out.metric("wavefront_over_packet", med[1] / med[2]);
    let same = |a: &Option<Image>, b: &Option<Image>| match (a, b) {
        (Some(a), Some(b)) => a.rgb == b.rgb && a.variance == b.variance,
        _ => false,
    };
    let ok = same(&images[0], &images[1]) && same(&images[0], &images[2]);
    out.metric("same_image", if ok { 1.0 } else { 0.0 });
    Ok(out)
}
