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
//! The files live in the run's private staging directory and are removed with the
//! stitcher. Extents of closed tiles are given back to the file system (hole punching on
//! Linux); a part file is written up to 256 MiB, then the next one is started, and a part is
//! removed once nothing in it is needed (the one being written is truncated instead), so the
//! disk use follows the frontier and no file grows with the run.

use super::summary::BorderSummary;
use super::StitchError;
use std::fs::File;
use std::os::unix::fs::FileExt;
use std::path::{Path, PathBuf};

/// A part file is closed for writing once it reaches this many bytes; it is removed when its
/// last summary is released. (Bounds the files' logical size on a run of any length: hole
/// punching frees blocks but never shrinks a file.)
const ROTATE_BYTES: u64 = 256 << 20;

/// Where a spilled summary lies.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Extent {
    /// Part file number.
    pub part: u32,
    /// Byte offset in it.
    pub at: u64,
    /// Length in bytes.
    pub len: u64,
}

/// One part file.
#[derive(Debug)]
struct Part {
    id: u32,
    path: PathBuf,
    file: File,
    end: u64,
    live: u64,
}

/// Append-only part files of border summaries (`frontier-N.spill`), written one after the
/// other.
#[derive(Debug)]
pub struct SpillFile {
    dir: PathBuf,
    rotate_bytes: u64,
    /// Parts with live summaries, and the one being written (last).
    parts: Vec<Part>,
    next_id: u32,
    live_bytes: u64,
    /// Summaries written.
    pub writes: u64,
    /// Bytes written.
    pub bytes_written: u64,
    /// Summaries read back.
    pub reads: u64,
    /// Bytes read back.
    pub bytes_read: u64,
    /// Most bytes of live summaries in the files at once.
    pub live_bytes_max: u64,
}

impl SpillFile {
    /// Spill files in `dir`, created when the first summary is written.
    pub fn new(dir: &Path) -> Self {
        Self::rotating_at(dir, ROTATE_BYTES)
    }

    fn rotating_at(dir: &Path, rotate_bytes: u64) -> Self {
        SpillFile {
            dir: dir.to_path_buf(),
            rotate_bytes,
            parts: Vec::new(),
            next_id: 0,
            live_bytes: 0,
            writes: 0,
            bytes_written: 0,
            reads: 0,
            bytes_read: 0,
            live_bytes_max: 0,
        }
    }

    fn err(path: &Path, what: &str, e: std::io::Error) -> StitchError {
        StitchError::Spill(format!("{what} {}: {e}", path.display()))
    }

    /// Appends `s`; returns where it went.
    pub fn write(&mut self, s: &BorderSummary) -> Result<Extent, StitchError> {
        if self.parts.last().is_none_or(|p| p.end >= self.rotate_bytes) {
            let path = self.dir.join(format!("frontier-{}.spill", self.next_id));
            let file = std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .create_new(true)
                .open(&path)
                .map_err(|e| Self::err(&path, "cannot create", e))?;
            self.parts.push(Part {
                id: self.next_id,
                path,
                file,
                end: 0,
                live: 0,
            });
            self.next_id += 1;
        }
        let bytes = s.to_bytes();
        let len = bytes.len() as u64;
        let Some(p) = self.parts.last_mut() else {
            return Err(StitchError::Spill("no spill file".into()));
        };
        p.file
            .write_all_at(&bytes, p.end)
            .map_err(|e| Self::err(&p.path, "cannot write", e))?;
        let x = Extent {
            part: p.id,
            at: p.end,
            len,
        };
        p.end += len;
        p.live += 1;
        self.live_bytes += len;
        self.live_bytes_max = self.live_bytes_max.max(self.live_bytes);
        self.writes += 1;
        self.bytes_written += len;
        Ok(x)
    }

    /// Reads back the summary at `x` (it stays in the file); `name` is the tile, for errors.
    pub fn read(&mut self, x: Extent, name: &str) -> Result<BorderSummary, StitchError> {
        let Some(p) = self.parts.iter().find(|p| p.id == x.part) else {
            return Err(StitchError::Spill(format!(
                "tile {name}: spill part {} is gone",
                x.part
            )));
        };
        let mut buf = vec![0u8; x.len as usize];
        p.file
            .read_exact_at(&mut buf, x.at)
            .map_err(|e| Self::err(&p.path, "cannot read", e))?;
        self.reads += 1;
        self.bytes_read += x.len;
        BorderSummary::from_bytes(&buf, name)
    }

    /// The summary at `x` is no longer needed: its blocks go back to the file system, and a
    /// part with nothing left is removed (or, the one being written, started over).
    pub fn release(&mut self, x: Extent) {
        self.live_bytes = self.live_bytes.saturating_sub(x.len);
        let last = self.parts.len().saturating_sub(1);
        let Some(i) = self.parts.iter().position(|p| p.id == x.part) else {
            return;
        };
        let p = &mut self.parts[i];
        p.live = p.live.saturating_sub(1);
        if p.live > 0 {
            crate::sys::punch_hole(&p.file, x.at, x.len);
        } else if i == last {
            if p.file.set_len(0).is_ok() {
                p.end = 0;
            }
        } else {
            let p = self.parts.remove(i);
            let _ = std::fs::remove_file(&p.path);
        }
    }
}

impl Drop for SpillFile {
    fn drop(&mut self) {
        for p in self.parts.drain(..) {
            let _ = std::fs::remove_file(&p.path);
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
        let path = dir.path().join("frontier-0.spill");
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
    fn full_parts_rotate_and_go_when_emptied() {
        let dir = tempfile::tempdir().unwrap();
        let files = || {
            let mut v: Vec<String> = std::fs::read_dir(dir.path())
                .unwrap()
                .map(|e| e.unwrap().file_name().to_string_lossy().to_string())
                .collect();
            v.sort();
            v
        };
        let a = summary(100, 1);
        let one = a.to_bytes().len() as u64;
        // Two summaries per part.
        let mut sp = SpillFile::rotating_at(dir.path(), 2 * one);
        let x: Vec<Extent> = (0..5).map(|_| sp.write(&a).unwrap()).collect();
        assert_eq!(
            x.iter().map(|e| e.part).collect::<Vec<_>>(),
            [0, 0, 1, 1, 2]
        );
        assert_eq!(
            files(),
            ["frontier-0.spill", "frontier-1.spill", "frontier-2.spill"]
        );
        sp.release(x[0]);
        assert_eq!(sp.read(x[1], "t1").unwrap(), a);
        sp.release(x[1]);
        assert_eq!(files(), ["frontier-1.spill", "frontier-2.spill"]);
        sp.release(x[3]);
        sp.release(x[2]);
        assert_eq!(files(), ["frontier-2.spill"]);
        assert_eq!(sp.read(x[4], "t1").unwrap(), a);
        assert!(matches!(sp.read(x[0], "t1"), Err(StitchError::Spill(_))));
        drop(sp);
        assert!(files().is_empty());
    }

    #[test]
    fn a_damaged_spill_file_is_an_error() {
        let dir = tempfile::tempdir().unwrap();
        let mut sp = SpillFile::new(dir.path());
        let x = sp.write(&summary(50, 1)).unwrap();
        let f = std::fs::OpenOptions::new()
            .write(true)
            .open(dir.path().join("frontier-0.spill"))
            .unwrap();
        f.set_len(x.len / 2).unwrap();
        assert!(matches!(sp.read(x, "t1"), Err(StitchError::Spill(_))));
    }
}
