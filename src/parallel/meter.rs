//! The fan-out meter: how far the current top-level parallel launch has got,
//! so a long render can show a bar with an ETA (`judge::progress::follow`).
//!
//! Off unless [`enable`] was called: then each launch that finds no other
//! launch open claims the meter ([`Meter::open`]), counts its finished items
//! with one relaxed atomic add each, and releases it when it ends. Launches
//! nested inside it are not counted, so the figure is the outer launch's.
//! Counting never changes what a launch computes.

use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;

/// The process's meter, fed by every launch in `parallel`.
pub static GLOBAL: Meter = Meter::new();

/// Turns the process's metering on (off by default).
pub fn enable() {
    GLOBAL.enabled.store(true, Ordering::Relaxed);
}

/// The process meter's current reading.
pub fn read() -> Reading {
    GLOBAL.read()
}

/// What a meter shows.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct Reading {
    /// The open launch's label, or the last one's when none is open.
    pub label: &'static str,
    /// Items finished in that launch.
    pub done: u64,
    /// Items in that launch.
    pub total: u64,
    /// Top-level launches opened so far (a render may run several stages).
    pub launches: u64,
}

/// Progress of the outermost open launch (one per process: [`GLOBAL`]).
pub struct Meter {
    enabled: AtomicBool,
    open: AtomicBool,
    done: AtomicU64,
    total: AtomicU64,
    launches: AtomicU64,
    label: Mutex<&'static str>,
}

impl Meter {
    /// A meter that is off and holds no launch.
    pub const fn new() -> Self {
        Meter {
            enabled: AtomicBool::new(false),
            open: AtomicBool::new(false),
            done: AtomicU64::new(0),
            total: AtomicU64::new(0),
            launches: AtomicU64::new(0),
            label: Mutex::new(""),
        }
    }

    /// The current reading.
    pub fn read(&self) -> Reading {
        Reading {
            label: *self.label.lock().unwrap_or_else(|e| e.into_inner()),
            done: self.done.load(Ordering::Relaxed),
            total: self.total.load(Ordering::Relaxed),
            launches: self.launches.load(Ordering::Relaxed),
        }
    }

    /// Claims the meter for a launch of `n` items when metering is on and
    /// no other launch holds it; the returned hold counts only if it owns it.
    pub fn open(&self, label: &'static str, n: usize) -> Launch<'_> {
        let owns = self.enabled.load(Ordering::Relaxed)
            && self
                .open
                .compare_exchange(false, true, Ordering::Acquire, Ordering::Relaxed)
                .is_ok();
        if owns {
            *self.label.lock().unwrap_or_else(|e| e.into_inner()) = label;
            self.done.store(0, Ordering::Relaxed);
            self.total.store(n as u64, Ordering::Relaxed);
            self.launches.fetch_add(1, Ordering::Relaxed);
        }
        Launch { meter: self, owns }
    }
}

impl Default for Meter {
    fn default() -> Self {
        Self::new()
    }
}

/// One launch's hold on a meter.
pub struct Launch<'a> {
    meter: &'a Meter,
    owns: bool,
}

impl Launch<'_> {
    /// Counts `k` finished items (nothing when this launch is not metered).
    #[inline]
    pub fn advance(&self, k: usize) {
        if self.owns {
            self.meter.done.fetch_add(k as u64, Ordering::Relaxed);
        }
    }
}

impl Drop for Launch<'_> {
    fn drop(&mut self) {
        if self.owns {
            self.meter.open.store(false, Ordering::Release);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_meter_that_is_off_counts_nothing() {
        let m = Meter::new();
        m.open("off", 5).advance(5);
        assert_eq!(m.read().launches, 0);
        assert_eq!(m.read().done, 0);
    }

    #[test]
    fn the_outer_launch_owns_the_meter_and_nested_ones_are_not_counted() {
        let m = Meter::new();
        m.enabled.store(true, Ordering::Relaxed);
        let outer = m.open("outer", 10);
        let inner = m.open("inner", 1000);
        inner.advance(1000);
        outer.advance(4);
        let r = m.read();
        assert_eq!((r.label, r.done, r.total, r.launches), ("outer", 4, 10, 1));
        drop(inner);
        drop(outer);
        let next = m.open("next", 3);
        next.advance(3);
        assert_eq!(
            m.read(),
            Reading {
                label: "next",
                done: 3,
                total: 3,
                launches: 2
            }
        );
    }
}
