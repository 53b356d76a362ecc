//! Measuring: wall and CPU seconds of a call. On a shared machine the wall
//! clock counts time other jobs held the cores; CPU time does not, so rates
//! per CPU second are the figures to compare.
//!
//! Per renderer, the timing harnesses the perf operations wire (repeats,
//! medians, CPU seconds): `volume.rs`, `pathtrace.rs`, `voxels.rs`.

pub mod pathtrace;
pub mod transport;
pub mod volume;
pub mod voxels;

use std::time::Instant;

/// CPU seconds this process has used (user + system, all threads), from
/// /proc/self/stat (USER_HZ = 100); `None` off Linux. Throughput per CPU
/// second is robust to other jobs sharing the machine, unlike wall time.
pub fn process_cpu_s() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/stat").ok()?;
    let rest = &s[s.rfind(')')? + 2..];
    let f: Vec<&str> = rest.split_whitespace().collect();
    let ticks = f.get(11)?.parse::<u64>().ok()? + f.get(12)?.parse::<u64>().ok()?;
    Some(ticks as f64 / 100.0)
}

/// Runs `f`, returning its result, wall seconds and CPU seconds (0 when unknown).
pub fn timed<R>(f: impl FnOnce() -> R) -> (R, f64, f64) {
    let (c0, t0) = (process_cpu_s(), Instant::now());
    let r = f();
    let wall = t0.elapsed().as_secs_f64();
    let cpu = match (c0, process_cpu_s()) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    };
    (r, wall, cpu)
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The process's CPU time counts every thread (other tests run beside
    /// this one), so the bound is wall time times the logical CPUs.
    #[test]
    fn process_cpu_time_is_bounded_by_wall_time_times_cpus() {
        if process_cpu_s().is_none() {
            return;
        }
        let (_, w, c) = timed(|| {
            let t = Instant::now();
            let mut x = 0u64;
            while t.elapsed().as_secs_f64() < 0.05 {
                x = x.wrapping_add(std::hint::black_box(1));
            }
            x
        });
        // /proc ticks are 10 ms: allow two ticks of rounding per CPU.
        let cpus = crate::judge::env::logical_cpus() as f64;
        assert!(
            w >= 0.05 && c >= 0.0 && c <= (w + 0.02) * cpus,
            "wall {w} cpu {c} on {cpus} CPUs"
        );
    }
}
