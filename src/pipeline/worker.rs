//! A worker: takes tile jobs, splits each while it is too big for its share of the budget,
//! loads the tile, runs the stages on it and compresses its core points to a temporary file
//! (or, with stitching, keeps them with local segment ids and summarises the tile's border).

use super::failure::Failure;
use super::journal::{part_files, FailedEntry, ResumeState, TileEntry, TileResult};
use super::plan::StitchPlan;
use super::tokens::MemoryTokens;
use super::writer::{Processed, TileMeta, TileOutput, ToWriter};
use crate::budget::{BudgetPlan, FarLoad};
use crate::error::{Error, Result};
use crate::io::output::{segment_table_tsv, TileSegments};
use crate::io::TileWriter;
use crate::model::{CellKey, RecordLayout, Tile};
use crate::report::FailedTile;
use crate::stages::{Stage, StageWork, TileReport};
use crate::stitch::BorderSummary;
use crate::sys::{alloc, ThreadClocks};
use crate::tiling::{load_tile, split_job, SplitParams, TileBuffers, TileJob, FAR_KEEP};
use crossbeam_channel::{Receiver, Sender};
use std::path::Path;
use std::time::Instant;

/// What every worker shares: the stages, the layout, the budget and where files go.
pub(super) struct WorkerRole<'a> {
    pub layout: &'a RecordLayout,
    pub stages: &'a [Box<dyn Stage>],
    pub budget: &'a BudgetPlan,
    pub split: SplitParams,
    pub writer: &'a TileWriter,
    /// The output's staging directory: finished tiles wait here for the writer's commit.
    pub stage_dir: &'a Path,
    /// Spill files (split children, tiles deferred for stitching).
    pub spill_dir: &'a Path,
    pub stitch: Option<&'a StitchPlan>,
    /// List a tile whose processing fails and go on (`pipeline.keep_going`).
    pub keep_going: bool,
    /// What the interrupted run this one resumes finished: those cells are not processed.
    pub resume: Option<&'a ResumeState>,
    /// The resume journal's parts directory: deferred tiles and their border summaries go
    /// there (flushed to the disk), and written tiles are flushed before they are committed.
    pub parts: Option<&'a Path>,
    /// Shares of the tile memory (one per worker): a tile takes as many as it needs.
    pub tokens: &'a MemoryTokens,
    /// Threads of each worker's pool (the stages' parallel sections).
    pub pool_threads: usize,
}

/// One worker's own thread pool: the stages' parallel sections run there, so their CPU time
/// (per-thread clocks) and heap (the worker's allocation domain) are this worker's alone.
struct WorkerPool {
    pool: Option<rayon::ThreadPool>,
    clocks: std::sync::Arc<ThreadClocks>,
    domain: usize,
}

impl WorkerPool {
    fn new(index: usize, threads: usize) -> Self {
        alloc::set_domain(index);
        let domain = alloc::current_domain();
        let clocks = std::sync::Arc::new(ThreadClocks::default());
        let c = clocks.clone();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.max(1))
            .thread_name(move |i| format!("tessera-w{index}-{i}"))
            .start_handler(move |_| {
                alloc::set_domain(index);
                c.register_current();
            })
            .build()
            .ok();
        if let Some(p) = &pool {
            // Every thread has started (and registered its clock) once each ran a task.
            p.broadcast(|_| ());
        }
        WorkerPool {
            pool,
            clocks,
            domain,
        }
    }

    /// Runs `f` in the pool (on this thread if the pool could not be built).
    fn install<R: Send>(&self, f: impl FnOnce() -> R + Send) -> R {
        match &self.pool {
            Some(p) => p.install(f),
            None => f(),
        }
    }

    /// CPU seconds of the pool's threads (of this thread without a pool).
    fn cpu_seconds(&self) -> f64 {
        if self.pool.is_some() {
            self.clocks.cpu_seconds()
        } else {
            crate::sys::thread_cpu_seconds()
        }
    }
}

/// The tokens a worker holds, and the tile buffers it keeps for reuse only while it holds
/// them (buffers kept without a token would be memory no share accounts for).
struct Held<'a> {
    tokens: &'a MemoryTokens,
    n: usize,
    spare: TileBuffers,
}

impl Held<'_> {
    /// Holds exactly `n` tokens, waiting for them in turn if more are needed.
    fn hold(&mut self, n: usize) {
        if self.n == n && !self.tokens.contended() {
            return;
        }
        self.release();
        self.tokens.take(n);
        self.n = n;
    }

    /// Gives every token back and frees the spare buffers.
    fn release(&mut self) {
        self.spare = TileBuffers::default();
        self.tokens.give(std::mem::take(&mut self.n));
    }

    /// After a tile: a worker waits for tokens, or this tile took several: give them back.
    fn after_tile(&mut self) {
        if self.n > 1 || self.tokens.contended() {
            self.release();
        }
    }
}

impl Drop for Held<'_> {
    fn drop(&mut self) {
        self.release();
    }
}

/// Runs one stage on a tile. A panic inside the stage (a bug, or a dependency's on data it
/// did not expect) becomes this tile's stage error instead of taking the process down: the
/// run stops with a message naming the tile and stage, or with `--keep-going` lists the tile
/// and goes on. The tile is dropped afterwards, so no half-updated state is used.
fn run_stage(
    st: &dyn Stage,
    tile: &mut Tile,
    layout: &RecordLayout,
    report: &mut TileReport,
) -> Result<()> {
    let r = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
        st.process(tile, layout, report)
    }));
    r.unwrap_or_else(|p| {
        let what = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Err(Error::Stage {
            tile: tile.name.to_string(),
            stage: st.name(),
            source: format!("panicked: {what}").into(),
        })
    })
}

impl WorkerRole<'_> {
    /// Processes jobs until the channel closes or the run fails. The worker's tile buffers
    /// are reused from tile to tile.
    pub fn run(
        &self,
        index: usize,
        jobs: Receiver<TileJob>,
        results: Sender<ToWriter>,
        failure: &Failure,
    ) {
        let pool = WorkerPool::new(index, self.pool_threads);
        let mut held = Held {
            tokens: self.tokens,
            n: 0,
            spare: TileBuffers::default(),
        };
        loop {
            // Idle: give the tokens back while waiting, so a big tile need not wait for us.
            let job = match jobs.try_recv() {
                Ok(j) => j,
                Err(crossbeam_channel::TryRecvError::Empty) => {
                    held.release();
                    match jobs.recv() {
                        Ok(j) => j,
                        Err(_) => break,
                    }
                }
                Err(crossbeam_channel::TryRecvError::Disconnected) => break,
            };
            if failure.failed() {
                break;
            }
            if let Err(e) = self.work(job, &results, &mut held, &pool) {
                failure.set(e);
                break;
            }
        }
    }

    /// One job: split while too big, then each resulting tile processed and sent on; with
    /// stitching, the cell's completion after its last leaf.
    fn work(
        &self,
        mut job: TileJob,
        res_tx: &Sender<ToWriter>,
        held: &mut Held<'_>,
        pool: &WorkerPool,
    ) -> Result<()> {
        let root = job.name.to_string();
        let cell = (job.id.ix, job.id.iy);
        if let Some((tiles, failed)) = self.resume.and_then(|r| r.cells.get(&cell)) {
            job.core_part.release();
            job.buf_part.release();
            return self.replay(cell, tiles, failed, res_tx);
        }
        let mut leaves = 0;
        let mut todo = vec![job];
        let mut was_split = false;
        let mut thinned = 0;
        while let Some(job) = todo.pop() {
            let far = self.far_load(&job);
            let tokens = self
                .budget
                .tokens_needed(job.n_core, job.n_buf, job.n_near, far);
            if self.should_split(&job, tokens) {
                was_split = true;
                // The split's buffers take the place of a loaded tile: give back the tokens
                // and the spare buffers.
                held.release();
                let (name, n_core, n_buf, n_near) = (job.name, job.n_core, job.n_buf, job.n_near);
                let (children, dropped) =
                    match split_job(job, self.layout, self.spill_dir, self.split) {
                        Ok(r) => r,
                        Err(e) => {
                            let failed = (name.to_string(), n_core, Some(root.clone()));
                            let thinned = std::mem::take(&mut thinned);
                            self.skip_or_fail(res_tx, failed, (thinned, cell), e)?;
                            continue;
                        }
                    };
                tracing::debug!(
                    "tile {name}: {n_core} core + {n_buf} buffer points ({n_near} near) do not fit; split into {} children ({dropped} far buffer copies thinned)",
                    children.len(),
                );
                thinned += dropped;
                // Reverse so children are processed in quadrant order.
                todo.extend(children.into_iter().rev());
                continue;
            }
            let tokens = tokens.unwrap_or(1);
            if tokens > 1 {
                tracing::debug!(
                    "tile {}: {} core + {} buffer points run alone with {tokens} memory tokens",
                    job.name,
                    job.n_core,
                    job.n_buf
                );
            }
            held.hold(tokens);
            let (tile, dropped_at_load) = load_tile(
                job,
                self.layout,
                std::mem::take(&mut held.spare),
                self.split.far,
            )?;
            let (name, n_core) = (tile.name.to_string(), tile.n_core as u64);
            let split_root = was_split.then(|| root.clone());
            let dropped = std::mem::take(&mut thinned) + dropped_at_load;
            let r = self.process(
                tile,
                &mut held.spare,
                pool,
                (split_root.clone(), dropped, cell),
            );
            held.after_tile();
            let p = match r {
                Ok(p) => p,
                Err(e) => {
                    self.skip_or_fail(res_tx, (name, n_core, split_root), (dropped, cell), e)?;
                    continue;
                }
            };
            if let Err(e) = res_tx.send(ToWriter::Tile(Box::new(p))) {
                e.into_inner().abandon(self.parts.is_some());
                return Ok(());
            }
            leaves += 1;
        }
        let _ = res_tx.send(ToWriter::CellDone {
            cell,
            leaves,
            reused: false,
        });
        Ok(())
    }

    /// The far thinning `load_tile` applies to `job`, as the budget charges it: at most one
    /// point per far cell kept, at most [`FAR_KEEP`] per cell held meanwhile.
    fn far_load(&self, job: &TileJob) -> Option<FarLoad> {
        let f = self
            .split
            .far
            .filter(|f| !job.far_thinned && f.applies(job.buffer_m))?;
        let cells = f.far_cells(job.core, job.buffer_m);
        Some(FarLoad {
            kept: job.n_kept,
            cells,
            held: job.n_buf.min(cells.saturating_mul(FAR_KEEP as u64)),
        })
    }

    /// Whether a job is split rather than loaded. One that fits a worker's share is loaded.
    /// One that needs several shares is split while its quadrants' cores stay at least twice
    /// as wide as the widest stage context (narrower children mostly repeat each other's
    /// context points: a 1.6 m core with a 5 m context processes 55 times its own points);
    /// then it runs alone with the tokens it needs. One too big for the whole tile memory is
    /// always split ([`split_job`] fails below `tiling.min_tile_size_m`).
    fn should_split(&self, job: &TileJob, tokens: Option<usize>) -> bool {
        match tokens {
            Some(1) => false,
            Some(_) => job.core.width() / 2.0 >= 2.0 * self.budget.near_m(),
            None => true,
        }
    }

    /// A cell the resume journal records as finished: its tiles' results and failures are
    /// handed on as recorded (deferred tiles with their border summaries, read back).
    fn replay(
        &self,
        cell: CellKey,
        tiles: &[TileEntry],
        failed: &[FailedEntry],
        res_tx: &Sender<ToWriter>,
    ) -> Result<()> {
        let resume = self
            .resume
            .ok_or_else(|| Error::Internal("replay without a resume journal".into()))?;
        for t in tiles {
            let final_files = resume.finals.get(&t.name).cloned();
            let meta = TileMeta::from_entry(t, cell, true, final_files);
            let output = match &t.result {
                TileResult::Written { files } => TileOutput::Reused(files.clone()),
                TileResult::Deferred { points } => {
                    TileOutput::from_parts(&resume.parts, &t.name, *points)?
                }
            };
            if res_tx
                .send(ToWriter::Tile(Box::new(Processed { meta, output })))
                .is_err()
            {
                return Ok(());
            }
        }
        for f in failed {
            let _ = res_tx.send(ToWriter::Failed {
                failed: f.failed.clone(),
                split_root: f.split_root.clone(),
                buffer_thinned: f.buffer_thinned,
                cell,
                reused: true,
            });
        }
        let _ = res_tx.send(ToWriter::CellDone {
            cell,
            leaves: tiles.len(),
            reused: true,
        });
        Ok(())
    }

    /// A tile (or a job's subtree) failed: with `keep_going`, a failure of this tile alone (a
    /// stage's error, a tile too dense for the budget) is reported to the writer and the
    /// worker goes on; anything else (I/O, configuration, cancellation) stops the run.
    /// `(tile, core points, split root)` name the failed tile; `buffer_thinned` counts the
    /// far buffer copies its job's splits dropped (still booked); `cell` is its grid cell.
    fn skip_or_fail(
        &self,
        res_tx: &Sender<ToWriter>,
        (tile, points, split_root): (String, u64, Option<String>),
        (buffer_thinned, cell): (u64, CellKey),
        e: Error,
    ) -> Result<()> {
        if !(self.keep_going && matches!(e, Error::Stage { .. } | Error::Budget(_))) {
            return Err(e);
        }
        tracing::warn!("tile {tile}: {e}; its {points} core points are not written (keep going)");
        let failed = FailedTile {
            tile,
            points,
            error: e.to_string(),
        };
        // A closed channel means the run is stopping anyway.
        let _ = res_tx.send(ToWriter::Failed {
            failed,
            split_root,
            buffer_thinned,
            cell,
            reused: false,
        });
        Ok(())
    }

    /// Runs the stages on a loaded tile and prepares its output; hands the tile's buffers
    /// back in `spare`.
    /// `(split root, far buffer copies thinned, grid cell)` are the tile's books.
    fn process(
        &self,
        mut tile: Tile,
        spare: &mut TileBuffers,
        pool: &WorkerPool,
        (split_root, buffer_thinned, cell): (Option<String>, u64, CellKey),
    ) -> Result<Processed> {
        let mut report = TileReport::default();
        for st in self.stages {
            let t = Instant::now();
            let cpu = pool.cpu_seconds();
            let probe = alloc::Probe::start(pool.domain);
            pool.install(|| run_stage(st.as_ref(), &mut tile, self.layout, &mut report))?;
            let n = tile.len() as u64;
            let w = report
                .work
                .entry(st.name().to_string())
                .or_insert_with(|| StageWork {
                    points: n,
                    ..StageWork::default()
                });
            w.tile_points = tile.len() as u64;
            w.cpu_seconds = pool.cpu_seconds() - cpu;
            w.peak_bytes = probe.peak_growth();
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
        let summary = match self.stitch {
            Some(st) => Some(BorderSummary::build(&tile, st.strip_m, |pid| {
                st.ordinal(pid)
            })?),
            None => None,
        };
        let mut records = std::mem::take(&mut tile.records);
        records.truncate(n_core * self.layout.record_len);
        let t = Instant::now();
        let table = self
            .writer
            .writes_segments()
            .then(|| segment_table_tsv(&tile.segment_table));
        let seg = table.as_deref().map(|table| TileSegments {
            ids: tile.segments.get(..n_core).unwrap_or(&[]),
            table,
        });
        let output = match (summary, seg) {
            (Some(summary), Some(seg)) => {
                let dir = self.parts.unwrap_or(self.spill_dir);
                let d = self.writer.defer(dir, &name, &mut records, seg)?;
                if self.parts.is_some() {
                    // The journal names the cell once its parts are on the disk.
                    let path = part_files(dir, &name)[2].clone();
                    let res = crate::io::output::write_atomic(&path, &summary.to_bytes())
                        .and_then(|_| crate::io::output::sync_file(&path))
                        .and_then(|_| d.sync());
                    if let Err(e) = res {
                        d.abandon();
                        return Err(e);
                    }
                }
                TileOutput::Deferred(d, Box::new(summary))
            }
            (_, seg) => {
                let pending = self
                    .writer
                    .prepare(self.stage_dir, &name, &mut records, seg)?;
                if self.parts.is_some() {
                    if let Err(e) = pending.sync() {
                        pending.abandon();
                        return Err(e);
                    }
                }
                TileOutput::Written(pending)
            }
        };
        *spare = TileBuffers::reclaim(&mut tile, records);
        drop(tile);
        report
            .seconds
            .insert("compress".into(), t.elapsed().as_secs_f64());
        Ok(Processed {
            meta: TileMeta {
                name,
                n_core: n_core as u64,
                buffer_points,
                report,
                split_root,
                buffer_thinned,
                cell,
                reused: false,
                final_files: None,
            },
            output,
        })
    }
}
