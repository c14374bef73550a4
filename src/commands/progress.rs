//! Progress reporting: a bar on a terminal, a log line every few seconds otherwise (nightly
//! logs), both with the rate and the time left.

use std::io::IsTerminal;

/// Progress of a run's reading.
pub struct Progress {
    bar: Option<indicatif::ProgressBar>,
    last: std::sync::Mutex<std::time::Instant>,
    start: std::time::Instant,
    quiet: bool,
}

impl Progress {
    /// A bar when stderr is a terminal (and not `quiet`), else log lines.
    pub fn new(quiet: bool) -> Self {
        let bar = (!quiet && std::io::stderr().is_terminal()).then(|| {
            let b = indicatif::ProgressBar::new(0);
            b.set_style(
                indicatif::ProgressStyle::with_template(
                    "{elapsed_precise} [{bar:40}] {human_pos}/{human_len} points processed ({per_sec}, eta {eta})",
                )
                .unwrap_or_else(|_| indicatif::ProgressStyle::default_bar()),
            );
            b
        });
        Progress {
            bar,
            last: std::sync::Mutex::new(std::time::Instant::now()),
            start: std::time::Instant::now(),
            quiet,
        }
    }

    /// Points processed so far of `total` (a task of a region plan: points read).
    pub fn update(&self, done: u64, total: u64) {
        if let Some(b) = &self.bar {
            b.set_length(total);
            b.set_position(done);
        } else if !self.quiet {
            let mut last = self.last.lock().unwrap_or_else(|p| p.into_inner());
            if last.elapsed().as_secs_f64() >= 5.0 || done == total {
                *last = std::time::Instant::now();
                let secs = self.start.elapsed().as_secs_f64().max(1e-3);
                let rate = done as f64 / secs;
                let eta = if rate > 0.0 {
                    format!("{:.0} s", total.saturating_sub(done) as f64 / rate)
                } else {
                    "?".into()
                };
                tracing::info!(
                    "{done}/{total} points processed ({:.1} %), {:.3} M points/s, eta {eta}",
                    100.0 * done as f64 / total.max(1) as f64,
                    rate / 1e6
                );
            }
        }
    }

    /// Clears the bar.
    pub fn finish(&self) {
        if let Some(b) = &self.bar {
            b.finish_and_clear();
        }
    }
}
