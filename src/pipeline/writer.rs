//! The writer: runs on the pipeline's own thread, commits finished tiles into the output
//! directory, keeps the run's books and, when segments are stitched, runs the [`Stitcher`] and
//! writes each tile once its global segment ids are final. With a resume journal, it records
//! each finished cell (after its files are on the disk) and each tile written with global ids.

use super::failure::Failure;
use super::journal::{Entry, FailedEntry, Journal, TileEntry, TileResult};
use crate::error::{Error, Result};
use crate::io::output::{Container, DeferredTile};
use crate::io::workspace::OutputDir;
use crate::io::{PendingTile, TileWriter};
use crate::report::{FailedTile, Summary, TileSummary, TileTable, TILE_TABLE};
use crate::stages::TileReport;
use crate::stitch::{BorderSummary, CellKey, CellRelease, Ready, StitchParams, Stitcher};
use crossbeam_channel::Receiver;
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::collections::HashMap;
use std::path::Path;
use std::time::Instant;

/// What the writer needs to know about a processed tile besides its files.
pub(super) struct TileMeta {
    pub name: String,
    pub n_core: u64,
    pub buffer_points: u64,
    pub report: TileReport,
    pub split_root: Option<String>,
    /// Far buffer point copies dropped while splitting this tile's job (see `FarThin`).
    pub buffer_thinned: u64,
    /// Its grid cell.
    pub cell: CellKey,
    /// Taken from the resume journal, not processed by this run.
    pub reused: bool,
    /// A reused deferred tile that the interrupted run already wrote with its global ids:
    /// its files in the output directory.
    pub final_files: Option<Vec<String>>,
}

impl TileMeta {
    /// The books of a tile its journal recorded (a resumed run's, or a task's for the stitch).
    pub fn from_entry(
        t: &TileEntry,
        cell: CellKey,
        reused: bool,
        final_files: Option<Vec<String>>,
    ) -> TileMeta {
        TileMeta {
            name: t.name.clone(),
            n_core: t.n_core,
            buffer_points: t.buffer_points,
            report: t.report.clone(),
            split_root: t.split_root.clone(),
            buffer_thinned: t.buffer_thinned,
            cell,
            reused,
            final_files,
        }
    }

    fn entry(&self, result: TileResult) -> TileEntry {
        TileEntry {
            name: self.name.clone(),
            n_core: self.n_core,
            buffer_points: self.buffer_points,
            report: self.report.clone(),
            split_root: self.split_root.clone(),
            buffer_thinned: self.buffer_thinned,
            result,
        }
    }
}

/// A processed tile's output.
pub(super) enum TileOutput {
    /// Compressed by its worker, waiting to be renamed into place.
    Written(PendingTile),
    /// Stitching: core records with local ids, plus the border summary.
    Deferred(DeferredTile, Box<BorderSummary>),
    /// Written into the output directory by the interrupted run this one resumes.
    Reused(Vec<String>),
    /// Written by a task of a distributed run: (its path, its name in the output), linked
    /// into place by `tessera stitch`.
    Link(Vec<(std::path::PathBuf, String)>),
}

impl TileOutput {
    /// A deferred tile a journal recorded: its records and table in `parts`, its border
    /// summary read back from there.
    pub fn from_parts(parts: &Path, name: &str, points: usize) -> Result<TileOutput> {
        let [raw, table, summary] = super::journal::part_files(parts, name);
        let bytes = std::fs::read(&summary).map_err(|e| Error::io(&summary, e))?;
        let s = BorderSummary::from_bytes(&bytes, &summary.display().to_string())?;
        let d = DeferredTile::from_parts(name.to_string(), raw, table, points);
        Ok(TileOutput::Deferred(d, Box::new(s)))
    }
}

/// A processed tile.
pub(super) struct Processed {
    pub meta: TileMeta,
    pub output: TileOutput,
}

/// Messages to the writer thread.
pub(super) enum ToWriter {
    /// A worker finished a tile.
    Tile(Box<Processed>),
    /// A worker finished every leaf tile of a grid cell (sent after them); `reused` when
    /// they came from the resume journal.
    CellDone {
        cell: CellKey,
        leaves: usize,
        reused: bool,
    },
    /// The tiler released cells (sent before their jobs).
    Released(Vec<CellRelease>),
    /// A tile failed and is left out (`pipeline.keep_going`); the split it came from and the
    /// buffer copies that split thinned are still booked.
    Failed {
        failed: FailedTile,
        split_root: Option<String>,
        buffer_thinned: u64,
        cell: CellKey,
        reused: bool,
    },
}

impl ToWriter {
    /// Deletes the temporary files a message refers to (the run failed). With a resume
    /// journal (`journaled`) deferred tiles stay: they are the journal's (a cell already
    /// recorded needs them; an unrecorded one is written again over them).
    pub fn abandon(self, journaled: bool) {
        if let ToWriter::Tile(p) = self {
            match p.output {
                TileOutput::Written(pending) => pending.abandon(),
                TileOutput::Deferred(d, _) if !journaled => d.abandon(),
                TileOutput::Deferred(..) | TileOutput::Reused(_) | TileOutput::Link(_) => {}
            }
        }
    }
}

/// The writer thread's state.
pub(super) struct Collector<'a> {
    writer: &'a TileWriter,
    out: &'a mut OutputDir,
    stitcher: Option<Stitcher<(TileMeta, DeferredTile)>>,
    /// The resume journal, and the entries of cells whose leaves are still arriving.
    journal: Option<&'a mut Journal>,
    open_cells: HashMap<CellKey, (Vec<TileEntry>, Vec<FailedEntry>)>,
    /// A task of a distributed run: deferred tiles are booked and left in the journal (no
    /// stitcher); `tessera stitch`: the deferred files it writes from are left in place too.
    pub keep_deferred: bool,
    /// Threads that write the files of tiles made ready together (1: this one). Stitching
    /// holds most tiles until their neighbours are done, so the last tile of a run readies
    /// many at once (demo: 12 of 14 tiles); written one by one, they were the run's last
    /// seconds on one core. Each writer holds a block of records and one tile's compressor,
    /// far less than a worker's tile, and the workers are idle or nearly so by then.
    pub write_threads: usize,
    pub summary: Summary,
    pub write_s: f64,
    pub stitch_s: f64,
    /// Reports core points processed (written, deferred or failed) of a total.
    pub progress: Option<(super::ProgressFn<'a>, u64)>,
    processed: u64,
    /// The tile table, started with the first booked tile.
    table: Option<TileTable>,
}

impl<'a> Collector<'a> {
    /// A collector committing tiles into `out`; stitching when `stitch` is given (params,
    /// strip width).
    pub fn new(
        writer: &'a TileWriter,
        out: &'a mut OutputDir,
        stitch: Option<(StitchParams, f64)>,
        journal: Option<&'a mut Journal>,
    ) -> Self {
        Collector {
            writer,
            out,
            stitcher: stitch.map(|(p, strip_m)| Stitcher::new(p, strip_m)),
            journal,
            open_cells: HashMap::new(),
            progress: None,
            processed: 0,
            table: None,
            keep_deferred: false,
            write_threads: 1,
            summary: Summary::default(),
            write_s: 0.0,
            stitch_s: 0.0,
        }
    }

    /// Keeps the stitcher's frontier in memory up to `cap_bytes` (the plan's reserve); the
    /// oldest border summaries beyond it wait in a spill file in the run's staging directory.
    pub fn spill_frontier_beyond(&mut self, cap_bytes: u64) {
        let stage = self.out.stage().to_path_buf();
        self.stitcher = self
            .stitcher
            .take()
            .map(|st| st.spill_beyond(&stage, cap_bytes));
    }

    /// Handles every message until all senders are gone, then finishes. After a failure,
    /// messages are only cleaned up (their temporary files removed).
    pub fn run(&mut self, results: Receiver<ToWriter>, failure: &Failure) {
        for msg in results.iter() {
            if failure.failed() {
                msg.abandon(self.journal.is_some());
                continue;
            }
            if let Err(e) = self.handle(msg) {
                failure.set(e);
            }
        }
        if !failure.failed() {
            if let Err(e) = self.finish() {
                failure.set(e);
            }
        }
    }

    fn advance(&mut self, core_points: u64) {
        self.processed += core_points;
        if let Some((report, total)) = self.progress {
            report(self.processed, total);
        }
    }

    /// Handles one message.
    pub fn handle(&mut self, msg: ToWriter) -> Result<()> {
        let t = Instant::now();
        match msg {
            ToWriter::Released(cells) => {
                if let Some(st) = &mut self.stitcher {
                    st.released(&cells);
                }
                self.stitch_s += t.elapsed().as_secs_f64();
            }
            ToWriter::CellDone {
                cell,
                leaves,
                reused,
            } => {
                if let Some(st) = &mut self.stitcher {
                    st.cell_done(cell, leaves)?;
                }
                self.stitch_s += t.elapsed().as_secs_f64();
                let entries = self.open_cells.remove(&cell);
                if let (Some(j), false) = (self.journal.as_deref_mut(), reused) {
                    let (tiles, failed) = entries.unwrap_or_default();
                    j.append(&Entry::Cell {
                        ix: cell.0,
                        iy: cell.1,
                        tiles,
                        failed,
                    })?;
                    self.out.set_resumable();
                }
            }
            ToWriter::Failed {
                failed,
                split_root,
                buffer_thinned,
                cell,
                reused,
            } => {
                if self.journal.is_some() && !reused {
                    self.open_cells
                        .entry(cell)
                        .or_default()
                        .1
                        .push(FailedEntry {
                            failed: failed.clone(),
                            split_root: split_root.clone(),
                            buffer_thinned,
                        });
                }
                let s = &mut self.summary;
                s.points_failed += failed.points;
                let points = failed.points;
                s.failed_tiles.push(failed);
                s.buffer_points_thinned += buffer_thinned;
                if let Some(root) = split_root {
                    if !s.split_tiles.contains(&root) {
                        s.split_tiles.push(root);
                    }
                }
                self.advance(points);
            }
            ToWriter::Tile(p) => {
                let Processed { meta, output } = *p;
                self.advance(meta.n_core);
                let journaled = self.journal.is_some() && !meta.reused;
                match output {
                    TileOutput::Written(pending) => {
                        let files = pending.names();
                        let path = pending.commit(self.out)?;
                        if journaled {
                            let e = meta.entry(TileResult::Written { files });
                            self.open_cells.entry(meta.cell).or_default().0.push(e);
                        }
                        self.book(meta, &path)?;
                        self.write_s += t.elapsed().as_secs_f64();
                    }
                    TileOutput::Link(files) => {
                        self.out.link(&files)?;
                        let path = self.out.path().join(files.first().map_or("", |f| &f.1));
                        self.book(meta, &path)?;
                        self.write_s += t.elapsed().as_secs_f64();
                    }
                    TileOutput::Reused(files) => {
                        let path = self.out.path().join(files.first().map_or("", |f| f));
                        self.book(meta, &path)?;
                    }
                    TileOutput::Deferred(d, summary) => match &mut self.stitcher {
                        Some(st) => {
                            if journaled {
                                let e = meta.entry(TileResult::Deferred { points: d.points });
                                self.open_cells.entry(meta.cell).or_default().0.push(e);
                            }
                            st.add_tile(*summary, (meta, d))?;
                            self.stitch_s += t.elapsed().as_secs_f64();
                        }
                        None if self.keep_deferred => {
                            if journaled {
                                let e = meta.entry(TileResult::Deferred { points: d.points });
                                self.open_cells.entry(meta.cell).or_default().0.push(e);
                            }
                            let raw = d.files().0.to_path_buf();
                            self.book(meta, &raw)?;
                        }
                        None => {
                            d.abandon();
                            return Err(Error::Internal(
                                "a tile was deferred for stitching in a run without it".into(),
                            ));
                        }
                    },
                }
            }
        }
        self.write_ready()
    }

    /// All messages handled: closes the stitcher's frontier and writes what is left.
    pub fn finish(&mut self) -> Result<()> {
        if let Some(st) = &mut self.stitcher {
            st.finish()?;
        }
        self.write_ready()?;
        if let Some(st) = &self.stitcher {
            self.summary.stitch = Some(st.stats().clone());
        }
        self.commit_table()
    }

    /// Commits the tile table (an empty one when no tile was written) and puts the tile count,
    /// and for a small run the tiles themselves, into the summary.
    fn commit_table(&mut self) -> Result<()> {
        let table = match self.table.take() {
            Some(t) => t,
            None => TileTable::create(self.out.stage())?,
        };
        self.summary.tiles = table.rows();
        let (staged, inline) = table.finish()?;
        self.out.commit(&[(staged, TILE_TABLE.to_string())])?;
        self.summary.tile_list = inline;
        self.summary.tile_table = Some(TILE_TABLE.to_string());
        Ok(())
    }

    /// Writes the tiles the stitcher has made ready, their files by up to `write_threads`
    /// threads at once, and commits them in the stitcher's order.
    fn write_ready(&mut self) -> Result<()> {
        let Some(st) = &mut self.stitcher else {
            return Ok(());
        };
        let ready = st.take_ready();
        let t = Instant::now();
        let mut written = self.write_files(&ready, self.write_threads)?.into_iter();
        let mut res = Ok(());
        for r in ready {
            let (meta, d) = r.payload;
            let pre = written.next().flatten();
            if res.is_err() {
                if let Some(Ok(p)) = pre {
                    p.abandon();
                }
                if self.journal.is_none() {
                    d.abandon();
                }
                continue;
            }
            res = self.write_final(meta, d, &r.ids, pre);
        }
        self.write_s += t.elapsed().as_secs_f64();
        res
    }

    /// With more than one thread and tile, the staged files of the `ready` tiles that need
    /// writing, in parallel (each tile compressed sequentially, as a worker does); none (all
    /// left to [`Collector::write_final`]) otherwise. COPC stays sequential: its octree
    /// maps a whole tile.
    fn write_files(
        &self,
        ready: &[Ready<(TileMeta, DeferredTile)>],
        threads: usize,
    ) -> Result<Vec<Option<Result<PendingTile>>>> {
        if threads < 2 || ready.len() < 2 || self.writer.container() == Container::Copc {
            return Ok(Vec::new());
        }
        let stage = self.out.stage().to_path_buf();
        let pool = rayon::ThreadPoolBuilder::new()
            .num_threads(threads.min(ready.len()))
            .thread_name(|i| format!("tessera-write-{i}"))
            .build()
            .map_err(|e| Error::Internal(format!("writer threads: {e}")))?;
        Ok(pool.install(|| {
            ready
                .par_iter()
                .with_max_len(1)
                .map(|r| {
                    let (meta, d) = &r.payload;
                    meta.final_files
                        .is_none()
                        .then(|| self.writer.write_deferred(&stage, d, &r.ids))
                })
                .collect()
        }))
    }

    /// Writes a deferred tile with its global ids and commits it. With a journal, the tile
    /// is on the disk and recorded before its deferred records are deleted (a crash in
    /// between rewrites it); a tile the interrupted run already wrote is only booked.
    /// `pre`: its staged files, when already written ([`Collector::write_files`]).
    fn write_final(
        &mut self,
        meta: TileMeta,
        d: DeferredTile,
        ids: &[u64],
        pre: Option<Result<PendingTile>>,
    ) -> Result<()> {
        let stage = self.out.stage().to_path_buf();
        if let Some(files) = &meta.final_files {
            let path = self.out.path().join(files.first().map_or("", |f| f));
            d.abandon();
            self.book(meta, &path)?;
            return Ok(());
        }
        let written = pre.unwrap_or_else(|| self.writer.write_deferred(&stage, &d, ids));
        let Some(j) = self.journal.as_deref_mut() else {
            if !self.keep_deferred {
                d.abandon();
            }
            let path = written.and_then(|p| p.commit(self.out))?;
            self.book(meta, &path)?;
            return Ok(());
        };
        let pending = written?;
        if let Err(e) = pending.sync() {
            pending.abandon();
            return Err(e);
        }
        let files = pending.names();
        let path = pending.commit(self.out)?;
        j.append(&Entry::Final {
            name: meta.name.clone(),
            files,
        })?;
        self.out.set_resumable();
        d.abandon();
        self.book(meta, &path)?;
        Ok(())
    }

    fn book(&mut self, meta: TileMeta, path: &Path) -> Result<()> {
        let table = match &mut self.table {
            Some(t) => t,
            None => self.table.insert(TileTable::create(self.out.stage())?),
        };
        let s = &mut self.summary;
        if meta.reused {
            s.tiles_reused += 1;
        } else {
            s.tiles_recomputed += 1;
            for (k, v) in &meta.report.seconds {
                *s.seconds.entry(format!("stage_{k}")).or_default() += v;
            }
            for (k, w) in &meta.report.work {
                let secs = meta.report.seconds.get(k).copied().unwrap_or(0.0);
                s.stages.entry(k.clone()).or_default().add(w, secs);
            }
        }
        s.points_out += meta.n_core;
        s.buffer_points_thinned += meta.buffer_thinned;
        if let Some(root) = meta.split_root {
            if !s.split_tiles.contains(&root) {
                s.split_tiles.push(root);
            }
        }
        table.push(TileSummary {
            name: meta.name,
            file: path
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            points: meta.n_core,
            buffer_points: meta.buffer_points,
            stats: meta.report.stats,
            seconds: if meta.reused {
                BTreeMap::new()
            } else {
                meta.report.seconds
            },
        })
    }
}
