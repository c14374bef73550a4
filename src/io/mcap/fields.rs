//! Which PointCloud2 fields go where in a LAS 1.4 record.
//!
//! - `x`, `y`, `z` (any numeric datatype) → coordinates, after georeferencing.
//! - `intensity` (configurable name) → LAS intensity, rounded and clamped to 0..=65535.
//! - the per-point time field (`t`, `time`, `timestamp`, ... or a configured name) → GPS time
//!   (and the per-point pose when de-skewing).
//! - `rgb` / `rgba` packed into a FLOAT32 or (U)INT32 (`0x00RRGGBB`) → LAS RGB (× 257), point
//!   format 7; without it, format 6.
//! - every other scalar field (`ring`, `reflectivity`, `range`, labels, ...) → an extra-bytes
//!   attribute of the same name and type (LAS has no 64-ring channel field: the 2-bit scanner
//!   channel cannot hold a ring number).
//!
//! The first cloud of a file fixes the layout (a LAS file has one record layout); later clouds
//! are bound to it by field name. A later cloud lacking an extra field writes 0 for it (and
//! it is reported); one giving it a different datatype is an error.

use super::pointcloud2::{datatype, Accessor, PointCloud2, PointField};
use super::{ExtraFields, McapParams};
use crate::io::extra;

/// Names tried, in order, for the per-point time field with `time_field = "auto"`.
pub const AUTO_TIME_NAMES: [&str; 6] = [
    "t",
    "time",
    "timestamp",
    "time_offset",
    "offset_time",
    "time_stamp",
];

/// One field kept as extra bytes.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExtraSpec {
    /// Field (and attribute) name.
    pub name: String,
    /// PointField datatype.
    pub datatype: u8,
    /// Size in bytes.
    pub size: usize,
}

/// The LAS layout of a file's decoded points, fixed by its first cloud.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct CloudSchema {
    /// Per-point time field, if any.
    pub time_field: Option<String>,
    /// Intensity field, if the clouds have it.
    pub intensity_field: Option<String>,
    /// Packed RGB field, if any.
    pub rgb_field: Option<String>,
    /// Extra-bytes attributes, in record order.
    pub extras: Vec<ExtraSpec>,
    /// Whether records end in the 8-byte [`SCAN_SEGMENT`] attribute (after `extras`).
    pub scan_segment: bool,
}

/// Name of the per-scan segment attribute: `scan << 24 | segment`, where `scan` numbers the
/// clouds written (from 1, in drive order) and `segment` is the segment within the scan
/// (1.., 0 = none).
pub const SCAN_SEGMENT: &str = "scan_segment";
/// Bits of the segment within its scan in a [`SCAN_SEGMENT`] value (a 64-ring × 2048-column
/// scan has 131,072 pixels, so fewer segments than 2^24).
pub const SCAN_SEGMENT_BITS: u32 = 24;

/// Accessors of one cloud bound to a schema.
#[derive(Debug, Clone)]
pub struct Bound {
    /// Coordinates.
    pub xyz: [Accessor; 3],
    /// Intensity.
    pub intensity: Option<Accessor>,
    /// Per-point time and its unit in seconds.
    pub time: Option<(Accessor, f64)>,
    /// Packed RGB.
    pub rgb: Option<Accessor>,
    /// Extra fields in schema order (`None`: absent in this cloud, written as zeros).
    pub extras: Vec<Option<Accessor>>,
    /// Names of schema extras this cloud lacks.
    pub missing: Vec<String>,
}

fn scalar(f: &PointField) -> bool {
    f.count == 1 && datatype::size(f.datatype).is_some()
}

/// LAS extra-bytes data type of a PointField datatype.
pub fn las_type(dt: u8) -> u8 {
    use datatype::*;
    match dt {
        UINT8 => 1,
        INT8 => 2,
        UINT16 => 3,
        INT16 => 4,
        UINT32 => 5,
        INT32 => 6,
        FLOAT32 => 9,
        _ => 10,
    }
}

impl CloudSchema {
    /// The layout for clouds like `c`.
    pub fn from_cloud(c: &PointCloud2, p: &McapParams) -> Result<Self, String> {
        for axis in ["x", "y", "z"] {
            match c.field(axis) {
                Some(f) if scalar(f) => {}
                Some(f) => {
                    return Err(format!(
                        "field \"{axis}\" is {} × {}, expected one number",
                        f.count,
                        datatype::name(f.datatype)
                    ))
                }
                None => {
                    return Err(format!(
                        "the cloud has no \"{axis}\" field (fields: {})",
                        field_list(c)
                    ))
                }
            }
        }
        let time_field = match p.time_field.as_str() {
            "" => None,
            "auto" => AUTO_TIME_NAMES
                .iter()
                .find(|n| c.field(n).is_some_and(scalar))
                .map(|n| n.to_string()),
            name => match c.field(name) {
                Some(f) if scalar(f) => Some(name.to_string()),
                _ => {
                    return Err(format!(
                    "mcap.time_field \"{name}\" is not a scalar field of the cloud (fields: {})",
                    field_list(c)
                ))
                }
            },
        };
        let intensity_field = c
            .field(&p.intensity_field)
            .filter(|f| scalar(f))
            .map(|f| f.name.clone());
        let rgb_field = ["rgb", "rgba"]
            .iter()
            .filter_map(|n| c.field(n))
            .find(|f| {
                f.count == 1
                    && matches!(
                        f.datatype,
                        datatype::FLOAT32 | datatype::UINT32 | datatype::INT32
                    )
            })
            .map(|f| f.name.clone());
        let used = |n: &str| {
            ["x", "y", "z"].contains(&n)
                || time_field.as_deref() == Some(n)
                || intensity_field.as_deref() == Some(n)
                || rgb_field.as_deref() == Some(n)
                || (p.scan_segments.is_some() && n == SCAN_SEGMENT)
        };
        let mut extras = Vec::new();
        match &p.extra_fields {
            ExtraFields::Keyword(k) if k == "none" => {}
            ExtraFields::Keyword(_) => {
                let mut fs: Vec<&PointField> = c
                    .fields
                    .iter()
                    .filter(|f| scalar(f) && !used(&f.name) && !f.name.is_empty())
                    .collect();
                fs.sort_by_key(|f| f.offset);
                for f in fs {
                    if !extras.iter().any(|e: &ExtraSpec| e.name == f.name) {
                        extras.push(spec(f));
                    }
                }
            }
            ExtraFields::Names(names) => {
                for n in names {
                    match c.field(n) {
                        Some(f) if scalar(f) && !used(n) => extras.push(spec(f)),
                        _ => {
                            return Err(format!(
                                "mcap.extra_fields names \"{n}\", which is not a free scalar field of the cloud (fields: {})",
                                field_list(c)
                            ))
                        }
                    }
                }
            }
        }
        for e in &extras {
            if e.name.len() > 32 {
                return Err(format!(
                    "field name \"{}\" is longer than the 32 bytes a LAS extra-bytes name holds; list the fields to keep in mcap.extra_fields",
                    e.name
                ));
            }
        }
        Ok(CloudSchema {
            time_field,
            intensity_field,
            rgb_field,
            extras,
            scan_segment: p.scan_segments.is_some(),
        })
    }

    /// Bytes of extra attributes per record.
    pub fn extra_bytes(&self) -> usize {
        self.cloud_extra_bytes() + if self.scan_segment { 8 } else { 0 }
    }

    /// Bytes of the extra attributes copied from the cloud's own fields.
    pub fn cloud_extra_bytes(&self) -> usize {
        self.extras.iter().map(|e| e.size).sum()
    }

    /// The LAS point format: 6, or 7 with RGB; extra bytes attached.
    pub fn format(&self) -> las::point::Format {
        let mut f = las::point::Format::new(if self.rgb_field.is_some() { 7 } else { 6 })
            .unwrap_or_default();
        f.extra_bytes = self.extra_bytes() as u16;
        f
    }

    /// The extra-bytes VLR describing the extras, if there are any.
    pub fn extra_bytes_vlr(&self) -> Option<las::Vlr> {
        if self.extras.is_empty() && !self.scan_segment {
            return None;
        }
        let mut data = Vec::new();
        for e in &self.extras {
            data.extend(extra::descriptor(
                las_type(e.datatype),
                &e.name,
                "PointCloud2 field",
            ));
        }
        if self.scan_segment {
            data.extend(extra::descriptor(
                extra::TYPE_U64,
                SCAN_SEGMENT,
                "scan << 24 | segment in scan",
            ));
        }
        Some(las::Vlr {
            user_id: extra::USER_ID.into(),
            record_id: extra::RECORD_ID,
            description: "PointCloud2 fields".into(),
            data,
        })
    }

    /// Binds cloud `c` to this layout.
    pub fn bind(&self, c: &PointCloud2, time_unit_s: f64) -> Result<Bound, String> {
        let get = |n: &str| c.field(n).filter(|f| scalar(f)).map(|f| c.accessor(f));
        let axis = |n: &str| {
            get(n).ok_or_else(|| {
                format!(
                    "the cloud has no scalar \"{n}\" field (fields: {})",
                    field_list(c)
                )
            })
        };
        let xyz = [axis("x")?, axis("y")?, axis("z")?];
        let time = match &self.time_field {
            None => None,
            Some(n) => {
                let a = get(n).ok_or_else(|| {
                    format!(
                        "the cloud lacks the time field \"{n}\" the first cloud had (fields: {})",
                        field_list(c)
                    )
                })?;
                let unit = if time_unit_s > 0.0 {
                    time_unit_s
                } else if datatype::is_integer(a.datatype) {
                    1e-9
                } else {
                    1.0
                };
                Some((a, unit))
            }
        };
        let mut extras = Vec::with_capacity(self.extras.len());
        let mut missing = Vec::new();
        for e in &self.extras {
            match c.field(&e.name) {
                Some(f) if f.datatype == e.datatype && f.count == 1 => {
                    extras.push(Some(c.accessor(f)))
                }
                Some(f) => {
                    return Err(format!(
                        "field \"{}\" is {} × {} here but {} in the file's first cloud",
                        e.name,
                        f.count,
                        datatype::name(f.datatype),
                        datatype::name(e.datatype)
                    ))
                }
                None => {
                    missing.push(e.name.clone());
                    extras.push(None);
                }
            }
        }
        Ok(Bound {
            xyz,
            intensity: self.intensity_field.as_deref().and_then(get),
            time,
            rgb: self.rgb_field.as_deref().and_then(get),
            extras,
            missing,
        })
    }
}

fn spec(f: &PointField) -> ExtraSpec {
    ExtraSpec {
        name: f.name.clone(),
        datatype: f.datatype,
        size: datatype::size(f.datatype).unwrap_or(0),
    }
}

/// "name:TYPE@offset, ..." of a cloud's fields, for messages.
pub fn field_list(c: &PointCloud2) -> String {
    c.fields
        .iter()
        .map(|f| {
            let n = if f.count == 1 {
                String::new()
            } else {
                format!("×{}", f.count)
            };
            format!("{}:{}{n}@{}", f.name, datatype::name(f.datatype), f.offset)
        })
        .collect::<Vec<_>>()
        .join(", ")
}

/// Unpacks a packed `0x00RRGGBB` colour into 16-bit LAS channels.
#[inline]
pub fn unpack_rgb(bits: u32) -> [u16; 3] {
    let c = |s: u32| ((bits >> s) & 0xFF) as u16 * 257;
    [c(16), c(8), c(0)]
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::mcap::pointcloud2::{decode, tests::cdr_cloud};
    use crate::io::mcap::wire::Encoding;

    fn params() -> McapParams {
        crate::Config::defaults().unwrap().mcap
    }

    #[test]
    fn roles_and_extras_follow_names_and_offsets() {
        use datatype::*;
        let fields = [
            ("x", 0, FLOAT32, 1),
            ("y", 4, FLOAT32, 1),
            ("z", 8, FLOAT32, 1),
            ("intensity", 16, FLOAT32, 1),
            ("t", 20, UINT32, 1),
            ("reflectivity", 24, UINT16, 1),
            ("ring", 26, UINT8, 1),
            ("normals", 28, FLOAT32, 3),
            ("rgb", 40, FLOAT32, 1),
        ];
        let msg = cdr_cloud(false, "l", (1, 1), &fields, false, 48, 48, &[0; 48], true);
        let c = decode(&msg, Encoding::Cdr).unwrap();
        let s = CloudSchema::from_cloud(&c, &params()).unwrap();
        assert_eq!(s.time_field.as_deref(), Some("t"));
        assert_eq!(s.intensity_field.as_deref(), Some("intensity"));
        assert_eq!(s.rgb_field.as_deref(), Some("rgb"));
        let names: Vec<&str> = s.extras.iter().map(|e| e.name.as_str()).collect();
        assert_eq!(names, vec!["reflectivity", "ring"]); // normals (count 3) is not scalar
        assert_eq!(s.extra_bytes(), 3);
        assert_eq!(s.format().to_u8().unwrap(), 7);
        assert_eq!(s.format().extra_bytes, 3);
        let b = s.bind(&c, 0.0).unwrap();
        assert_eq!(b.time.unwrap().1, 1e-9);
        // A cloud without "ring" binds with a zero-filled attribute; a retyped one fails.
        let fewer = [
            ("x", 0, FLOAT32, 1),
            ("y", 4, FLOAT32, 1),
            ("z", 8, FLOAT32, 1),
        ];
        let msg2 = cdr_cloud(false, "l", (1, 1), &fewer, false, 12, 12, &[0; 12], true);
        let c2 = decode(&msg2, Encoding::Cdr).unwrap();
        assert!(s.bind(&c2, 0.0).is_err()); // lacks the time field
        let mut p = params();
        p.time_field = String::new();
        let s2 = CloudSchema::from_cloud(&c, &p).unwrap();
        let b2 = s2.bind(&c2, 0.0).unwrap();
        assert_eq!(b2.missing, vec!["t", "reflectivity", "ring"]);
        let retyped = [
            ("x", 0, FLOAT32, 1),
            ("y", 4, FLOAT32, 1),
            ("z", 8, FLOAT32, 1),
            ("ring", 12, UINT16, 1),
        ];
        let msg3 = cdr_cloud(false, "l", (1, 1), &retyped, false, 16, 16, &[0; 16], true);
        let c3 = decode(&msg3, Encoding::Cdr).unwrap();
        assert!(s2.bind(&c3, 0.0).unwrap_err().contains("ring"));
    }

    #[test]
    fn missing_coordinates_and_bad_selections_are_reported() {
        use datatype::*;
        let fields = [("x", 0, FLOAT32, 1), ("y", 4, FLOAT32, 1)];
        let msg = cdr_cloud(false, "l", (1, 1), &fields, false, 8, 8, &[0; 8], true);
        let c = decode(&msg, Encoding::Cdr).unwrap();
        let e = CloudSchema::from_cloud(&c, &params()).unwrap_err();
        assert!(e.contains("\"z\"") && e.contains("x:FLOAT32@0"), "{e}");
        let fields = [
            ("x", 0, FLOAT32, 1),
            ("y", 4, FLOAT32, 1),
            ("z", 8, INT16, 1),
        ];
        let msg = cdr_cloud(false, "l", (1, 1), &fields, false, 10, 10, &[0; 10], true);
        let c = decode(&msg, Encoding::Cdr).unwrap();
        let mut p = params();
        p.extra_fields = ExtraFields::Names(vec!["ring".into()]);
        assert!(CloudSchema::from_cloud(&c, &p).is_err());
        p.extra_fields = ExtraFields::Keyword("none".into());
        p.time_field = "stamp".into();
        assert!(CloudSchema::from_cloud(&c, &p).is_err());
    }

    #[test]
    fn packed_rgb() {
        assert_eq!(unpack_rgb(0x00FF8001), [65535, 128 * 257, 257]);
    }
}
