//! `tessera run`: the pipeline over the inputs, with progress and a closing summary line.

use super::progress::Progress;
use std::path::{Path, PathBuf};
use tessera::cli::RunOpts;
use tessera::Config;

/// Loads the configuration (validated whole before any input is read) and runs.
pub fn run(inputs: &[PathBuf], out: &Path, opts: &RunOpts, quiet: bool) -> anyhow::Result<()> {
    let cfg = Config::load(opts.cfg.config.as_deref(), &opts.overrides())?;
    process(inputs, out, &cfg, quiet)
}

/// Runs the pipeline with `cfg` (also used by `demo`).
pub fn process(inputs: &[PathBuf], out: &Path, cfg: &Config, quiet: bool) -> anyhow::Result<()> {
    let progress = Progress::new(quiet);
    let res = tessera::pipeline::run(inputs, out, cfg, &|d, t| progress.update(d, t));
    progress.finish();
    let s = res?;
    tracing::info!(
        "{} points in, {} out, {} tiles ({} grid tiles split), {:.2} s, peak RSS {:.0} MiB (budget {} MiB); summary: {}",
        s.points_in,
        s.points_out,
        s.tiles,
        s.tiles_split,
        s.seconds.get("total").copied().unwrap_or(0.0),
        s.peak_rss_mb,
        s.memory_budget_mb,
        out.join("summary.json").display()
    );
    if s.is_incomplete() {
        return Err(tessera::Error::Incomplete {
            skipped: s.skipped_inputs.len(),
            failed: s.failed_tiles.len(),
            points: s.points_failed,
            summary: out.join("summary.json"),
        }
        .into());
    }
    Ok(())
}
