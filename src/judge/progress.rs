//! Progress bars (indicatif) for `run`, `perf` and multi-frame `render`:
//! on stderr, only on a terminal, never under `--json` or when `CI` is set
//! (the decision is [`super::runner::show_progress`], one pure function).
//! A bar with a known length shows elapsed time, count and ETA; a render
//! of one frame, whose length is unknown, shows a spinner with elapsed time.

use std::io::IsTerminal;
use std::time::Duration;

use indicatif::{ProgressBar, ProgressStyle};

use super::runner::show_progress;

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

/// A spinner with elapsed time for work of unknown length, hidden unless [`wanted`].
pub fn spinner(msg: &str, json: bool) -> ProgressBar {
    if !wanted(json) {
        return ProgressBar::hidden();
    }
    let b = ProgressBar::new_spinner();
    if let Ok(s) = ProgressStyle::with_template("{spinner} [{elapsed_precise}] {msg}") {
        b.set_style(s);
    }
    b.set_message(msg.to_string());
    b.enable_steady_tick(Duration::from_millis(200));
    b
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
        assert!(spinner("x", true).is_hidden());
    }
}
