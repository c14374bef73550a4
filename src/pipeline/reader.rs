//! The reader: decodes the inputs chunk by chunk, in the tiler's file order, and sends the
//! raw records downstream (bounded channel; spent chunk buffers come back for reuse).

use super::failure::Failure;
use crate::error::{Error, Result};
use crate::io::input::read_file_chunks;
use crate::io::InputFile;
use crate::model::RecordLayout;
use crossbeam_channel::{Receiver, Sender};
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::Instant;

/// Progress callback: called with (points read so far, total points).
pub type ProgressFn<'a> = &'a (dyn Fn(u64, u64) + Sync);

/// Reader → tiler messages.
pub(super) enum ReadMsg {
    /// Records `first..first + records.len()` of input `file`.
    Chunk {
        file: usize,
        first: u64,
        records: las::PointData,
    },
    /// Every record of input `file` was sent.
    FileDone(usize),
}

/// What the reader needs: the inputs, the order to read them in and the chunk size.
pub(super) struct Reader<'a> {
    pub files: &'a [InputFile],
    pub order: &'a [usize],
    pub layout: &'a RecordLayout,
    pub chunk_points: usize,
    pub total_points: u64,
    pub progress: ProgressFn<'a>,
}

impl Reader<'_> {
    /// Reads everything into `chunk_tx`, counting points in `read_points`; returns the seconds
    /// spent. Errors go to `failure`.
    pub fn run(
        &self,
        chunk_tx: Sender<ReadMsg>,
        free_rx: Receiver<las::PointData>,
        failure: &Failure,
        read_points: &AtomicU64,
    ) -> f64 {
        let t = Instant::now();
        if let Err(e) = self.read_all(&chunk_tx, &free_rx, failure, read_points) {
            if !failure.failed() {
                failure.set(e);
            }
        }
        drop(chunk_tx);
        t.elapsed().as_secs_f64()
    }

    fn read_all(
        &self,
        chunk_tx: &Sender<ReadMsg>,
        free_rx: &Receiver<las::PointData>,
        failure: &Failure,
        read_points: &AtomicU64,
    ) -> Result<()> {
        for &fi in self.order {
            let f = &self.files[fi];
            let spare = || free_rx.try_recv().ok();
            read_file_chunks(
                f,
                self.layout,
                self.chunk_points,
                spare,
                |first, records| {
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
                    (self.progress)(done, self.total_points);
                    Ok(())
                },
            )?;
            chunk_tx
                .send(ReadMsg::FileDone(fi))
                .map_err(|_| Error::Cancelled)?;
        }
        Ok(())
    }
}
