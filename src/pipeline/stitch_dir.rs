//! `tessera stitch DIR`: joins the finished tasks of a plan into the region's output — the
//! same tiles, byte for byte, as one `tessera run` of the region.
//!
//! Every task's journal lists its finished cells. The cells are fed to the writer of a run
//! (the same writer, `Collector`, and stitcher) in (ix, iy) order, each announced with its later
//! neighbours as still open — so the stitcher's frontier is about two grid columns, whatever
//! the region's size — then its tiles with their border summaries, then its completion.
//! Global ids are defined by point ordinals, not by order, so they are those of a single run.
//! Tiles written by tasks (runs without stitching) are linked into place; deferred tiles are
//! written with their global ids. The tasks' directories are removed once the region's
//! summary is written; until then a stitch that fails or is killed can simply be run again
//! (with `--overwrite`).

use super::journal::{read_log, TileResult};
use super::task::{task_dir, PlanFile};
use super::writer::{Collector, Processed, TileMeta, TileOutput, ToWriter};
use super::RunPlan;
use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::workspace::{remove_run_dir, OutputDir, RESUME_DIR, SUMMARY};
use crate::model::CellKey;
use crate::report::overview::OverviewSink;
use crate::report::{peak_rss_mb, Summary};
use crate::stitch::CellRelease;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// A finished cell of some task.
struct TaskCell {
    task: usize,
    tiles: Vec<super::journal::TileEntry>,
    failed: Vec<super::journal::FailedEntry>,
}

/// Stitches the plan in `dir` (see the module docs); `overwrite` replaces the outputs of an
/// earlier stitch.
pub fn stitch_plan_dir(dir: &Path, overwrite: bool) -> Result<Summary> {
    let t0 = Instant::now();
    let plan = PlanFile::load(dir)?;
    let n_tasks = plan.tasks.len();
    let unfinished: Vec<usize> = (0..n_tasks)
        .filter(|&i| !task_dir(dir, i).join(SUMMARY).is_file())
        .collect();
    if !unfinished.is_empty() {
        let shown: Vec<String> = unfinished.iter().take(10).map(|i| i.to_string()).collect();
        return Err(Error::Config(format!(
            "{}: {} of {n_tasks} tasks have not finished (tasks {}{}); run them (`tessera run --plan {} --task I`) first",
            dir.display(),
            unfinished.len(),
            shown.join(", "),
            if unfinished.len() > 10 { ", …" } else { "" },
            dir.display()
        )));
    }
    let cfg = Config::load(Some(&PlanFile::config_path(dir)), &[])?;
    // The tasks ran in the inputs' unit (see `units`): so does their stitching.
    let (cfg, units) = super::units::for_inputs(&cfg, &plan.inputs)?;
    let stages = cfg.build_stages()?;
    let mut out = OutputDir::open(dir, overwrite)?;
    let work = out.stage().to_path_buf();
    let mut run = RunPlan::resolve(&cfg, &stages, &plan.inputs, &work)?;
    run.set.layout.z_to_xy = units.z_to_xy;
    let sink = run
        .report_raster
        .filter(|_| cfg.output.report)
        .map(|g| std::sync::Arc::new(OverviewSink::new(g)));
    if let Some(s) = &sink {
        run.observers.push(s.clone());
    }
    let classes = if cfg.output.per_class {
        let w = run.tile_writer()?;
        let c = std::sync::Arc::new(crate::io::perclass::ClassFiles::new(
            w.header(),
            w.is_laz(),
            out.stage(),
        )?);
        run.observers.push(c.clone());
        Some(c)
    } else {
        None
    };
    let (expected, skipped) = task_accounts(dir, n_tasks, &run.skipped_inputs)?;
    if skipped.is_empty() && run.set.total_points != plan.points {
        return Err(Error::Config(format!(
            "{}: the inputs now announce {} points, the plan {}; plan again",
            dir.display(),
            run.set.total_points,
            plan.points
        )));
    }
    // Without skipped inputs the tasks together binned every point the plan counted.
    let expected = if skipped.is_empty() {
        plan.points
    } else {
        expected
    };
    // Every task's finished cells; a cell belongs to one task.
    let mut cells: BTreeMap<CellKey, TaskCell> = BTreeMap::new();
    for task in 0..n_tasks {
        let tdir = task_dir(dir, task).join(RESUME_DIR);
        let st = read_log(&tdir.join("log"), tdir.join("parts"))?;
        for (cell, (tiles, failed)) in st.cells {
            if let Some(other) = cells.insert(
                cell,
                TaskCell {
                    task,
                    tiles,
                    failed,
                },
            ) {
                return Err(Error::Internal(format!(
                    "cell {cell:?} was processed by tasks {} and {task}",
                    other.task
                )));
            }
        }
    }
    let writer = run.tile_writer()?;
    let stitching = run.stitch.as_ref();
    let mut collector = Collector::new(
        &writer,
        &mut out,
        stitching.map(|st| (st.params.clone(), st.strip_m)),
        None,
    );
    collector.keep_deferred = true;
    // No worker holds a tile here: the tiles readied together are written in parallel.
    collector.write_threads = run.budget.workers;
    collector.spill_frontier_beyond(run.budget.stitch_bytes);
    let keys: Vec<CellKey> = cells.keys().copied().collect();
    for &cell in &keys {
        let c = &cells[&cell];
        feed_cell(&mut collector, dir, cell, c, |n| {
            n > cell && cells.contains_key(&n)
        })?;
    }
    collector.finish()?;
    let Collector {
        mut summary,
        write_s,
        stitch_s,
        ..
    } = collector;
    summary.failed_tiles.sort_by(|a, b| a.tile.cmp(&b.tile));
    summary.split_tiles.sort();
    summary.tiles_split = summary.split_tiles.len();
    summary.version = env!("CARGO_PKG_VERSION").into();
    summary.inputs = run.set.files.len();
    summary.points_in = expected;
    summary.points_read = expected;
    summary.skipped_inputs = skipped;
    summary.buffer_m = run.grid.buffer_m;
    summary.memory_budget_mb = cfg.pipeline.memory_budget_mb;
    summary.point_format = run.set.layout.format.to_u8().unwrap_or(255);
    summary.budget = Some(run.budget.clone());
    summary.seconds.insert("write".into(), write_s);
    if stitching.is_some() {
        summary.seconds.insert("stitch".into(), stitch_s);
    }
    summary
        .seconds
        .insert("total".into(), t0.elapsed().as_secs_f64());
    summary.peak_rss_mb = peak_rss_mb().unwrap_or(0.0);
    // Every point the tasks read is in exactly one task's cells: written, or in a failed tile.
    if summary.points_out + summary.points_failed != expected {
        return Err(Error::Internal(format!(
            "the tasks read {expected} points of the plan's {}; they wrote {} and failed {}",
            plan.points, summary.points_out, summary.points_failed
        )));
    }
    if let Some(c) = &classes {
        super::finish_class_files(c, &mut out, &mut summary)?;
    }
    if let Some(s) = &sink {
        super::write_report(&mut out, &mut summary, Some(s))?;
    }
    let json = serde_json::to_vec_pretty(&summary).map_err(|e| Error::Internal(e.to_string()))?;
    out.finish(&json)?;
    drop(run);
    for task in 0..n_tasks {
        remove_run_dir(&task_dir(dir, task))?;
    }
    let _ = std::fs::remove_dir(dir.join("tasks"));
    Ok(summary)
}

/// The tasks' own accounts from their summaries: the core points they binned together (each
/// read its inputs less the ones it left out, `pipeline.keep_going`), and every input a task
/// or the stitch itself left out, once each. An input skipped by one task may have been read
/// by another (it failed later, or only there): the points are then counted where read.
fn task_accounts(
    dir: &Path,
    n_tasks: usize,
    own: &[crate::io::input::SkippedInput],
) -> Result<(u64, Vec<crate::io::input::SkippedInput>)> {
    let mut points = 0u64;
    let mut skipped: Vec<crate::io::input::SkippedInput> = own.to_vec();
    for task in 0..n_tasks {
        let path = task_dir(dir, task).join(SUMMARY);
        let text = std::fs::read_to_string(&path).map_err(|e| Error::io(&path, e))?;
        let v: serde_json::Value = serde_json::from_str(&text).map_err(|e| Error::OutputDir {
            path: path.clone(),
            reason: format!("not a task summary: {e}"),
            usage: false,
        })?;
        points += v
            .get("points_in")
            .and_then(serde_json::Value::as_u64)
            .unwrap_or(0);
        for s in v
            .get("skipped_inputs")
            .and_then(serde_json::Value::as_array)
            .into_iter()
            .flatten()
        {
            let (Some(p), Some(e)) = (
                s.get("path").and_then(serde_json::Value::as_str),
                s.get("error").and_then(serde_json::Value::as_str),
            ) else {
                continue;
            };
            let p = PathBuf::from(p);
            if !skipped.iter().any(|k| k.path == p) {
                skipped.push(crate::io::input::SkippedInput {
                    path: p,
                    error: format!("task {task}: {e}"),
                });
            }
        }
    }
    Ok((points, skipped))
}

/// Hands one finished cell to the writer: its release (later neighbours still open), its
/// tiles, its failed tiles and its completion.
fn feed_cell(
    collector: &mut Collector<'_>,
    dir: &Path,
    cell: CellKey,
    c: &TaskCell,
    later: impl Fn(CellKey) -> bool,
) -> Result<()> {
    let tdir = task_dir(dir, c.task);
    let parts = tdir.join(RESUME_DIR).join("parts");
    let open_neighbours: Vec<CellKey> = (-1..=1i64)
        .flat_map(|dx| (-1..=1i64).map(move |dy| (cell.0 + dx, cell.1 + dy)))
        .filter(|&n| n != cell && later(n))
        .collect();
    collector.handle(ToWriter::Released(vec![CellRelease {
        cell,
        has_core: true,
        open_neighbours,
    }]))?;
    for t in &c.tiles {
        let meta = TileMeta::from_entry(t, cell, false, None);
        let output = match &t.result {
            TileResult::Written { files } => TileOutput::Link(
                files
                    .iter()
                    .map(|f| (tdir.join(f), f.clone()))
                    .collect::<Vec<(PathBuf, String)>>(),
            ),
            TileResult::Deferred { points } => TileOutput::from_parts(&parts, &t.name, *points)?,
        };
        collector.handle(ToWriter::Tile(Box::new(Processed { meta, output })))?;
    }
    for f in &c.failed {
        collector.handle(ToWriter::Failed {
            failed: f.failed.clone(),
            split_root: f.split_root.clone(),
            buffer_thinned: f.buffer_thinned,
            cell,
            reused: false,
        })?;
    }
    collector.handle(ToWriter::CellDone {
        cell,
        leaves: c.tiles.len(),
        reused: false,
    })
}
