//! Evidence for the unit tests of the assertion kinds: named f64 tensors,
//! metrics, a tolerance `t` (atol 1e-3), gates `g` (0.05) and `two` (2).

use std::collections::BTreeMap;
use std::path::Path;

use super::Evidence;
use crate::judge::thresholds::{Profile, Thresholds, ThresholdsFile, Tol};
use crate::tensor::Tensor;

pub struct Fixture {
    tensors: BTreeMap<String, Tensor>,
    metrics: BTreeMap<String, f64>,
    thresholds: Thresholds,
}

/// Evidence of 1-D tensors `tensors`.
pub fn fixture(tensors: &[(&str, &[f64])]) -> Fixture {
    let tol = Tol {
        atol: 1e-3,
        ..Tol::default()
    };
    let file = ThresholdsFile {
        schema_version: 1,
        tolerances: [("t".to_string(), tol)].into(),
        gates: [("g".to_string(), 0.05), ("two".to_string(), 2.0)].into(),
        timeouts: BTreeMap::new(),
        profiles: BTreeMap::new(),
    };
    let thresholds = Thresholds {
        path: "thresholds.yaml".into(),
        sha256: String::new(),
        profile_name: "default".into(),
        profile: Profile::default(),
        file,
    };
    let mut f = Fixture {
        tensors: BTreeMap::new(),
        metrics: BTreeMap::new(),
        thresholds,
    };
    for (n, v) in tensors {
        f = f.shaped(n, &[v.len()], v);
    }
    f
}

impl Fixture {
    /// Adds tensor `name` of `shape`.
    pub fn shaped(mut self, name: &str, shape: &[usize], v: &[f64]) -> Fixture {
        self.tensors.insert(
            name.into(),
            Tensor::from_shape_vec(shape, v.to_vec()).unwrap(),
        );
        self
    }

    /// Adds metric `name`.
    pub fn metric(mut self, name: &str, v: f64) -> Fixture {
        self.metrics.insert(name.into(), v);
        self
    }

    pub fn ev(&self) -> Evidence<'_> {
        Evidence {
            tensors: &self.tensors,
            metrics: &self.metrics,
            goldens: Path::new("GOLDENS"),
            thresholds: &self.thresholds,
        }
    }
}
