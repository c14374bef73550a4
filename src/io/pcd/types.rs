//! The PCD header model and errors, shared by the header parser and the body decoder.

use super::lzf;
use std::path::PathBuf;

/// Errors reading a PCD file. Each names what was wrong and, where it applies, where.
#[derive(Debug, thiserror::Error)]
pub enum PcdError {
    /// The file could not be read.
    #[error("cannot read {path}: {source}")]
    Io {
        /// The file.
        path: PathBuf,
        /// The I/O error.
        source: std::io::Error,
    },
    /// Any other error, with the file it happened in.
    #[error("{path}: {source}")]
    InFile {
        /// The file.
        path: PathBuf,
        /// What went wrong.
        source: Box<PcdError>,
    },
    /// A header line that cannot be understood.
    #[error("header line {line_no} ({line:?}): {reason}")]
    BadHeaderLine {
        /// 1-based line number.
        line_no: usize,
        /// The line, trimmed.
        line: String,
        /// What is wrong with it.
        reason: String,
    },
    /// A required header keyword is absent (or the header never reaches `DATA`).
    #[error("header has no {0} line")]
    MissingHeader(&'static str),
    /// Header entries contradict each other.
    #[error("inconsistent header: {0}")]
    Inconsistent(String),
    /// A field type/size combination PCD does not define, or one this reader cannot use.
    #[error("field {field:?}: unsupported type {ty} with size {size}{note}")]
    UnsupportedType {
        /// The field.
        field: String,
        /// Its TYPE letter.
        ty: char,
        /// Its SIZE.
        size: usize,
        /// Extra explanation (may be empty).
        note: &'static str,
    },
    /// A `DATA` mode other than ascii / binary / binary_compressed.
    #[error("unsupported DATA mode {0:?} (expected ascii, binary or binary_compressed)")]
    UnsupportedDataMode(String),
    /// Fewer data bytes or lines than the header announces.
    #[error("truncated data: expected {expected} {what}, found {found}")]
    Truncated {
        /// What was counted (bytes, lines).
        what: &'static str,
        /// How many the header implies.
        expected: usize,
        /// How many there are.
        found: usize,
    },
    /// The compressed data is not a valid LZF stream.
    #[error("binary_compressed data: {0}")]
    Lzf(#[from] lzf::LzfError),
    /// An ASCII value that does not parse as its field's type.
    #[error("data line {line_no}: value {token:?} of field {field:?} is not a valid {ty}{size}")]
    BadValue {
        /// 1-based line number in the file.
        line_no: usize,
        /// The offending text.
        token: String,
        /// The field.
        field: String,
        /// Its TYPE letter.
        ty: char,
        /// Its SIZE.
        size: usize,
    },
    /// An ASCII line with the wrong number of values.
    #[error("data line {line_no}: {found} values, expected {expected}")]
    BadValueCount {
        /// 1-based line number in the file.
        line_no: usize,
        /// Values the fields need.
        expected: usize,
        /// Values on the line.
        found: usize,
    },
    /// A required field is absent.
    #[error("no {0:?} field (x, y and z are required)")]
    MissingField(&'static str),
    /// A `label` value that is not a non-negative integer below 2³².
    #[error("point {point}: label {value} is not a non-negative 32-bit integer")]
    BadLabel {
        /// Point index.
        point: usize,
        /// The value read.
        value: f64,
    },
}

/// Numeric kind of a field (`TYPE`).
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum FieldType {
    /// Signed integer (`I`).
    Signed,
    /// Unsigned integer (`U`).
    Unsigned,
    /// IEEE float (`F`).
    Float,
}

impl FieldType {
    /// The PCD `TYPE` letter (I, U, F).
    pub(super) fn letter(self) -> char {
        match self {
            FieldType::Signed => 'I',
            FieldType::Unsigned => 'U',
            FieldType::Float => 'F',
        }
    }
}

/// One header field: `FIELDS` name with its `SIZE`, `TYPE` and `COUNT`.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PcdField {
    /// Field name (`_` is padding).
    pub name: String,
    /// Bytes per element: 1, 2, 4 or 8.
    pub size: usize,
    /// Numeric kind.
    pub ty: FieldType,
    /// Elements per point.
    pub count: usize,
}

/// Encoding of the point data.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
pub enum DataMode {
    /// Text, one point per line.
    Ascii,
    /// Little-endian records.
    Binary,
    /// LZF-compressed, field-major.
    BinaryCompressed,
}

/// A parsed PCD header.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct PcdHeader {
    /// `VERSION` as written (e.g. "0.7", ".7"), if present.
    pub version: Option<String>,
    /// Fields in file order.
    pub fields: Vec<PcdField>,
    /// `WIDTH` (points per row for organised clouds).
    pub width: usize,
    /// `HEIGHT` (1 for unorganised clouds).
    pub height: usize,
    /// `VIEWPOINT` tx ty tz qw qx qy qz (default: identity).
    pub viewpoint: [f64; 7],
    /// `POINTS`.
    pub points: usize,
    /// `DATA` mode.
    pub data: DataMode,
}

impl PcdHeader {
    /// Bytes per point in binary layout.
    pub fn point_bytes(&self) -> usize {
        self.fields.iter().map(|f| f.size * f.count).sum()
    }

    /// Index of the first field called `name`.
    pub fn field_index(&self, name: &str) -> Option<usize> {
        self.fields.iter().position(|f| f.name == name)
    }
}
