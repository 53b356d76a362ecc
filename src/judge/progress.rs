//! Progress bars (indicatif) for `run`, `perf` and multi-frame `render`:
//! on stderr, only on a terminal, never under `--json` or when `CI` is set
//! (the decision is [`super::runner::show_progress`], one pure function).
//! A bar with a known length shows elapsed time, count and ETA. A render of
//! one frame is followed through the fan-out meter ([`follow`]): the bar
//! tracks the running parallel stage (its label, items done of its items,
//! and an ETA for that stage; long renders are one dominant stage).

use std::io::IsTerminal;
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::Arc;
use std::thread::JoinHandle;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

use super::runner::show_progress;
use crate::parallel::meter;

/// The bar's layout: elapsed, bar, count, ETA, then the current item.
pub const BAR_TEMPLATE: &str = "[{elapsed_precise}] {bar:30.cyan/blue} {pos}/{len} ETA {eta} {msg}";

/// Whether this process should draw progress (`json`: results go to stdout as JSON).
pub fn wanted(json: bool) -> bool {
    show_progress(
        json,
        std::env::var_os("CI").is_some(),
        std::io::stderr().is_terminal(),
    )
}

/// A bar over `total` items with ETA, hidden unless [`wanted`].
pub fn bar(total: u64, json: bool) -> ProgressBar {
    if !wanted(json) {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new(total);
    if let Ok(s) = ProgressStyle::with_template(BAR_TEMPLATE) {
        b.set_style(s.progress_chars("=> "));
    }
    b
}

/// A bar that follows the process's parallel stages while `msg` runs;
/// hidden (and the meter left off) unless [`wanted`]. Ends when dropped.
pub struct Follower {
    bar: ProgressBar,
    stop: Arc<AtomicBool>,
    poll: Option<JoinHandle<()>>,
}

/// Starts following the fan-out meter under the message `msg`.
pub fn follow(msg: &str, json: bool) -> Follower {
    let stop = Arc::new(AtomicBool::new(false));
    if !wanted(json) {
        return Follower {
            bar: ProgressBar::hidden(),
            stop,
            poll: None,
        };
    }
    meter::enable();
    let bar = bar(0, json);
    bar.set_message(msg.to_string());
    let (b, s, msg) = (bar.clone(), stop.clone(), msg.to_string());
    let poll = std::thread::spawn(move || {
        let mut seen = 0;
        while !s.load(Ordering::Relaxed) {
            let r = meter::read();
            if r.launches != seen {
                seen = r.launches;
                b.reset();
            }
            b.set_length(r.total);
            b.set_position(r.done);
            b.set_message(stage_message(&msg, &r));
            std::thread::sleep(Duration::from_millis(200));
        }
    });
    Follower {
        bar,
        stop,
        poll: Some(poll),
    }
}

/// The bar's message for a reading: the render, then the stage it is in.
pub fn stage_message(msg: &str, r: &meter::Reading) -> String {
    match r.launches {
        0 => format!("{msg}: preparing"),
        n => format!("{msg}: {} (stage {n})", r.label),
    }
}

impl Drop for Follower {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        if let Some(p) = self.poll.take() {
            let _ = p.join();
        }
        self.bar.finish_and_clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_bar_template_parses_and_names_the_eta() {
        assert!(ProgressStyle::with_template(BAR_TEMPLATE).is_ok());
        assert!(BAR_TEMPLATE.contains("{eta}"));
    }

    #[test]
    fn no_bar_under_json() {
        assert!(bar(10, true).is_hidden());
        assert!(follow("x", true).bar.is_hidden());
    }

    #[test]
    fn the_stage_message_names_the_running_launch() {
        let r = meter::Reading {
            label: "pt_tiles",
            done: 3,
            total: 9,
            launches: 2,
        };
        assert_eq!(
            stage_message("rendering a", &r),
            "rendering a: pt_tiles (stage 2)"
        );
        let idle = meter::Reading { launches: 0, ..r };
        assert_eq!(
            stage_message("rendering a", &idle),
            "rendering a: preparing"
        );
    }
}
