//! The ASCII header of a PCD file.

use super::{DataMode, FieldType, PcdError, PcdField, PcdHeader};

/// Parses the header; returns it, the byte offset of the data and the 1-based line number of
/// the `DATA` line.
pub fn parse_header(bytes: &[u8]) -> Result<(PcdHeader, usize, usize), PcdError> {
    let mut pos = 0usize;
    let mut line_no = 0usize;
    let mut keywords = Keywords::default();
    let data = loop {
        if pos >= bytes.len() {
            return Err(PcdError::MissingHeader("DATA"));
        }
        let end = bytes[pos..]
            .iter()
            .position(|&b| b == b'\n')
            .map_or(bytes.len(), |e| pos + e + 1);
        let raw = &bytes[pos..end];
        pos = end;
        line_no += 1;
        let text = String::from_utf8_lossy(raw);
        let line = text.trim();
        if line.is_empty() || line.starts_with('#') {
            continue;
        }
        if let Some(data) = keywords.read_line(line, line_no)? {
            break data;
        }
    };
    let header = keywords.finish(data)?;
    Ok((header, pos, line_no))
}

/// The header keywords read so far.
struct Keywords {
    version: Option<String>,
    names: Option<Vec<String>>,
    sizes: Option<Vec<usize>>,
    types: Option<Vec<char>>,
    counts: Option<Vec<usize>>,
    width: Option<usize>,
    height: Option<usize>,
    points: Option<usize>,
    viewpoint: [f64; 7],
}

impl Default for Keywords {
    fn default() -> Self {
        Keywords {
            version: None,
            names: None,
            sizes: None,
            types: None,
            counts: None,
            width: None,
            height: None,
            points: None,
            viewpoint: [0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0],
        }
    }
}

impl Keywords {
    /// Reads one (trimmed, non-empty, non-comment) header line; returns the data mode when it
    /// is the `DATA` line, which ends the header.
    fn read_line(&mut self, line: &str, line_no: usize) -> Result<Option<DataMode>, PcdError> {
        let bad = |reason: String| PcdError::BadHeaderLine {
            line_no,
            line: line.to_string(),
            reason,
        };
        let mut words = line.split_whitespace();
        let key = words.next().unwrap_or_default();
        let rest: Vec<&str> = words.collect();
        let one_usize = |rest: &[&str]| -> Result<usize, PcdError> {
            match rest {
                [v] => v
                    .parse()
                    .map_err(|_| bad(format!("{v:?} is not a non-negative integer"))),
                _ => Err(bad(format!("expected one value, found {}", rest.len()))),
            }
        };
        let usizes = |rest: &[&str]| -> Result<Vec<usize>, PcdError> {
            rest.iter()
                .map(|v| {
                    v.parse()
                        .map_err(|_| bad(format!("{v:?} is not a non-negative integer")))
                })
                .collect()
        };
        match key {
            "VERSION" => self.version = rest.first().map(|v| v.to_string()),
            // COLUMNS is the pre-0.6 name of FIELDS.
            "FIELDS" | "COLUMNS" => self.names = Some(rest.iter().map(|s| s.to_string()).collect()),
            "SIZE" => self.sizes = Some(usizes(&rest)?),
            "TYPE" => {
                let t = rest
                    .iter()
                    .map(|v| match *v {
                        "I" | "U" | "F" => Ok(v.chars().next().unwrap_or('F')),
                        other => Err(bad(format!("type {other:?} is not I, U or F"))),
                    })
                    .collect::<Result<Vec<char>, PcdError>>()?;
                self.types = Some(t);
            }
            "COUNT" => self.counts = Some(usizes(&rest)?),
            "WIDTH" => self.width = Some(one_usize(&rest)?),
            "HEIGHT" => self.height = Some(one_usize(&rest)?),
            "POINTS" => self.points = Some(one_usize(&rest)?),
            "VIEWPOINT" => {
                if rest.len() != 7 {
                    return Err(bad(format!("expected 7 numbers, found {}", rest.len())));
                }
                for (k, v) in rest.iter().enumerate() {
                    self.viewpoint[k] = v
                        .parse()
                        .map_err(|_| bad(format!("{v:?} is not a number")))?;
                }
            }
            "DATA" => {
                let mode = rest.first().copied().unwrap_or_default();
                return Ok(Some(match mode.to_ascii_lowercase().as_str() {
                    "ascii" => DataMode::Ascii,
                    "binary" => DataMode::Binary,
                    "binary_compressed" => DataMode::BinaryCompressed,
                    _ => return Err(PcdError::UnsupportedDataMode(mode.to_string())),
                }));
            }
            other => return Err(bad(format!("unknown keyword {other:?}"))),
        }
        Ok(None)
    }

    /// Checks the keywords read for completeness and consistency; the header with data mode
    /// `data`.
    fn finish(self, data: DataMode) -> Result<PcdHeader, PcdError> {
        let names = self.names.ok_or(PcdError::MissingHeader("FIELDS"))?;
        let sizes = self.sizes.ok_or(PcdError::MissingHeader("SIZE"))?;
        let types = self.types.ok_or(PcdError::MissingHeader("TYPE"))?;
        let counts = self.counts.unwrap_or_else(|| vec![1; names.len()]);
        for (what, len) in [
            ("SIZE", sizes.len()),
            ("TYPE", types.len()),
            ("COUNT", counts.len()),
        ] {
            if len != names.len() {
                return Err(PcdError::Inconsistent(format!(
                    "FIELDS names {} fields but {what} has {len} entries",
                    names.len()
                )));
            }
        }
        let mut fields = Vec::with_capacity(names.len());
        for (((name, size), t), count) in names.into_iter().zip(sizes).zip(types).zip(counts) {
            let ty = match t {
                'I' => FieldType::Signed,
                'U' => FieldType::Unsigned,
                _ => FieldType::Float,
            };
            let valid = match ty {
                FieldType::Float => size == 4 || size == 8,
                _ => matches!(size, 1 | 2 | 4 | 8),
            };
            if !valid {
                return Err(PcdError::UnsupportedType {
                    field: name,
                    ty: t,
                    size,
                    note: "",
                });
            }
            if count == 0 {
                return Err(PcdError::Inconsistent(format!(
                    "field {name:?} has COUNT 0"
                )));
            }
            fields.push(PcdField {
                name,
                size,
                ty,
                count,
            });
        }
        let height = self.height.unwrap_or(1);
        let (width, points) = match (self.width, self.points) {
            (Some(w), Some(p)) => (w, p),
            (Some(w), None) => (w, w * height),
            (None, Some(p)) => (p / height.max(1), p),
            (None, None) => return Err(PcdError::MissingHeader("POINTS or WIDTH")),
        };
        if width * height != points {
            return Err(PcdError::Inconsistent(format!(
                "WIDTH {width} × HEIGHT {height} is not POINTS {points}"
            )));
        }
        Ok(PcdHeader {
            version: self.version,
            fields,
            width,
            height,
            viewpoint: self.viewpoint,
            points,
            data,
        })
    }
}
