//! Memory budget: every stage computes the bytes a plan needs before it
//! allocates and refuses plans over the budget with `Error::OutOfMemory`.
//! Linux overcommits, so a failed allocation is not how a too-large request
//! is caught.

use crate::error::{Error, Result};

/// The most bytes one plan may allocate.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct MemBudget {
    pub bytes: u64,
}

impl MemBudget {
    /// A fixed budget (`--mem-limit`).
    pub fn fixed(bytes: u64) -> Self {
        MemBudget { bytes }
    }

    /// The machine's available memory (`MemAvailable` in /proc/meminfo) less
    /// a quarter for everything else; 4 GiB where that cannot be read.
    pub fn from_machine() -> Self {
        let avail = std::fs::read_to_string("/proc/meminfo")
            .ok()
            .and_then(|s| parse_mem_available(&s));
        MemBudget {
            bytes: avail.map_or(4 << 30, |b| b / 4 * 3),
        }
    }

    /// Refuses `needed` bytes for `what` when over budget. `needed` is
    /// computed with checked arithmetic by the caller ([`bytes_for`]).
    pub fn check(&self, what: &str, needed: Option<u64>) -> Result<()> {
        match needed {
            Some(n) if n <= self.bytes => Ok(()),
            Some(n) => Err(Error::OutOfMemory {
                what: what.to_string(),
                needed: n,
                budget: self.bytes,
            }),
            None => Err(Error::OutOfMemory {
                what: what.to_string(),
                needed: u64::MAX,
                budget: self.bytes,
            }),
        }
    }
}

/// `count * bytes_each`, `None` on overflow.
pub fn bytes_for(count: u64, bytes_each: u64) -> Option<u64> {
    count.checked_mul(bytes_each)
}

/// Parses `MemAvailable:  123 kB` from /proc/meminfo text.
pub fn parse_mem_available(meminfo: &str) -> Option<u64> {
    let line = meminfo.lines().find(|l| l.starts_with("MemAvailable:"))?;
    let kb: u64 = line.split_whitespace().nth(1)?.parse().ok()?;
    kb.checked_mul(1024)
}

/// A per-render work budget: the product of `factors` (each a count and
/// what it counts) must be at most `2^log2` `unit`, or the render is refused
/// as `key` before any work, instead of running for days. Each renderer sets
/// its own limit from its measured rate (`pathtrace::integrator::MAX_PATHS`,
/// `scene::transport::MAX_PHOTON_STEPS`, `scene::volume::MAX_SAMPLES`,
/// `scene::voxels::MAX_BUILD_CELLS`).
pub fn check_work(key: &str, factors: &[(u64, &str)], unit: &str, limit: u64) -> Result<()> {
    let total = factors.iter().try_fold(1u64, |a, &(n, _)| a.checked_mul(n));
    if total.is_some_and(|t| t <= limit) {
        return Ok(());
    }
    let terms: Vec<String> = factors.iter().map(|(n, w)| format!("{n} {w}")).collect();
    let total = total.map_or("over 2^64".to_string(), |t| t.to_string());
    let sum = match factors.len() {
        1 => String::new(),
        _ => format!(" = {total}"),
    };
    let why = format!(
        "{}{sum}: over the work budget of 2^{} {unit}",
        terms.join(" x "),
        limit.trailing_zeros()
    );
    Err(Error::invalid(key, why))
}

/// Parses a size like `512M`, `2G`, `1048576` (bytes; K/M/G/T are powers of 1024).
pub fn parse_size(s: &str) -> std::result::Result<u64, String> {
    let s = s.trim();
    let (num, mult) = match s.chars().last() {
        Some('K' | 'k') => (&s[..s.len() - 1], 1u64 << 10),
        Some('M' | 'm') => (&s[..s.len() - 1], 1 << 20),
        Some('G' | 'g') => (&s[..s.len() - 1], 1 << 30),
        Some('T' | 't') => (&s[..s.len() - 1], 1 << 40),
        _ => (s, 1),
    };
    let n: u64 = num
        .trim()
        .parse()
        .map_err(|_| format!("not a size: {s:?} (use e.g. 512M or 2G)"))?;
    n.checked_mul(mult)
        .ok_or_else(|| format!("size {s:?} overflows 64 bits"))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn over_budget_plans_are_refused_with_their_size() {
        let b = MemBudget::fixed(1000);
        assert!(b.check("x", Some(1000)).is_ok());
        let e = b.check("rays", Some(1001)).unwrap_err().to_string();
        assert!(e.contains("rays needs 1001 bytes"), "{e}");
        assert!(b.check("huge", bytes_for(u64::MAX, 2)).is_err());
    }

    #[test]
    fn work_over_its_budget_is_refused_naming_key_factors_and_limit() {
        assert!(check_work(
            "spp",
            &[(1 << 10, "pixels"), (1 << 26, "spp")],
            "paths per render",
            1 << 36
        )
        .is_ok());
        let e = check_work(
            "spp",
            &[(1 << 10, "pixels"), ((1 << 26) + 1, "spp")],
            "paths per render",
            1 << 36,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("spp") && e.contains("1024 pixels x 67108865 spp") && e.contains("2^36"),
            "{e}"
        );
        let e = check_work(
            "n",
            &[(u64::MAX, "rays"), (2, "steps")],
            "steps per render",
            1 << 40,
        )
        .unwrap_err()
        .to_string();
        assert!(
            e.contains("= over 2^64: over the work budget of 2^40 steps per render"),
            "{e}"
        );
    }

    #[test]
    fn meminfo_and_sizes_parse() {
        assert_eq!(
            parse_mem_available("MemTotal: 10 kB\nMemAvailable:    2048 kB\n"),
            Some(2048 * 1024)
        );
        assert_eq!(parse_size("2G"), Ok(2 << 30));
        assert_eq!(parse_size("17"), Ok(17));
        assert!(parse_size("lots").is_err());
    }
}
