//! Output: LAS 1.4 tiles written atomically (temporary file in the same directory, then
//! rename), so a crash or error never leaves a half-written tile where a user looks.

use crate::error::{Error, Result};
use crate::io::extra;
use crate::io::laswrite::LasFile;
use crate::io::workspace::OutputDir;
use crate::model::RecordLayout;
use las::{Builder, PointDataBuilder, Version};
use std::fs::File;
use std::io::Write;
use std::path::{Path, PathBuf};

/// Writes `bytes` to `path` atomically.
pub fn write_atomic(path: &Path, bytes: &[u8]) -> Result<()> {
    let tmp = tmp_path(path);
    let res = (|| {
        let mut f = std::fs::OpenOptions::new()
            .write(true)
            .create_new(true)
            .open(&tmp)?;
        f.write_all(bytes)?;
        f.sync_all()
    })();
    if let Err(e) = res {
        let _ = std::fs::remove_file(&tmp);
        return Err(Error::io(path, e));
    }
    commit_tmp(&tmp, path)
}

/// The temporary sibling used while `path` is written: hidden, and unique to this process and
/// call, so it never names (and never empties) a file of the user's.
pub fn tmp_path(path: &Path) -> PathBuf {
    static NEXT: std::sync::atomic::AtomicU64 = std::sync::atomic::AtomicU64::new(0);
    let n = NEXT.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
    let mut name = std::ffi::OsString::from(".");
    name.push(path.file_name().unwrap_or_default());
    name.push(format!(".{}-{n}.tmp", std::process::id()));
    path.with_file_name(name)
}

/// Moves a finished temporary file onto `path`; the temporary file is removed when that
/// fails.
pub fn commit_tmp(tmp: &Path, path: &Path) -> Result<()> {
    std::fs::rename(tmp, path).map_err(|e| {
        let _ = std::fs::remove_file(tmp);
        Error::io(path, e)
    })
}

/// Where output records carry the per-point segment id.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentField {
    /// No segmentation ran: records are written as they are.
    None,
    /// Appended as a new `segment_id` extra-bytes attribute (after the record).
    Append,
    /// The input already has a `segment_id` attribute of the right type at this record
    /// offset: overwritten.
    InPlace(usize),
}

/// Integer type of the `segment_id` attribute.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum SegmentIdType {
    /// Unsigned 32-bit (tile-local ids, and stitched ids of runs under 2^32 − 1 points).
    U32,
    /// Unsigned 64-bit (stitched ids of larger runs: ids are point ordinals + 1).
    U64,
}

impl SegmentIdType {
    /// Extra-bytes data type code (LAS 1.4 R15 table 24).
    pub fn code(self) -> u8 {
        match self {
            SegmentIdType::U32 => extra::TYPE_U32,
            SegmentIdType::U64 => extra::TYPE_U64,
        }
    }
    /// Bytes per value.
    pub fn bytes(self) -> usize {
        match self {
            SegmentIdType::U32 => 4,
            SegmentIdType::U64 => 8,
        }
    }
    /// Largest id the type holds.
    pub fn max(self) -> u64 {
        match self {
            SegmentIdType::U32 => u32::MAX as u64,
            SegmentIdType::U64 => u64::MAX,
        }
    }
}

/// Name of the per-point segment id attribute.
pub const SEGMENT_ID: &str = "segment_id";

/// Puts the template's CRS into `header` as an OGC WKT record (formats 6–10), and only
/// that. A template without a CRS gives none; GeoTIFF keys whose CRS has no EPSG code are kept
/// as they are, with a warning (no WKT can be made for them).
pub fn set_wkt(header: &mut las::Header, template: &las::Header) -> Result<()> {
    let has_geotiff = template.all_vlrs().any(|v| v.is_geotiff_crs());
    let wkt = match template.get_wkt_crs_bytes() {
        // The input's own WKT, without the GeoTIFF keys some writers add next to it.
        Some(w) if has_geotiff => Some(String::from_utf8_lossy(w).into_owned()),
        Some(_) => return Ok(()),
        None if has_geotiff => crate::io::crs::CrsInfo::of_header(template).output_wkt(),
        None => return Ok(()),
    };
    match wkt {
        // Replaces the GeoTIFF keys copied from the template (the `las` crate would remove
        // them too, but says so on the user's terminal for every tile).
        Some(wkt) => {
            header.remove_crs_vlrs();
            header
                .set_wkt_crs(wkt.into_bytes())
                .map_err(|e| Error::Config(format!("cannot write the OGC WKT record: {e}")))
        }
        None => {
            let format = header.point_format().to_u8().unwrap_or(255);
            crate::io::warn::warn_once("geotiff-without-wkt", || {
                format!("the inputs' GeoTIFF CRS has no EPSG code tessera can convert to WKT: outputs in point format {format} keep the GeoTIFF keys")
            });
            Ok(())
        }
    }
}

/// Name of the per-point truth class attribute (synthetic scenes, reference data).
pub const TRUTH_FIELD: &str = "gt_class";

/// Where a record's coordinates, class, segment id and truth class are (what the run
/// report draws), read from a LAS header.
#[derive(Debug, Clone, Copy)]
pub struct RecordFields {
    /// Bytes per record.
    pub record_len: usize,
    /// Scale/offset of x, y, z.
    pub transforms: las::Vector<las::Transform>,
    /// Byte of the classification.
    pub class_at: usize,
    /// Its bits (5 in formats 0–5).
    pub class_mask: u8,
    /// Offset and width (4 or 8) of the `segment_id` attribute.
    pub segment: Option<(usize, usize)>,
    /// Offset of the `gt_class` attribute (one byte).
    pub truth: Option<usize>,
}

impl RecordFields {
    /// The fields of `h`'s records.
    pub fn of_header(h: &las::Header) -> RecordFields {
        let fmt = h.point_format();
        let record_len = usize::from(fmt.len());
        let eb_start = record_len - usize::from(fmt.extra_bytes);
        let fields = h
            .all_vlrs()
            .find(|v| v.user_id == extra::USER_ID && v.record_id == extra::RECORD_ID)
            .map(|v| extra::fields(&v.data))
            .unwrap_or_default();
        let find = |name: &str| {
            fields.iter().find_map(|f| {
                (f.name == name && eb_start + f.offset + f.size <= record_len)
                    .then_some((eb_start + f.offset, f.size))
            })
        };
        RecordFields {
            record_len,
            transforms: *h.transforms(),
            class_at: if fmt.is_extended { 16 } else { 15 },
            class_mask: if fmt.is_extended { 0xFF } else { 0x1F },
            segment: find(SEGMENT_ID).filter(|s| matches!(s.1, 4 | 8)),
            truth: find(TRUTH_FIELD).filter(|s| s.1 == 1).map(|s| s.0),
        }
    }
}

/// Sees every block of records a [`TileWriter`] writes, final ids included (the run
/// report's rasters are drawn this way, without decoding the tiles again).
pub trait WrittenRecords: Send + Sync + std::fmt::Debug {
    /// `records` (whole records as `fields` describes them) were written into tile `tile`.
    fn written(&self, tile: &str, fields: &RecordFields, records: &[u8]) -> Result<()>;
}

/// Records read at a time by [`for_each_record`].
const READ_BLOCK: u64 = 65_536;

/// Calls `f` on every raw record of the file `path` whose header is `h`, in blocks. With
/// `drawn_only`, LAZ in point formats 6–10 is decoded selectively: only the layers the run
/// report reads (x, y, z, classification, extra bytes), which roughly halves the decoding
/// time; the other fields of the records are then not meaningful.
pub fn for_each_record(
    path: &Path,
    h: &las::Header,
    layout: &RecordFields,
    drawn_only: bool,
    f: &mut dyn FnMut(&[u8]),
) -> Result<()> {
    let fmt = h.point_format();
    let laszip = h
        .all_vlrs()
        .find(|v| v.user_id == "laszip encoded" && v.record_id == 22204);
    if let (true, true, true, Some(vlr)) = (drawn_only, fmt.is_compressed, fmt.is_extended, laszip)
    {
        use laz::DecompressionSelection as S;
        use std::io::{Seek, SeekFrom};
        let lazerr = |e: laz::LasZipError| Error::bad_input(path, format!("LAZ: {e}"));
        let vlr = laz::LazVlr::from_buffer(&vlr.data).map_err(lazerr)?;
        let file = crate::io::files::open_regular(path)?;
        let mut src = std::io::BufReader::new(file);
        let offset = {
            let mut b = [0u8; 100];
            use std::io::Read;
            src.read_exact(&mut b).map_err(|e| Error::io(path, e))?;
            u64::from(u32::from_le_bytes([b[96], b[97], b[98], b[99]]))
        };
        src.seek(SeekFrom::Start(offset))
            .map_err(|e| Error::io(path, e))?;
        let mut sel = S::Z | S::CLASSIFICATION;
        if layout.segment.is_some() || layout.truth.is_some() {
            sel |= S::ALL_EXTRA_BYTES;
        }
        let mut d = laz::LasZipDecompressor::selective(src, vlr, S(sel)).map_err(lazerr)?;
        let mut left = h.number_of_points();
        let mut buf = vec![0u8; READ_BLOCK as usize * layout.record_len];
        while left > 0 {
            let n = left.min(READ_BLOCK) as usize;
            let chunk = &mut buf[..n * layout.record_len];
            d.decompress_many(chunk).map_err(|e| Error::io(path, e))?;
            chunk.chunks_exact(layout.record_len).for_each(&mut *f);
            left -= n as u64;
        }
        return Ok(());
    }
    let mut r = las::Reader::from_path(path).map_err(|e| Error::las(path, e))?;
    let mut data = las::PointDataBuilder::new().for_header(h).build();
    loop {
        let n = r
            .fill_points(READ_BLOCK, &mut data)
            .map_err(|e| Error::las(path, e))?;
        if n == 0 {
            return Ok(());
        }
        data.raw_bytes()
            .chunks_exact(layout.record_len)
            .for_each(&mut *f);
    }
}

/// Per-tile segmentation results handed to [`TileWriter::prepare`].
#[derive(Debug, Clone, Copy)]
pub struct TileSegments<'a> {
    /// Segment id per core point.
    pub ids: &'a [u32],
    /// The tile's segment table (tab-separated text).
    pub table: &'a str,
}

/// How tiles are stored.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Container {
    /// Uncompressed LAS.
    Las,
    /// LAZ in fixed chunks of 50,000 points, in the tile's point order.
    Laz,
    /// COPC: LAZ whose chunks are octree nodes (see [`crate::io::copc`]).
    Copc,
}

impl Container {
    /// The `output.format` value: "las", "laz" or "copc".
    pub fn parse(s: &str) -> Option<Container> {
        match s {
            "las" => Some(Container::Las),
            "laz" => Some(Container::Laz),
            "copc" => Some(Container::Copc),
            _ => None,
        }
    }

    /// File name extension (without the dot).
    pub fn extension(self) -> &'static str {
        match self {
            Container::Las => "las",
            Container::Laz => "laz",
            Container::Copc => "copc.laz",
        }
    }

    /// Whether points are LAZ-compressed.
    pub fn compressed(self) -> bool {
        self != Container::Las
    }
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
    id_type: SegmentIdType,
    container: Container,
    /// Where the records written are reported.
    observers: Vec<std::sync::Arc<dyn WrittenRecords>>,
    fields: RecordFields,
}

impl TileWriter {
    /// The container the tiles are written in.
    pub fn container(&self) -> Container {
        self.container
    }

    /// Prepares a writer from the first input's header and the run layout. With
    /// `segments`, output records carry a `segment_id` extra-bytes attribute of that type
    /// (reusing the input's own `segment_id` attribute when it has one of the same type, so
    /// re-runs do not stack copies).
    pub fn new(
        template: &las::Header,
        layout: &RecordLayout,
        container: Container,
        segments: Option<SegmentIdType>,
    ) -> Result<Self> {
        let mut b = Builder::from(template.clone());
        b.version = Version::new(1, 4);
        b.point_format = layout.format;
        b.point_format.is_compressed = container.compressed();
        b.transforms = layout.transforms;
        b.vlrs.retain(|v| !las::laz::is_laszip_vlr(v));
        // A COPC input's info VLR and hierarchy describe that file's chunks, not ours: kept,
        // they would make readers take a plain tile for a (broken) COPC file.
        b.vlrs.retain(|v| v.user_id != crate::io::copc::USER_ID);
        b.evlrs.retain(|v| v.user_id != crate::io::copc::USER_ID);
        if container == Container::Copc && !matches!(layout.format.to_u8(), Ok(6..=8)) {
            return Err(Error::Config(format!(
                "output.format = \"copc\" holds point formats 6, 7 and 8; the run's format is {} (set output.point_format)",
                layout.format.to_u8().unwrap_or(255)
            )));
        }
        b.padding.clear();
        b.vlr_padding.clear();
        b.point_padding.clear();
        b.generating_software = format!("tessera {}", env!("CARGO_PKG_VERSION"));
        let mut out_layout = layout.clone();
        let mut segment_field = SegmentField::None;
        let id_type = segments.unwrap_or(SegmentIdType::U32);
        if segments.is_some() {
            let is_eb =
                |v: &las::Vlr| v.user_id == extra::USER_ID && v.record_id == extra::RECORD_ID;
            let eb_start = layout.record_len - usize::from(layout.format.extra_bytes);
            let existing = b.vlrs.iter().find(|v| is_eb(v)).and_then(|v| {
                extra::fields(&v.data)
                    .into_iter()
                    .find(|f| f.name == SEGMENT_ID)
            });
            match existing {
                Some(f) if f.data_type == id_type.code() => {
                    segment_field = SegmentField::InPlace(eb_start + f.offset);
                }
                Some(f) => {
                    return Err(Error::Config(format!(
                        "the input already has a \"{SEGMENT_ID}\" attribute of extra-bytes type {} (this run writes type {}); rename it before segmenting",
                        f.data_type,
                        id_type.code()
                    )))
                }
                None => {
                    let d = extra::descriptor(id_type.code(), SEGMENT_ID, "tessera segment id, 0 = none");
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
                    f.extra_bytes += id_type.bytes() as u16;
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
        if header.point_format().is_extended {
            // LAS 1.4 R15: point formats 6–10 carry their CRS as OGC WKT (the WKT bit is set
            // for them); GeoTIFF keys of a legacy input are converted through their EPSG code.
            set_wkt(&mut header, template)?;
        }
        Ok(TileWriter {
            fields: RecordFields::of_header(&header),
            observers: Vec::new(),
            header,
            layout: layout.clone(),
            out_layout,
            segment_field,
            id_type,
            container,
        })
    }

    /// Byte offset of the segment id in an output record, if records carry one.
    fn id_offset(&self) -> Option<usize> {
        match self.segment_field {
            SegmentField::None => None,
            SegmentField::InPlace(o) => Some(o),
            SegmentField::Append => Some(self.layout.record_len),
        }
    }

    /// Reports every block of records written to `observer` too.
    pub fn observe(&mut self, observer: std::sync::Arc<dyn WrittenRecords>) {
        self.observers.push(observer);
    }

    /// The header of the tiles written.
    pub fn header(&self) -> &las::Header {
        &self.header
    }

    /// Whether tiles are LAZ (plain or COPC).
    pub fn is_laz(&self) -> bool {
        self.container.compressed()
    }

    /// Type of the segment id attribute.
    pub fn id_type(&self) -> SegmentIdType {
        self.id_type
    }

    /// `records` (run layout) as output records carrying `ids(i)` as segment id: the same
    /// bytes (updated in place) unless the id is appended to each record.
    fn with_ids<'a>(
        &self,
        records: &'a mut [u8],
        ids: impl Fn(usize) -> u64,
    ) -> std::borrow::Cow<'a, [u8]> {
        use std::borrow::Cow;
        let w = self.id_type.bytes();
        let put = |dst: &mut [u8], v: u64| dst.copy_from_slice(&v.to_le_bytes()[..w]);
        match self.segment_field {
            SegmentField::None => Cow::Borrowed(records),
            SegmentField::InPlace(o) => {
                for (i, rec) in records.chunks_exact_mut(self.layout.record_len).enumerate() {
                    put(&mut rec[o..o + w], ids(i));
                }
                Cow::Borrowed(records)
            }
            SegmentField::Append => {
                let n = records.len() / self.layout.record_len;
                let mut out = Vec::with_capacity(n * self.out_layout.record_len);
                for (i, rec) in records.chunks_exact(self.layout.record_len).enumerate() {
                    out.extend_from_slice(rec);
                    out.extend_from_slice(&ids(i).to_le_bytes()[..w]);
                }
                Cow::Owned(out)
            }
        }
    }

    /// Whether output records carry a segment id (a segmentation stage runs).
    pub fn writes_segments(&self) -> bool {
        self.segment_field != SegmentField::None
    }

    /// Writes `records` (raw, in the run layout, core points only) to `stage/name.<ext>` (and
    /// the segment table to `stage/name.segments.tsv`), where `stage` is the run's private
    /// staging directory; [`PendingTile::commit`] then moves them into the output directory.
    /// Splitting the two lets workers compress tiles in parallel while one thread decides
    /// what becomes visible.
    pub fn prepare(
        &self,
        stage: &Path,
        name: &str,
        records: &mut [u8],
        segments: Option<TileSegments<'_>>,
    ) -> Result<PendingTile> {
        let file = format!("{name}.{}", self.container.extension());
        let path = stage.join(&file);
        let mut pending = PendingTile { files: Vec::new() };
        let ids = |i: usize| {
            segments
                .and_then(|s| s.ids.get(i).copied())
                .unwrap_or(0)
                .into()
        };
        let records = self.with_ids(records, ids);
        pending.files.push((path.clone(), file));
        if let Err(e) = self.write_to(&path, name, &records) {
            pending.abandon();
            return Err(e);
        }
        if let Some(s) = segments {
            let file = format!("{name}.segments.tsv");
            let path = stage.join(&file);
            pending.files.push((path.clone(), file));
            if let Err(e) = std::fs::write(&path, s.table) {
                pending.abandon();
                return Err(Error::io(&path, e));
            }
        }
        Ok(pending)
    }

    /// Stitching: writes the tile's core `records` (run layout) with their *local* segment ids
    /// uncompressed to `spill_dir` (and its segment table beside them), to be written for
    /// real by [`TileWriter::write_deferred`] once the global ids are known. Uncompressed
    /// because the file is read back exactly once: compressing twice would double the
    /// output's dominant cost (LAZ coding).
    pub fn defer(
        &self,
        spill_dir: &Path,
        name: &str,
        records: &mut [u8],
        segments: TileSegments<'_>,
    ) -> Result<DeferredTile> {
        let n = records.len() / self.layout.record_len;
        if segments.ids.len() != n {
            return Err(Error::Internal(format!(
                "tile {name}: {} segment ids for {n} core points",
                segments.ids.len()
            )));
        }
        let records = self.with_ids(records, |i| segments.ids[i].into());
        let d = DeferredTile {
            name: name.to_string(),
            raw: spill_dir.join(format!("{name}.stitch")),
            table: spill_dir.join(format!("{name}.segments.part")),
            points: n,
        };
        let res = std::fs::write(&d.raw, &records)
            .map_err(|e| Error::io(&d.raw, e))
            .and_then(|_| {
                std::fs::write(&d.table, segments.table).map_err(|e| Error::io(&d.table, e))
            });
        if let Err(e) = res {
            d.abandon();
            return Err(e);
        }
        Ok(d)
    }

    /// Writes a deferred tile into the staging directory `dir` (commit with
    /// [`PendingTile::commit`]) with local segment id `l` replaced by `ids[l - 1]`, reading
    /// its uncompressed records once, in blocks. The segment table gets the global id first
    /// and the local id in a `local_id` column. The deferred files stay: the caller deletes
    /// them ([`DeferredTile::abandon`]) when it no longer needs them (a resumable run only
    /// once its journal records the written tile).
    pub fn write_deferred(&self, dir: &Path, d: &DeferredTile, ids: &[u64]) -> Result<PendingTile> {
        use std::io::Read;
        let off = self.id_offset().ok_or_else(|| {
            Error::Internal("deferred tile without a segment id attribute".into())
        })?;
        let w = self.id_type.bytes();
        let rl = self.out_layout.record_len;
        let global = |local: u64| -> Result<u64> {
            if local == 0 {
                return Ok(0);
            }
            let id = usize::try_from(local - 1)
                .ok()
                .and_then(|i| ids.get(i))
                .copied()
                .ok_or_else(|| {
                    Error::Internal(format!(
                        "tile {}: local segment {local} has no global id ({} known)",
                        d.name,
                        ids.len()
                    ))
                })?;
            if id > self.id_type.max() {
                return Err(crate::error::StitchError::IdOverflow(id).into());
            }
            Ok(id)
        };
        // A record's local segment id replaced by its global one.
        let rewrite = |rec: &mut [u8]| -> Result<()> {
            let mut raw = [0u8; 8];
            raw[..w].copy_from_slice(&rec[off..off + w]);
            let id = global(u64::from_le_bytes(raw))?;
            rec[off..off + w].copy_from_slice(&id.to_le_bytes()[..w]);
            Ok(())
        };
        let file = format!("{}.{}", d.name, self.container.extension());
        let tmp = dir.join(&file);
        let mut pending = PendingTile {
            files: vec![(tmp.clone(), file)],
        };
        let res = (|| -> Result<()> {
            if self.container == Container::Copc {
                // The octree needs every record at once: mapped, not read (the spill file is
                // the tile's records; the page cache holds them, not the heap).
                let file = File::open(&d.raw).map_err(|e| Error::io(&d.raw, e))?;
                let len = file.metadata().map_err(|e| Error::io(&d.raw, e))?.len();
                if len != (d.points * rl) as u64 {
                    return Err(Error::Internal(format!(
                        "{}: {len} bytes for {} records of {rl}",
                        d.raw.display(),
                        d.points
                    )));
                }
                // The spill file is private to this run: nothing changes it while mapped.
                let map = if len == 0 {
                    None
                } else {
                    Some(crate::sys::map_readonly(&file).map_err(|e| Error::io(&d.raw, e))?)
                };
                let records: &[u8] = map.as_deref().unwrap_or(&[]);
                let mut observe = |b: &[u8]| self.tell(&d.name, b);
                crate::io::copc::write(&tmp, &self.header, records, &rewrite, &mut observe)?;
                if let Some(m) = &map {
                    // Touched file pages count in the resident set until reclaimed.
                    crate::sys::release_mapped(m, 0, m.len());
                }
                return self.write_table(dir, d, &global, &mut pending);
            }
            let file = File::open(&d.raw).map_err(|e| Error::io(&d.raw, e))?;
            let mut src = std::io::BufReader::with_capacity(1 << 20, file);
            let mut writer = self.open_writer(&tmp)?;
            const BLOCK: usize = 64 * 1024;
            let mut left = d.points;
            while left > 0 {
                let n = left.min(BLOCK);
                let mut buf = vec![0u8; n * rl];
                src.read_exact(&mut buf).map_err(|e| Error::io(&d.raw, e))?;
                for rec in buf.chunks_exact_mut(rl) {
                    rewrite(rec)?;
                }
                self.tell(&d.name, &buf)?;
                let data = PointDataBuilder::new()
                    .with_format(self.out_layout.format)
                    .with_transforms(self.out_layout.transforms)
                    .build_from_bytes(buf)
                    .map_err(|e| Error::las(&tmp, e))?;
                writer.write_points(&data)?;
                left -= n;
            }
            Self::close_writer(writer, &tmp)?;
            self.write_table(dir, d, &global, &mut pending)
        })();
        if let Err(e) = res {
            pending.abandon();
            return Err(e);
        }
        Ok(pending)
    }

    /// Reports records written to the observers.
    fn tell(&self, name: &str, records: &[u8]) -> Result<()> {
        for o in &self.observers {
            o.written(name, &self.fields, records)?;
        }
        Ok(())
    }

    /// The segment table of a deferred tile with global ids first, the local id second.
    fn write_table(
        &self,
        dir: &Path,
        d: &DeferredTile,
        global: &dyn Fn(u64) -> Result<u64>,
        pending: &mut PendingTile,
    ) -> Result<()> {
        let table = std::fs::read_to_string(&d.table).map_err(|e| Error::io(&d.table, e))?;
        let mut out = String::with_capacity(table.len() + table.len() / 4);
        for (i, line) in table.lines().enumerate() {
            let (first, rest) = line.split_once('\t').unwrap_or((line, ""));
            if i == 0 {
                out.push_str(&format!("{first}\tlocal_id\t{rest}\n"));
                continue;
            }
            let local: u64 = first.parse().map_err(|_| {
                Error::Internal(format!("tile {}: bad segment table row '{line}'", d.name))
            })?;
            out.push_str(&format!("{}\t{local}\t{rest}\n", global(local)?));
        }
        let tfile = format!("{}.segments.tsv", d.name);
        let ttmp = dir.join(&tfile);
        pending.files.push((ttmp.clone(), tfile));
        std::fs::write(&ttmp, out).map_err(|e| Error::io(&ttmp, e))
    }

    fn open_writer(&self, tmp: &Path) -> Result<LasFile> {
        // One tile per worker thread: sequential compression keeps each worker on one core.
        let opts = las::WriterOptions::default().with_laz_parallelism(las::LazParallelism::No);
        LasFile::create(tmp, self.header.clone(), opts)
    }

    fn close_writer(writer: LasFile, _tmp: &Path) -> Result<()> {
        writer.finish()
    }

    // No fsync: rename after a complete write already guarantees readers never see a partial
    // tile if the process dies; syncing every tile would cost more than the compression.
    //
    // Written in blocks through one reused slab so the caller keeps (and reuses) its buffer.
    fn write_to(&self, tmp: &Path, name: &str, records: &[u8]) -> Result<()> {
        if self.container == Container::Copc {
            let mut observe = |b: &[u8]| self.tell(name, b);
            return crate::io::copc::write(tmp, &self.header, records, &|_| Ok(()), &mut observe);
        }
        const BLOCK: usize = 64 * 1024;
        let rl = self.out_layout.record_len;
        let mut writer = self.open_writer(tmp)?;
        let mut slab = PointDataBuilder::new()
            .with_format(self.out_layout.format)
            .with_transforms(self.out_layout.transforms)
            .build();
        for block in records.chunks(BLOCK * rl) {
            slab.resize_for(block.len() / rl).copy_from_slice(block);
            writer.write_points(&slab)?;
            self.tell(name, block)?;
        }
        Self::close_writer(writer, tmp)
    }
}

/// A tile's core records with local segment ids, uncompressed in the spill directory, waiting
/// for its global ids (see [`TileWriter::defer`]).
#[derive(Debug)]
pub struct DeferredTile {
    /// Tile name.
    pub name: String,
    raw: PathBuf,
    table: PathBuf,
    /// Core points.
    pub points: usize,
}

impl DeferredTile {
    /// A deferred tile whose files another run (or task) wrote and a journal recorded:
    /// `raw` records with local ids, `table` the segment table, `points` core points.
    pub fn from_parts(name: String, raw: PathBuf, table: PathBuf, points: usize) -> Self {
        DeferredTile {
            name,
            raw,
            table,
            points,
        }
    }

    /// The records file and the segment table file.
    pub fn files(&self) -> (&Path, &Path) {
        (&self.raw, &self.table)
    }

    /// Flushes both files to the disk (before a journal names them).
    pub fn sync(&self) -> Result<()> {
        sync_file(&self.raw)?;
        sync_file(&self.table)
    }

    /// Deletes the deferred files.
    pub fn abandon(&self) {
        let _ = std::fs::remove_file(&self.raw);
        let _ = std::fs::remove_file(&self.table);
    }
}

/// A completely written tile (its LAS/LAZ file and, with segmentation, its segment table) in
/// the run's staging directory.
#[derive(Debug)]
pub struct PendingTile {
    /// (staged path, file name in the output directory); the point file first.
    files: Vec<(PathBuf, String)>,
}

/// Flushes a written file's data to the disk.
pub fn sync_file(path: &Path) -> Result<()> {
    File::open(path)
        .and_then(|f| f.sync_all())
        .map_err(|e| Error::io(path, e))
}

impl PendingTile {
    /// Flushes the staged files to the disk (a journal will name them as committed).
    pub fn sync(&self) -> Result<()> {
        self.files.iter().try_for_each(|(p, _)| sync_file(p))
    }

    /// The names the tile's files get in the output directory, the point file first.
    pub fn names(&self) -> Vec<String> {
        self.files.iter().map(|(_, n)| n.clone()).collect()
    }

    /// Moves the tile's files into the output directory (the point file last: a visible tile
    /// always has its table) and returns the point file's path.
    pub fn commit(self, out: &mut OutputDir) -> Result<PathBuf> {
        let files: Vec<(PathBuf, String)> = self.files.iter().rev().cloned().collect();
        if let Err(e) = out.commit(&files) {
            self.abandon();
            return Err(e);
        }
        Ok(out
            .path()
            .join(self.files.first().map(|f| f.1.as_str()).unwrap_or_default()))
    }
    /// Deletes the staged files (the run failed).
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
