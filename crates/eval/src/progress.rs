//! Progress of a long stage: an indicatif bar when standard error is a terminal, and one line
//! per finished unit (with elapsed time and an ETA) when it goes to a file or a pipe, so a
//! logged run is never silent for minutes.

use std::io::IsTerminal as _;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use indicatif::{ProgressBar, ProgressStyle};

/// A stage's progress over `len` units (see the module doc).
#[derive(Debug)]
pub struct Progress {
    bar: ProgressBar,
    lines: Option<Lines>,
}

#[derive(Debug)]
struct Lines {
    start: Instant,
    len: u64,
    done: AtomicU64,
    unit: &'static str,
}

/// `hh:mm:ss`.
fn clock(d: Duration) -> String {
    let s = d.as_secs();
    format!("{:02}:{:02}:{:02}", s / 3600, s / 60 % 60, s % 60)
}

impl Progress {
    /// Progress over `len` units called `unit` (plural, e.g. "runs"); nothing is shown unless
    /// `show`.
    #[must_use]
    pub fn new(len: u64, show: bool, unit: &'static str) -> Self {
        if !show {
            return Self { bar: ProgressBar::hidden(), lines: None };
        }
        if !std::io::stderr().is_terminal() {
            let lines = Lines { start: Instant::now(), len, done: AtomicU64::new(0), unit };
            return Self { bar: ProgressBar::hidden(), lines: Some(lines) };
        }
        let bar = ProgressBar::new(len);
        if let Ok(style) = ProgressStyle::with_template(&format!(
            "{{elapsed_precise}} [{{wide_bar}}] {{pos}}/{{len}} {unit}, ETA {{eta}} | {{msg}}"
        )) {
            bar.set_style(style);
        }
        Self { bar, lines: None }
    }

    /// What the stage is doing now (shown on the bar only).
    pub fn set_message(&self, msg: String) {
        self.bar.set_message(msg);
    }

    /// One unit finished; `what` names it in the log line.
    pub fn finish_unit(&self, what: &str) {
        self.bar.inc(1);
        if let Some(l) = &self.lines {
            let done = l.done.fetch_add(1, Ordering::Relaxed) + 1;
            let elapsed = l.start.elapsed();
            #[allow(clippy::cast_precision_loss)] // unit counts are small
            let eta = elapsed.mul_f64(l.len.saturating_sub(done) as f64 / done as f64);
            eprintln!("[{}] {done}/{} {} done ({what}), ETA {}", clock(elapsed), l.len, l.unit, clock(eta));
        }
    }

    /// The stage is over: the bar is cleared.
    pub fn finish(&self) {
        self.bar.finish_and_clear();
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn clock_formats_hours_minutes_seconds() {
        assert_eq!(clock(Duration::from_secs(3 * 3600 + 7 * 60 + 5)), "03:07:05");
    }
}
