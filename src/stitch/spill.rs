//! The stitcher's spill file: border summaries of open tiles beyond the frontier's memory
//! share wait on disk instead of in memory.
//!
//! Why: the frontier is the summaries of tiles whose neighbours have not all arrived. With
//! one worker it spans a grid column and more (every cell waits for the next column), and
//! dense mobile-mapping streets split into small leaves whose summaries hold most of their
//! points: 63 MB of frontier on a 300 m street at a 160 MiB budget, where the plan reserves
//! 16 MB. A waiting summary is read back only when a neighbouring tile arrives (a few times
//! in its life), so keeping it in a file costs a sequential write and a few reads from the
//! page cache, and the memory stays at the reserve whatever the street.
//!
//! The file lives in the run's private staging directory and is removed with the stitcher.
//! Extents of closed tiles are given back to the file system (hole punching on Linux; the
//! file is truncated whenever nothing is left in it), so the disk use follows the frontier
//! too.

use super::summary::BorderSummary;
use super::StitchError;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// Where a spilled summary lies in the spill file.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Extent {
    /// Byte offset.
    pub at: u64,
    /// Length in bytes.
    pub len: u64,
}

/// An append-only file of border summaries.
#[derive(Debug)]
pub struct SpillFile {
    path: PathBuf,
    file: Option<File>,
    end: u64,
    live: u64,
    live_bytes: u64,
    /// Summaries written.
    pub writes: u64,
    /// Bytes written.
    pub bytes_written: u64,
    /// Summaries read back.
    pub reads: u64,
    /// Bytes read back.
    pub bytes_read: u64,
    /// Most bytes of live summaries in the file at once.
    pub live_bytes_max: u64,
}

impl SpillFile {
    /// A spill file at `dir/frontier.spill`, created when the first summary is written.
    pub fn new(dir: &Path) -> Self {
        SpillFile {
            path: dir.join("frontier.spill"),
            file: None,
            end: 0,
            live: 0,
            live_bytes: 0,
            writes: 0,
            bytes_written: 0,
            reads: 0,
            bytes_read: 0,
            live_bytes_max: 0,
        }
    }

    fn err(&self, what: &str, e: std::io::Error) -> StitchError {
        StitchError::Spill(format!("{what} {}: {e}", self.path.display()))
    }

    /// Appends `s`; returns where it went.
    pub fn write(&mut self, s: &BorderSummary) -> Result<Extent, StitchError> {
        if self.file.is_none() {
            let f = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create_new(true)
                .open(&self.path)
                .map_err(|e| self.err("cannot create", e))?;
            self.file = Some(f);
        }
        let bytes = s.to_bytes();
        let at = self.end;
        if let Some(f) = &self.file {
            f.write_all_at(&bytes, at)
                .map_err(|e| self.err("cannot write", e))?;
        }
        let len = bytes.len() as u64;
        self.end += len;
        self.live += 1;
        self.live_bytes += len;
        self.live_bytes_max = self.live_bytes_max.max(self.live_bytes);
        self.writes += 1;
        self.bytes_written += len;
        Ok(Extent { at, len })
    }

    /// Reads back the summary at `x` (it stays in the file); `name` is the tile, for errors.
    pub fn read(&mut self, x: Extent, name: &str) -> Result<BorderSummary, StitchError> {
        let Some(f) = &self.file else {
            return Err(StitchError::Spill(format!(
                "tile {name}: its summary is not in the spill file"
            )));
        };
        let mut buf = vec![0u8; x.len as usize];
        f.read_exact_at(&mut buf, x.at)
            .map_err(|e| self.err("cannot read", e))?;
        self.reads += 1;
        self.bytes_read += x.len;
        BorderSummary::from_bytes(&buf, name)
    }

    /// The summary at `x` is no longer needed: its blocks go back to the file system.
    pub fn release(&mut self, x: Extent) {
        self.live = self.live.saturating_sub(1);
        self.live_bytes = self.live_bytes.saturating_sub(x.len);
        let Some(f) = &self.file else { return };
        if self.live == 0 {
            // Nothing left: start the file over (portable, and undoes any fragmentation).
            if f.set_len(0).is_ok() {
                self.end = 0;
            }
            return;
        }
        crate::sys::punch_hole(f, x.at, x.len);
    }
}

impl Drop for SpillFile {
    fn drop(&mut self) {
        if self.file.take().is_some() {
            let _ = std::fs::remove_file(&self.path);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::{Rect, TileId};
    use crate::stitch::BorderRecord;

    fn summary(n: usize, ix: i64) -> BorderSummary {
        BorderSummary {
            tile: TileId::grid(ix, 0),
            name: format!("t{ix}"),
            core: Rect {
                x0: 0.0,
                y0: 0.0,
                x1: 10.0,
                y1: 10.0,
            },
            anchors: vec![7, u64::MAX],
            inner: (0..n)
                .map(|i| BorderRecord {
                    pid: i as u64,
                    label: 1,
                    dx: i as f32 * 0.01,
                    dy: 0.5,
                })
                .collect(),
            outer: vec![BorderRecord {
                pid: 99,
                label: 2,
                dx: -1.0,
                dy: 3.0,
            }],
        }
    }

    #[test]
    fn summaries_round_trip_and_the_file_goes_away() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("frontier.spill");
        let mut sp = SpillFile::new(dir.path());
        let (a, b) = (summary(1000, 1), summary(10, 2));
        let xa = sp.write(&a).unwrap();
        let xb = sp.write(&b).unwrap();
        assert_eq!(sp.read(xb, "t2").unwrap(), b);
        assert_eq!(sp.read(xa, "t1").unwrap(), a);
        sp.release(xa);
        // Still readable after its neighbour's blocks were punched out.
        assert_eq!(sp.read(xb, "t2").unwrap(), b);
        sp.release(xb);
        assert_eq!(std::fs::metadata(&path).unwrap().len(), 0);
        let xc = sp.write(&a).unwrap();
        assert_eq!(xc.at, 0);
        assert_eq!(sp.live_bytes_max, xa.len + xb.len);
        drop(sp);
        assert!(!path.exists());
    }

    #[test]
    fn a_damaged_spill_file_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut sp = SpillFile::new(dir.path());
        let x = sp.write(&summary(50, 1)).unwrap();
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(dir.path().join("frontier.spill"))
            .unwrap();
        f.set_len(x.len / 2).unwrap();
        assert!(matches!(sp.read(x, "t1"), Err(StitchError::Spill(_))));
    }
}
