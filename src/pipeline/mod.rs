//! The pipeline: reader → tiler → worker pool → writer, wired with bounded channels so a slow
//! stage holds the others back instead of letting queues grow.
//!
//! ```text
//! reader ──chunks(bounded)──▶ tiler ──jobs(bounded)──▶ workers ×N ──results(bounded)──▶ writer
//!   (LAS/LAZ, fill_points)     (spill files)            (load/split, stages)             (LAZ, atomic)
//! ```
//! Jobs carry only spill-file paths; a tile is loaded, processed and compressed (to a
//! temporary file) by one worker, and the writer only commits finished files by renaming, so
//! the tiles in memory at once are bounded by the worker count.

pub mod budget;
mod collect;
pub mod ground_stage;
pub mod label_stage;
pub mod segment_stage;
pub mod stage;
pub mod stats_stage;

use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::input::read_file_chunks;
use crate::io::output::{segment_table_tsv, SegmentIdType, TileSegments};
use crate::io::workspace::{OutputDir, WorkDir};
use crate::io::{scan_inputs, InputSet, TileWriter};
use crate::report::{peak_rss_mb, Summary};
use crate::stitch::BorderSummary;
use crate::tiling::{
    load_tile, schedule, split_job, FarThin, Grid, SplitParams, TileBuffers, TileJob, Tiler,
};
use budget::BudgetPlan;
use collect::{Collector, Processed, TileMeta, TileOutput, ToWriter};
use crossbeam_channel::{bounded, Receiver, Sender};
pub use stage::{build_stages, Stage, StageSpec, TileReport, REGISTRY};
pub use stats_stage::StatsStage;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::Mutex;
use std::time::Instant;

/// Progress callback: called with (points read so far, total points).
pub type ProgressFn<'a> = &'a (dyn Fn(u64, u64) + Sync);

enum ReadMsg {
    Chunk {
        file: usize,
        first: u64,
        records: las::PointData,
    },
    FileDone(usize),
}

/// Everything the pipeline threads share for one run.
struct RunCtx<'a> {
    set: &'a InputSet,
    /// The output's private staging directory: workers write finished tiles here, the writer
    /// commits them into the output directory.
    stage: &'a Path,
    spill_dir: &'a Path,
    cfg: &'a Config,
    plan: &'a BudgetPlan,
    stages: &'a [Box<dyn Stage>],
    writer: &'a TileWriter,
    /// Stitching: the overlap strip width and each input's first point ordinal.
    stitch: Option<StitchCtx>,
    /// Far-buffer thinning of split tiles, when the stages allow it.
    far_thin: Option<FarThin>,
}

/// What workers need to summarise tiles for stitching.
struct StitchCtx {
    strip_m: f64,
    /// Ordinal of the first point of each input file (prefix sums in input order).
    first_ordinal: Vec<u64>,
}

impl StitchCtx {
    /// Position of a point in the run's inputs: dense, deterministic, unique.
    fn ordinal(&self, pid: u64) -> u64 {
        let file = (pid >> 40) as usize;
        self.first_ordinal
            .get(file)
            .copied()
            .unwrap_or(u64::MAX >> 1)
            + (pid & ((1 << 40) - 1))
    }
}

/// Shared failure state: the first real error wins (a [`Error::Cancelled`] only until a real
/// one arrives); everyone else stops quietly.
struct Failure {
    first: Mutex<Option<Error>>,
    flag: AtomicBool,
}

impl Failure {
    fn set(&self, e: Error) {
        let mut g = self.first.lock().unwrap_or_else(|p| p.into_inner());
        let replace = match &*g {
            None => true,
            Some(Error::Cancelled) => !matches!(e, Error::Cancelled),
            Some(_) => false,
        };
        if replace {
            *g = Some(e);
        }
        self.flag.store(true, Ordering::SeqCst);
    }
    fn failed(&self) -> bool {
        self.flag.load(Ordering::SeqCst)
    }
}

/// Runs the whole pipeline on `inputs`, writing tiles and `summary.json` into `out_dir`.
pub fn run(
    inputs: &[PathBuf],
    out_dir: &Path,
    cfg: &Config,
    progress: ProgressFn,
) -> Result<Summary> {
    let stages = build_stages(cfg)?;
    run_with_stages(inputs, out_dir, cfg, &stages, progress)
}

/// Like [`run`], with the stages given by the caller instead of `cfg.stages.run`.
pub fn run_with_stages(
    inputs: &[PathBuf],
    out_dir: &Path,
    cfg: &Config,
    stages: &[Box<dyn Stage>],
    progress: ProgressFn,
) -> Result<Summary> {
    let t0 = Instant::now();
    // The output directory is taken first: a second run into it refuses before any work, and
    // an earlier run's outputs are replaced only with `output.overwrite`.
    let mut out = OutputDir::open(out_dir, cfg.output.overwrite)?;
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
    // MCAP drives are decoded and georeferenced first, into LAS parts whose headers carry the
    // exact bounds the tiler needs; the parts are removed when `staged` is dropped.
    let staged = crate::io::mcap::stage_inputs(
        &inputs,
        &work_base.join("mcap"),
        &cfg.mcap,
        cfg.pipeline.threads,
    )?;
    let requested = cfg.output_point_format()?;
    let mut set = scan_inputs(&staged.paths, requested)?;
    let max_code = stages.iter().map(|s| s.max_class_code()).max().unwrap_or(0);
    if requested.is_none() && max_code > 31 && !set.layout.format.is_extended {
        // Legacy formats hold class codes up to 31; write the LAS 1.4 format with the same
        // attributes (0, 1 → 6; 2, 3 → 7; 4 → 9; 5 → 10) rather than fail or truncate codes.
        let f = &set.layout.format;
        let up = match (f.has_color, f.has_waveform) {
            (false, false) => 6,
            (true, false) => 7,
            (false, true) => 9,
            (true, true) => 10,
        };
        tracing::info!(
            "stages write class codes up to {max_code}: output point format {} -> {up}",
            f.to_u8().unwrap_or(255)
        );
        set = scan_inputs(&staged.paths, Some(up))?;
    }
    let scan_s = t0.elapsed().as_secs_f64();
    let workers = if cfg.pipeline.threads == 0 {
        std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1)
    } else {
        cfg.pipeline.threads
    };
    // Stages run one after the other on a tile and free their working memory before the next
    // starts, so the largest one counts (the plan charges results carried between stages,
    // such as segment labels, to every point).
    let stage_mem: Vec<budget::StageMemory> = stages
        .iter()
        .map(|s| budget::StageMemory {
            context_bytes: s.bytes_per_point(),
            tile_bytes: s.bytes_per_tile_point(),
            context_m: s.context_m(),
        })
        .collect();
    let segments = stages.iter().any(|s| s.assigns_segment_ids());
    let stitching = segments && cfg.stitch.enabled;
    let mut plan = BudgetPlan::with_stages(
        cfg.pipeline.memory_budget_mb,
        set.layout.record_len,
        &stage_mem,
        workers,
    )?;
    if stitching {
        plan.reserve_stitch()?;
    }
    let spill_dir = work_base.join("spill");
    std::fs::create_dir_all(&spill_dir).map_err(|e| Error::io(&spill_dir, e))?;
    // Stitching needs the segment stage (whose buffer strip is the overlap the tiles are
    // matched in). Global ids are point ordinals + 1: u32 while the run has fewer points.
    let stitch = stitching.then(|| {
        let mut first_ordinal = Vec::with_capacity(set.files.len());
        let mut acc = 0u64;
        for f in &set.files {
            first_ordinal.push(acc);
            acc += f.points;
        }
        let strip_m = cfg.segment.buffer_m.min(cfg.tiling.buffer_m);
        if strip_m <= 0.0 {
            tracing::warn!(
                "stitching with a 0 m overlap strip (segment.buffer_m = {}, tiling.buffer_m = {}): segments cannot be matched across borders and keep one id per tile",
                cfg.segment.buffer_m,
                cfg.tiling.buffer_m
            );
        }
        StitchCtx {
            strip_m,
            first_ordinal,
        }
    });
    let id_type = if stitch.is_some() && set.total_points >= u32::MAX as u64 {
        SegmentIdType::U64
    } else {
        SegmentIdType::U32
    };
    let writer = TileWriter::new(
        &set.template,
        &set.layout,
        cfg.output.format == "laz",
        segments.then_some(id_type),
    )?;
    let far_thin = far_thin(cfg, stages);
    let stage_dir = out.stage().to_path_buf();
    let ctx = RunCtx {
        far_thin,
        set: &set,
        stage: &stage_dir,
        spill_dir: &spill_dir,
        cfg,
        plan: &plan,
        stages,
        writer: &writer,
        stitch,
    };
    let mut summary = run_inner(&ctx, &mut out, progress)?;
    summary.seconds.insert("scan".into(), scan_s);
    summary
        .seconds
        .insert("total".into(), t0.elapsed().as_secs_f64());
    summary.version = env!("CARGO_PKG_VERSION").into();
    summary.inputs = set.files.len();
    summary.mcap = staged.reports.clone();
    summary.points_in = set.total_points;
    summary.memory_budget_mb = cfg.pipeline.memory_budget_mb;
    summary.point_format = set.layout.format.to_u8().unwrap_or(255);
    if let Some(st) = &summary.stitch {
        if st.frontier_bytes_max > plan.stitch_bytes {
            tracing::warn!(
                "the stitcher's frontier peaked at {} MiB, above the {} MiB reserved for it in the memory plan",
                st.frontier_bytes_max >> 20,
                plan.stitch_bytes >> 20
            );
        }
    }
    summary.budget = Some(plan);
    summary.peak_rss_mb = peak_rss_mb().unwrap_or(0.0);
    // Every point the headers promise was read (the reader checks each file's count), and
    // every point read was written exactly once.
    if summary.points_read != summary.points_in || summary.points_out != summary.points_in {
        return Err(Error::Internal(format!(
            "the input headers promise {} points; {} were read and {} written",
            summary.points_in, summary.points_read, summary.points_out
        )));
    }
    let json = serde_json::to_vec_pretty(&summary).map_err(|e| Error::Internal(e.to_string()))?;
    // The run's files are all in place; the summary comes last and marks the run finished.
    // (A failure before this point drops `out`, which removes this run's partial outputs.)
    out.finish(&json)?;
    drop(staged);
    drop(spill_work);
    Ok(summary)
}

fn run_inner(ctx: &RunCtx, out: &mut OutputDir, progress: ProgressFn) -> Result<Summary> {
    let RunCtx {
        set,
        spill_dir,
        cfg,
        plan,
        stages,
        ..
    } = *ctx;
    // Buffers only cost (spill traffic grows with (tile + 2 buffer)² / tile²): build them only
    // when some stage reads context.
    let buffer_m = if stages.iter().any(|s| s.needs_context()) {
        cfg.tiling.buffer_m
    } else {
        0.0
    };
    let grid = Grid {
        tile_size_m: cfg.tiling.tile_size_m,
        buffer_m,
    };
    let order = schedule(&set.files, &grid);
    let failure = Failure {
        first: Mutex::new(None),
        flag: AtomicBool::new(false),
    };
    let read_points = AtomicU64::new(0);
    let max_open = AtomicU64::new(0);
    let (chunk_tx, chunk_rx) = bounded::<ReadMsg>(plan.chunk_depth);
    let (free_tx, free_rx) = bounded::<las::PointData>(plan.chunk_depth + 2);
    let (job_tx, job_rx) = bounded::<TileJob>(plan.workers);
    let (res_tx, res_rx) = bounded::<ToWriter>(1);
    let layout = &set.layout;
    let tread = Mutex::new(0.0f64);
    let ttile = Mutex::new(0.0f64);

    let twrite = Instant::now();
    let mut collector = Collector::new(
        ctx.writer,
        out,
        ctx.stitch
            .as_ref()
            .map(|st| (cfg.stitch.clone(), st.strip_m)),
    );
    // The tiler tells the stitcher which cells it releases, before their jobs leave.
    let release_tx = ctx.stitch.is_some().then(|| res_tx.clone());
    std::thread::scope(|s| {
        // Reader.
        s.spawn(|| {
            let t = Instant::now();
            let r = (|| -> Result<()> {
                for &fi in &order {
                    let f = &set.files[fi];
                    let spare = || free_rx.try_recv().ok();
                    read_file_chunks(f, layout, plan.chunk_points, spare, |first, records| {
                        if failure.failed() {
                            return Err(Error::Cancelled);
                        }
                        let n = records.len() as u64;
                        chunk_tx
                            .send(ReadMsg::Chunk {
                                file: fi,
                                first,
                                records,
                            })
                            .map_err(|_| Error::Cancelled)?;
                        let done = read_points.fetch_add(n, Ordering::Relaxed) + n;
                        progress(done, set.total_points);
                        Ok(())
                    })?;
                    chunk_tx
                        .send(ReadMsg::FileDone(fi))
                        .map_err(|_| Error::Cancelled)?;
                }
                Ok(())
            })();
            if let Err(e) = r {
                if !failure.failed() {
                    failure.set(e);
                }
            }
            drop(chunk_tx);
            *tread.lock().unwrap_or_else(|p| p.into_inner()) = t.elapsed().as_secs_f64();
        });
        // Tiler.
        s.spawn(|| {
            let release_tx = release_tx;
            let t = Instant::now();
            let r = (|| -> Result<()> {
                let mut tiler = Tiler::new(
                    grid,
                    layout,
                    &set.files,
                    spill_dir,
                    plan.spill_bytes,
                    plan.near_m(),
                );
                let announce = |tiler: &mut Tiler| -> bool {
                    let cells = tiler.take_releases();
                    match &release_tx {
                        Some(tx) if !cells.is_empty() => tx.send(ToWriter::Released(cells)).is_ok(),
                        _ => true,
                    }
                };
                for msg in chunk_rx.iter() {
                    match msg {
                        ReadMsg::Chunk {
                            file,
                            first,
                            records,
                        } => {
                            tiler.push_chunk(file, first, records.raw_bytes())?;
                            let _ = free_tx.try_send(records);
                            max_open.fetch_max(tiler.open_tiles() as u64, Ordering::Relaxed);
                        }
                        ReadMsg::FileDone(f) => {
                            let jobs = tiler.file_done(f)?;
                            if !announce(&mut tiler) {
                                return Ok(());
                            }
                            for job in jobs {
                                if job_tx.send(job).is_err() {
                                    return Ok(());
                                }
                            }
                        }
                    }
                }
                if failure.failed() {
                    return Ok(());
                }
                let jobs = tiler.finish()?;
                if !announce(&mut tiler) {
                    return Ok(());
                }
                for job in jobs {
                    if job_tx.send(job).is_err() {
                        return Ok(());
                    }
                }
                Ok(())
            })();
            if let Err(e) = r {
                failure.set(e);
            }
            // Dropping both ends here (not at the end of the scope) is what lets a blocked
            // reader see a closed channel when the tiler stops early.
            drop(chunk_rx);
            drop(job_tx);
            *ttile.lock().unwrap_or_else(|p| p.into_inner()) = t.elapsed().as_secs_f64();
        });
        // Workers.
        for _ in 0..plan.workers {
            let job_rx: Receiver<TileJob> = job_rx.clone();
            let res_tx: Sender<ToWriter> = res_tx.clone();
            let failure = &failure;
            s.spawn(move || {
                let mut spare = TileBuffers::default();
                for job in job_rx.iter() {
                    if failure.failed() {
                        break;
                    }
                    if let Err(e) = work(job, ctx, &res_tx, &mut spare) {
                        failure.set(e);
                        break;
                    }
                }
            });
        }
        drop(res_tx);
        drop(job_rx);
        // Writer (this thread): commits tiles (stitched ones once their ids are final) and
        // keeps the books.
        for msg in res_rx.iter() {
            if failure.failed() {
                msg.abandon();
                continue;
            }
            if let Err(e) = collector.handle(msg) {
                failure.set(e);
            }
        }
        if !failure.failed() {
            if let Err(e) = collector.finish() {
                failure.set(e);
            }
        }
    });
    if let Some(e) = failure
        .first
        .into_inner()
        .unwrap_or_else(|p| p.into_inner())
    {
        return Err(e);
    }
    let Collector {
        mut summary,
        write_s,
        stitch_s,
        ..
    } = collector;
    if ctx.stitch.is_some() {
        summary.seconds.insert("stitch".into(), stitch_s);
    }
    summary.buffer_m = buffer_m;
    summary.tiles = summary.tile_list.len();
    summary.tiles_split = summary.split_tiles.len();
    summary.max_open_tiles = max_open.load(Ordering::Relaxed) as usize;
    summary.points_read = read_points.load(Ordering::Relaxed);
    summary.seconds.insert(
        "read".into(),
        *tread.lock().unwrap_or_else(|p| p.into_inner()),
    );
    summary.seconds.insert(
        "tile".into(),
        *ttile.lock().unwrap_or_else(|p| p.into_inner()),
    );
    summary.seconds.insert("write".into(), write_s);
    summary
        .seconds
        .insert("pipeline".into(), twrite.elapsed().as_secs_f64());
    Ok(summary)
}

/// Far-buffer thinning for split tiles: allowed when every stage that reads the whole buffer
/// names its far cells ([`Stage::far_cells`]) and they agree; points within the widest bounded
/// context of the other stages, and at least within `tiling.split_dense_buffer_m`, are all
/// kept.
fn far_thin(cfg: &Config, stages: &[Box<dyn Stage>]) -> Option<FarThin> {
    if !cfg.tiling.thin_split_buffers {
        return None;
    }
    let readers: Vec<&dyn Stage> = stages
        .iter()
        .filter(|s| s.needs_context())
        .map(|s| s.as_ref())
        .collect();
    let mut cells = None;
    for s in readers.iter().filter(|s| s.context_m().is_none()) {
        let c = s.far_cells()?;
        // Two different representative rules would each need their own points: keep all.
        if cells.is_some_and(|p| p != c) {
            return None;
        }
        cells = Some(c);
    }
    let near_m = readers
        .iter()
        .filter_map(|s| s.context_m())
        .fold(0.0f64, f64::max);
    Some(FarThin {
        near_m: near_m.max(cfg.tiling.split_dense_buffer_m),
        cells: cells?,
    })
}

/// Processes one job: splits it while it is too big for the budget, then loads and runs the
/// stages on each resulting tile and compresses its core points to a temporary file. The
/// worker's tile buffers are reused from tile to tile (`spare`).
fn work(
    job: TileJob,
    ctx: &RunCtx,
    res_tx: &Sender<ToWriter>,
    spare: &mut TileBuffers,
) -> Result<()> {
    let RunCtx {
        set,
        stage,
        spill_dir,
        cfg,
        plan,
        stages,
        writer,
        ref stitch,
        far_thin,
    } = *ctx;
    let root = job.name.to_string();
    let cell = (job.id.ix, job.id.iy);
    let mut leaves = 0;
    let mut todo = vec![job];
    let mut was_split = false;
    let mut thinned = 0;
    while let Some(job) = todo.pop() {
        if !plan.fits(job.n_core, job.n_buf, job.n_near) {
            was_split = true;
            // The split's buffers take the place of a loaded tile: free the spare one.
            *spare = TileBuffers::default();
            let params = SplitParams {
                min_tile_size_m: cfg.tiling.min_tile_size_m,
                buffer_bytes: plan.spill_bytes / plan.workers.max(1),
                max_points: plan.max_tile_points,
                near_m: plan.near_m(),
                far: far_thin,
            };
            let (name, n_core, n_buf, n_near) = (job.name, job.n_core, job.n_buf, job.n_near);
            let (children, dropped) = split_job(job, &set.layout, spill_dir, params)?;
            tracing::debug!(
                "tile {name}: {n_core} core + {n_buf} buffer points ({n_near} near) do not fit; split into {} children ({dropped} far buffer copies thinned)",
                children.len(),
            );
            thinned += dropped;
            // Reverse so children are processed in quadrant order.
            todo.extend(children.into_iter().rev());
            continue;
        }
        let mut tile = load_tile(job, &set.layout, std::mem::take(spare))?;
        let mut report = TileReport::default();
        for st in stages {
            let t = Instant::now();
            st.process(&mut tile, &set.layout, &mut report)?;
            report
                .seconds
                .insert(st.name().to_string(), t.elapsed().as_secs_f64());
        }
        tracing::debug!(
            "tile {}: {} core + {} buffer points, stage seconds {:?}",
            tile.name,
            tile.n_core,
            tile.len() - tile.n_core,
            report.seconds
        );
        let name = tile.name.to_string();
        let n_core = tile.n_core;
        let buffer_points = (tile.len() - n_core) as u64;
        let summary = match stitch {
            Some(st) => Some(BorderSummary::build(&tile, st.strip_m, |pid| {
                st.ordinal(pid)
            })?),
            None => None,
        };
        let mut records = std::mem::take(&mut tile.records);
        records.truncate(n_core * set.layout.record_len);
        let t = Instant::now();
        let table = writer
            .writes_segments()
            .then(|| segment_table_tsv(&tile.segment_table));
        let seg = table.as_deref().map(|table| TileSegments {
            ids: tile.segments.get(..n_core).unwrap_or(&[]),
            table,
        });
        let output = match (summary, seg) {
            (Some(summary), Some(seg)) => TileOutput::Deferred(
                writer.defer(spill_dir, &name, &mut records, seg)?,
                Box::new(summary),
            ),
            (_, seg) => TileOutput::Written(writer.prepare(stage, &name, &mut records, seg)?),
        };
        *spare = TileBuffers::reclaim(&mut tile, records);
        drop(tile);
        report
            .seconds
            .insert("compress".into(), t.elapsed().as_secs_f64());
        let p = Processed {
            meta: TileMeta {
                name,
                n_core: n_core as u64,
                buffer_points,
                report,
                split_root: was_split.then(|| root.clone()),
                buffer_thinned: std::mem::take(&mut thinned),
            },
            output,
        };
        if let Err(e) = res_tx.send(ToWriter::Tile(Box::new(p))) {
            e.into_inner().abandon();
            return Ok(());
        }
        leaves += 1;
    }
    if stitch.is_some() {
        let _ = res_tx.send(ToWriter::CellDone { cell, leaves });
    }
    Ok(())
}
