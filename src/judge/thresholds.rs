//! `thresholds.yaml`: every tolerance, gate and time limit, by name, with
//! per-device-profile overrides. Algorithm code never reads this file; the
//! judge resolves names here and hands numbers to the assertions.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

use serde::{Deserialize, Serialize};
use sha2::{Digest, Sha256};

use super::load::{load_yaml_typed, JudgeInputError};

/// The one tolerance type: `|a - b| <= atol + rtol * |b|` after NaN and
/// infinity are handled (NaN never passes; equal infinities pass). For
/// relative-error checks, `|a - b| / max(|b|, floor)` with
/// `floor = max(floor, floor_rel * max|b|)`.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq)]
#[serde(deny_unknown_fields)]
pub struct Tol {
    #[serde(default)]
    pub atol: f64,
    #[serde(default)]
    pub rtol: f64,
    #[serde(default)]
    pub floor: f64,
    #[serde(default)]
    pub floor_rel: f64,
}

impl Tol {
    /// Whether `a` is within tolerance of `b`.
    pub fn close(&self, a: f64, b: f64) -> bool {
        if a.is_nan() || b.is_nan() {
            return false;
        }
        if a.is_infinite() || b.is_infinite() {
            return a == b;
        }
        (a - b).abs() <= self.atol + self.rtol * b.abs()
    }
}

/// Which cases run at which size.
#[derive(Clone, Copy, Debug, Default, Deserialize, Serialize, PartialEq, Eq)]
#[serde(rename_all = "lowercase")]
pub enum SizeProfile {
    /// Small fixtures: every case with `size: ci`, with its `ci:` overrides.
    Ci,
    /// Every case at full size.
    #[default]
    Full,
}

/// A device profile.
#[derive(Clone, Debug, Default, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct Profile {
    #[serde(default)]
    pub description: String,
    #[serde(default)]
    pub size: SizeProfile,
    /// Whether `throughput_ge` / `speedup_ge` fail a case (else they report).
    #[serde(default)]
    pub enforce_perf: bool,
    /// Chosen automatically when the GPU adapter name contains this.
    #[serde(default)]
    pub match_gpu: Option<String>,
    /// Multiplies every time limit.
    #[serde(default = "one")]
    pub timeout_scale: f64,
    #[serde(default)]
    pub gates: BTreeMap<String, f64>,
    #[serde(default)]
    pub tolerances: BTreeMap<String, Tol>,
}

fn one() -> f64 {
    1.0
}

/// The file as written.
#[derive(Clone, Debug, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct ThresholdsFile {
    pub schema_version: u32,
    #[serde(default)]
    pub tolerances: BTreeMap<String, Tol>,
    #[serde(default)]
    pub gates: BTreeMap<String, f64>,
    #[serde(default)]
    pub timeouts: BTreeMap<String, f64>,
    #[serde(default)]
    pub profiles: BTreeMap<String, Profile>,
}

/// Thresholds with one profile applied.
#[derive(Clone, Debug, Deserialize, Serialize)]
pub struct Thresholds {
    pub path: PathBuf,
    pub sha256: String,
    pub profile_name: String,
    pub profile: Profile,
    pub file: ThresholdsFile,
}

impl Thresholds {
    /// Reads the file and applies `profile` (which must exist).
    pub fn load(path: &Path, profile: &str) -> Result<Thresholds, JudgeInputError> {
        let (file, text): (ThresholdsFile, String) = load_yaml_typed(path)?;
        let at = path.display().to_string();
        if file.schema_version != 1 {
            return Err(JudgeInputError::new(
                &at,
                "schema_version",
                format!("{} is not 1", file.schema_version),
            ));
        }
        validate_values(&file).map_err(|(key, what)| {
            JudgeInputError::new(&at, &key, what).at_line(line_of(&text, &key))
        })?;
        let p = file.profiles.get(profile).cloned().ok_or_else(|| {
            let known: Vec<&String> = file.profiles.keys().collect();
            JudgeInputError::new(
                &at,
                "profiles",
                format!("no profile {profile:?} (known: {known:?})"),
            )
        })?;
        for (k, _) in p.gates.iter() {
            if !file.gates.contains_key(k) {
                return Err(JudgeInputError::new(
                    &at,
                    &format!("profiles.{profile}.gates.{k}"),
                    "not a gate name",
                ));
            }
        }
        for (k, _) in p.tolerances.iter() {
            if !file.tolerances.contains_key(k) {
                return Err(JudgeInputError::new(
                    &at,
                    &format!("profiles.{profile}.tolerances.{k}"),
                    "not a tolerance name",
                ));
            }
        }
        if !file.timeouts.contains_key("default") {
            return Err(JudgeInputError::new(
                &at,
                "timeouts.default",
                "missing (seconds per case)",
            ));
        }
        let sha256 = format!("{:x}", Sha256::digest(text.as_bytes()));
        Ok(Thresholds {
            path: path.to_path_buf(),
            sha256,
            profile_name: profile.to_string(),
            profile: p,
            file,
        })
    }

    pub fn tol(&self, name: &str) -> Option<Tol> {
        self.profile
            .tolerances
            .get(name)
            .or_else(|| self.file.tolerances.get(name))
            .copied()
    }

    pub fn gate(&self, name: &str) -> Option<f64> {
        self.profile
            .gates
            .get(name)
            .or_else(|| self.file.gates.get(name))
            .copied()
    }

    /// The time limit in seconds for a timeout name, scaled by the profile.
    pub fn timeout(&self, name: &str) -> Option<f64> {
        self.file
            .timeouts
            .get(name)
            .map(|s| s * self.profile.timeout_scale)
    }
}

/// Checks every number of the file: tolerances finite and >= 0; gates
/// finite; time limits and scales finite and > 0. Returns the key path and
/// what is wrong.
pub fn validate_values(f: &ThresholdsFile) -> Result<(), (String, String)> {
    let tol_ok = |key: &str, t: &Tol| -> Result<(), (String, String)> {
        for (k, v) in [
            ("atol", t.atol),
            ("rtol", t.rtol),
            ("floor", t.floor),
            ("floor_rel", t.floor_rel),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return Err((
                    format!("{key}.{k}"),
                    format!("{v} is not a finite number >= 0"),
                ));
            }
        }
        Ok(())
    };
    let gate_ok = |key: &str, g: f64| {
        if g.is_finite() {
            Ok(())
        } else {
            Err((key.to_string(), format!("{g} is not a finite number")))
        }
    };
    let positive = |key: &str, x: f64| {
        if x.is_finite() && x > 0.0 {
            Ok(())
        } else {
            Err((key.to_string(), format!("{x} is not a finite number > 0")))
        }
    };
    for (k, t) in &f.tolerances {
        tol_ok(&format!("tolerances.{k}"), t)?;
    }
    for (k, g) in &f.gates {
        gate_ok(&format!("gates.{k}"), *g)?;
    }
    for (k, s) in &f.timeouts {
        positive(&format!("timeouts.{k}"), *s)?;
    }
    for (name, p) in &f.profiles {
        positive(&format!("profiles.{name}.timeout_scale"), p.timeout_scale)?;
        for (k, t) in &p.tolerances {
            tol_ok(&format!("profiles.{name}.tolerances.{k}"), t)?;
        }
        for (k, g) in &p.gates {
            gate_ok(&format!("profiles.{name}.gates.{k}"), *g)?;
        }
    }
    Ok(())
}

/// The line of the last segment of a dotted key path (`tolerances.x.atol`
/// -> the first line naming `x:` after `tolerances:`), best effort.
fn line_of(text: &str, key: &str) -> Option<usize> {
    let mut from = 0usize;
    let mut line = None;
    for seg in key.split('.') {
        let pat = format!("{seg}:");
        let i = text
            .lines()
            .enumerate()
            .skip(from)
            .find(|(_, l)| {
                l.trim_start().starts_with(&pat)
                    || l.contains(&format!(" {pat}"))
                    || l.contains(&format!("{{{pat}"))
            })
            .map(|(i, _)| i)?;
        from = i;
        line = Some(i + 1);
    }
    line
}

/// Picks the profile when `--profile` is not given: `ci` when the `CI`
/// environment variable is set, else the profile whose `match_gpu` is in the
/// GPU adapter name, else `default`. Returns the name and why.
pub fn pick_profile(file: &ThresholdsFile, ci: bool, gpu_name: Option<&str>) -> (String, String) {
    if ci && file.profiles.contains_key("ci") {
        return ("ci".into(), "CI is set".into());
    }
    if let Some(g) = gpu_name {
        for (name, p) in &file.profiles {
            if p.match_gpu.as_deref().is_some_and(|m| g.contains(m)) {
                return (name.clone(), format!("GPU {g:?} matches"));
            }
        }
    }
    ("default".into(), "no CI, no matching GPU".into())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn file(text: &str) -> ThresholdsFile {
        serde_yaml::from_str(text).unwrap()
    }

    #[test]
    fn infinite_negative_and_nan_values_are_refused_with_their_key() {
        let base = "schema_version: 1\ntimeouts: {default: 10}\n";
        for (extra, key) in [
            ("tolerances: {t: {atol: .inf}}", "tolerances.t.atol"),
            ("tolerances: {t: {rtol: -1}}", "tolerances.t.rtol"),
            ("tolerances: {t: {floor: .nan}}", "tolerances.t.floor"),
            ("gates: {g: .nan}", "gates.g"),
            (
                "profiles: {p: {timeout_scale: 0}}",
                "profiles.p.timeout_scale",
            ),
            (
                "profiles: {p: {tolerances: {t: {atol: .inf}}}}",
                "profiles.p.tolerances.t.atol",
            ),
        ] {
            let f = file(&format!("{base}{extra}\n"));
            assert_eq!(validate_values(&f).unwrap_err().0, key, "{extra}");
        }
        let f = file("schema_version: 1\ntimeouts: {default: .nan}\n");
        assert_eq!(validate_values(&f).unwrap_err().0, "timeouts.default");
        let f = file("schema_version: 1\ntimeouts: {default: -3}\n");
        assert_eq!(validate_values(&f).unwrap_err().0, "timeouts.default");
        let f = file(&format!(
            "{base}tolerances: {{t: {{atol: 0.5}}}}\ngates: {{g: -2}}\n"
        ));
        assert!(validate_values(&f).is_ok());
    }

    #[test]
    fn the_committed_thresholds_file_is_valid() {
        let p = Path::new(env!("CARGO_MANIFEST_DIR")).join("thresholds.yaml");
        let (f, _): (ThresholdsFile, String) = load_yaml_typed(&p).unwrap();
        assert_eq!(validate_values(&f), Ok(()));
    }

    #[test]
    fn tolerance_handles_nan_and_infinity_first() {
        let t = Tol {
            atol: 1e-3,
            rtol: 1e-2,
            ..Default::default()
        };
        assert!(t.close(1.0105, 1.0));
        assert!(!t.close(1.02, 1.0));
        assert!(!t.close(f64::NAN, 1.0));
        assert!(!t.close(f64::NAN, f64::NAN));
        assert!(t.close(f64::INFINITY, f64::INFINITY));
        assert!(!t.close(f64::INFINITY, 1e300));
    }
}
