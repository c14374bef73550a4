//! The writer: runs on the pipeline's own thread, commits finished tiles into the output
//! directory, keeps the run's books and, when segments are stitched, runs the [`Stitcher`] and
//! writes each tile once its global segment ids are final.

use super::failure::Failure;
use crate::error::{Error, Result};
use crate::io::output::DeferredTile;
use crate::io::workspace::OutputDir;
use crate::io::{PendingTile, TileWriter};
use crate::report::{FailedTile, Summary, TileSummary};
use crate::stages::TileReport;
use crate::stitch::{BorderSummary, CellKey, CellRelease, StitchParams, Stitcher};
use crossbeam_channel::Receiver;
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
}

/// A processed tile's output.
pub(super) enum TileOutput {
    /// Compressed by its worker, waiting to be renamed into place.
    Written(PendingTile),
    /// Stitching: core records with local ids, plus the border summary.
    Deferred(DeferredTile, Box<BorderSummary>),
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
    /// A worker finished every leaf tile of a grid cell (sent after them).
    CellDone { cell: CellKey, leaves: usize },
    /// The tiler released cells (sent before their jobs).
    Released(Vec<CellRelease>),
    /// A tile failed and is left out (`pipeline.keep_going`); the split it came from and the
    /// buffer copies that split thinned are still booked.
    Failed {
        failed: FailedTile,
        split_root: Option<String>,
        buffer_thinned: u64,
    },
}

impl ToWriter {
    /// Deletes the temporary files a message refers to (the run failed).
    pub fn abandon(self) {
        if let ToWriter::Tile(p) = self {
            match p.output {
                TileOutput::Written(pending) => pending.abandon(),
                TileOutput::Deferred(d, _) => d.abandon(),
            }
        }
    }
}

/// The writer thread's state.
pub(super) struct Collector<'a> {
    writer: &'a TileWriter,
    out: &'a mut OutputDir,
    stitcher: Option<Stitcher<(TileMeta, DeferredTile)>>,
    pub summary: Summary,
    pub write_s: f64,
    pub stitch_s: f64,
}

impl<'a> Collector<'a> {
    /// A collector committing tiles into `out`; stitching when `stitch` is given (params,
    /// strip width).
    pub fn new(
        writer: &'a TileWriter,
        out: &'a mut OutputDir,
        stitch: Option<(StitchParams, f64)>,
    ) -> Self {
        Collector {
            writer,
            out,
            stitcher: stitch.map(|(p, strip_m)| Stitcher::new(p, strip_m)),
            summary: Summary::default(),
            write_s: 0.0,
            stitch_s: 0.0,
        }
    }

    /// Handles every message until all senders are gone, then finishes. After a failure,
    /// messages are only cleaned up (their temporary files removed).
    pub fn run(&mut self, results: Receiver<ToWriter>, failure: &Failure) {
        for msg in results.iter() {
            if failure.failed() {
                msg.abandon();
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
            ToWriter::CellDone { cell, leaves } => {
                if let Some(st) = &mut self.stitcher {
                    st.cell_done(cell, leaves)?;
                }
                self.stitch_s += t.elapsed().as_secs_f64();
            }
            ToWriter::Failed {
                failed,
                split_root,
                buffer_thinned,
            } => {
                let s = &mut self.summary;
                s.points_failed += failed.points;
                s.failed_tiles.push(failed);
                s.buffer_points_thinned += buffer_thinned;
                if let Some(root) = split_root {
                    if !s.split_tiles.contains(&root) {
                        s.split_tiles.push(root);
                    }
                }
            }
            ToWriter::Tile(p) => {
                let Processed { meta, output } = *p;
                match output {
                    TileOutput::Written(pending) => {
                        let path = pending.commit(self.out)?;
                        self.book(meta, &path);
                        self.write_s += t.elapsed().as_secs_f64();
                    }
                    TileOutput::Deferred(d, summary) => match &mut self.stitcher {
                        Some(st) => {
                            st.add_tile(*summary, (meta, d))?;
                            self.stitch_s += t.elapsed().as_secs_f64();
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
        Ok(())
    }

    fn write_ready(&mut self) -> Result<()> {
        let Some(st) = &mut self.stitcher else {
            return Ok(());
        };
        let ready = st.take_ready();
        let t = Instant::now();
        let mut res = Ok(());
        for r in ready {
            let (meta, d) = r.payload;
            if res.is_err() {
                d.abandon();
                continue;
            }
            let stage = self.out.stage().to_path_buf();
            match self
                .writer
                .finish_deferred(&stage, d, &r.ids)
                .and_then(|p| p.commit(self.out))
            {
                Ok(path) => self.book(meta, &path),
                Err(e) => res = Err(e),
            }
        }
        self.write_s += t.elapsed().as_secs_f64();
        res
    }

    fn book(&mut self, meta: TileMeta, path: &Path) {
        let s = &mut self.summary;
        s.points_out += meta.n_core;
        s.buffer_points_thinned += meta.buffer_thinned;
        if let Some(root) = meta.split_root {
            if !s.split_tiles.contains(&root) {
                s.split_tiles.push(root);
            }
        }
        for (k, v) in &meta.report.seconds {
            *s.seconds.entry(format!("stage_{k}")).or_default() += v;
        }
        s.tile_list.push(TileSummary {
            name: meta.name,
            file: path
                .file_name()
                .map(|f| f.to_string_lossy().into_owned())
                .unwrap_or_default(),
            points: meta.n_core,
            buffer_points: meta.buffer_points,
            stats: meta.report.stats,
        });
    }
}
