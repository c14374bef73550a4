//! Pre-flight checks of a LAS/LAZ file's structure, before a dependency parses it.
//!
//! The `las` and `laz` crates trust the sizes a file states: an EVLR claiming 2^63 bytes, or a
//! LAZ chunk table claiming 4 billion chunks, makes them allocate that much (the process
//! aborts with "memory allocation of N bytes failed"), and a LASzip record without items
//! makes `laz` panic. Every size the dependencies will allocate by is checked here against
//! what the file can hold, so such files get a clear error naming the file instead.

use crate::error::{Error, Result};
use std::fs::File;
use std::io::{Read, Seek, SeekFrom};
use std::path::Path;

/// LAS VLR header bytes.
const VLR_HEADER: u64 = 54;
/// LAS 1.4 EVLR header bytes.
const EVLR_HEADER: u64 = 60;

fn read_at(f: &mut File, at: u64, buf: &mut [u8]) -> std::io::Result<()> {
    f.seek(SeekFrom::Start(at))?;
    f.read_exact(buf)
}

fn u16_at(b: &[u8], o: usize) -> u16 {
    u16::from_le_bytes([b[o], b[o + 1]])
}
fn u32_at(b: &[u8], o: usize) -> u32 {
    u32::from_le_bytes(b[o..o + 4].try_into().unwrap_or([0; 4]))
}
fn u64_at(b: &[u8], o: usize) -> u64 {
    u64::from_le_bytes(b[o..o + 8].try_into().unwrap_or([0; 8]))
}

/// [`check_las_structure`] for a file whose length is not known yet.
pub fn check_path(path: &Path) -> Result<Structure> {
    let len = std::fs::metadata(path)
        .map_err(|e| Error::io(path, e))?
        .len();
    check_las_structure(path, len)
}

/// What [`check_las_structure`] found odd but readable.
#[derive(Debug, Clone, Copy, Default, PartialEq)]
pub struct Structure {
    /// The header announces more VLRs than lie before the point data (PDAL's
    /// `bad_vlr_count.las`): how many do. Readers are given this count.
    pub vlrs_present: Option<u32>,
}

/// Checks the sizes `path` states (header, VLRs, EVLRs, LASzip record, LAZ chunk table)
/// against its length `file_len`. Call before `las::Reader` opens the file.
pub fn check_las_structure(path: &Path, file_len: u64) -> Result<Structure> {
    let bad = |m: String| Err(Error::bad_input(path, m));
    let mut f = crate::io::files::open_regular(path)?;
    let mut h = [0u8; 375];
    let n = f.read(&mut h).map_err(|e| Error::io(path, e))?;
    if n < 227 {
        return bad(format!("truncated header: file is only {n} bytes"));
    }
    let (minor, header_size) = (h[25], u64::from(u16_at(&h, 94)));
    let offset_to_points = u64::from(u32_at(&h, 96));
    let n_vlrs = u64::from(u32_at(&h, 100));
    let format = h[104] & 0x3f;
    let compressed = h[104] & 0x80 != 0 || h[104] & 0x40 != 0;
    let record_len = u64::from(u16_at(&h, 105));
    if header_size < 227 || header_size > offset_to_points || offset_to_points > file_len {
        return bad(format!(
            "header size {header_size} and point data offset {offset_to_points} do not fit a {file_len}-byte file"
        ));
    }
    // VLRs lie between the header and the point data. A count larger than the VLRs there
    // (the records end where the point data begins) is read as the count present, as PDAL
    // and laspy do; a VLR that runs into the point data is corrupt.
    let mut structure = Structure::default();
    let mut laszip: Option<Vec<u8>> = None;
    let mut at = header_size;
    for k in 0..n_vlrs {
        let mut v = [0u8; VLR_HEADER as usize];
        if at + VLR_HEADER > offset_to_points {
            structure.vlrs_present = Some(k as u32);
            break;
        }
        if read_at(&mut f, at, &mut v).is_err() {
            return bad(format!(
                "VLR {k} of {n_vlrs} does not fit before the point data (byte {offset_to_points})"
            ));
        }
        let len = u64::from(u16_at(&v, 20));
        if at + VLR_HEADER + len > offset_to_points {
            return bad(format!(
                "VLR {k} of {n_vlrs} claims {len} bytes, past the start of the point data"
            ));
        }
        if v[2..16].starts_with(b"laszip encoded") && u16_at(&v, 18) == 22204 {
            let mut d = vec![0u8; len as usize];
            read_at(&mut f, at + VLR_HEADER, &mut d).map_err(|e| Error::io(path, e))?;
            laszip = Some(d);
        }
        at += VLR_HEADER + len;
    }
    // LAS 1.4: EVLRs from their start to the end of the file.
    if minor >= 4 && n >= 375 {
        let (start, count) = (u64_at(&h, 235), u64::from(u32_at(&h, 243)));
        if count > 0 {
            if start < offset_to_points || start > file_len {
                return bad(format!(
                    "header places {count} EVLRs at byte {start}, outside the file's point data end ({offset_to_points}..{file_len})"
                ));
            }
            if count.saturating_mul(EVLR_HEADER) > file_len - start {
                return bad(format!(
                    "header announces {count} EVLRs, more than the {} bytes after byte {start} hold",
                    file_len - start
                ));
            }
            let mut at = start;
            for k in 0..count {
                let mut v = [0u8; EVLR_HEADER as usize];
                if read_at(&mut f, at, &mut v).is_err() {
                    return bad(format!("EVLR {k} of {count} is cut off at byte {at}"));
                }
                let len = u64_at(&v, 20);
                let end = at.checked_add(EVLR_HEADER).and_then(|e| e.checked_add(len));
                match end {
                    Some(e) if e <= file_len => at = e,
                    _ => {
                        return bad(format!(
                            "EVLR {k} of {count} at byte {at} claims {len} bytes, past the end of the {file_len}-byte file"
                        ))
                    }
                }
            }
        }
    }
    if compressed {
        let Some(vlr) = laszip else {
            return bad("point format is marked compressed but there is no LASzip VLR".into());
        };
        check_laszip(path, &vlr, record_len, format)?;
        // LASzip 1.0's point-wise compression (compressor 1) has no chunks and no table.
        if u16_at(&vlr, 0) != 1 {
            check_chunk_table(path, &mut f, offset_to_points, file_len, record_len, &vlr)?;
        }
    }
    Ok(structure)
}

/// The LASzip VLR: items present, versions `laz` knows, and item sizes adding up to the
/// point record length.
fn check_laszip(path: &Path, d: &[u8], record_len: u64, format: u8) -> Result<()> {
    let bad = |m: String| Err(Error::bad_input(path, format!("LASzip VLR: {m}")));
    if d.len() < 34 {
        return bad(format!("{} bytes, too short (34 at least)", d.len()));
    }
    // The fields a broken writer garbles first, named as such (not as the chunk table or
    // the point count they would be mistaken for further on).
    let (compressor, coder) = (u16_at(d, 0), u16_at(d, 2));
    if !(1..=3).contains(&compressor) {
        return bad(format!(
            "compressor {compressor} is not one LASzip writes (1 point-wise, 2 point-wise chunked, 3 layered chunked)"
        ));
    }
    if coder != 0 {
        return bad(format!(
            "coder {coder} is not one LASzip writes (0, arithmetic)"
        ));
    }
    let n_items = usize::from(u16_at(d, 32));
    if n_items == 0 {
        return bad("no items".into());
    }
    if d.len() < 34 + 6 * n_items {
        return bad(format!("{n_items} items do not fit its {} bytes", d.len()));
    }
    let mut sum = 0u64;
    for k in 0..n_items {
        let o = 34 + 6 * k;
        let (ty, size, version) = (u16_at(d, o), u16_at(d, o + 2), u16_at(d, o + 4));
        // Item types 0 (bytes) and 6..=14 (LAS 1.0–1.4 fields), versions 1..=4.
        if !(ty == 0 || (6..=14).contains(&ty)) || !(1..=4).contains(&version) {
            return bad(format!(
                "item {k} has type {ty} version {version}, which no LASzip version writes"
            ));
        }
        sum += u64::from(size);
    }
    if sum != record_len {
        return bad(format!(
            "items add up to {sum} bytes per point but the header says records are {record_len} bytes (format {format})"
        ));
    }
    Ok(())
}

/// The LAZ chunk table: its offset (the first 8 bytes of the point data) inside the file and
/// its chunk count no more than the file can hold (each chunk starts with one raw point).
fn check_chunk_table(
    path: &Path,
    f: &mut File,
    start: u64,
    file_len: u64,
    record_len: u64,
    vlr: &[u8],
) -> Result<()> {
    let bad = |m: String| Err(Error::bad_input(path, format!("LAZ chunk table: {m}")));
    let mut b = [0u8; 8];
    if read_at(f, start, &mut b).is_err() {
        return bad(format!("its offset at byte {start} is cut off"));
    }
    let table = i64::from_le_bytes(b);
    if table == -1 {
        // Written by a streaming writer that never came back: `laz` looks for the table at
        // the end of the file; it is checked there.
        if file_len < 8 {
            return bad("missing".into());
        }
        let mut e = [0u8; 8];
        if read_at(f, file_len - 8, &mut e).is_err() {
            return bad("missing".into());
        }
        return check_table_at(
            path,
            f,
            i64::from_le_bytes(e),
            start,
            file_len,
            record_len,
            vlr,
        );
    }
    check_table_at(path, f, table, start, file_len, record_len, vlr)
}

fn check_table_at(
    path: &Path,
    f: &mut File,
    table: i64,
    start: u64,
    file_len: u64,
    record_len: u64,
    vlr: &[u8],
) -> Result<()> {
    let bad = |m: String| Err(Error::bad_input(path, format!("LAZ chunk table: {m}")));
    let Ok(table) = u64::try_from(table) else {
        return bad(format!("negative offset {table}"));
    };
    if table < start + 8 || table.saturating_add(8) > file_len {
        // `laz` treats a table it cannot find as absent (one chunk); a table offset inside
        // the data would be read as garbage: refuse both the same way.
        return bad(format!(
            "offset {table} is outside the file's compressed data (bytes {}..{file_len})",
            start + 8
        ));
    }
    let mut h = [0u8; 8];
    read_at(f, table, &mut h).map_err(|e| Error::io(path, e))?;
    let chunks = u64::from(u32_at(&h, 4));
    let data = table - (start + 8);
    let most = data / record_len.max(1);
    if chunks > most {
        return bad(format!(
            "claims {chunks} chunks, but its {data} bytes of compressed data hold at most {most} (every chunk begins with a raw {record_len}-byte point)"
        ));
    }
    // A chunk size of 0 (LAStools' COPC files) is read as variable-size chunks, as laz-rs
    // and LASzip read it: the table then gives each chunk's point count.
    // The entries (now that their count is bounded): `laz` allocates by the largest chunk's
    // point count. A compressed point takes at least a bit, so a chunk of `b` bytes holds at
    // most 8·b points (chunks up to 2^20 points always pass).
    let parsed = laz::LazVlr::read_from(vlr)
        .map_err(|e| Error::bad_input(path, format!("LASzip VLR: cannot be read ({e})")))?;
    f.seek(SeekFrom::Start(start))
        .map_err(|e| Error::io(path, e))?;
    let entries = match laz::laszip::ChunkTable::read_from(&mut *f, &parsed) {
        Ok(t) => t,
        // Unreadable tables are reported by the reader, with its own message.
        Err(_) => return Ok(()),
    };
    for (k, e) in entries.as_ref().iter().enumerate() {
        if e.point_count > (1 << 20) && e.point_count / 8 > e.byte_count {
            return bad(format!(
                "chunk {k} claims {} points in {} bytes",
                e.point_count, e.byte_count
            ));
        }
    }
    check_layers(path, f, start + 8, table, record_len, vlr, entries.as_ref())
}

/// Number of compressed layers a LAS 1.4 layered chunk stores per LASzip item (type, size),
/// or `None` for the point-wise items of formats 0–5.
fn layers_of(ty: u16, size: u16) -> Option<u64> {
    match ty {
        10 => Some(9),               // Point14: xy+returns, z, class, flags, intensity, ...
        11 | 13 => Some(1),          // RGB14, WavePacket14
        12 => Some(2),               // RGBNIR14: RGB and NIR
        14 => Some(u64::from(size)), // Byte14: one layer per extra byte
        _ => None,
    }
}

/// Layered chunks (point formats 6–10): each begins with a raw point, its point count and the
/// byte size of every layer; `laz` allocates each layer's buffer by that size before reading
/// it (laz 0.13 `copy_bytes_into_decoder`), so a size bit-flipped to 2^31 allocated gigabytes
/// and aborted under a memory cap. The sizes must fit in the chunk, as the chunk table states.
fn check_layers(
    path: &Path,
    f: &mut File,
    first: u64,
    table: u64,
    record_len: u64,
    vlr: &[u8],
    entries: &[laz::laszip::ChunkTableEntry],
) -> Result<()> {
    let items = usize::from(u16_at(vlr, 32));
    let mut layers = 0u64;
    for k in 0..items {
        let o = 34 + 6 * k;
        match layers_of(u16_at(vlr, o), u16_at(vlr, o + 2)) {
            Some(n) if u16_at(vlr, o + 4) >= 3 => layers += n,
            _ => return Ok(()),
        }
    }
    let head = record_len + 4 + 4 * layers;
    let mut buf = vec![0u8; usize::try_from(4 * layers).unwrap_or(0)];
    let mut at = first;
    for (k, e) in entries.iter().enumerate() {
        if e.byte_count == 0 {
            continue;
        }
        let end = at.saturating_add(e.byte_count);
        let bad = |m: String| {
            Err(Error::bad_input(
                path,
                format!("LAZ chunk {k} at byte {at} ({} bytes): {m}", e.byte_count),
            ))
        };
        if end > table {
            return bad(format!("runs past the chunk table at byte {table}"));
        }
        if e.byte_count < head {
            return bad(format!(
                "too short for its {head}-byte header (raw point, count, {layers} layer sizes)"
            ));
        }
        if read_at(f, at + record_len + 4, &mut buf).is_err() {
            return bad("cut off".into());
        }
        let sum: u64 = buf
            .chunks_exact(4)
            .map(|c| u64::from(u32::from_le_bytes([c[0], c[1], c[2], c[3]])))
            .sum();
        if sum > e.byte_count - head {
            return bad(format!(
                "its layers claim {sum} bytes, more than the {} after its header",
                e.byte_count - head
            ));
        }
        at = end;
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn write(dir: &Path, name: &str, bytes: &[u8]) -> std::path::PathBuf {
        let p = dir.join(name);
        std::fs::write(&p, bytes).unwrap();
        p
    }

    /// A minimal LAS 1.4 file: header, no VLRs, `n` format-0 records, `evlrs` EVLR headers.
    fn las14(n: u32, evlr_len: Option<u64>) -> Vec<u8> {
        let mut h = vec![0u8; 375];
        h[..4].copy_from_slice(b"LASF");
        h[24] = 1;
        h[25] = 4;
        h[94..96].copy_from_slice(&375u16.to_le_bytes());
        h[96..100].copy_from_slice(&375u32.to_le_bytes());
        h[105..107].copy_from_slice(&20u16.to_le_bytes());
        h[107..111].copy_from_slice(&n.to_le_bytes());
        h.extend(vec![0u8; 20 * n as usize]);
        if let Some(len) = evlr_len {
            let start = h.len() as u64;
            h[235..243].copy_from_slice(&start.to_le_bytes());
            h[243..247].copy_from_slice(&1u32.to_le_bytes());
            let mut e = vec![0u8; 60];
            e[20..28].copy_from_slice(&len.to_le_bytes());
            h.extend(e);
            h.extend(vec![0u8; len.min(64) as usize]);
        }
        h
    }

    #[test]
    fn sizes_past_the_file_are_refused_with_the_reason() {
        let d = tempfile::tempdir().unwrap();
        let ok = las14(3, Some(16));
        let p = write(d.path(), "ok.las", &ok);
        check_las_structure(&p, ok.len() as u64).unwrap();
        let huge = las14(3, Some(1 << 62));
        let p = write(d.path(), "evlr.las", &huge);
        let e = check_las_structure(&p, huge.len() as u64)
            .unwrap_err()
            .to_string();
        assert!(e.contains("evlr.las") && e.contains("EVLR 0"), "{e}");
        // More VLRs announced than there are: read as the count present.
        let mut many = ok.clone();
        many[100..104].copy_from_slice(&u32::MAX.to_le_bytes());
        let p = write(d.path(), "vlrs.las", &many);
        let s = check_las_structure(&p, many.len() as u64).unwrap();
        assert_eq!(s.vlrs_present, Some(0));
        // A VLR running into the point data is corrupt.
        let mut into = ok.clone();
        into[96..100].copy_from_slice(&(375u32 + 54).to_le_bytes());
        into[100..104].copy_from_slice(&1u32.to_le_bytes());
        into.splice(375..375, {
            let mut v = vec![0u8; 54];
            v[20..22].copy_from_slice(&100u16.to_le_bytes());
            v
        });
        let p = write(d.path(), "into.las", &into);
        let e = check_las_structure(&p, into.len() as u64)
            .unwrap_err()
            .to_string();
        assert!(e.contains("VLR 0 of 1 claims 100 bytes"), "{e}");
        let mut off = ok.clone();
        off[96..100].copy_from_slice(&u32::MAX.to_le_bytes());
        let p = write(d.path(), "off.las", &off);
        let e = check_las_structure(&p, off.len() as u64)
            .unwrap_err()
            .to_string();
        assert!(e.contains("point data offset"), "{e}");
    }

    #[test]
    fn laszip_records_are_checked() {
        let d = tempfile::tempdir().unwrap();
        let p = d.path().join("x.laz");
        let mut v = vec![0u8; 34 + 6];
        v[0..2].copy_from_slice(&2u16.to_le_bytes());
        v[32..34].copy_from_slice(&1u16.to_le_bytes());
        v[34..36].copy_from_slice(&6u16.to_le_bytes());
        v[36..38].copy_from_slice(&20u16.to_le_bytes());
        v[38..40].copy_from_slice(&2u16.to_le_bytes());
        check_laszip(&p, &v, 20, 0).unwrap();
        let e = check_laszip(&p, &v, 28, 1).unwrap_err().to_string();
        assert!(e.contains("20 bytes per point"), "{e}");
        let mut none = v.clone();
        none[32..34].copy_from_slice(&0u16.to_le_bytes());
        assert!(check_laszip(&p, &none, 20, 0)
            .unwrap_err()
            .to_string()
            .contains("no items"));
        let mut odd = v.clone();
        odd[38..40].copy_from_slice(&9u16.to_le_bytes());
        assert!(check_laszip(&p, &odd, 20, 0)
            .unwrap_err()
            .to_string()
            .contains("version 9"));
        // LASzip's own broken test files: a coder of 15, a compressor of 16.
        for (at, value, says) in [(2, 15u16, "coder 15"), (0, 16, "compressor 16")] {
            let mut bad = v.clone();
            bad[at..at + 2].copy_from_slice(&value.to_le_bytes());
            let e = check_laszip(&p, &bad, 20, 0).unwrap_err().to_string();
            assert!(e.contains(says), "{e}");
        }
        let mut point_wise = v.clone();
        point_wise[0..2].copy_from_slice(&1u16.to_le_bytes());
        check_laszip(&p, &point_wise, 20, 0).unwrap();
    }
}
