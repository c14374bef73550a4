//! The pipeline: reader → tiler → worker pool → writer, wired with bounded channels so a slow
//! part holds the others back instead of letting queues grow.
//!
//! ```text
//! reader ──chunks(bounded)──▶ tiler ──jobs(bounded)──▶ workers ×N ──results(bounded)──▶ writer
//!   (LAS/LAZ, fill_points)     (spill files)            (load/split, stages)             (LAZ, atomic)
//! ```
//! Jobs carry only spill-file paths; a tile is loaded, processed and compressed (to a
//! temporary file) by one worker, and the writer only commits finished files by renaming, so
//! the tiles in memory at once are bounded by the worker count.
//!
//! A run is first resolved into a [`RunPlan`] (inputs scanned, grid, budget, stitching,
//! output layout); each role then gets its part of the plan and its channel ends:
//! `reader.rs`, `tiler.rs`, `worker.rs`, `writer.rs` — one file each.

mod failure;
pub mod journal;
pub mod plan;
pub mod reader;
pub mod stitch_dir;
pub mod task;
mod tiler;
mod tokens;
pub mod train;
pub mod units;
mod worker;
mod writer;

pub use plan::{RunPlan, StitchPlan};
pub use reader::ProgressFn;

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::perclass::ClassFiles;
use crate::io::workspace::{OutputDir, WorkDir};
use crate::report::overview::OverviewSink;
use crate::report::{peak_rss_mb, Summary};
use crate::stages::Stage;
use crate::tiling::{schedule, TileJob};
use crossbeam_channel::bounded;
use failure::Failure;
use journal::{Journal, ResumeState};
use reader::{ReadMsg, Reader};
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;
use tiler::{TilerChannels, TilerRole};
use worker::WorkerRole;
use writer::{Collector, ToWriter};

/// Runs the whole pipeline on `inputs`, writing tiles and `summary.json` into `out_dir`.
pub fn run(
    inputs: &[PathBuf],
    out_dir: &Path,
    cfg: &Config,
    progress: ProgressFn,
) -> Result<Summary> {
    run_scoped(inputs, out_dir, cfg, None, progress, None)
}

/// Like [`run`], with the stages given by the caller instead of `cfg.stages.run` (built by
/// the caller, so in metres: inputs in another unit are refused).
pub fn run_with_stages(
    inputs: &[PathBuf],
    out_dir: &Path,
    cfg: &Config,
    stages: &[Box<dyn Stage>],
    progress: ProgressFn,
) -> Result<Summary> {
    run_scoped(inputs, out_dir, cfg, Some(stages), progress, None)
}

/// Runs task `index` of the plan in `plan_dir` into its task directory (see [`task`]).
/// `None` when the task had already finished (a retried array task).
pub fn run_task(plan_dir: &Path, index: usize, progress: ProgressFn) -> Result<Option<Summary>> {
    let plan = task::PlanFile::load(plan_dir)?;
    if index >= plan.tasks.len() {
        return Err(Error::Config(format!(
            "task {index}: the plan in {} has {} tasks (0..{})",
            plan_dir.display(),
            plan.tasks.len(),
            plan.tasks.len()
        )));
    }
    let out = task::task_dir(plan_dir, index);
    if out.join(crate::io::workspace::SUMMARY).is_file() {
        tracing::info!("task {index} has finished already ({})", out.display());
        return Ok(None);
    }
    let cfg = Config::load(Some(&task::PlanFile::config_path(plan_dir)), &[])?;
    let scope = task::TaskScope::load(plan_dir, index)?;
    run_scoped(&plan.inputs, &out, &cfg, None, progress, Some(&scope)).map(Some)
}

/// A run of the whole region (`scope` None) or of one task of a plan.
fn run_scoped(
    inputs: &[PathBuf],
    out_dir: &Path,
    cfg: &Config,
    given_stages: Option<&[Box<dyn Stage>]>,
    progress: ProgressFn,
    scope: Option<&task::TaskScope>,
) -> Result<Summary> {
    let t0 = Instant::now();
    let sampler = crate::report::MemorySampler::start();
    // The output directory is taken first: a second run into it refuses before any work, and
    // an earlier run's outputs are replaced only with `output.overwrite`.
    let mut out = OutputDir::open(out_dir, cfg.output.overwrite || cfg.output.restart)?;
    // Spill files and decoded MCAP parts live in a fresh work directory of this run: inside
    // `pipeline.spill_dir` when set (which itself is never removed), else in the output's
    // staging directory. Both go away with the run, also when it fails.
    let spill_work = if cfg.pipeline.spill_dir.is_empty() {
        None
    } else {
        Some(WorkDir::create(Path::new(&cfg.pipeline.spill_dir))?)
    };
    let work_base = spill_work
        .as_ref()
        .map(|w| w.path().to_path_buf())
        .unwrap_or_else(|| out.stage().to_path_buf());
    // The output directory (and anything under it) is never an input.
    let inputs = crate::io::input::expand_paths_excluding(inputs, &[out_dir.to_path_buf()])?;
    // Distance parameters in the inputs' unit (feet CRSs), and the stages built from them.
    let (unit_cfg, units) = units::for_inputs(cfg, &inputs)?;
    let cfg = &unit_cfg;
    let built;
    let stages = match given_stages {
        Some(s) if units.converted.is_empty() => s,
        Some(_) => {
            return Err(Error::Config(format!(
                "the inputs are in {} ({}); stages built by the caller take metres",
                units.unit.name, units.source
            )))
        }
        None => {
            built = cfg.build_stages()?;
            &built[..]
        }
    };
    // MCAP drives are decoded and georeferenced first, into LAS parts whose headers carry the
    // exact bounds the tiler needs; the parts are removed when `staged` is dropped.
    // With `segment.method = "multicue"` every scan is segmented while it is decoded (where
    // the scan's image structure exists); the segment stage then ties the scans' segments.
    let mut mcap = cfg.mcap.clone();
    mcap.scan_segments = crate::stages::segment::scan_segmenter(&cfg.stages.run, &cfg.sections)?;
    if mcap.scan_segments.is_some() && !inputs.iter().all(|f| crate::io::mcap::is_mcap(f)) {
        let other = inputs.iter().find(|f| !crate::io::mcap::is_mcap(f));
        return Err(Error::Config(format!(
            "segment.method = \"multicue\" segments the scans of MCAP drives; {} is not one (use method = \"region_growing\" for LAS/LAZ/PCD input)",
            other.map(|f| f.display().to_string()).unwrap_or_default()
        )));
    }
    let staged = crate::io::mcap::stage_inputs(
        &inputs,
        &work_base.join("mcap"),
        &mcap,
        cfg.pipeline.threads,
    )?;
    let mut plan = RunPlan::resolve(cfg, stages, &staged.paths, &work_base)?;
    plan.set.layout.z_to_xy = units.z_to_xy;
    let Observers { sink, classes } = observers(&mut plan, cfg, scope.is_some(), &out)?;
    // The journal of finished cells: an interrupted run of the same fingerprint is resumed.
    let mut fingerprint = journal::Fingerprint::of(cfg, &inputs, &plan.grid);
    if let Some(sc) = scope {
        fingerprint.grid.push_str(&format!("; task {}", sc.index));
    }
    let (mut journal, resume) = journal::start(
        &mut out,
        &fingerprint,
        cfg.output.restart,
        cfg.output.overwrite,
    )?;
    let scan_s = t0.elapsed().as_secs_f64();
    plan::create_spill_dir(&plan)?;
    let (mut summary, promised) = execute(
        &plan,
        stages,
        &mut out,
        progress,
        (&mut journal, resume.as_ref(), scope),
    )?;
    summary.seconds.insert("scan".into(), scan_s);
    summary
        .seconds
        .insert("total".into(), t0.elapsed().as_secs_f64());
    summary.version = env!("CARGO_PKG_VERSION").into();
    summary.inputs = plan.set.files.len();
    summary.mcap = staged.reports.clone();
    summary.units = Some(units);
    summary.points_in = promised.points_in;
    for t in summary.stages.values_mut() {
        t.finish(summary.points_in);
    }
    summary.memory_budget_mb = cfg.pipeline.memory_budget_mb;
    summary.point_format = plan.set.layout.format.to_u8().unwrap_or(255);
    summary.skipped_inputs = plan.skipped_inputs.clone();
    if let Some(st) = &summary.stitch {
        if st.frontier_bytes_max > plan.budget.stitch_bytes {
            tracing::warn!(
                "the stitcher's frontier peaked at {} MiB, above the {} MiB reserved for it in the memory plan",
                st.frontier_bytes_max >> 20,
                plan.budget.stitch_bytes >> 20
            );
        }
    }
    summary.budget = Some(plan.budget.clone());
    summary.peak_rss_mb = peak_rss_mb().unwrap_or(0.0);
    // Every point the headers promise was read (the reader checks each file's count), and
    // every point read was written exactly once, or belongs to a tile listed as failed. (A
    // task reads the inputs reaching its cells and writes its cells' core points.)
    if summary.points_read != promised.read
        || summary.points_out + summary.points_failed != summary.points_in
    {
        return Err(Error::Internal(format!(
            "the input headers promise {} points to read and {} to write; {} were read, {} written and {} in failed tiles",
            promised.read, summary.points_in, summary.points_read, summary.points_out, summary.points_failed
        )));
    }
    if let Some(c) = &classes {
        finish_class_files(c, &mut out, &mut summary)?;
    }
    summary.memory_timeline = sampler.finish();
    if let Some(s) = &sink {
        write_report(&mut out, &mut summary, Some(s))?;
    }
    let json = serde_json::to_vec_pretty(&summary).map_err(|e| Error::Internal(e.to_string()))?;
    // The run's files are all in place; the summary comes last and marks the run finished.
    // (A failure before this point drops `out`, which removes this run's partial outputs.)
    // A task keeps its journal: `tessera stitch` reads it.
    if scope.is_some() {
        out.finish_keeping_journal(&json)?;
    } else {
        out.finish(&json)?;
    }
    drop(staged);
    drop(spill_work);
    Ok(summary)
}

/// Points a run must read and write.
struct Promised {
    /// Announced by the headers of the inputs it reads.
    read: u64,
    /// Core points of its cells (all points, for a run of the whole region).
    points_in: u64,
}

/// Wires the roles with bounded channels, runs them to the end and returns the books. The
/// journal records finished cells; the cells `resume` holds are not processed again; a task
/// (`scope`) reads only the inputs reaching its cells and bins only its cells.
fn execute(
    plan: &RunPlan,
    stages: &[Box<dyn Stage>],
    out: &mut OutputDir,
    progress: ProgressFn,
    (journal, resume, scope): (&mut Journal, Option<&ResumeState>, Option<&task::TaskScope>),
) -> Result<(Summary, Promised)> {
    let set = &plan.set;
    let budget = &plan.budget;
    let parts = journal.parts().to_path_buf();
    let mut order = schedule(&set.files, &plan.grid);
    if let Some(sc) = scope {
        order.retain(|&i| sc.reads(&set.files[i], &plan.grid));
    }
    let to_read: u64 = order.iter().map(|&i| set.files[i].points).sum();
    let core_points = AtomicU64::new(0);
    let failure = Failure::default();
    let read_points = AtomicU64::new(0);
    let max_open = AtomicU64::new(0);
    let (chunk_tx, chunk_rx) = bounded::<ReadMsg>(budget.chunk_depth);
    let (free_tx, free_rx) = bounded::<las::PointData>(budget.chunk_depth + 2);
    let (job_tx, job_rx) = bounded::<TileJob>(budget.workers);
    let (res_tx, res_rx) = bounded::<ToWriter>(1);
    let writer = plan.tile_writer()?;
    let stage_dir = out.stage().to_path_buf();
    // Progress is the core points processed (the writer's count) of a whole run: reading
    // finishes long before the work when the tiler holds tiles. A task's core points are
    // known only once read, so a task reports its reading.
    let silent = |_: u64, _: u64| {};
    let reader = Reader {
        files: &set.files,
        order: &order,
        layout: &set.layout,
        chunk_points: budget.chunk_points,
        total_points: to_read,
        progress: if scope.is_some() { progress } else { &silent },
    };
    let tiler = TilerRole {
        grid: plan.grid,
        layout: &set.layout,
        files: &set.files,
        spill_dir: &plan.spill_dir,
        spill_bytes: budget.spill_bytes,
        near_m: budget.near_m(),
        kept_m: plan.kept_m(),
        scope: scope.map(|s| &s.cells),
    };
    let tokens = tokens::MemoryTokens::new(budget.tiles_in_flight);
    let worker = WorkerRole {
        tokens: &tokens,
        pool_threads: std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1),
        layout: &set.layout,
        stages,
        budget,
        split: plan.split_params(),
        writer: &writer,
        stage_dir: &stage_dir,
        spill_dir: &plan.spill_dir,
        stitch: plan.stitch.as_ref(),
        keep_going: plan.keep_going,
        resume,
        parts: Some(&parts),
    };
    let t_pipeline = Instant::now();
    // A task does not stitch: its deferred tiles stay in its journal for `tessera stitch`.
    let stitching = plan.stitch.as_ref().filter(|_| scope.is_none());
    let mut collector = Collector::new(
        &writer,
        out,
        stitching.map(|st| (st.params.clone(), st.strip_m)),
        Some(journal),
    );
    collector.keep_deferred = scope.is_some();
    collector.write_threads = budget.workers;
    if scope.is_none() {
        collector.progress = Some((progress, set.total_points));
    }
    collector.spill_frontier_beyond(plan.budget.stitch_bytes);
    let channels = TilerChannels {
        chunk_rx,
        free_tx,
        job_tx,
        // The tiler tells the stitcher which cells it releases, before their jobs leave.
        release_tx: stitching.is_some().then(|| res_tx.clone()),
    };
    let (read_s, tile_s) = std::thread::scope(|s| {
        let read = s.spawn(|| reader.run(chunk_tx, free_rx, &failure, &read_points));
        let tile = s.spawn(|| tiler.run(channels, &failure, (&max_open, &core_points)));
        for w in 0..budget.workers {
            let (jobs, results) = (job_rx.clone(), res_tx.clone());
            let (worker, failure) = (&worker, &failure);
            s.spawn(move || worker.run(w, jobs, results, failure));
        }
        drop(res_tx);
        drop(job_rx);
        // The writer runs on this thread.
        collector.run(res_rx, &failure);
        // A panic in a role is a bug: it propagates, as it would from the scope.
        let join = |h: std::thread::ScopedJoinHandle<'_, f64>| {
            h.join().unwrap_or_else(|p| std::panic::resume_unwind(p))
        };
        (join(read), join(tile))
    });
    if let Some(e) = failure.into_error() {
        return Err(e);
    }
    let Collector {
        mut summary,
        write_s,
        stitch_s,
        ..
    } = collector;
    if stitching.is_some() {
        summary.seconds.insert("stitch".into(), stitch_s);
    }
    summary.buffer_m = plan.grid.buffer_m;
    // Tiles by name, failed tiles by name, split roots by name: the summary of a run does not
    // depend on which worker finished first.
    summary.failed_tiles.sort_by(|a, b| a.tile.cmp(&b.tile));
    summary.split_tiles.sort();
    summary.tiles_split = summary.split_tiles.len();
    summary.max_open_tiles = max_open.load(Ordering::Relaxed) as usize;
    summary.points_read = read_points.load(Ordering::Relaxed);
    summary.seconds.insert("read".into(), read_s);
    summary.seconds.insert("tile".into(), tile_s);
    summary.seconds.insert("write".into(), write_s);
    summary
        .seconds
        .insert("pipeline".into(), t_pipeline.elapsed().as_secs_f64());
    let points_in = match scope {
        Some(_) => core_points.load(Ordering::Relaxed),
        None => set.total_points,
    };
    Ok((
        summary,
        Promised {
            read: to_read,
            points_in,
        },
    ))
}

/// Builds `report.html` from the tiles in place and commits it (before the summary, which
/// stays the last file); its cost goes into the summary as `seconds.report` (not part of
/// `seconds.total`).
pub(crate) fn write_report(
    out: &mut OutputDir,
    summary: &mut Summary,
    sink: Option<&OverviewSink>,
) -> Result<()> {
    let value = serde_json::to_value(&*summary).map_err(|e| Error::Internal(e.to_string()))?;
    let drawn = sink.map(OverviewSink::take);
    let staged = out.stage().join(crate::report::html::REPORT);
    let file = std::fs::File::create(&staged).map_err(|e| Error::io(&staged, e))?;
    let mut w = std::io::BufWriter::with_capacity(1 << 16, file);
    let cost = crate::report::html::build(out.path(), &value, drawn, &mut w)?;
    w.into_inner()
        .map_err(|e| e.into_error())
        .and_then(|f| f.sync_all())
        .map_err(|e| Error::io(&staged, e))?;
    out.commit(&[(staged, crate::report::html::REPORT.to_string())])?;
    summary.seconds.insert("report".into(), cost.seconds);
    summary.report_raster = Some(cost.geometry);
    // The report's memory counts against the budget like the rest of the run.
    summary.peak_rss_mb = peak_rss_mb().unwrap_or(summary.peak_rss_mb);
    tracing::info!(
        "report: {} ({} points in {} cells, {} tiles decoded again, {:.2} s)",
        out.path().join(crate::report::html::REPORT).display(),
        cost.points,
        cost.pixels,
        cost.decoded_tiles,
        cost.seconds
    );
    Ok(())
}

/// Completes the per-class files with the tiles the run did not write itself (reused from an
/// interrupted run, or a task's) and commits them.
pub(crate) fn finish_class_files(
    classes: &ClassFiles,
    out: &mut OutputDir,
    summary: &mut Summary,
) -> Result<()> {
    let t = Instant::now();
    // The tiles in batches, read from the tile table: no list of every tile in memory.
    let table = match &summary.tile_table {
        Some(name) => serde_json::json!({ "tile_table": name }),
        None => serde_json::json!({ "tile_list": summary.tile_list }),
    };
    let mut batch: Vec<(String, PathBuf)> = Vec::new();
    let dir = out.path().to_path_buf();
    crate::report::for_each_tile(&dir, &table, |t| {
        let name = t.get("name").and_then(serde_json::Value::as_str);
        let file = t.get("file").and_then(serde_json::Value::as_str);
        if let (Some(name), Some(file)) = (name, file) {
            batch.push((name.to_string(), dir.join(file)));
        }
        if batch.len() >= 256 {
            classes.add_files(&batch)?;
            batch.clear();
        }
        Ok(())
    })?;
    classes.add_files(&batch)?;
    summary.class_files = classes.finish(out)?;
    summary
        .seconds
        .insert("class_files".into(), t.elapsed().as_secs_f64());
    Ok(())
}

/// The observers of the records the run writes: the report's raster and the per-class files.
/// The report's rasters are drawn from the records as the tiles are written. (A task's tiles
/// are not the region's: `tessera stitch` writes the region's report and class files.)
fn observers(plan: &mut RunPlan, cfg: &Config, task: bool, out: &OutputDir) -> Result<Observers> {
    let sink = plan
        .report_raster
        .filter(|_| !task && cfg.output.report)
        .map(|g| std::sync::Arc::new(OverviewSink::new(g)));
    if let Some(s) = &sink {
        plan.observers.push(s.clone());
    }
    let classes = if !task && cfg.output.per_class {
        let w = plan.tile_writer()?;
        let c = std::sync::Arc::new(ClassFiles::new(w.header(), w.is_laz(), out.stage())?);
        plan.observers.push(c.clone());
        Some(c)
    } else {
        None
    };
    Ok(Observers { sink, classes })
}

/// What [`observers`] set up.
struct Observers {
    sink: Option<std::sync::Arc<OverviewSink>>,
    classes: Option<std::sync::Arc<ClassFiles>>,
}
