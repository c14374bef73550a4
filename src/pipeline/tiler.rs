//! The tiler thread: bins the reader's chunks into spill files per tile and sends each grid
//! cell as a job once no later input can reach it; with stitching, it first tells the writer
//! which cells it releases.

use super::failure::Failure;
use super::reader::ReadMsg;
use super::writer::ToWriter;
use crate::error::Result;
use crate::io::InputFile;
use crate::model::{RecordLayout, TileId};
use crate::tiling::{Grid, TileJob, Tiler};
use crossbeam_channel::{Receiver, Sender};
use std::path::Path;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// What the tiler needs.
pub(super) struct TilerRole<'a> {
    pub grid: Grid,
    pub layout: &'a RecordLayout,
    pub files: &'a [InputFile],
    pub spill_dir: &'a Path,
    /// Bound on the spill write buffers, bytes.
    pub spill_bytes: usize,
    /// Buffer points within this distance of a core are counted per job (`TileJob::n_near`).
    pub near_m: f64,
    /// ... and within this one (`TileJob::n_kept`, for far thinning; 0: not counted).
    pub kept_m: f64,
    /// A task of a distributed run: only these cells are binned.
    pub scope: Option<&'a std::collections::HashSet<crate::model::CellKey>>,
}

/// The tiler's channel ends.
pub(super) struct TilerChannels {
    pub chunk_rx: Receiver<ReadMsg>,
    pub free_tx: Sender<las::PointData>,
    pub job_tx: Sender<TileJob>,
    /// Cell releases for the stitcher (None without stitching).
    pub release_tx: Option<Sender<ToWriter>>,
}

impl TilerRole<'_> {
    /// Runs until the reader is done or the run fails; returns the seconds spent. The peak
    /// number of open tiles goes to `max_open`, the core points binned to `core_points`.
    pub fn run(
        &self,
        ch: TilerChannels,
        failure: &Failure,
        (max_open, core_points): (&AtomicU64, &AtomicU64),
    ) -> f64 {
        let t = Instant::now();
        if let Err(e) = self.tile_all(&ch, failure, (max_open, core_points)) {
            failure.set(e);
        }
        // Dropping both ends here (not at the end of the run's scope) is what lets a blocked
        // reader see a closed channel when the tiler stops early.
        drop(ch);
        t.elapsed().as_secs_f64()
    }

    fn tile_all(
        &self,
        ch: &TilerChannels,
        failure: &Failure,
        (max_open, core_points): (&AtomicU64, &AtomicU64),
    ) -> Result<()> {
        let mut tiler = Tiler::new(
            self.grid,
            self.layout,
            self.files,
            self.spill_dir,
            self.spill_bytes,
            (self.near_m, self.kept_m),
        );
        if let Some(cells) = self.scope {
            tiler.restrict(cells);
        }
        for msg in ch.chunk_rx.iter() {
            match msg {
                ReadMsg::Chunk {
                    file,
                    first,
                    records,
                } => {
                    tiler.push_chunk(file, first, records.raw_bytes())?;
                    let _ = ch.free_tx.try_send(records);
                    max_open.fetch_max(tiler.open_tiles() as u64, Ordering::Relaxed);
                }
                ReadMsg::FileDone(f) => {
                    let ready = tiler.complete_after(f);
                    if !release(&mut tiler, ch, ready)? {
                        return Ok(());
                    }
                }
            }
        }
        if failure.failed() {
            return Ok(());
        }
        let open = tiler.still_open();
        release(&mut tiler, ch, open)?;
        core_points.store(tiler.core_points(), Ordering::Relaxed);
        Ok(())
    }
}

/// Releases the cells `ids` (sorted) one column at a time: announces the column's cells
/// (before their jobs leave), then sends its jobs. Only one column's jobs exist at once, so
/// a region whose cells all complete together (a one-file region) does not hold a job per
/// cell. False when the run is shutting down (a channel closed).
fn release(tiler: &mut Tiler, ch: &TilerChannels, ids: Vec<TileId>) -> Result<bool> {
    let mut rest = ids.into_iter().peekable();
    while let Some(first) = rest.next() {
        let mut column = vec![first];
        while let Some(id) = rest.next_if(|id| id.ix == first.ix) {
            column.push(id);
        }
        let jobs = tiler.release(column)?;
        let cells = tiler.take_releases();
        if let Some(tx) = &ch.release_tx {
            if !cells.is_empty() && tx.send(ToWriter::Released(cells)).is_err() {
                return Ok(false);
            }
        }
        if !jobs.into_iter().all(|job| ch.job_tx.send(job).is_ok()) {
            return Ok(false);
        }
    }
    Ok(true)
}
