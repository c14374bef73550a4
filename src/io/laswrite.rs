//! The one way tessera writes LAS/LAZ files: a writer that is finished explicitly, returns
//! every error, and never panics when it is dropped unfinished.
//!
//! Why a wrapper: `las::Writer` closes itself in `Drop` and panics if closing fails (a full
//! disk, or a header that cannot be encoded, e.g. return number 6 in a LAS 1.2 header), so an
//! error on any early-return path turned into an abort with exit 101 and left temporary files
//! behind. Here the file sits behind a shared handle: dropping an unfinished writer first
//! takes the file away (closing it; later writes by the `las` writer go nowhere), then lets
//! the `las` writer close into the void. If even that fails (only a header that cannot be
//! encoded), the `las` writer's in-memory state is leaked instead of dropped — at most one
//! LAZ chunk and a 1 MiB buffer per failed file, on a path that ends the run.

use crate::error::{Error, Result};
use las::{PointData, Writer, WriterOptions};
use std::fs::File;
use std::io::{BufWriter, Seek, SeekFrom, Write};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex};

/// A file that can be taken away from the writer that uses it: afterwards writes and seeks
/// succeed without touching the disk, moving a virtual position (the LAZ compressor does
/// arithmetic on positions, so they must stay consistent).
#[derive(Clone)]
struct SharedFile(Arc<Mutex<Sink>>);

struct Sink {
    file: Option<File>,
    /// Position and end of the discarded stream once `file` is gone.
    pos: u64,
    end: u64,
}

impl SharedFile {
    fn new(f: File) -> Self {
        SharedFile(Arc::new(Mutex::new(Sink {
            file: Some(f),
            pos: 0,
            end: 0,
        })))
    }
    fn lock(&self) -> std::sync::MutexGuard<'_, Sink> {
        self.0.lock().unwrap_or_else(|p| p.into_inner())
    }
    /// Takes the file away (closing it when dropped), keeping the current position.
    fn take(&self) -> Option<File> {
        let mut g = self.lock();
        let mut f = g.file.take()?;
        let pos = f.stream_position().unwrap_or(0);
        let end = f.metadata().map(|m| m.len()).unwrap_or(0).max(pos);
        g.pos = pos;
        g.end = end;
        Some(f)
    }
}

impl Write for SharedFile {
    fn write(&mut self, buf: &[u8]) -> std::io::Result<usize> {
        let mut g = self.lock();
        match g.file.as_mut() {
            Some(f) => f.write(buf),
            None => {
                g.pos += buf.len() as u64;
                g.end = g.end.max(g.pos);
                Ok(buf.len())
            }
        }
    }
    fn flush(&mut self) -> std::io::Result<()> {
        match self.lock().file.as_mut() {
            Some(f) => f.flush(),
            None => Ok(()),
        }
    }
}

impl Seek for SharedFile {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        let mut g = self.lock();
        if let Some(f) = g.file.as_mut() {
            return f.seek(to);
        }
        let base = |b: u64, d: i64| b.checked_add_signed(d).unwrap_or(0);
        g.pos = match to {
            SeekFrom::Start(n) => n,
            SeekFrom::Current(d) => base(g.pos, d),
            SeekFrom::End(d) => base(g.end, d),
        };
        Ok(g.pos)
    }
}

/// A LAS/LAZ file being written (see the module docs). Call [`LasFile::finish`]; dropping it
/// unfinished discards the file's contents (the caller removes the path).
pub struct LasFile {
    // Buffered above the shared handle, so the lock is taken once per 1 MiB, not per field.
    // `None` once finished or discarded.
    writer: Option<Writer<BufWriter<SharedFile>>>,
    file: SharedFile,
    path: PathBuf,
    /// Smallest and largest integer X, Y, Z written (the header bounds, exactly).
    extent: Option<([i32; 3], [i32; 3])>,
    transforms: las::Vector<las::Transform>,
    extended: bool,
}

/// Byte offsets in the LAS header (all versions) of the legacy point count, the legacy
/// points by return (5 × u32) and the bounds (max x, min x, max y, min y, max z, min z).
const LEGACY_COUNT_AT: u64 = 107;
const BOUNDS_AT: u64 = 179;

impl LasFile {
    /// Creates `path` (truncating it) and writes `header`.
    pub fn create(path: &Path, header: las::Header, options: WriterOptions) -> Result<LasFile> {
        let f = File::create(path).map_err(|e| Error::io(path, e))?;
        let file = SharedFile::new(f);
        let buf = BufWriter::with_capacity(1 << 20, file.clone());
        let transforms = *header.transforms();
        let extended = header.point_format().is_extended;
        let writer = Writer::with_options(buf, header, options).map_err(|e| Error::las(path, e))?;
        Ok(LasFile {
            writer: Some(writer),
            file,
            path: path.to_path_buf(),
            extent: None,
            transforms,
            extended,
        })
    }

    fn grow(&mut self, xyz: [i32; 3]) {
        let (lo, hi) = self.extent.get_or_insert((xyz, xyz));
        for k in 0..3 {
            lo[k] = lo[k].min(xyz[k]);
            hi[k] = hi[k].max(xyz[k]);
        }
    }

    /// Sets what `las` 0.11 writes wrong in the header, in place once the file is complete:
    /// - the bounds: `las` widens them outward to the scale grid after a floating-point round
    ///   trip, so a maximum sitting exactly on the grid often comes out one unit too large;
    ///   here they are the written extremes, computed as readers compute coordinates;
    /// - point formats 6–10 cannot keep legacy compatibility (LAS 1.4 R15): their legacy
    ///   point count and points by return must be 0; `las` fills them in.
    fn fix_header(&self, f: &File) -> std::io::Result<()> {
        use std::os::unix::fs::FileExt;
        if self.extended {
            f.write_all_at(&[0u8; 24], LEGACY_COUNT_AT)?;
        }
        if let Some((lo, hi)) = self.extent {
            let t = [self.transforms.x, self.transforms.y, self.transforms.z];
            let mut b = Vec::with_capacity(48);
            for k in 0..3 {
                for v in [hi[k], lo[k]] {
                    b.extend((f64::from(v) * t[k].scale + t[k].offset).to_le_bytes());
                }
            }
            f.write_all_at(&b, BOUNDS_AT)?;
        }
        Ok(())
    }

    fn writer(&mut self) -> Result<&mut Writer<BufWriter<SharedFile>>> {
        self.writer.as_mut().ok_or_else(|| {
            Error::Internal(format!("{}: writer already closed", self.path.display()))
        })
    }

    /// Writes pre-encoded records (the writer's point format).
    pub fn write_points(&mut self, data: &PointData) -> Result<()> {
        self.writer()?
            .write_points(data)
            .map_err(|e| Error::las(&self.path, e))?;
        let rl = data.record_len();
        for r in data.raw_bytes().chunks_exact(rl) {
            let at = |o: usize| i32::from_le_bytes([r[o], r[o + 1], r[o + 2], r[o + 3]]);
            self.grow([at(0), at(4), at(8)]);
        }
        Ok(())
    }

    /// Writes one point.
    pub fn write_point(&mut self, p: las::Point) -> Result<()> {
        let t = self.transforms;
        let xyz = (|| {
            Some([
                t.x.inverse(p.x).ok()?,
                t.y.inverse(p.y).ok()?,
                t.z.inverse(p.z).ok()?,
            ])
        })();
        self.writer()?
            .write_point(p)
            .map_err(|e| Error::las(&self.path, e))?;
        if let Some(xyz) = xyz {
            self.grow(xyz);
        }
        Ok(())
    }

    /// Closes the file: writes the final header, flushes, and reports every error.
    pub fn finish(mut self) -> Result<()> {
        let mut w = self.writer.take().ok_or_else(|| {
            Error::Internal(format!("{}: writer already closed", self.path.display()))
        })?;
        if let Err(e) = w.close() {
            discard(w, &self.file);
            return Err(Error::las(&self.path, e));
        }
        // Closed: `into_inner` only seeks back; dropping a closed writer does nothing.
        let mut inner = w.into_inner().map_err(|e| Error::las(&self.path, e))?;
        inner.flush().map_err(|e| Error::io(&self.path, e))?;
        drop(inner);
        // Closing the descriptor reports nothing more for a regular file; data is in the page
        // cache (tiles are not fsynced, see `TileWriter`).
        if let Some(f) = self.file.take() {
            self.fix_header(&f).map_err(|e| Error::io(&self.path, e))?;
        }
        Ok(())
    }
}

/// Gets rid of a writer that did not close: its file is taken away first, so its `Drop`
/// (which closes again and panics on failure) writes nowhere; if closing into the void still
/// fails, it is leaked rather than dropped.
fn discard(mut w: Writer<BufWriter<SharedFile>>, file: &SharedFile) {
    drop(file.take());
    // A writer whose `close` failed keeps `closed == false`, so its `Drop` would close again.
    match w.close() {
        Ok(()) => drop(w),
        Err(_) => std::mem::forget(w),
    }
}

impl Drop for LasFile {
    fn drop(&mut self) {
        if let Some(w) = self.writer.take() {
            discard(w, &self.file);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn header(version: (u8, u8), format: u8) -> las::Header {
        let mut b = las::Builder::from(version);
        b.point_format = las::point::Format::new(format).unwrap();
        b.into_header().unwrap()
    }

    #[test]
    fn header_that_cannot_be_encoded_is_an_error_not_a_panic() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("a.las");
        let mut w = LasFile::create(&path, header((1, 2), 1), WriterOptions::default()).unwrap();
        let p = las::Point {
            return_number: 6,
            number_of_returns: 7,
            gps_time: Some(0.0),
            ..Default::default()
        };
        w.write_point(p).unwrap();
        let e = w.finish().unwrap_err().to_string();
        assert!(e.contains("a.las"), "{e}");
    }

    #[test]
    fn dropping_unfinished_writers_does_not_panic() {
        let dir = tempfile::tempdir().unwrap();
        for (i, v) in [(1, 2), (1, 4)].into_iter().enumerate() {
            let path = dir.path().join(format!("{i}.laz"));
            let mut o = WriterOptions::default();
            o = o.with_laz_parallelism(las::LazParallelism::No);
            let mut h = header(v, 1);
            let mut b = las::Builder::from(h.clone());
            b.point_format.is_compressed = true;
            h = b.into_header().unwrap();
            let mut w = LasFile::create(&path, h, o).unwrap();
            let p = las::Point {
                return_number: 6,
                number_of_returns: 7,
                gps_time: Some(0.0),
                ..Default::default()
            };
            w.write_point(p).unwrap();
            drop(w);
        }
    }

    #[test]
    fn finished_file_reads_back() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("ok.las");
        let mut w = LasFile::create(&path, header((1, 4), 6), WriterOptions::default()).unwrap();
        for i in 0..10 {
            w.write_point(las::Point {
                x: i as f64,
                return_number: 1,
                number_of_returns: 1,
                gps_time: Some(1.0),
                ..Default::default()
            })
            .unwrap();
        }
        w.finish().unwrap();
        let r = las::Reader::from_path(&path).unwrap();
        assert_eq!(r.header().number_of_points(), 10);
    }
}
