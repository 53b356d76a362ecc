//! Analytic densities (SCENES.md "Analytic fields"): the f64 description,
//! its validation and its conservative occupancy test.

use crate::error::{Error, Result};

use super::MAX_SIGMA;

/// An analytic density, f64 parameters.
#[derive(Clone, Debug, PartialEq)]
pub enum Analytic {
    Constant {
        s: f64,
    },
    /// Piecewise constant along `axis` (0 = x): `breaks` strictly increasing,
    /// `sigma.len() == breaks.len() - 1`.
    Slabs {
        axis: usize,
        breaks: Vec<f64>,
        sigma: Vec<f64>,
    },
    Gaussian {
        amplitude: f64,
        mean: [f64; 3],
        std: f64,
    },
    Shell {
        centre: [f64; 3],
        r0: f64,
        r1: f64,
        s: f64,
    },
    Linear {
        a: f64,
        g: [f64; 3],
    },
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

impl Analytic {
    /// sigma at `x` in f64 (the description's own formula; used for grid
    /// generation and occupancy, never by the renderer's hot loop).
    pub fn eval(&self, x: [f64; 3]) -> f64 {
        match self {
            Analytic::Constant { s } => *s,
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => slab_value(breaks, sigma, x[*axis]),
            Analytic::Gaussian {
                amplitude,
                mean,
                std,
            } => {
                let r2 = (0..3).map(|a| (x[a] - mean[a]).powi(2)).sum::<f64>();
                amplitude * (-r2 / (2.0 * std * std)).exp()
            }
            Analytic::Shell { centre, r0, r1, s } => {
                let r = (0..3)
                    .map(|a| (x[a] - centre[a]).powi(2))
                    .sum::<f64>()
                    .sqrt();
                if *r0 <= r && r <= *r1 {
                    *s
                } else {
                    0.0
                }
            }
            Analytic::Linear { a, g } => (a + dot(*g, x)).max(0.0),
        }
    }

    /// Checks parameters; `bmin`/`bmax` is the world box (for `linear`'s
    /// sign condition). `at` names the scene key.
    pub fn validate(&self, at: &str, bmin: [f64; 3], bmax: [f64; 3]) -> Result<()> {
        let fin = |v: f64, k: &str| -> Result<()> {
            if v.is_finite() {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("{at}.{k}"),
                    format!("{v} is not finite"),
                ))
            }
        };
        let dens = |v: f64, k: &str| -> Result<()> {
            if v.is_finite() && (0.0..=MAX_SIGMA).contains(&v) {
                Ok(())
            } else {
                Err(Error::invalid(
                    format!("{at}.{k}"),
                    format!("density {v} is not in [0, {MAX_SIGMA:e}]"),
                ))
            }
        };
        match self {
            Analytic::Constant { s } => dens(*s, "s"),
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => {
                if *axis > 2 {
                    return Err(Error::invalid(format!("{at}.axis"), "must be x, y or z"));
                }
                if breaks.len() < 2 || sigma.len() + 1 != breaks.len() {
                    return Err(Error::invalid(
                        at,
                        format!(
                            "need n + 1 >= 2 breaks for n sigmas, got {} and {}",
                            breaks.len(),
                            sigma.len()
                        ),
                    ));
                }
                for b in breaks {
                    fin(*b, "breaks")?;
                }
                if breaks.windows(2).any(|w| w[0] >= w[1]) {
                    return Err(Error::invalid(
                        format!("{at}.breaks"),
                        "must be strictly increasing",
                    ));
                }
                sigma.iter().try_for_each(|s| dens(*s, "sigma"))
            }
            Analytic::Gaussian {
                amplitude,
                mean,
                std,
            } => {
                dens(*amplitude, "amplitude")?;
                mean.iter().try_for_each(|m| fin(*m, "mean"))?;
                if !(std.is_finite() && *std > 0.0) {
                    return Err(Error::invalid(
                        format!("{at}.std"),
                        format!("{std} is not a positive number"),
                    ));
                }
                Ok(())
            }
            Analytic::Shell { centre, r0, r1, s } => {
                centre.iter().try_for_each(|m| fin(*m, "centre"))?;
                dens(*s, "s")?;
                if !(r0.is_finite() && r1.is_finite() && 0.0 <= *r0 && r0 <= r1) {
                    return Err(Error::invalid(
                        at,
                        format!("need 0 <= r0 <= r1, got r0 = {r0}, r1 = {r1}"),
                    ));
                }
                Ok(())
            }
            Analytic::Linear { a, g } => {
                fin(*a, "a")?;
                g.iter().try_for_each(|v| fin(*v, "g"))?;
                let mut lo = f64::INFINITY;
                let mut hi = f64::NEG_INFINITY;
                for c in 0..8 {
                    let x = [0, 1, 2].map(|k| if c >> k & 1 == 1 { bmax[k] } else { bmin[k] });
                    lo = lo.min(a + dot(*g, x));
                    hi = hi.max(a + dot(*g, x));
                }
                if lo < 0.0 || hi > MAX_SIGMA {
                    return Err(Error::invalid(
                        at,
                        format!("a + g . x ranges over [{lo}, {hi}] on the box; need [0, {MAX_SIGMA:e}]"),
                    ));
                }
                Ok(())
            }
        }
    }

    /// Whether sigma can be non-zero somewhere in the closed box [lo, hi]
    /// (conservative: `true` when unsure). Drives the occupancy bitfield.
    pub fn may_be_nonzero(&self, lo: [f64; 3], hi: [f64; 3]) -> bool {
        match self {
            Analytic::Constant { s } => *s > 0.0,
            Analytic::Slabs {
                axis,
                breaks,
                sigma,
            } => (0..sigma.len())
                .any(|i| sigma[i] > 0.0 && breaks[i] <= hi[*axis] && lo[*axis] <= breaks[i + 1]),
            Analytic::Gaussian { amplitude, .. } => *amplitude > 0.0,
            Analytic::Shell { centre, r0, r1, s } => {
                let (mut near2, mut far2) = (0.0, 0.0);
                for a in 0..3 {
                    let (dl, dh) = (lo[a] - centre[a], hi[a] - centre[a]);
                    let n = if dl > 0.0 {
                        dl
                    } else if dh < 0.0 {
                        -dh
                    } else {
                        0.0
                    };
                    near2 += n * n;
                    far2 += dl.abs().max(dh.abs()).powi(2);
                }
                *s > 0.0 && far2.sqrt() >= *r0 && near2.sqrt() <= *r1
            }
            Analytic::Linear { a, g } => {
                let hi_val = a
                    + (0..3)
                        .map(|k| (g[k] * lo[k]).max(g[k] * hi[k]))
                        .sum::<f64>();
                hi_val > 0.0
            }
        }
    }
}

/// The slab value at coordinate `v`: half-open slabs, the last one closed.
fn slab_value(breaks: &[f64], sigma: &[f64], v: f64) -> f64 {
    let n = sigma.len();
    for i in 0..n {
        if breaks[i] <= v && (v < breaks[i + 1] || (i + 1 == n && v <= breaks[n])) {
            return sigma[i];
        }
    }
    0.0
}

#[cfg(test)]
mod tests {
    use super::super::{Field, FieldDesc, GridDesc, Oob};
    use super::*;

    const B0: [f64; 3] = [-1.0; 3];
    const B1: [f64; 3] = [1.0; 3];

    #[test]
    fn analytic_fields_follow_their_formulas() {
        let slabs = Analytic::Slabs {
            axis: 0,
            breaks: vec![-1.0, -0.2, 0.3, 1.0],
            sigma: vec![0.5, 8.0, 1.0],
        };
        let f: Field<f32> = FieldDesc::Analytic(slabs.clone()).to_real();
        assert_eq!(f.sigma([-0.2, 0.0, 0.0]), 8.0);
        assert_eq!(f.sigma([0.3, 0.0, 0.0]), 1.0);
        assert_eq!(f.sigma([1.0, 0.0, 0.0]), 1.0);
        assert_eq!(f.sigma([1.0001, 0.0, 0.0]), 0.0);
        let shell = FieldDesc::Analytic(Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        });
        let s: Field<f64> = shell.to_real();
        assert_eq!(s.sigma([0.65, 0.0, 0.0]), 30.0);
        assert_eq!(s.sigma([0.0, 0.5, 0.0]), 0.0);
        let g: Field<f64> = FieldDesc::Analytic(Analytic::Gaussian {
            amplitude: 20.0,
            mean: [0.0; 3],
            std: 0.3,
        })
        .to_real();
        assert!((g.sigma([0.3, 0.0, 0.0]) - 20.0 * (-0.5f64).exp()).abs() < 1e-13);
    }

    #[test]
    fn invalid_fields_are_refused_with_their_key() {
        let bad = Analytic::Slabs {
            axis: 0,
            breaks: vec![0.0, 0.0],
            sigma: vec![1.0],
        };
        assert!(bad
            .validate("field", B0, B1)
            .unwrap_err()
            .to_string()
            .contains("increasing"));
        let neg = Analytic::Linear {
            a: 0.5,
            g: [1.0, 0.0, 0.0],
        };
        assert!(neg.validate("field", B0, B1).is_err());
        let mut g = GridDesc::filled([2, 2, 2], &[1.0], B0, B1, Oob::Zero);
        g.data[3] = f64::NAN;
        assert!(g
            .validate("grid.npy", true)
            .unwrap_err()
            .to_string()
            .contains("flat index 3"));
        g.data[3] = -1.0;
        assert!(g.validate("grid.npy", true).is_err());
        assert!(g.validate("colour.npy", false).is_ok());
    }

    #[test]
    fn occupancy_tests_are_conservative() {
        let shell = Analytic::Shell {
            centre: [0.0; 3],
            r0: 0.6,
            r1: 0.7,
            s: 30.0,
        };
        assert!(!shell.may_be_nonzero([-0.1; 3], [0.1; 3]));
        assert!(shell.may_be_nonzero([0.6, 0.0, 0.0], [0.7, 0.1, 0.1]));
        assert!(!shell.may_be_nonzero([0.9, 0.9, 0.9], [1.0, 1.0, 1.0]));
        let g = GridDesc::sample([9, 9, 9], B0, B1, Oob::Zero, |x| {
            if x[0] > 0.6 {
                1.0
            } else {
                0.0
            }
        });
        assert!(!g.may_be_nonzero([-1.0; 3], [0.2, 1.0, 1.0]));
        assert!(g.may_be_nonzero([0.3, -1.0, -1.0], [0.5, 1.0, 1.0]));
    }
}
