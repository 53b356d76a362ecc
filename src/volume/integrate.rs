//! `f_int`: emission–absorption integration (seed 000, module 3; SCENES.md
//! "Integration").
//!
//! `alpha_k = -expm1(-sigma_k dt_k)`, `w_k = T_k alpha_k`,
//! `C = sum w_k c_k + T_N bg`, `depth = sum w_k t_k`, `opacity = 1 - T_N`,
//! `log T_{k+1} = log T_k - sigma_k dt_k`. Early stop: before sample k, stop
//! when `T_k < early_stop`. The sums of C, depth and log T are compensated
//! (Kahan), so rays of 10^5 samples keep their accuracy in f32.
//!
//! [`RayAcc`] is the per-ray state machine both this stage and the fused
//! loop (`fused.rs`) drive, sample by sample, with the same operations in
//! the same order: that is what makes fused and unfused bit-identical. Its
//! WGSL twin is `kernels/volume.wgsl` (entry `f_int`, and the accumulation
//! inside `f_fused`); parity cases `gpu_vol_*_unfused_parity`.
//!
//! Persisted for the backward pass (issue 4), per sample: `alpha_k` and
//! `log T_k` (before sample k). Samples after an early stop keep alpha = 0
//! and log T = the final log T.

use crate::parallel::par_each;
use crate::real::{Precision, Real};

use super::sample::{March, Samples, TransPath, FLAG_STOPPED, TILE_RAYS};

/// `alpha = 1 - exp(-tau) = -expm1(-tau)` for `tau >= 0`, to full relative
/// accuracy. f64: libm `expm1`. f32: for `tau < 0.25` the Taylor series
/// `tau (1 - tau/2 + tau^2/6 - ... + tau^6/5040)` (truncation below 2e-9
/// relative) in Estrin's scheme (short dependency chains: this sits in the
/// per-sample loop), else `1 - exp(-tau)` (`exp(-tau) <= 0.78`, so no
/// cancellation). WGSL has no `expm1`: the GPU twin uses this f32 formula.
#[inline(always)]
pub fn alpha_of<F: Real>(tau: F) -> F {
    if F::PRECISION == Precision::F64 {
        return -(-tau).exp_m1();
    }
    let one = F::one();
    if tau < F::of(0.25) {
        let c = |v: f64| F::of(v);
        let t2 = tau * tau;
        let t4 = t2 * t2;
        let p01 = one - c(1.0 / 2.0) * tau;
        let p23 = c(1.0 / 6.0) - c(1.0 / 24.0) * tau;
        let p45 = c(1.0 / 120.0) - c(1.0 / 720.0) * tau;
        let p = (p01 + t2 * p23) + t4 * (p45 + t2 * c(1.0 / 5040.0));
        tau * p
    } else {
        one - (-tau).exp()
    }
}

/// Kahan summation step: adds `x` to `(sum, comp)`.
#[inline]
pub fn kahan_add<F: Real>(sum: &mut F, comp: &mut F, x: F) {
    let y = x - *comp;
    let t = *sum + y;
    *comp = (t - *sum) - y;
    *sum = t;
}

/// Per-ray integration state.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayAcc<F> {
    /// `T_k` of the product path.
    pub trans: F,
    /// `log T_k` and its Kahan compensation.
    pub log_t: F,
    pub log_c: F,
    pub rgb: [F; 3],
    pub rgb_c: [F; 3],
    pub depth: F,
    pub depth_c: F,
    /// Samples integrated.
    pub n: u32,
    /// Samples with alpha rounded to exactly 1.
    pub saturated: u32,
}

impl<F: Real> Default for RayAcc<F> {
    fn default() -> Self {
        RayAcc {
            trans: F::one(),
            log_t: F::zero(),
            log_c: F::zero(),
            rgb: [F::zero(); 3],
            rgb_c: [F::zero(); 3],
            depth: F::zero(),
            depth_c: F::zero(),
            n: 0,
            saturated: 0,
        }
    }
}

/// One ray's result.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct RayOut<F> {
    pub rgb: [F; 3],
    pub trans: F,
    pub log_trans: F,
    pub depth: F,
    pub opacity: F,
    /// Samples integrated.
    pub n: u32,
    pub saturated: u32,
    /// `FLAG_*` bits of `sample.rs`.
    pub flags: u8,
}

impl<F: Real> RayAcc<F> {
    /// `T_k` for the early-stop test and the weight of the next sample:
    /// `exp(log T_k)` on the log path (`LOG`), the product otherwise. The
    /// path is a const parameter so the product path's loop holds no `exp`
    /// (LLVM otherwise evaluates both arms and selects).
    #[inline(always)]
    pub fn transmittance<const LOG: bool>(&self) -> F {
        if LOG {
            self.log_t.exp()
        } else {
            self.trans
        }
    }

    /// Integrates one sample with transmittance `tk` (from
    /// [`RayAcc::transmittance`]); returns alpha.
    #[inline]
    pub fn step(&mut self, tk: F, sigma: F, c: [F; 3], t: F, dt: F) -> F {
        let tau = sigma * dt;
        let alpha = alpha_of(tau);
        let w = tk * alpha;
        for ((sum, comp), ci) in self.rgb.iter_mut().zip(self.rgb_c.iter_mut()).zip(c) {
            kahan_add(sum, comp, w * ci);
        }
        kahan_add(&mut self.depth, &mut self.depth_c, w * t);
        kahan_add(&mut self.log_t, &mut self.log_c, -tau);
        self.trans *= F::one() - alpha;
        self.n += 1;
        if alpha == F::one() {
            self.saturated += 1;
        }
        alpha
    }

    /// The ray's outputs: `rgb = C + T_N bg`, `opacity = 1 - T_N` computed
    /// as `-expm1(log T_N)` (the same number, without the cancellation
    /// when T_N is close to 1).
    #[inline]
    pub fn finish<const LOG: bool>(&self, background: [F; 3], flags: u8) -> RayOut<F> {
        let tn = self.transmittance::<LOG>();
        RayOut {
            rgb: [0, 1, 2].map(|c| self.rgb[c] + tn * background[c]),
            trans: tn,
            log_trans: self.log_t,
            depth: self.depth,
            opacity: -self.log_t.exp_m1(),
            n: self.n,
            saturated: self.saturated,
            flags,
        }
    }
}

impl RayOut<f32> {
    /// The same result in precision `F` (exact: every f32 is an `F`).
    pub fn to_real<F: Real>(self) -> RayOut<F> {
        let c = |v: f32| F::of(v as f64);
        RayOut {
            rgb: self.rgb.map(c),
            trans: c(self.trans),
            log_trans: c(self.log_trans),
            depth: c(self.depth),
            opacity: c(self.opacity),
            n: self.n,
            saturated: self.saturated,
            flags: self.flags,
        }
    }
}

/// `f_int` output: per-ray results and the per-sample buffers the backward
/// pass reads.
#[derive(Clone, Debug, PartialEq)]
pub struct Integrated<F> {
    pub rays: Vec<RayOut<F>>,
    /// Per sample: alpha_k (0 after an early stop).
    pub alpha: Vec<F>,
    /// Per sample: log T_k, the log-transmittance before sample k.
    pub log_t: Vec<F>,
}

impl<F: Real> Integrated<F> {
    /// Bytes per sample of the persisted buffers.
    pub const BYTES_PER_SAMPLE: u64 = (2 * std::mem::size_of::<F>()) as u64;
}

/// Integrates the samples of one ray (`lo..hi` of the packed buffers),
/// writing the persisted alpha / log T into `alpha`, `log_t` (slices of the
/// same length). A pure function, the WGSL `volume_int` twin's loop.
#[inline]
#[allow(clippy::too_many_arguments)]
pub fn integrate_ray<F: Real>(
    t: &[F],
    dt: &[F],
    sigma: &[F],
    color: &[[F; 3]],
    alpha: &mut [F],
    log_t: &mut [F],
    m: &March<F>,
    flags: u8,
) -> RayOut<F> {
    match m.path {
        TransPath::Product => {
            integrate_ray_path::<F, false>(t, dt, sigma, color, alpha, log_t, m, flags)
        }
        TransPath::Log => {
            integrate_ray_path::<F, true>(t, dt, sigma, color, alpha, log_t, m, flags)
        }
    }
}

#[inline]
#[allow(clippy::too_many_arguments)]
fn integrate_ray_path<F: Real, const LOG: bool>(
    t: &[F],
    dt: &[F],
    sigma: &[F],
    color: &[[F; 3]],
    alpha: &mut [F],
    log_t: &mut [F],
    m: &March<F>,
    flags: u8,
) -> RayOut<F> {
    let mut acc = RayAcc::default();
    let mut flags = flags;
    for s in 0..t.len() {
        let tk = acc.transmittance::<LOG>();
        if tk < m.early_stop {
            flags |= FLAG_STOPPED;
            for r in s..t.len() {
                alpha[r] = F::zero();
                log_t[r] = acc.log_t;
            }
            break;
        }
        log_t[s] = acc.log_t;
        alpha[s] = acc.step(tk, sigma[s], color[s], t[s], dt[s]);
    }
    acc.finish::<LOG>(m.background, flags)
}

struct IntTile<'a, F> {
    first_ray: usize,
    out: &'a mut [RayOut<F>],
    alpha: &'a mut [F],
    log_t: &'a mut [F],
}

/// `f_int`: integrates every ray's samples in parallel over tiles of rays.
/// Memory: the caller checks `Integrated::BYTES_PER_SAMPLE * m` with the plan.
pub fn f_int<F: Real>(s: &Samples<F>, m: &March<F>) -> Integrated<F> {
    let n = s.off.len() - 1;
    let blank = RayOut {
        rgb: [F::zero(); 3],
        trans: F::one(),
        log_trans: F::zero(),
        depth: F::zero(),
        opacity: F::zero(),
        n: 0,
        saturated: 0,
        flags: 0,
    };
    let mut out = Integrated {
        rays: vec![blank; n],
        alpha: vec![F::zero(); s.len()],
        log_t: vec![F::zero(); s.len()],
    };
    let mut tiles = Vec::with_capacity(n.div_ceil(TILE_RAYS));
    {
        let (mut o, mut a, mut l) = (&mut out.rays[..], &mut out.alpha[..], &mut out.log_t[..]);
        for first in (0..n).step_by(TILE_RAYS) {
            let last = (first + TILE_RAYS).min(n);
            let len = (s.off[last] - s.off[first]) as usize;
            let (ot, rest) = std::mem::take(&mut o).split_at_mut(last - first);
            o = rest;
            let (at, rest) = std::mem::take(&mut a).split_at_mut(len);
            a = rest;
            let (lt, rest) = std::mem::take(&mut l).split_at_mut(len);
            l = rest;
            tiles.push(IntTile {
                first_ray: first,
                out: ot,
                alpha: at,
                log_t: lt,
            });
        }
    }
    par_each("f_int", tiles, |_, tile| {
        let base = s.off[tile.first_ray] as usize;
        for (i, slot) in tile.out.iter_mut().enumerate() {
            let r = tile.first_ray + i;
            let (lo, hi) = (s.off[r] as usize, s.off[r + 1] as usize);
            *slot = integrate_ray(
                &s.t[lo..hi],
                &s.dt[lo..hi],
                &s.sigma[lo..hi],
                &s.color[lo..hi],
                &mut tile.alpha[lo - base..hi - base],
                &mut tile.log_t[lo - base..hi - base],
                m,
                s.flags[r],
            );
        }
    });
    out
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::volume::sample::Sampling;

    fn march(path: TransPath, early_stop: f64) -> March<f64> {
        March {
            dt: 0.1,
            max_steps: 100,
            early_stop,
            sampling: Sampling::Fixed,
            path,
            background: [0.0, 0.0, 1.0],
        }
    }

    fn run(path: TransPath, es: f64, sigma: f64, n: usize) -> (RayOut<f64>, Vec<f64>, Vec<f64>) {
        let t: Vec<f64> = (0..n).map(|k| 0.05 + 0.1 * k as f64).collect();
        let (mut a, mut l) = (vec![9.0; n], vec![9.0; n]);
        let out = integrate_ray(
            &t,
            &vec![0.1; n],
            &vec![sigma; n],
            &vec![[1.0, 0.5, 0.25]; n],
            &mut a,
            &mut l,
            &march(path, es),
            1,
        );
        (out, a, l)
    }

    #[test]
    fn constant_medium_matches_the_geometric_series() {
        let (o, a, l) = run(TransPath::Product, 0.0, 2.0, 10);
        let q = (-0.2f64).exp();
        assert!((o.trans - q.powi(10)).abs() < 1e-15);
        assert!((o.log_trans + 2.0).abs() < 1e-14);
        assert!((o.rgb[0] - (1.0 - q.powi(10))).abs() < 1e-14);
        assert!((o.rgb[2] - (0.25 * (1.0 - q.powi(10)) + q.powi(10))).abs() < 1e-14);
        assert!((a[3] - (1.0 - q)).abs() < 1e-15 && (l[3] + 0.6).abs() < 1e-15);
        assert!((o.opacity - (1.0 - o.trans)).abs() < 1e-15);
    }

    #[test]
    fn log_path_equals_product_path_in_benign_media() {
        let (p, _, _) = run(TransPath::Product, 0.0, 1.5, 20);
        let (l, _, _) = run(TransPath::Log, 0.0, 1.5, 20);
        assert!((p.trans - l.trans).abs() < 1e-14 && (p.rgb[1] - l.rgb[1]).abs() < 1e-14);
    }

    #[test]
    fn early_stop_keeps_t_and_zeroes_later_alphas() {
        let (o, a, l) = run(TransPath::Product, 1e-4, 20.0, 50);
        // T_k = e^{-2k} drops below 1e-4 at k = 5.
        assert_eq!(o.n, 5);
        assert!(o.flags & FLAG_STOPPED != 0);
        assert!((o.trans - (-10.0f64).exp()).abs() < 1e-18);
        assert_eq!(a[5], 0.0);
        assert_eq!(l[49], o.log_trans);
    }

    #[test]
    fn huge_density_saturates_without_nan_and_keeps_exact_log_t() {
        let t = [0.005f32];
        let (mut a, mut l) = ([0.0f32], [0.0f32]);
        let m = March {
            dt: 0.01f32,
            max_steps: 10,
            early_stop: 1e-4,
            sampling: Sampling::Fixed,
            path: TransPath::Product,
            background: [0.0; 3],
        };
        let o = integrate_ray(
            &t,
            &[0.01],
            &[1e4],
            &[[1.0, 0.5, 0.25]],
            &mut a,
            &mut l,
            &m,
            1,
        );
        assert_eq!((o.trans, o.opacity, o.saturated), (0.0, 1.0, 1));
        assert_eq!(o.log_trans, -(1e4f32 * 0.01));
        assert_eq!(o.rgb, [1.0, 0.5, 0.25]);
    }

    #[test]
    fn f32_alpha_has_full_relative_accuracy_everywhere() {
        let mut worst = 0.0f64;
        for i in 0..20_000 {
            let tau = 1e-12f64 * (1.0017f64).powi(i);
            let a = alpha_of(tau as f32) as f64;
            let exact = -(-(tau as f32 as f64)).exp_m1();
            worst = worst.max(((a - exact) / exact).abs());
        }
        assert!(worst < 4.0 * f32::EPSILON as f64, "{worst}");
        assert_eq!(alpha_of(0.0f32), 0.0);
        assert_eq!(alpha_of(1e4f32), 1.0);
    }

    #[test]
    fn tiny_optical_depth_keeps_full_relative_accuracy_of_alpha() {
        let mut acc = RayAcc::<f32>::default();
        let alpha = acc.step(1.0, 1e-7, [1.0; 3], 0.0, 0.01);
        let exact = -(-1e-9f64).exp_m1();
        assert!(((alpha as f64 - exact) / exact).abs() < 1e-6, "{alpha}");
    }
}
