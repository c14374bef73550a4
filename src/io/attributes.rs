//! Named per-point attributes of LAS/LAZ records (standard fields and extra-bytes
//! attributes), read as unsigned integers: what `eval` compares and what training samples
//! name. Below both, so neither imports the other.

use crate::error::{Error, Result};
use std::path::Path;

/// Where a named attribute lives in a point record.
#[derive(Clone, Copy, Debug)]
pub(crate) enum FieldSource {
    Classification,
    UserData,
    PointSourceId,
    Intensity,
    /// An extra-bytes attribute: byte offset, size and data type.
    Extra(usize, usize, u8),
}

/// Where attribute `name` lives in the records of the file `path` with `header`.
pub(crate) fn field_source(path: &Path, header: &las::Header, name: &str) -> Result<FieldSource> {
    match name {
        "classification" => return Ok(FieldSource::Classification),
        "user_data" => return Ok(FieldSource::UserData),
        "point_source_id" => return Ok(FieldSource::PointSourceId),
        "intensity" => return Ok(FieldSource::Intensity),
        _ => {}
    }
    let extra = header
        .all_vlrs()
        .find(|v| {
            v.user_id == crate::io::extra::USER_ID && v.record_id == crate::io::extra::RECORD_ID
        })
        .map(|v| crate::io::extra::fields(&v.data))
        .unwrap_or_default();
    match extra.iter().find(|f| f.name == name) {
        Some(f) if (1..=10).contains(&f.data_type) => {
            Ok(FieldSource::Extra(f.offset, f.size, f.data_type))
        }
        Some(f) => Err(Error::Config(format!(
            "{}: extra-bytes attribute '{name}' has data type {}, not a scalar",
            path.display(),
            f.data_type
        ))),
        None => Err(Error::Config(format!(
            "{}: no attribute '{name}' (standard: classification, user_data, point_source_id, intensity; extra bytes: {})",
            path.display(),
            if extra.is_empty() {
                "none".to_string()
            } else {
                extra.iter().map(|f| f.name.as_str()).collect::<Vec<_>>().join(", ")
            }
        ))),
    }
}

/// Attribute `src` of point `p` of `path`.
pub(crate) fn field_value(path: &Path, p: &las::Point, src: FieldSource) -> Result<u32> {
    Ok(match src {
        FieldSource::Classification => u32::from(u8::from(p.classification)),
        FieldSource::UserData => u32::from(p.user_data),
        FieldSource::PointSourceId => u32::from(p.point_source_id),
        FieldSource::Intensity => u32::from(p.intensity),
        FieldSource::Extra(off, size, ty) => {
            let b = p.extra_bytes.get(off..off + size).ok_or_else(|| {
                Error::Config(format!(
                    "{}: point record shorter than its extra bytes",
                    path.display()
                ))
            })?;
            let mut raw = [0u8; 8];
            raw[..size].copy_from_slice(b);
            let v = match ty {
                9 => f32::from_le_bytes([raw[0], raw[1], raw[2], raw[3]]).round() as f64,
                10 => f64::from_le_bytes(raw).round(),
                // Signed types: sign-extend from `size` bytes.
                2 | 4 | 6 | 8 => {
                    let shift = 64 - 8 * size as u32;
                    ((i64::from_le_bytes(raw) << shift) >> shift) as f64
                }
                _ => u64::from_le_bytes(raw) as f64,
            };
            if !(0.0..=u32::MAX as f64).contains(&v) {
                return Err(Error::Config(format!(
                    "{}: attribute value {v} is not a segment id (0..2^32)",
                    path.display()
                )));
            }
            v as u32
        }
    })
}
