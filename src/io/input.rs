//! LAS/LAZ input: expand paths, read and validate every header up front (so a nightly run fails
//! in seconds on a bad file instead of hours in), choose the run's record layout, and stream
//! points in fixed-size chunks into reused buffers.

use crate::error::{Error, Result};
use crate::model::{RecordLayout, Rect};
use las::point::Format;
use las::{PointData, PointDataBuilder, Reader, Vector};
use std::fs::File;
use std::io::{BufReader, Read, Seek, SeekFrom};
use std::path::{Path, PathBuf};

/// One validated input file.
#[derive(Debug, Clone)]
pub struct InputFile {
    /// Path as given (or found in a directory).
    pub path: PathBuf,
    /// Index in the run's sorted input list (the high bits of global point ids).
    pub index: usize,
    /// Header of the file.
    pub header: las::Header,
    /// Points announced by the header.
    pub points: u64,
    /// Header xy bounds (closed).
    pub bounds: Rect,
}

/// Points at the start of each input whose intensities set its scale ([`intensity_scales`]).
const INTENSITY_SAMPLE: usize = 16_384;

/// Per input file, indexed by [`InputFile::index`]: the 99th percentile of the intensities of
/// its first 16,384 points (0 when they are all 0: no intensity). A property of the file
/// alone, so every tiling, thread count and task of a distributed run scales a file's
/// intensities alike; scaling by each tile's own percentile made a trained model's labels
/// depend on the tile layout (33 of 821,620 points of a synthetic street changed class
/// between 25 m and 50 m tiles). A file whose first points cannot be read gets 0 here; the
/// run's reader reports it (and `pipeline.keep_going` decides) as for any other run.
pub fn intensity_scales(files: &[InputFile]) -> Vec<u16> {
    use rayon::prelude::*;
    let p99 = |f: &InputFile| -> Result<u16> {
        let mut r = open_reader(&f.path, None)?;
        let mut pd = PointDataBuilder::new().for_header(r.header()).build();
        r.fill_points(INTENSITY_SAMPLE as u64, &mut pd)
            .map_err(|e| Error::las(&f.path, e))?;
        let mut v = Vec::with_capacity(INTENSITY_SAMPLE);
        for p in pd.points() {
            v.push(p.map_err(|e| Error::las(&f.path, e))?.intensity);
        }
        v.sort_unstable();
        Ok(v.get(v.len() * 99 / 100).copied().unwrap_or(0))
    };
    let per_file: Vec<(usize, u16)> = files
        .par_iter()
        .map(|f| (f.index, p99(f).unwrap_or(0)))
        .collect();
    let mut out = vec![0u16; files.iter().map(|f| f.index + 1).max().unwrap_or(0)];
    for (i, p) in per_file {
        out[i] = p;
    }
    out
}

/// All inputs of a run plus the record layout their points are carried in.
#[derive(Debug, Clone)]
pub struct InputSet {
    /// Inputs, sorted by path.
    pub files: Vec<InputFile>,
    /// The run's record layout (output point format and transforms).
    pub layout: RecordLayout,
    /// Header used as the template for output tiles (VLRs, CRS, GPS time type).
    pub template: las::Header,
    /// Sum of the header point counts.
    pub total_points: u64,
}

fn is_point_file(p: &Path) -> bool {
    matches!(
        p.extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase())
            .as_deref(),
        Some("las") | Some("laz") | Some("mcap")
    )
}

/// Expands directories (recursively, `*.las`/`*.laz`/`*.mcap`) and sorts the list. Every
/// file must be a regular file (checked before it is opened); the same file reached twice
/// (two spellings, a symlink) is listed once; tessera's work directories are skipped. Used
/// where files are read as named (evaluation, samples): tessera output directories inside
/// the given ones are read too.
pub fn expand_paths(inputs: &[PathBuf]) -> Result<Vec<PathBuf>> {
    walk_inputs(inputs, &[], false)
}

/// [`expand_paths`] for a run: never entering `exclude` (the run's output directory) or
/// anything under it, and skipping other tessera output directories met while walking (a
/// re-run would read its own earlier tiles); name one explicitly to read it.
pub fn expand_paths_excluding(inputs: &[PathBuf], exclude: &[PathBuf]) -> Result<Vec<PathBuf>> {
    walk_inputs(inputs, exclude, true)
}

fn walk_inputs(
    inputs: &[PathBuf],
    exclude: &[PathBuf],
    skip_outputs: bool,
) -> Result<Vec<PathBuf>> {
    use crate::io::workspace::{is_output_dir, is_work_dir};
    // Directories entered, by canonical path: a symlink loop is walked once.
    let mut visited: std::collections::HashSet<PathBuf> = std::collections::HashSet::new();
    let exclude: Vec<PathBuf> = exclude
        .iter()
        .filter_map(|p| std::fs::canonicalize(p).ok())
        .collect();
    let excluded = |canon: &Path| exclude.iter().any(|x| canon.starts_with(x));
    let mut found: Vec<(PathBuf, PathBuf)> = Vec::new();
    let mut skipped_excluded = 0usize;
    for p in inputs {
        let canon = std::fs::canonicalize(p).map_err(|e| Error::io(p, e))?;
        if excluded(&canon) {
            return Err(Error::Config(format!(
                "input {} lies inside the output directory; tessera never reads its own outputs as input",
                p.display()
            )));
        }
        if !canon.is_dir() {
            crate::io::files::require_regular(p)?;
            found.push((canon, p.clone()));
            continue;
        }
        visited.insert(canon);
        let mut stack = vec![p.clone()];
        while let Some(dir) = stack.pop() {
            let rd = std::fs::read_dir(&dir).map_err(|e| Error::io(&dir, e))?;
            let derived = crate::io::perclass::derived_files(&dir);
            if !derived.is_empty() {
                tracing::info!(
                    "{}: its {} per-class files repeat its tiles' points; reading the tiles only",
                    dir.display(),
                    derived.len()
                );
            }
            for entry in rd {
                let entry = entry.map_err(|e| Error::io(&dir, e))?;
                let path = entry.path();
                if derived.contains(entry.file_name().to_string_lossy().as_ref()) {
                    continue;
                }
                let canon = match std::fs::canonicalize(&path) {
                    Ok(c) => c,
                    // A dangling symlink is not an input.
                    Err(_) => continue,
                };
                if excluded(&canon) {
                    skipped_excluded += 1;
                    continue;
                }
                if canon.is_dir() {
                    if is_work_dir(&path) {
                        continue;
                    }
                    if skip_outputs && is_output_dir(&path) {
                        tracing::warn!(
                            "skipping {}: it holds the outputs of a tessera run (name it as an input to read it)",
                            path.display()
                        );
                        continue;
                    }
                    if visited.insert(canon) {
                        stack.push(path);
                    }
                } else if is_point_file(&path) {
                    crate::io::files::require_regular(&path)?;
                    found.push((canon, path));
                }
            }
        }
    }
    if skipped_excluded > 0 {
        tracing::info!(
            "{skipped_excluded} entries inside the output directory were not read as input"
        );
    }
    found.sort_by(|a, b| a.1.cmp(&b.1));
    let mut seen: std::collections::HashMap<PathBuf, PathBuf> = std::collections::HashMap::new();
    let mut out = Vec::new();
    for (canon, path) in found {
        match seen.get(&canon) {
            Some(first) if first != &path => tracing::warn!(
                "{} and {} are the same file; reading it once",
                first.display(),
                path.display()
            ),
            Some(_) => {}
            None => {
                seen.insert(canon, path.clone());
                out.push(path);
            }
        }
    }
    if out.is_empty() {
        return Err(Error::Config("no LAS/LAZ/MCAP input files given".into()));
    }
    Ok(out)
}

/// Checks the bytes of a file before handing it to the LAS parser, so the common ways a file
/// is not point data get a precise message.
fn sniff(path: &Path) -> Result<u64> {
    let len = crate::io::files::require_regular(path)?;
    if len == 0 {
        return Err(Error::bad_input(path, "empty file (0 bytes)"));
    }
    let mut head = [0u8; 64];
    let mut f = crate::io::files::open_regular(path)?;
    let n = f.read(&mut head).map_err(|e| Error::io(path, e))?;
    if head[..n].starts_with(b"version https://git-lfs") {
        return Err(Error::bad_input(
            path,
            "this is a Git LFS pointer file, not point data (fetch the real file with `git lfs pull`)",
        ));
    }
    if head[..n].starts_with(crate::io::mcap::MAGIC) {
        return Err(Error::bad_input(
            path,
            "this is an MCAP recording, not a LAS/LAZ file (`tessera run` decodes it into points; `tessera info` describes it)",
        ));
    }
    if n < 4 || &head[..4] != b"LASF" {
        let shown: String = head[..n.min(4)]
            .iter()
            .map(|b| {
                if b.is_ascii_graphic() {
                    *b as char
                } else {
                    '.'
                }
            })
            .collect();
        return Err(Error::bad_input(
            path,
            format!("not a LAS/LAZ file: signature is \"{shown}\", expected \"LASF\""),
        ));
    }
    if n < 64 {
        return Err(Error::bad_input(
            path,
            format!("truncated header: file is only {n} bytes"),
        ));
    }
    Ok(len)
}

/// How many point records the data of a file physically holds, as far as it can be told
/// without decoding.
struct Present {
    /// Bounds a count must respect.
    lo: u64,
    hi: u64,
    /// The count the data most likely holds (records up to the EVLRs or the file's end; the
    /// chunk table's sum), when one can be named.
    likely: Option<u64>,
}

fn records_present(
    path: &Path,
    header: &las::Header,
    raw: &las::raw::Header,
    file_len: u64,
) -> Result<Present> {
    let start = raw.offset_to_point_data as u64;
    if start > file_len {
        return Err(Error::bad_input(
            path,
            format!("truncated: point data should start at byte {start} but the file is {file_len} bytes"),
        ));
    }
    if !header.point_format().is_compressed {
        let rl = u64::from(raw.point_data_record_length.max(1));
        // LAS 1.4 says where the point data ends when EVLRs follow it; otherwise the file's
        // end bounds it (writers may pad).
        let evlr_start = raw
            .evlr
            .map(|e| e.start_of_first_evlr)
            .filter(|&s| s >= start && s <= file_len);
        return Ok(match evlr_start {
            Some(end) => Present {
                lo: (end - start) / rl,
                hi: (end - start) / rl,
                likely: Some((end - start) / rl),
            },
            None => Present {
                lo: 0,
                hi: (file_len - start) / rl,
                likely: Some((file_len - start) / rl),
            },
        });
    }
    if point_wise(header) {
        // One stream without a table: only the decoder can tell; a compressed point takes
        // at least a bit.
        return Ok(Present {
            lo: 0,
            hi: (file_len - start).saturating_mul(8),
            likely: None,
        });
    }
    // LAZ: the chunk table at the end tells how many points and bytes really exist.
    let vlr = header.laz_vlr().map_err(|e| Error::las(path, e))?;
    let mut f = BufReader::new(crate::io::files::open_regular(path)?);
    f.seek(SeekFrom::Start(start))
        .map_err(|e| Error::io(path, e))?;
    let table = laz::laszip::ChunkTable::read_from(&mut f, &vlr).map_err(|e| {
        Error::bad_input(
            path,
            format!("truncated or corrupt LAZ: cannot read the chunk table ({e})"),
        )
    })?;
    let corrupt_table = || {
        Error::bad_input(
            path,
            "corrupt LAZ chunk table: its byte or point counts overflow".to_string(),
        )
    };
    let needed = table
        .as_ref()
        .iter()
        .try_fold(start + 8, |acc, c| acc.checked_add(c.byte_count))
        .ok_or_else(corrupt_table)?;
    if needed > file_len {
        return Err(Error::bad_input(
            path,
            format!("truncated LAZ: chunks need {needed} bytes but the file is {file_len}"),
        ));
    }
    let n_chunks = table.len() as u64;
    Ok(if vlr.uses_variable_size_chunks() {
        let s = table
            .as_ref()
            .iter()
            .try_fold(0u64, |acc, c| acc.checked_add(c.point_count))
            .ok_or_else(corrupt_table)?;
        Present {
            lo: s,
            hi: s,
            likely: Some(s),
        }
    } else {
        let cs = u64::from(vlr.chunk_size());
        Present {
            lo: n_chunks
                .saturating_sub(1)
                .saturating_mul(cs)
                .saturating_add(1),
            hi: n_chunks.saturating_mul(cs),
            likely: None,
        }
    })
}

/// The number of points of a file: the header's count, checked against the data.
///
/// LAS 1.4 has two counts: the legacy 32-bit one (0 for formats 6–10, or when the count does
/// not fit) and the 64-bit one, which the specification makes authoritative and laspy reads
/// (measured: laspy 2.7 reads the 64-bit count and ignores the legacy one). The `las` crate
/// prefers the legacy count, which silently lost 99 % of a file whose legacy count said 10.
/// When the two disagree, the one the data supports is used, the 64-bit one first, with a
/// warning naming both; when neither fits the data it is an error.
fn point_count(path: &Path, raw: &las::raw::Header, present: Present) -> Result<u64> {
    let legacy = u64::from(raw.number_of_point_records);
    let Present { lo, hi, likely } = present;
    // One count: it must not exceed the data and must reach the data's lower bound; a count
    // of 0 is refused when the data is known to hold records (a writer that never finished
    // its header would otherwise read as an empty file). Two disagreeing counts: the data
    // must hold exactly what a count says.
    let holds_records = likely.is_some_and(|l| l > 0);
    let plausible = |n: u64| {
        if n == 0 {
            !holds_records
        } else {
            n >= lo && n <= hi
        }
    };
    let fits = |n: u64| n <= hi && n >= lo;
    let describe = || {
        if lo == hi {
            format!("the point data holds {lo} points")
        } else if lo == 0 {
            format!("the point data has room for at most {hi} points")
        } else {
            format!("the point data holds between {lo} and {hi} points")
        }
    };
    let Some(large) = raw.large_file else {
        if !plausible(legacy) {
            return Err(Error::bad_input(
                path,
                format!(
                    "header announces {legacy} points but {} (truncated or wrong point count)",
                    describe()
                ),
            ));
        }
        return Ok(legacy);
    };
    let n64 = large.number_of_point_records;
    if legacy == 0 || legacy == n64 {
        if !plausible(n64) {
            return Err(Error::bad_input(
                path,
                format!(
                    "header announces {n64} points but {} (truncated or wrong point count)",
                    describe()
                ),
            ));
        }
        return Ok(n64);
    }
    let chosen = if likely == Some(n64) {
        n64
    } else if likely == Some(legacy) {
        legacy
    } else if likely.is_none() && fits(n64) {
        n64
    } else if likely.is_none() && fits(legacy) {
        legacy
    } else {
        return Err(Error::bad_input(
            path,
            format!(
                "the header's point counts disagree (64-bit {n64}, legacy 32-bit {legacy}) and neither matches the data: {}",
                describe()
            ),
        ));
    };
    tracing::warn!(
        "{}: the header's point counts disagree (64-bit {n64}, legacy 32-bit {legacy}); reading {chosen} points, the count the data holds{}",
        path.display(),
        if chosen == n64 { " and the LAS 1.4 specification makes authoritative" } else { "" }
    );
    Ok(chosen)
}

/// A `las` reader of `path` that decodes LAZ sequentially: the header and the first points
/// are all it is asked for, and the sequential decoder also reads LASzip 1.0's point-wise
/// files, which the parallel one refuses.
///
/// `vlrs`: the number of VLRs to read instead of the header's (a header that announces more
/// than there are, [`crate::io::guard::Structure::vlrs_present`]).
pub(crate) fn open_reader(path: &Path, vlrs: Option<u32>) -> Result<Reader> {
    let f = crate::io::files::open_regular(path)?;
    let patch = vlrs.map(|n| (100u64, n.to_le_bytes()));
    let f = BufReader::new(Patched {
        inner: f,
        pos: 0,
        patch,
    });
    let options = las::ReaderOptions::default().with_laz_parallelism(las::LazParallelism::No);
    Reader::with_options(f, options).map_err(|e| Error::las(path, e))
}

/// A file read with four bytes replaced (a header field corrected, the file left as it is).
struct Patched {
    inner: File,
    pos: u64,
    patch: Option<(u64, [u8; 4])>,
}

impl Read for Patched {
    fn read(&mut self, buf: &mut [u8]) -> std::io::Result<usize> {
        let n = self.inner.read(buf)?;
        if let Some((at, bytes)) = self.patch {
            for (k, b) in bytes.iter().enumerate() {
                let p = at + k as u64;
                if p >= self.pos && p < self.pos + n as u64 {
                    buf[(p - self.pos) as usize] = *b;
                }
            }
        }
        self.pos += n as u64;
        Ok(n)
    }
}

impl Seek for Patched {
    fn seek(&mut self, to: SeekFrom) -> std::io::Result<u64> {
        self.pos = self.inner.seek(to)?;
        Ok(self.pos)
    }
}

/// Opens and validates one input.
pub fn scan_file(path: &Path, index: usize) -> Result<InputFile> {
    let file_len = sniff(path)?;
    let structure = crate::io::guard::check_las_structure(path, file_len)?;
    if let Some(k) = structure.vlrs_present {
        crate::io::warn::warn_once(&format!("vlr-count:{}", path.display()), || {
            format!(
                "{}: the header announces more VLRs than the {k} before the point data; reading those {k}",
                path.display()
            )
        });
    }
    let reader = open_reader(path, structure.vlrs_present)?;
    let mut header = reader.header().clone();
    drop(reader);
    let t = header.transforms();
    for (axis, tr) in [("x", t.x), ("y", t.y), ("z", t.z)] {
        if !(tr.scale.is_finite() && tr.scale != 0.0 && tr.offset.is_finite()) {
            return Err(Error::bad_input(
                path,
                format!(
                    "invalid {axis} scale/offset in header ({} / {})",
                    tr.scale, tr.offset
                ),
            ));
        }
    }
    let raw = {
        let mut f = BufReader::new(crate::io::files::open_regular(path)?);
        las::raw::Header::read_from(&mut f).map_err(|e| Error::las(path, e))?
    };
    let present = records_present(path, &header, &raw, file_len)?;
    let points = point_count(path, &raw, present)?;
    let b = header.bounds();
    let vals = [b.min.x, b.min.y, b.min.z, b.max.x, b.max.y, b.max.z];
    let mut bounds = Rect {
        x0: b.min.x,
        y0: b.min.y,
        x1: b.max.x,
        y1: b.max.y,
    };
    let valid = !(vals.iter().any(|v| !v.is_finite()) || b.min.x > b.max.x || b.min.y > b.max.y);
    if points > 0 {
        let first = first_point(path, &header, &raw)?;
        let within = |r: &Rect| {
            first.is_none_or(|p| InputFile::accepts(&accepted_rect(r, header.transforms()), p))
        };
        if !valid || !within(&bounds) {
            // Wrong header bounds (laspy writes some: raw integers where coordinates belong)
            // with intact points: readers that do not tile ignore them. The tiler needs true
            // bounds to know when a tile is complete, so they are taken from the points.
            bounds = bounds_from_points(path, &header, points)?;
            let shown = if valid {
                format!("x {} .. {}, y {} .. {}", b.min.x, b.max.x, b.min.y, b.max.y)
            } else {
                format!("{vals:?}")
            };
            crate::io::warn::warn_once(&format!("bounds:{}", path.display()), || {
                format!(
                    "{}: the header's bounds ({shown}) do not hold its points{}; bounds taken from the points instead: x {} .. {}, y {} .. {}",
                    path.display(),
                    first.map_or(String::new(), |p| format!(" (the first lies at {}, {})", p[0], p[1])),
                    bounds.x0, bounds.x1, bounds.y0, bounds.y1
                )
            });
        }
    }
    let is_eb = |v: &las::Vlr| {
        v.user_id == crate::io::extra::USER_ID && v.record_id == crate::io::extra::RECORD_ID
    };
    let broken = header
        .all_vlrs()
        .filter(|v| is_eb(v))
        .find_map(|v| crate::io::extra::validate(&v.data, header.point_format().extra_bytes).err());
    if let Some(e) = broken {
        // The records are intact, only their description is wrong (lasR and PDAL read such
        // files): the description is left out, so outputs carry the extra bytes undescribed
        // rather than a descriptor readers refuse.
        let mut b = las::Builder::from(header.clone());
        b.vlrs.retain(|v| !is_eb(v));
        b.evlrs.retain(|v| !is_eb(v));
        header = b.into_header().map_err(|e| Error::las(path, e))?;
        crate::io::warn::warn_once(&format!("extra-bytes:{}", path.display()), || {
            format!(
                "{}: {e}; the descriptors are left out, the records' extra bytes are read and kept as they are",
                path.display()
            )
        });
    }
    Ok(InputFile {
        path: path.to_path_buf(),
        index,
        points,
        bounds,
        header,
    })
}

/// LASzip compressor 1: LASzip 1.0's point-wise compression, one stream without chunks and
/// without a chunk table (laz-rs reads it sequentially).
fn point_wise(header: &las::Header) -> bool {
    header
        .all_vlrs()
        .find(|v| v.user_id == "laszip encoded" && v.record_id == 22204)
        .is_some_and(|v| v.data.len() >= 2 && u16::from_le_bytes([v.data[0], v.data[1]]) == 1)
}

/// Where a file's first point lies, read without decoding: LAS records are raw, and LAZ
/// stores the first point of each chunk raw (after the chunk table's offset, except in
/// LASzip 1.0's point-wise files, which have none). `None` when the record cannot be read.
fn first_point(
    path: &Path,
    header: &las::Header,
    raw: &las::raw::Header,
) -> Result<Option<[f64; 3]>> {
    let mut at = u64::from(raw.offset_to_point_data);
    if header.point_format().is_compressed && !point_wise(header) {
        at += 8;
    }
    let mut f = crate::io::files::open_regular(path)?;
    let mut rec = [0u8; 12];
    if f.seek(SeekFrom::Start(at)).is_err() || f.read_exact(&mut rec).is_err() {
        return Ok(None);
    }
    let i = |o: usize| i32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
    let t = header.transforms();
    Ok(Some([t.x.direct(i(0)), t.y.direct(i(4)), t.z.direct(i(8))]))
}

/// The x/y bounds of a file's points, by one pass over them (for files whose header bounds
/// are wrong). Kept per file for the process: the run, its unit check and its plan scan the
/// same inputs.
fn bounds_from_points(path: &Path, header: &las::Header, points: u64) -> Result<Rect> {
    use std::collections::HashMap;
    use std::sync::Mutex;
    static KNOWN: Mutex<Option<HashMap<PathBuf, Rect>>> = Mutex::new(None);
    let key = path.to_path_buf();
    if let Some(r) = KNOWN
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .get_or_insert_with(HashMap::new)
        .get(&key)
    {
        return Ok(*r);
    }
    let layout = RecordLayout::new(*header.point_format(), *header.transforms());
    let file = InputFile {
        path: key.clone(),
        index: 0,
        points,
        bounds: Rect {
            x0: f64::NEG_INFINITY,
            y0: f64::NEG_INFINITY,
            x1: f64::INFINITY,
            y1: f64::INFINITY,
        },
        header: header.clone(),
    };
    let mut r = Rect {
        x0: f64::INFINITY,
        y0: f64::INFINITY,
        x1: f64::NEG_INFINITY,
        y1: f64::NEG_INFINITY,
    };
    let mut bad: Option<(u64, [f64; 3])> = None;
    read_file_chunks(
        &file,
        &layout,
        1 << 16,
        || None,
        |first, data| {
            for (k, rec) in data.raw_bytes().chunks_exact(layout.record_len).enumerate() {
                let p = layout.xyz(rec);
                if !p.iter().all(|v| v.is_finite()) {
                    bad.get_or_insert((first + k as u64, p));
                    continue;
                }
                r.x0 = r.x0.min(p[0]);
                r.y0 = r.y0.min(p[1]);
                r.x1 = r.x1.max(p[0]);
                r.y1 = r.y1.max(p[1]);
            }
            Ok(())
        },
    )?;
    if let Some((k, p)) = bad {
        return Err(Error::bad_input(
            path,
            format!("point {k} at {p:?} is not finite"),
        ));
    }
    KNOWN
        .lock()
        .unwrap_or_else(|p| p.into_inner())
        .get_or_insert_with(HashMap::new)
        .insert(key, r);
    Ok(r)
}

fn base_format(mut f: Format) -> Format {
    f.is_compressed = false;
    f
}

/// Reads every header, validates, and plans the run's record layout.
pub fn scan_inputs(inputs: &[PathBuf], point_format: Option<u8>) -> Result<InputSet> {
    scan_inputs_skipping(inputs, point_format, false).map(|(set, _)| set)
}

/// An input a `keep_going` run left out, and why.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct SkippedInput {
    /// The file.
    pub path: PathBuf,
    /// What was wrong with it.
    pub error: String,
}

/// Like [`scan_inputs`]; with `keep_going`, an input that cannot be scanned is left out and
/// returned with its error instead of failing the run (the others are numbered as if it had
/// never been given). Fails when no input is left.
pub fn scan_inputs_skipping(
    inputs: &[PathBuf],
    point_format: Option<u8>,
    keep_going: bool,
) -> Result<(InputSet, Vec<SkippedInput>)> {
    let paths = expand_paths(inputs)?;
    let mut files: Vec<InputFile> = Vec::with_capacity(paths.len());
    let mut skipped = Vec::new();
    for p in &paths {
        match scan_file(p, files.len()) {
            Ok(f) => files.push(f),
            Err(e) if keep_going => {
                tracing::warn!("skipping input {}: {e}", p.display());
                skipped.push(SkippedInput {
                    path: p.clone(),
                    error: e.to_string(),
                });
            }
            Err(e) => return Err(e),
        }
    }
    if files.is_empty() {
        return Err(Error::Data(format!(
            "none of the {} inputs could be read (first: {}: {})",
            skipped.len(),
            skipped
                .first()
                .map(|s| s.path.display().to_string())
                .unwrap_or_default(),
            skipped.first().map(|s| s.error.as_str()).unwrap_or("")
        )));
    }
    Ok((assemble(files, point_format)?, skipped))
}

/// The run's input set from scanned files.
fn assemble(files: Vec<InputFile>, point_format: Option<u8>) -> Result<InputSet> {
    refuse_copies(&files)?;
    if files.len() as u64 >= (1 << 23) {
        return Err(Error::Config(
            "more than 8 million input files in one run".into(),
        ));
    }
    if let Some(f) = files.iter().find(|f| f.points >= (1 << 40)) {
        return Err(Error::bad_input(
            &f.path,
            "more than 2^40 points in one file",
        ));
    }
    let first = &files[0];
    // Extra bytes must describe the same attributes in every input: they are carried as
    // opaque bytes, so mixing layouts would silently garble them.
    let eb = |f: &InputFile| {
        f.header
            .vlrs()
            .iter()
            .find(|v| v.user_id == "LASF_Spec" && v.record_id == 4)
            .map(|v| v.data.clone())
    };
    for f in &files[1..] {
        if f.header.point_format().extra_bytes != first.header.point_format().extra_bytes
            || eb(f) != eb(first)
        {
            return Err(Error::Config(format!(
                "inputs {} and {} describe different extra-bytes attributes; process them in separate runs",
                first.path.display(),
                f.path.display()
            )));
        }
    }
    let mut union = base_format(*first.header.point_format());
    let all_same = files
        .iter()
        .all(|f| base_format(*f.header.point_format()) == union);
    for f in &files {
        let g = f.header.point_format();
        union.has_gps_time |= g.has_gps_time;
        union.has_color |= g.has_color;
        union.has_nir |= g.has_nir;
        union.has_waveform |= g.has_waveform;
        union.is_extended |= g.is_extended;
    }
    if union.has_nir {
        union.is_extended = true;
    }
    if union.is_extended {
        union.has_gps_time = true;
    }
    let format = match point_format {
        None if all_same => union,
        None => {
            let mut f = union;
            if f.to_u8().is_err() {
                f.is_extended = true;
                f.has_gps_time = true;
            }
            f
        }
        Some(n) => {
            let mut f = Format::new(n)
                .map_err(|e| Error::Config(format!("output.point_format {n}: {e}")))?;
            f.extra_bytes = union.extra_bytes;
            let holds = (!union.has_gps_time || f.has_gps_time)
                && (!union.has_color || f.has_color)
                && (!union.has_nir || f.has_nir)
                && (!union.has_waveform || f.has_waveform)
                && (!union.is_extended || f.is_extended);
            if !holds {
                return Err(Error::Config(format!(
                    "output.point_format {n} cannot hold every attribute of the inputs (they need format {}); refusing to drop data",
                    union.to_u8().unwrap_or(255)
                )));
            }
            f
        }
    };
    format.to_u8().map_err(|e| {
        Error::Config(format!(
            "no LAS point format holds the inputs' attributes: {e}"
        ))
    })?;
    // Transforms: the first input's offsets with the finest scale of all inputs, so every
    // input coordinate stays representable at its own precision.
    let mut transforms: Vector<las::Transform> = *first.header.transforms();
    for f in &files[1..] {
        let t = f.header.transforms();
        transforms.x.scale = transforms.x.scale.min(t.x.scale);
        transforms.y.scale = transforms.y.scale.min(t.y.scale);
        transforms.z.scale = transforms.z.scale.min(t.z.scale);
    }
    let mut layout = RecordLayout::new(format, transforms);
    layout.extras = eb(first)
        .map(|d| crate::io::extra::fields(&d))
        .unwrap_or_default();
    let total_points = files.iter().map(|f| f.points).sum();
    Ok(InputSet {
        template: first.header.clone(),
        files,
        layout,
        total_points,
    })
}

/// Refuses two inputs that are copies of one file (same size, same first and last 64 KiB —
/// header, VLRs and the first and last records): their points would be counted twice.
/// Different paths to the *same* file were already merged by [`expand_paths_excluding`].
/// Only files whose size and first 4 KiB collide are sampled further, so a run over 10,000
/// inputs reads 4 KiB of each.
fn refuse_copies(files: &[InputFile]) -> Result<()> {
    use std::hash::{Hash, Hasher};
    let mut by_key: std::collections::HashMap<(u64, u64), Vec<&InputFile>> = Default::default();
    for f in files {
        let len = std::fs::metadata(&f.path)
            .map_err(|e| Error::io(&f.path, e))?
            .len();
        let head = content_sample(&f.path, len, 4 << 10)?;
        let mut h = std::collections::hash_map::DefaultHasher::new();
        head.hash(&mut h);
        let same = by_key.entry((len, h.finish())).or_default();
        if !same.is_empty() {
            let sample = content_sample(&f.path, len, 64 << 10)?;
            for first in same.iter() {
                if content_sample(&first.path, len, 64 << 10)? == sample {
                    return Err(Error::bad_input(
                        &f.path,
                        format!(
                            "identical to {} (same size, header and data samples): a copy of one file would be read twice; pass only one of them",
                            first.path.display()
                        ),
                    ));
                }
            }
        }
        same.push(f);
    }
    Ok(())
}

/// The first and the last `part` bytes of a file.
fn content_sample(path: &Path, len: u64, part: u64) -> Result<Vec<u8>> {
    let mut f = crate::io::files::open_regular(path)?;
    let mut out = Vec::with_capacity(2 * part as usize);
    (&mut f)
        .take(part)
        .read_to_end(&mut out)
        .map_err(|e| Error::io(path, e))?;
    if len > part {
        f.seek(SeekFrom::Start(len.saturating_sub(part).max(part)))
            .map_err(|e| Error::io(path, e))?;
        f.take(part)
            .read_to_end(&mut out)
            .map_err(|e| Error::io(path, e))?;
    }
    Ok(out)
}

/// `bounds` widened by 1.5 scale units of `t` ([`InputFile::accepted`]).
fn accepted_rect(b: &Rect, t: &Vector<las::Transform>) -> Rect {
    let tol = |s: f64| 1.5 * s.abs() + 1e-9;
    Rect {
        x0: b.x0 - tol(t.x.scale),
        y0: b.y0 - tol(t.y.scale),
        x1: b.x1 + tol(t.x.scale),
        y1: b.y1 + tol(t.y.scale),
    }
}

impl InputFile {
    /// Where this file's points must lie: finite, within the header's xy bounds widened by
    /// 1.5 scale units (writers round bounds and coordinates independently). The tiler relies
    /// on it to know when a tile is complete, and checks every point.
    pub fn accepted(&self) -> Rect {
        accepted_rect(&self.bounds, self.header.transforms())
    }

    /// Whether a point passes [`InputFile::accepted`] (`rect` is its value).
    #[inline]
    pub fn accepts(rect: &Rect, [x, y, z]: [f64; 3]) -> bool {
        z.is_finite() && x >= rect.x0 && x <= rect.x1 && y >= rect.y0 && y <= rect.y1
    }

    /// The error for point `index` of this file failing [`InputFile::accepts`].
    pub fn rejected(&self, index: u64, [x, y, z]: [f64; 3]) -> Error {
        let b = self.bounds;
        Error::bad_input(
            &self.path,
            format!(
                "point {index} at ({x}, {y}, {z}) lies outside the header bounds [{}, {}] × [{}, {}] or is not finite",
                b.x0, b.x1, b.y0, b.y1
            ),
        )
    }
}

/// Streams one file's points in chunks of `chunk_points`, converted to `layout`, into `emit`
/// (`emit(first_point_index, records)`); `records.raw_bytes()` are records in `layout`.
/// Chunks are filled in place (`fill_points`) in buffers taken from `spare` when it has one,
/// and handed over whole, so this thread goes straight back to decoding (parallel LAZ
/// decoding waits for it) and the receiver returns them for reuse. Points are not checked
/// here: see [`InputFile::accepted`].
pub fn read_file_chunks(
    file: &InputFile,
    layout: &RecordLayout,
    chunk_points: usize,
    mut spare: impl FnMut() -> Option<PointData>,
    mut emit: impl FnMut(u64, PointData) -> Result<()>,
) -> Result<u64> {
    if let Some(chunks) = laz_chunks(file)? {
        return read_laz_chunks(file, layout, chunk_points, &chunks, spare, emit);
    }
    let path = &file.path;
    let header = &file.header;
    let same = base_format(*header.point_format()) == layout.format
        && header.transforms() == &layout.transforms;
    // Records are read up to the count `scan_file` settled on (not the `las` reader's, which
    // prefers the legacy count of LAS 1.4 headers).
    let mut source = RecordSource::open(file)?;
    let fresh = || PointDataBuilder::new().for_header(header).build();
    // Conversion decodes into this buffer and emits a converted copy.
    let mut decoded: Option<PointData> = None;
    let mut done: u64 = 0;
    let total = file.points;
    while done < total {
        let want = (total - done).min(chunk_points.max(1) as u64);
        let mut data = match decoded.take() {
            Some(d) => d,
            None => match spare() {
                Some(d) if same && d.format() == header.point_format() => d,
                _ => fresh(),
            },
        };
        source
            .fill(data.resize_for(want as usize))
            .map_err(|e| {
                Error::bad_input(
                    path,
                    format!(
                        "header announces {total} points, but reading points {done}..{} failed (truncated or corrupt data?): {e}",
                        done + want
                    ),
                )
            })?;
        if same {
            emit(done, data)?;
        } else {
            let mut converted = Vec::with_capacity(want as usize * layout.record_len);
            convert_chunk(&data, layout, &mut converted)
                .map_err(|e| Error::bad_input(path, format!("point {done}+: {e}")))?;
            let out = PointDataBuilder::new()
                .with_format(layout.format)
                .with_transforms(layout.transforms)
                .build_from_bytes(converted)
                .map_err(|e| Error::las(path, e))?;
            decoded = Some(data);
            emit(done, out)?;
        }
        done += want;
    }
    Ok(done)
}

/// Sequential access to a file's point records: raw LAS records, or LAZ decoded in order
/// (files whose chunks are too big to decode whole on the pool).
enum RecordSource {
    Las(BufReader<File>),
    Laz(Box<laz::LasZipDecompressor<'static, BufReader<File>>>),
}

impl RecordSource {
    fn open(file: &InputFile) -> Result<RecordSource> {
        let path = &file.path;
        let mut f = BufReader::with_capacity(1 << 20, crate::io::files::open_regular(path)?);
        let raw = las::raw::Header::read_from(&mut f).map_err(|e| Error::las(path, e))?;
        f.seek(SeekFrom::Start(u64::from(raw.offset_to_point_data)))
            .map_err(|e| Error::io(path, e))?;
        if !file.header.point_format().is_compressed {
            return Ok(RecordSource::Las(f));
        }
        let vlr = file.header.laz_vlr().map_err(|e| Error::las(path, e))?;
        let d = laz::LasZipDecompressor::new(f, vlr)
            .map_err(|e| Error::bad_input(path, format!("cannot start LAZ decompression: {e}")))?;
        Ok(RecordSource::Laz(Box::new(d)))
    }

    /// Fills `out` with the next records (a whole number of them).
    fn fill(&mut self, out: &mut [u8]) -> std::io::Result<()> {
        match self {
            RecordSource::Las(f) => f.read_exact(out),
            RecordSource::Laz(d) => {
                std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| d.decompress_many(out)))
                    .unwrap_or_else(|p| {
                        Err(std::io::Error::other(format!(
                            "the LAZ decoder failed: {}",
                            panic_text(&p)
                        )))
                    })
            }
        }
    }
}

/// The message of a caught panic.
fn panic_text(p: &Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

/// Largest LAZ chunk decoded whole, points; files with larger chunks are read through the
/// `las` reader in pieces instead.
const MAX_WHOLE_CHUNK: u64 = 1 << 20;

/// The compressed chunks of a LAZ file, in file order.
struct LazChunks {
    vlr: laz::LazVlr,
    /// Byte offset of the first chunk.
    start: u64,
    /// (points, bytes) per chunk.
    chunks: Vec<(u64, u64)>,
}

/// The chunk layout of a LAZ input, or None for LAS files and LAZ files whose chunks are too
/// big to decode whole.
fn laz_chunks(file: &InputFile) -> Result<Option<LazChunks>> {
    let header = &file.header;
    if !header.point_format().is_compressed {
        return Ok(None);
    }
    if point_wise(header) {
        return Ok(None);
    }
    let path = &file.path;
    let vlr = header.laz_vlr().map_err(|e| Error::las(path, e))?;
    let mut f = BufReader::new(File::open(path).map_err(|e| Error::io(path, e))?);
    let raw = las::raw::Header::read_from(&mut f).map_err(|e| Error::las(path, e))?;
    let start = raw.offset_to_point_data as u64;
    f.seek(SeekFrom::Start(start))
        .map_err(|e| Error::io(path, e))?;
    let table = laz::laszip::ChunkTable::read_from(&mut f, &vlr).map_err(|e| {
        Error::bad_input(
            path,
            format!("truncated or corrupt LAZ: cannot read the chunk table ({e})"),
        )
    })?;
    let mut left = file.points;
    let mut chunks = Vec::with_capacity(table.len());
    for e in table.as_ref() {
        if left == 0 {
            break;
        }
        // Fixed-size chunks: the table holds the nominal size, the last chunk may be shorter.
        let n = if vlr.uses_variable_size_chunks() {
            e.point_count
        } else {
            u64::from(vlr.chunk_size())
        }
        .min(left);
        if n > MAX_WHOLE_CHUNK {
            return Ok(None);
        }
        chunks.push((n, e.byte_count));
        left -= n;
    }
    if left > 0 {
        return Err(Error::bad_input(
            path,
            format!(
                "header announces {} points but the LAZ chunk table holds only {}",
                file.points,
                file.points - left
            ),
        ));
    }
    Ok(Some(LazChunks {
        vlr,
        start: start + 8,
        chunks,
    }))
}

/// [`read_file_chunks`] for LAZ: one chunk per emitted buffer, decoded on the rayon pool with
/// a window of chunks in flight, emitted in file order. Unlike asking the `las` reader for
/// many chunks at a time, the cores never wait for the slowest chunk of a batch or for this
/// thread: it only reads compressed bytes and hands decoded chunks on.
fn read_laz_chunks(
    file: &InputFile,
    layout: &RecordLayout,
    chunk_points: usize,
    laz: &LazChunks,
    mut spare: impl FnMut() -> Option<PointData>,
    mut emit: impl FnMut(u64, PointData) -> Result<()>,
) -> Result<u64> {
    use std::collections::VecDeque;
    type Decoded = (std::result::Result<PointData, String>, Vec<u8>);
    let path = &file.path;
    let header = &file.header;
    let same = base_format(*header.point_format()) == layout.format
        && header.transforms() == &layout.transforms;
    let threads = rayon::current_num_threads().max(1);
    let nominal = laz.chunks.first().map_or(1, |c| c.0.max(1)) as usize;
    // Enough chunks in flight to keep every core busy while the oldest is emitted; more
    // when the plan's chunk size allows (memory: window × one chunk, decoded + compressed).
    let window = (2 * chunk_points / nominal).clamp(threads + 1, 2 * threads + 2);
    let mut f =
        BufReader::with_capacity(1 << 20, File::open(path).map_err(|e| Error::io(path, e))?);
    f.seek(SeekFrom::Start(laz.start))
        .map_err(|e| Error::io(path, e))?;
    let fresh = || PointDataBuilder::new().for_header(header).build();
    let mut pending: VecDeque<(u64, u64, crossbeam_channel::Receiver<Decoded>)> = VecDeque::new();
    let mut byte_bufs: Vec<Vec<u8>> = Vec::new();
    let mut first = 0u64;
    let mut emitted = 0u64;
    let mut next = |pending: &mut VecDeque<(u64, u64, crossbeam_channel::Receiver<Decoded>)>,
                    byte_bufs: &mut Vec<Vec<u8>>|
     -> Result<u64> {
        let Some((at, n, rx)) = pending.pop_front() else {
            return Ok(0);
        };
        let (res, bytes) = rx
            .recv()
            .map_err(|_| Error::Internal("LAZ decoder task vanished".into()))?;
        byte_bufs.push(bytes);
        let data = res.map_err(|e| {
            Error::bad_input(
                path,
                format!(
                    "header announces {} points, but reading points {at}..{} failed (truncated or corrupt data?): {e}",
                    file.points,
                    at + n
                ),
            )
        })?;
        if same {
            emit(at, data)?;
        } else {
            let mut converted = Vec::with_capacity(n as usize * layout.record_len);
            convert_chunk(&data, layout, &mut converted)
                .map_err(|e| Error::bad_input(path, format!("point {at}+: {e}")))?;
            let out = PointDataBuilder::new()
                .with_format(layout.format)
                .with_transforms(layout.transforms)
                .build_from_bytes(converted)
                .map_err(|e| Error::las(path, e))?;
            emit(at, out)?;
        }
        Ok(n)
    };
    for &(n, byte_count) in &laz.chunks {
        while pending.len() >= window {
            emitted += next(&mut pending, &mut byte_bufs)?;
        }
        let mut bytes = byte_bufs.pop().unwrap_or_default();
        bytes.resize(byte_count as usize, 0);
        f.read_exact(&mut bytes).map_err(|e| {
            Error::bad_input(
                path,
                format!(
                    "truncated LAZ: cannot read the chunk of points {first}..{} ({e})",
                    first + n
                ),
            )
        })?;
        let mut data = match spare() {
            Some(d) if d.format() == header.point_format() && same => d,
            _ => fresh(),
        };
        let vlr = laz.vlr.clone();
        let (tx, rx) = crossbeam_channel::bounded::<Decoded>(1);
        rayon::spawn(move || {
            let entry = laz::laszip::ChunkTableEntry {
                point_count: n,
                byte_count,
            };
            let out = data.resize_for(n as usize);
            // A panic inside `laz` on hostile data must not take the process down (a panic
            // in a rayon job aborts): it becomes this chunk's error.
            let res = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                laz::par_decompress(&bytes, out, &vlr, std::slice::from_ref(&entry))
            }))
            .map_err(|p| format!("the LAZ decoder failed: {}", panic_text(&p)))
            .and_then(|r| r.map_err(|e| e.to_string()))
            .map(|_| data);
            let _ = tx.send((res, bytes));
        });
        pending.push_back((first, n, rx));
        first += n;
    }
    while !pending.is_empty() {
        emitted += next(&mut pending, &mut byte_bufs)?;
    }
    Ok(emitted)
}

/// Re-encodes records of another format/transform into `layout`, filling attributes the
/// input lacks with zeros.
fn convert_chunk(data: &PointData, layout: &RecordLayout, out: &mut Vec<u8>) -> las::Result<()> {
    let f = &layout.format;
    for p in data.points() {
        let mut p = p?;
        if f.has_gps_time && p.gps_time.is_none() {
            p.gps_time = Some(0.0);
        }
        if f.has_color && p.color.is_none() {
            p.color = Some(las::Color::default());
        }
        if f.has_nir && p.nir.is_none() {
            p.nir = Some(0);
        }
        if f.has_waveform && p.waveform.is_none() {
            p.waveform = Some(Default::default());
        }
        p.into_raw(&layout.transforms)?.write_to(&mut *out, f)?;
    }
    Ok(())
}
