//! Reader for PCL's PCD point-cloud files (format v0.7; v0.6 and files without `VERSION` are
//! accepted too) with `DATA ascii`, `binary` and `binary_compressed`.
//!
//! # Layout
//! The header is ASCII, one keyword per line, ending with the `DATA` line; the point data starts
//! right after its newline. `binary` data is record-major (all fields of point 0, then point 1,
//! …, little-endian). `binary_compressed` data is a `u32` compressed size, a `u32` uncompressed
//! size, then an LZF stream ([`lzf`]) that expands to **field-major** data: all values of field
//! 0, then all of field 1, and so on. `ascii` data has one point per line, values separated by
//! any run of whitespace.
//!
//! All points are returned, including the NaN points of organised clouds (so that
//! `row * width + column` still indexes them); [`PcdCloud::retain_finite`] drops them.
//!
//! # Fields
//! `x`, `y`, `z` are required (any numeric type, one element each). `rgb` / `rgba` (4 bytes,
//! type `F` or `U`, packed as `0x00RRGGBB` / `0xAARRGGBB` in the bits) become [`PcdCloud::rgb`];
//! `intensity` becomes [`PcdCloud::intensity`]; `label` (integral) becomes [`PcdCloud::label`].
//! Every other field except the padding field `_` is listed in [`PcdCloud::other_fields`].

mod types;
pub use types::*;

mod header;
pub mod lzf;

pub use header::parse_header;

use std::path::Path;

/// Points of a PCD file; all vectors have [`PcdHeader::points`] entries.
#[derive(Debug, Clone, PartialEq)]
pub struct PcdCloud {
    /// The header as read.
    pub header: PcdHeader,
    /// Coordinates (NaN for invalid points of organised clouds).
    pub xyz: Vec<[f64; 3]>,
    /// Colour from a packed `rgb` or `rgba` field.
    pub rgb: Option<Vec<[u8; 3]>>,
    /// The `intensity` field.
    pub intensity: Option<Vec<f32>>,
    /// The `label` field.
    pub label: Option<Vec<u32>>,
    /// Names of the remaining fields (not x, y, z, the colour field used, intensity, label, `_`).
    pub other_fields: Vec<String>,
}

impl PcdCloud {
    /// Number of points.
    pub fn len(&self) -> usize {
        self.xyz.len()
    }

    /// Whether the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.xyz.is_empty()
    }

    /// Points whose three coordinates are finite.
    pub fn finite_count(&self) -> usize {
        self.xyz.iter().filter(|p| is_finite(p)).count()
    }

    /// Drops points with a non-finite coordinate from every column. The cloud is then
    /// unorganised, so `header.width`/`height` are set to `len × 1` and `points` to `len`.
    pub fn retain_finite(&mut self) {
        let keep: Vec<bool> = self.xyz.iter().map(is_finite).collect();
        retain_by(&mut self.xyz, &keep);
        if let Some(v) = &mut self.rgb {
            retain_by(v, &keep);
        }
        if let Some(v) = &mut self.intensity {
            retain_by(v, &keep);
        }
        if let Some(v) = &mut self.label {
            retain_by(v, &keep);
        }
        self.header.points = self.xyz.len();
        self.header.width = self.xyz.len();
        self.header.height = 1;
    }
}

fn is_finite(p: &[f64; 3]) -> bool {
    p.iter().all(|v| v.is_finite())
}

fn retain_by<T>(v: &mut Vec<T>, keep: &[bool]) {
    let mut it = keep.iter();
    v.retain(|_| it.next().copied().unwrap_or(false));
}

/// Reads a PCD file; errors name the file.
pub fn read_pcd(path: &Path) -> Result<PcdCloud, PcdError> {
    // A FIFO or device would block or never end: only regular files are read.
    let bytes = crate::io::files::open_regular(path)
        .map_err(|e| match e {
            crate::error::Error::Io { source, .. } => source,
            other => std::io::Error::other(other.to_string()),
        })
        .and_then(|mut f| {
            let mut b = Vec::new();
            std::io::Read::read_to_end(&mut f, &mut b).map(|_| b)
        })
        .map_err(|source| PcdError::Io {
            path: path.to_path_buf(),
            source,
        })?;
    parse_pcd(&bytes).map_err(|e| PcdError::InFile {
        path: path.to_path_buf(),
        source: Box::new(e),
    })
}

/// Parses PCD data held in memory.
pub fn parse_pcd(bytes: &[u8]) -> Result<PcdCloud, PcdError> {
    let (header, data_start, data_line) = parse_header(bytes)?;
    let body = &bytes[data_start..];
    let n = header.points;
    let rec = header.point_bytes();
    // Every mode is brought to one accessor: field f, element k of point i is at
    // `base[f] + i * stride[f] + k * size`.
    let (buf, base, stride): (Vec<u8>, Vec<usize>, Vec<usize>) = match header.data {
        DataMode::Binary => {
            let need = n * rec;
            if body.len() < need {
                return Err(PcdError::Truncated {
                    what: "bytes of binary data",
                    expected: need,
                    found: body.len(),
                });
            }
            let (base, stride) = record_major(&header);
            (body[..need].to_vec(), base, stride)
        }
        DataMode::BinaryCompressed => {
            let buf = decompress_body(body, n * rec)?;
            let mut base = Vec::with_capacity(header.fields.len());
            let mut stride = Vec::with_capacity(header.fields.len());
            let mut off = 0;
            for f in &header.fields {
                base.push(off);
                stride.push(f.size * f.count);
                off += n * f.size * f.count;
            }
            (buf, base, stride)
        }
        DataMode::Ascii => {
            let buf = ascii_to_records(&header, body, data_line)?;
            let (base, stride) = record_major(&header);
            (buf, base, stride)
        }
    };
    let col = Columns {
        header: &header,
        buf: &buf,
        base,
        stride,
    };
    build_cloud(&header, &col)
}

fn record_major(header: &PcdHeader) -> (Vec<usize>, Vec<usize>) {
    let rec = header.point_bytes();
    let mut off = 0;
    let mut base = Vec::with_capacity(header.fields.len());
    for f in &header.fields {
        base.push(off);
        off += f.size * f.count;
    }
    (base, vec![rec; header.fields.len()])
}

fn decompress_body(body: &[u8], expected: usize) -> Result<Vec<u8>, PcdError> {
    let word = |at: usize| -> Result<usize, PcdError> {
        let b = body.get(at..at + 4).ok_or(PcdError::Truncated {
            what: "bytes of binary_compressed size header",
            expected: 8,
            found: body.len(),
        })?;
        Ok(u32::from_le_bytes([b[0], b[1], b[2], b[3]]) as usize)
    };
    let compressed = word(0)?;
    let uncompressed = word(4)?;
    if uncompressed != expected {
        return Err(PcdError::Inconsistent(format!(
            "binary_compressed data expands to {uncompressed} bytes, but POINTS × point size is \
             {expected}"
        )));
    }
    let stream = body.get(8..8 + compressed).ok_or(PcdError::Truncated {
        what: "bytes of compressed data",
        expected: compressed,
        found: body.len().saturating_sub(8),
    })?;
    Ok(lzf::decompress(stream, uncompressed)?)
}

/// Column access to decoded point data.
struct Columns<'a> {
    header: &'a PcdHeader,
    buf: &'a [u8],
    base: Vec<usize>,
    stride: Vec<usize>,
}

impl Columns<'_> {
    fn bytes(&self, field: usize, point: usize) -> &[u8] {
        let size = self.header.fields[field].size;
        let at = self.base[field] + point * self.stride[field];
        &self.buf[at..at + size]
    }

    fn f64(&self, field: usize, point: usize) -> f64 {
        let f = &self.header.fields[field];
        decode_f64(self.bytes(field, point), f.ty)
    }

    fn bits32(&self, field: usize, point: usize) -> u32 {
        let b = self.bytes(field, point);
        u32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }
}

fn decode_f64(b: &[u8], ty: FieldType) -> f64 {
    match (ty, b.len()) {
        (FieldType::Float, 4) => f64::from(f32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        (FieldType::Float, _) => f64::from_le_bytes(arr8(b)),
        (FieldType::Unsigned, 1) => f64::from(b[0]),
        (FieldType::Unsigned, 2) => f64::from(u16::from_le_bytes([b[0], b[1]])),
        (FieldType::Unsigned, 4) => f64::from(u32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        (FieldType::Unsigned, _) => u64::from_le_bytes(arr8(b)) as f64,
        (FieldType::Signed, 1) => f64::from(b[0] as i8),
        (FieldType::Signed, 2) => f64::from(i16::from_le_bytes([b[0], b[1]])),
        (FieldType::Signed, 4) => f64::from(i32::from_le_bytes([b[0], b[1], b[2], b[3]])),
        (FieldType::Signed, _) => i64::from_le_bytes(arr8(b)) as f64,
    }
}

fn arr8(b: &[u8]) -> [u8; 8] {
    let mut a = [0u8; 8];
    a.copy_from_slice(&b[..8]);
    a
}

fn build_cloud(header: &PcdHeader, col: &Columns) -> Result<PcdCloud, PcdError> {
    let n = header.points;
    let single = |name: &'static str| -> Result<usize, PcdError> {
        let i = header
            .field_index(name)
            .ok_or(PcdError::MissingField(name))?;
        if header.fields[i].count != 1 {
            return Err(PcdError::Inconsistent(format!(
                "field {name:?} has COUNT {}, expected 1",
                header.fields[i].count
            )));
        }
        Ok(i)
    };
    let (ix, iy, iz) = (single("x")?, single("y")?, single("z")?);
    let xyz = (0..n)
        .map(|i| [col.f64(ix, i), col.f64(iy, i), col.f64(iz, i)])
        .collect();

    let mut used = vec![ix, iy, iz];
    let colour = ["rgb", "rgba"]
        .iter()
        .find_map(|name| header.field_index(name));
    let rgb = match colour {
        Some(ic) => {
            let f = &header.fields[ic];
            if f.size != 4 || f.count != 1 || f.ty == FieldType::Signed {
                return Err(PcdError::UnsupportedType {
                    field: f.name.clone(),
                    ty: f.ty.letter(),
                    size: f.size,
                    note: " (packed colour needs one 4-byte F or U element)",
                });
            }
            used.push(ic);
            Some(
                (0..n)
                    .map(|i| {
                        let v = col.bits32(ic, i);
                        [(v >> 16) as u8, (v >> 8) as u8, v as u8]
                    })
                    .collect(),
            )
        }
        None => None,
    };
    let intensity = match header.field_index("intensity") {
        Some(ii) => {
            used.push(ii);
            Some((0..n).map(|i| col.f64(ii, i) as f32).collect())
        }
        None => None,
    };
    let label = match header.field_index("label") {
        Some(il) => {
            used.push(il);
            let mut v = Vec::with_capacity(n);
            for i in 0..n {
                let x = col.f64(il, i);
                if !(0.0..=f64::from(u32::MAX)).contains(&x) || x.fract() != 0.0 {
                    return Err(PcdError::BadLabel { point: i, value: x });
                }
                v.push(x as u32);
            }
            Some(v)
        }
        None => None,
    };
    let other_fields = header
        .fields
        .iter()
        .enumerate()
        .filter(|(i, f)| !used.contains(i) && f.name != "_")
        .map(|(_, f)| f.name.clone())
        .collect();
    Ok(PcdCloud {
        header: header.clone(),
        xyz,
        rgb,
        intensity,
        label,
        other_fields,
    })
}

/// Converts ASCII point lines to little-endian records, parsing each value as its field's
/// type (so a packed-float `rgb` keeps its exact bits).
fn ascii_to_records(
    header: &PcdHeader,
    body: &[u8],
    data_line: usize,
) -> Result<Vec<u8>, PcdError> {
    let n = header.points;
    let per_point: usize = header.fields.iter().map(|f| f.count).sum();
    // Reserved by what the body can hold, not by the header's count (fuzzing: WIDTH × HEIGHT
    // of 9311² over 135 bytes reserved 4.5 GB): every value takes a character and a separator.
    let fit = body.len() / (2 * per_point.max(1)) + 1;
    let mut out = Vec::with_capacity(n.min(fit).saturating_mul(header.point_bytes()));
    let text = String::from_utf8_lossy(body);
    let mut done = 0usize;
    for (k, line) in text.lines().enumerate() {
        if done == n {
            break;
        }
        let line_no = data_line + 1 + k;
        let mut tokens = line.split_whitespace().peekable();
        if tokens.peek().is_none() {
            continue;
        }
        let mut found = 0usize;
        for f in &header.fields {
            for _ in 0..f.count {
                let tok = tokens.next().ok_or(PcdError::BadValueCount {
                    line_no,
                    expected: per_point,
                    found,
                })?;
                found += 1;
                encode_value(tok, f, &mut out).ok_or_else(|| PcdError::BadValue {
                    line_no,
                    token: tok.to_string(),
                    field: f.name.clone(),
                    ty: f.ty.letter(),
                    size: f.size,
                })?;
            }
        }
        let extra = tokens.count();
        if extra > 0 {
            return Err(PcdError::BadValueCount {
                line_no,
                expected: per_point,
                found: per_point + extra,
            });
        }
        done += 1;
    }
    if done < n {
        return Err(PcdError::Truncated {
            what: "point lines",
            expected: n,
            found: done,
        });
    }
    Ok(out)
}

/// Appends `tok` encoded as field `f`; `None` if it does not parse or fit.
fn encode_value(tok: &str, f: &PcdField, out: &mut Vec<u8>) -> Option<()> {
    match (f.ty, f.size) {
        (FieldType::Float, 4) => out.extend_from_slice(&tok.parse::<f32>().ok()?.to_le_bytes()),
        (FieldType::Float, _) => out.extend_from_slice(&tok.parse::<f64>().ok()?.to_le_bytes()),
        (FieldType::Unsigned, size) => {
            let v = parse_integral(tok)?;
            let v = u64::try_from(v).ok()?;
            if size < 8 && v >> (8 * size) != 0 {
                return None;
            }
            out.extend_from_slice(&v.to_le_bytes()[..size]);
        }
        (FieldType::Signed, size) => {
            let v = parse_integral(tok)?;
            let v = i64::try_from(v).ok()?;
            let bits = 8 * size as u32;
            if size < 8 && (v < -(1i64 << (bits - 1)) || v >= 1i64 << (bits - 1)) {
                return None;
            }
            out.extend_from_slice(&v.to_le_bytes()[..size]);
        }
    }
    Some(())
}

/// An integer, also when written as an integral float ("3.0", "1e3").
fn parse_integral(tok: &str) -> Option<i128> {
    if let Ok(v) = tok.parse::<i128>() {
        return Some(v);
    }
    let v = tok.parse::<f64>().ok()?;
    (v.is_finite() && v.fract() == 0.0 && v.abs() < 1.9e19).then_some(v as i128)
}

#[cfg(test)]
mod tests;
