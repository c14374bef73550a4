//! Output: LAS 1.4 tiles written atomically (temporary file in the same directory, then
//! rename), so a crash or error never leaves a half-written tile where a user looks.

use crate::error::{Error, Result};
use crate::model::RecordLayout;
use las::{Builder, PointDataBuilder, Version, Writer};
use std::fs::File;
use std::io::{BufWriter, Write};
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = tmp_path(path);
    let res = (|| {
        let mut f = File::create(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    std::fs::rename(&tmp, path).map_err(|e| Error::io(path, e))
}

/// The temporary sibling used while `path` is written.
pub fn tmp_path(path: &Path) -> PathBuf {
    let mut name = path.file_name().unwrap_or_default().to_os_string();
    name.push(".tmp");
    path.with_file_name(name)
}

/// Writes tiles of one run: every tile shares the template header (CRS and other VLRs,
/// GPS time type), the run's point format and transforms.
#[derive(Debug, Clone)]
pub struct TileWriter {
    header: las::Header,
    layout: RecordLayout,
    extension: &'static str,
}

impl TileWriter {
    /// Prepares a writer from the first input's header and the run layout.
    pub fn new(template: &las::Header, layout: &RecordLayout, laz: bool) -> Result<Self> {
        let mut b = Builder::from(template.clone());
        b.version = Version::new(1, 4);
        b.point_format = layout.format;
        b.point_format.is_compressed = laz;
        b.transforms = layout.transforms;
        b.vlrs.retain(|v| !las::laz::is_laszip_vlr(v));
        b.padding.clear();
        b.vlr_padding.clear();
        b.point_padding.clear();
        b.generating_software = format!("tessera {}", env!("CARGO_PKG_VERSION"));
        let mut header = b
            .into_header()
            .map_err(|e| Error::Config(format!("cannot build the output header: {e}")))?;
        header.clear();
        Ok(TileWriter {
            header,
            layout: layout.clone(),
            extension: if laz { "laz" } else { "las" },
        })
    }

    /// Writes `records` (raw, in the run layout) to a temporary sibling of `dir/name.<ext>`;
    /// [`PendingTile::commit`] then renames it into place. Splitting the two lets workers
    /// compress tiles in parallel while one thread decides what becomes visible.
    pub fn prepare(&self, dir: &Path, name: &str, records: Vec<u8>) -> Result<PendingTile> {
        let path = dir.join(format!("{name}.{}", self.extension));
        let tmp = tmp_path(&path);
        if let Err(e) = self.write_to(&tmp, records) {
            let _ = std::fs::remove_file(&tmp);
            return Err(e);
        }
        Ok(PendingTile { tmp, path })
    }

    // No fsync: rename after a complete write already guarantees readers never see a partial
    // tile if the process dies; syncing every tile would cost more than the compression.
    fn write_to(&self, tmp: &Path, records: Vec<u8>) -> Result<()> {
        let file = File::create(tmp).map_err(|e| Error::io(tmp, e))?;
        // One tile per worker thread: sequential compression keeps each worker on one core.
        let opts = las::WriterOptions::default().with_laz_parallelism(las::LazParallelism::No);
        let mut writer = Writer::with_options(
            BufWriter::with_capacity(1 << 20, file),
            self.header.clone(),
            opts,
        )
        .map_err(|e| Error::las(tmp, e))?;
        let data = PointDataBuilder::new()
            .with_format(self.layout.format)
            .with_transforms(self.layout.transforms)
            .build_from_bytes(records)
            .map_err(|e| Error::las(tmp, e))?;
        writer.write_points(&data).map_err(|e| Error::las(tmp, e))?;
        writer.close().map_err(|e| Error::las(tmp, e))?;
        let mut inner = writer.into_inner().map_err(|e| Error::las(tmp, e))?;
        inner.flush().map_err(|e| Error::io(tmp, e))
    }
}

/// A completely written tile under its temporary name.
#[derive(Debug)]
pub struct PendingTile {
    tmp: PathBuf,
    path: PathBuf,
}

impl PendingTile {
    /// Renames the tile into place.
    pub fn commit(self) -> Result<PathBuf> {
        std::fs::rename(&self.tmp, &self.path).map_err(|e| Error::io(&self.path, e))?;
        Ok(self.path)
    }
    /// Deletes the temporary file (the run failed).
    pub fn abandon(self) {
        let _ = std::fs::remove_file(&self.tmp);
    }
}
