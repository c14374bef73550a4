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

/// Runs one task of the region plan in `plan` (index from `task` or the job-array variables).
/// Its settings are the plan's: `--set`, `--config` and the setting flags are refused.
pub fn run_task(
    plan: &Path,
    task: Option<usize>,
    opts: &RunOpts,
    quiet: bool,
) -> anyhow::Result<()> {
    if !opts.overrides().is_empty() || opts.cfg.config.is_some() {
        return Err(tessera::Error::Config(format!(
            "run --plan: a task runs with the plan's settings ({}); change them when planning",
            tessera::pipeline::task::PlanFile::config_path(plan).display()
        ))
        .into());
    }
    let index = match task {
        Some(i) => i,
        None => tessera::pipeline::task::task_from_env()?.ok_or_else(|| {
            tessera::Error::Config(
                "run --plan: no --task, and none of SLURM_ARRAY_TASK_ID, JOB_COMPLETION_INDEX, AWS_BATCH_JOB_ARRAY_INDEX is set".into(),
            )
        })?,
    };
    let progress = Progress::new(quiet);
    let res = tessera::pipeline::run_task(plan, index, &|d, t| progress.update(d, t));
    progress.finish();
    if let Some(s) = res? {
        tracing::info!(
            "task {index}: {} points read, {} core points written, {} tiles ({} reused), {:.2} s, peak RSS {:.0} MiB",
            s.points_read,
            s.points_out,
            s.tiles,
            s.tiles_reused,
            s.seconds.get("total").copied().unwrap_or(0.0),
            s.peak_rss_mb
        );
        if s.is_incomplete() {
            tracing::warn!(
                "task {index}: {} tiles failed (listed in its summary)",
                s.failed_tiles.len()
            );
        }
        let dir = tessera::pipeline::task::task_dir(plan, index);
        within_budget(&s, &dir.join("summary.json"))?;
    }
    Ok(())
}

/// A run that finished over its memory budget is an error (exit code 4) although its outputs
/// are complete: a CI job under a hard cap must learn that the cap would have killed it.
fn within_budget(s: &tessera::report::Summary, summary: &Path) -> anyhow::Result<()> {
    if s.memory_budget_mb > 0 && s.peak_rss_mb > s.memory_budget_mb as f64 {
        return Err(tessera::Error::OverBudget {
            peak_mb: s.peak_rss_mb,
            budget_mb: s.memory_budget_mb,
            summary: summary.to_path_buf(),
        }
        .into());
    }
    Ok(())
}

/// `tessera stitch DIR`.
pub fn stitch(dir: &Path, overwrite: bool, quiet: bool) -> anyhow::Result<()> {
    let s = tessera::pipeline::stitch_dir::stitch_plan_dir(dir, overwrite)?;
    if !quiet {
        tracing::info!(
            "{} points, {} tiles, {:.2} s; summary: {}",
            s.points_out,
            s.tiles,
            s.seconds.get("total").copied().unwrap_or(0.0),
            dir.join("summary.json").display()
        );
    }
    if s.is_incomplete() {
        return Err(tessera::Error::Incomplete {
            skipped: s.skipped_inputs.len(),
            failed: s.failed_tiles.len(),
            points: s.points_failed,
            summary: dir.join("summary.json"),
        }
        .into());
    }
    within_budget(&s, &dir.join("summary.json"))
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
    within_budget(&s, &out.join("summary.json"))
}
