//! Output: LAS 1.4 tiles written atomically (temporary file in the same directory, then
//! rename), so a crash or error never leaves a half-written tile where a user looks.

use crate::error::{Error, Result};
use crate::io::extra;
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

/// Where output records carry the per-point segment id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentField {
    /// No segmentation ran: records are written as they are.
    None,
    /// Appended as a new `segment_id` u32 extra-bytes attribute (4 bytes after the record).
    Append,
    /// The input already has a `segment_id` u32 attribute at this record offset: overwritten.
    InPlace(usize),
}

/// Name of the per-point segment id attribute.
pub const SEGMENT_ID: &str = "segment_id";

/// Per-tile segmentation results handed to [`TileWriter::prepare`].
#[derive(Debug, Clone, Copy)]
pub struct TileSegments<'a> {
    /// Segment id per core point.
    pub ids: &'a [u32],
    /// The tile's segment table (tab-separated text).
    pub table: &'a str,
}

/// Writes tiles of one run: every tile shares the template header (CRS and other VLRs,
/// GPS time type), the run's point format and transforms.
#[derive(Debug, Clone)]
pub struct TileWriter {
    header: las::Header,
    /// Layout of the records handed in (the run layout).
    layout: RecordLayout,
    /// Layout of the records written (the run layout plus an appended `segment_id`).
    out_layout: RecordLayout,
    segment_field: SegmentField,
    extension: &'static str,
}

impl TileWriter {
    /// Prepares a writer from the first input's header and the run layout. With
    /// `segments`, output records carry a `segment_id` u32 extra-bytes attribute (reusing the
    /// input's own `segment_id` attribute when it has one, so re-runs do not stack copies).
    pub fn new(
        template: &las::Header,
        layout: &RecordLayout,
        laz: bool,
        segments: bool,
    ) -> Result<Self> {
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
        let mut out_layout = layout.clone();
        let mut segment_field = SegmentField::None;
        if segments {
            let is_eb =
                |v: &las::Vlr| v.user_id == extra::USER_ID && v.record_id == extra::RECORD_ID;
            let eb_start = layout.record_len - usize::from(layout.format.extra_bytes);
            let existing = b.vlrs.iter().find(|v| is_eb(v)).and_then(|v| {
                extra::fields(&v.data)
                    .into_iter()
                    .find(|f| f.name == SEGMENT_ID)
            });
            match existing {
                Some(f) if f.data_type == extra::TYPE_U32 => {
                    segment_field = SegmentField::InPlace(eb_start + f.offset);
                }
                Some(f) => {
                    return Err(Error::Config(format!(
                        "the input already has a \"{SEGMENT_ID}\" attribute of extra-bytes type {} (not u32); rename it before segmenting",
                        f.data_type
                    )))
                }
                None => {
                    let d = extra::descriptor(extra::TYPE_U32, SEGMENT_ID, "tessera segment id, 0 = none");
                    match b.vlrs.iter_mut().find(|v| is_eb(v)) {
                        Some(v) => v.data.extend(d),
                        None => b.vlrs.push(las::Vlr {
                            user_id: extra::USER_ID.into(),
                            record_id: extra::RECORD_ID,
                            description: "Extra bytes".into(),
                            data: d,
                        }),
                    }
                    let mut f = layout.format;
                    f.extra_bytes += 4;
                    b.point_format.extra_bytes = f.extra_bytes;
                    out_layout = RecordLayout::new(f, layout.transforms);
                    segment_field = SegmentField::Append;
                }
            }
        }
        let mut header = b
            .into_header()
            .map_err(|e| Error::Config(format!("cannot build the output header: {e}")))?;
        header.clear();
        Ok(TileWriter {
            header,
            layout: layout.clone(),
            out_layout,
            segment_field,
            extension: if laz { "laz" } else { "las" },
        })
    }

    /// Whether output records carry a segment id (a segmentation stage runs).
    pub fn writes_segments(&self) -> bool {
        self.segment_field != SegmentField::None
    }

    /// Writes `records` (raw, in the run layout, core points only) to a temporary sibling of
    /// `dir/name.<ext>` (and the segment table to `dir/name.segments.tsv`);
    /// [`PendingTile::commit`] then renames them into place. Splitting the two lets workers
    /// compress tiles in parallel while one thread decides what becomes visible.
    pub fn prepare(
        &self,
        dir: &Path,
        name: &str,
        mut records: Vec<u8>,
        segments: Option<TileSegments<'_>>,
    ) -> Result<PendingTile> {
        let path = dir.join(format!("{name}.{}", self.extension));
        let mut pending = PendingTile { files: Vec::new() };
        let n = records.len() / self.layout.record_len;
        let ids = |i: usize| segments.and_then(|s| s.ids.get(i).copied()).unwrap_or(0);
        match self.segment_field {
            SegmentField::None => {}
            SegmentField::InPlace(o) => {
                for (i, rec) in records.chunks_exact_mut(self.layout.record_len).enumerate() {
                    rec[o..o + 4].copy_from_slice(&ids(i).to_le_bytes());
                }
            }
            SegmentField::Append => {
                let mut out = Vec::with_capacity(n * self.out_layout.record_len);
                for (i, rec) in records.chunks_exact(self.layout.record_len).enumerate() {
                    out.extend_from_slice(rec);
                    out.extend_from_slice(&ids(i).to_le_bytes());
                }
                records = out;
            }
        }
        let tmp = tmp_path(&path);
        pending.files.push((tmp.clone(), path));
        if let Err(e) = self.write_to(&tmp, records) {
            pending.abandon();
            return Err(e);
        }
        if let Some(s) = segments {
            let path = dir.join(format!("{name}.segments.tsv"));
            let tmp = tmp_path(&path);
            pending.files.push((tmp.clone(), path));
            if let Err(e) = std::fs::write(&tmp, s.table) {
                pending.abandon();
                return Err(Error::io(&tmp, e));
            }
        }
        Ok(pending)
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
            .with_format(self.out_layout.format)
            .with_transforms(self.out_layout.transforms)
            .build_from_bytes(records)
            .map_err(|e| Error::las(tmp, e))?;
        writer.write_points(&data).map_err(|e| Error::las(tmp, e))?;
        writer.close().map_err(|e| Error::las(tmp, e))?;
        let mut inner = writer.into_inner().map_err(|e| Error::las(tmp, e))?;
        inner.flush().map_err(|e| Error::io(tmp, e))
    }
}

/// A completely written tile (its LAS/LAZ file and, with segmentation, its segment table)
/// under temporary names.
#[derive(Debug)]
pub struct PendingTile {
    /// (temporary, final) paths.
    files: Vec<(PathBuf, PathBuf)>,
}

impl PendingTile {
    /// Renames the tile's files into place (the point file last: a visible tile always has
    /// its table) and returns the point file's path.
    pub fn commit(self) -> Result<PathBuf> {
        let mut point_file = PathBuf::new();
        for (i, (tmp, path)) in self.files.iter().enumerate().rev() {
            std::fs::rename(tmp, path).map_err(|e| Error::io(path, e))?;
            if i == 0 {
                point_file = path.clone();
            }
        }
        Ok(point_file)
    }
    /// Deletes the temporary files (the run failed).
    pub fn abandon(self) {
        for (tmp, _) in &self.files {
            let _ = std::fs::remove_file(tmp);
        }
    }
}

/// The segment table of a tile as tab-separated text: one row per segment with core points.
pub fn segment_table_tsv(rows: &[crate::model::SegmentRow]) -> String {
    use std::fmt::Write as _;
    let mut s = String::from(
        "segment_id\tpoints\tcore_points\tnormal_x\tnormal_y\tnormal_z\td\tmean_r\tmean_g\tmean_b\trms_m\n",
    );
    for r in rows {
        let i = &r.info;
        let _ = writeln!(
            s,
            "{}\t{}\t{}\t{:.6}\t{:.6}\t{:.6}\t{:.4}\t{:.1}\t{:.1}\t{:.1}\t{:.4}",
            i.id,
            i.n,
            r.core_points,
            i.normal[0],
            i.normal[1],
            i.normal[2],
            i.d,
            i.mean_rgb[0],
            i.mean_rgb[1],
            i.mean_rgb[2],
            i.rms
        );
    }
    s
}
