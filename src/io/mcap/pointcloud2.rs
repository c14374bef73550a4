//! `sensor_msgs/PointCloud2`: the message (ROS 1 or CDR), its field table, and typed access
//! to the points in its data blob.
//!
//! Layout handled here, as the message defines it: `height` rows of `width` points, row `r`
//! starting at `r * row_step`, point `c` of a row at `c * point_step` (so padding inside a
//! point, and at the end of a row, is skipped), every field at its own `offset` with its own
//! datatype, the whole blob in the byte order `is_bigendian` states (independent of the CDR
//! encapsulation's byte order).

use super::wire::{DResult, DecodeError, Encoding, Stamp, WireReader};

/// `sensor_msgs/PointField` datatypes.
pub mod datatype {
    /// `INT8`
    pub const INT8: u8 = 1;
    /// `UINT8`
    pub const UINT8: u8 = 2;
    /// `INT16`
    pub const INT16: u8 = 3;
    /// `UINT16`
    pub const UINT16: u8 = 4;
    /// `INT32`
    pub const INT32: u8 = 5;
    /// `UINT32`
    pub const UINT32: u8 = 6;
    /// `FLOAT32`
    pub const FLOAT32: u8 = 7;
    /// `FLOAT64`
    pub const FLOAT64: u8 = 8;

    /// Size in bytes of one element, `None` for an unknown datatype.
    pub fn size(dt: u8) -> Option<usize> {
        match dt {
            INT8 | UINT8 => Some(1),
            INT16 | UINT16 => Some(2),
            INT32 | UINT32 | FLOAT32 => Some(4),
            FLOAT64 => Some(8),
            _ => None,
        }
    }

    /// Name as in the message definition.
    pub fn name(dt: u8) -> &'static str {
        match dt {
            INT8 => "INT8",
            UINT8 => "UINT8",
            INT16 => "INT16",
            UINT16 => "UINT16",
            INT32 => "INT32",
            UINT32 => "UINT32",
            FLOAT32 => "FLOAT32",
            FLOAT64 => "FLOAT64",
            _ => "unknown",
        }
    }

    /// True for the integer datatypes.
    pub fn is_integer(dt: u8) -> bool {
        matches!(dt, INT8 | UINT8 | INT16 | UINT16 | INT32 | UINT32)
    }
}

/// One entry of the field table.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct PointField {
    /// Field name (`x`, `intensity`, `ring`, ...).
    pub name: String,
    /// Byte offset inside a point.
    pub offset: u32,
    /// Datatype code, see [`datatype`].
    pub datatype: u8,
    /// Number of elements (1 for scalars).
    pub count: u32,
}

/// A decoded `PointCloud2` whose data blob borrows from the message buffer.
#[derive(Debug, Clone)]
pub struct PointCloud2<'a> {
    /// `header.stamp`.
    pub stamp: Stamp,
    /// `header.frame_id`.
    pub frame_id: &'a str,
    /// Rows (1 for unorganised clouds).
    pub height: u32,
    /// Points per row.
    pub width: u32,
    /// The field table.
    pub fields: Vec<PointField>,
    /// Byte order of `data`.
    pub is_bigendian: bool,
    /// Bytes per point (may exceed the fields: padding).
    pub point_step: u32,
    /// Bytes per row.
    pub row_step: u32,
    /// The point blob.
    pub data: &'a [u8],
    /// True if the cloud promises no invalid (NaN) points.
    pub is_dense: bool,
}

/// Decodes a `PointCloud2` and checks that its geometry is self-consistent: every field inside
/// `point_step`, every row inside `row_step`, and the data holding `height` rows.
pub fn decode(buf: &[u8], enc: Encoding) -> DResult<PointCloud2<'_>> {
    let mut r = WireReader::new(buf, enc)?;
    let (stamp, frame_id) = r.header()?;
    let height = r.u32()?;
    let width = r.u32()?;
    let n_fields = r.seq_len(13)?;
    let mut fields = Vec::with_capacity(n_fields);
    for _ in 0..n_fields {
        let name = r.string()?.to_string();
        let offset = r.u32()?;
        let datatype = r.u8()?;
        let count = r.u32()?;
        fields.push(PointField {
            name,
            offset,
            datatype,
            count,
        });
    }
    let is_bigendian = r.bool()?;
    let point_step = r.u32()?;
    let row_step = r.u32()?;
    let n = r.seq_len(1)?;
    let data = r.bytes(n)?;
    let is_dense = r.bool()?;
    let c = PointCloud2 {
        stamp,
        frame_id,
        height,
        width,
        fields,
        is_bigendian,
        point_step,
        row_step,
        data,
        is_dense,
    };
    c.check()?;
    Ok(c)
}

impl PointCloud2<'_> {
    /// Number of points (`width * height`, valid or not).
    pub fn len(&self) -> usize {
        self.width as usize * self.height as usize
    }

    /// True if the cloud has no points.
    pub fn is_empty(&self) -> bool {
        self.len() == 0
    }

    fn check(&self) -> DResult<()> {
        let step = self.point_step as u64;
        for f in &self.fields {
            let size = datatype::size(f.datatype).ok_or_else(|| {
                DecodeError(format!(
                    "field \"{}\" has unknown datatype {}",
                    f.name, f.datatype
                ))
            })? as u64;
            if f.offset as u64 + size * (f.count.max(1) as u64) > step {
                return Err(DecodeError(format!(
                    "field \"{}\" ({} × {} at offset {}) does not fit in point_step {}",
                    f.name,
                    f.count,
                    datatype::name(f.datatype),
                    f.offset,
                    self.point_step
                )));
            }
        }
        if self.is_empty() {
            return Ok(());
        }
        if step == 0 {
            return Err(DecodeError("point_step is 0".into()));
        }
        if (self.row_step as u64) < self.width as u64 * step {
            return Err(DecodeError(format!(
                "row_step {} is smaller than width {} × point_step {}",
                self.row_step, self.width, self.point_step
            )));
        }
        // The last row only needs its points, not the row padding after them.
        let need = (self.height as u64 - 1) * self.row_step as u64 + self.width as u64 * step;
        if (self.data.len() as u64) < need {
            return Err(DecodeError(format!(
                "data holds {} bytes but {} rows of {} points need {need} (truncated?)",
                self.data.len(),
                self.height,
                self.width
            )));
        }
        Ok(())
    }

    /// The field called `name`, if any.
    pub fn field(&self, name: &str) -> Option<&PointField> {
        self.fields.iter().find(|f| f.name == name)
    }

    /// The bytes of point `i` (row-major: `i = row * width + column`).
    #[inline]
    pub fn point(&self, i: usize) -> &[u8] {
        let w = self.width as usize;
        let (row, col) = (i / w, i % w);
        let start = row * self.row_step as usize + col * self.point_step as usize;
        &self.data[start..start + self.point_step as usize]
    }

    /// An accessor for scalar field `f` (its first element).
    pub fn accessor(&self, f: &PointField) -> Accessor {
        Accessor {
            offset: f.offset as usize,
            datatype: f.datatype,
            big_endian: self.is_bigendian,
        }
    }
}

/// Reads one scalar field from point bytes (the point's offset already applied by
/// [`PointCloud2::point`]; the cloud's checks guarantee the bytes exist).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Accessor {
    /// Offset inside the point.
    pub offset: usize,
    /// Datatype code.
    pub datatype: u8,
    /// Byte order of the blob.
    pub big_endian: bool,
}

impl Accessor {
    #[inline]
    fn raw<const N: usize>(&self, p: &[u8]) -> [u8; N] {
        let mut a = [0u8; N];
        a.copy_from_slice(&p[self.offset..self.offset + N]);
        if self.big_endian {
            a.reverse();
        }
        a
    }

    /// The value as f64 (exact for every datatype but FLOAT64, which is already f64).
    #[inline]
    pub fn get(&self, p: &[u8]) -> f64 {
        use datatype::*;
        match self.datatype {
            INT8 => p[self.offset] as i8 as f64,
            UINT8 => p[self.offset] as f64,
            INT16 => i16::from_le_bytes(self.raw(p)) as f64,
            UINT16 => u16::from_le_bytes(self.raw(p)) as f64,
            INT32 => i32::from_le_bytes(self.raw(p)) as f64,
            UINT32 => u32::from_le_bytes(self.raw(p)) as f64,
            FLOAT32 => f32::from_le_bytes(self.raw(p)) as f64,
            _ => f64::from_le_bytes(self.raw(p)),
        }
    }

    /// The raw 32 bits of a 4-byte field in native order (for packed RGB floats).
    #[inline]
    pub fn bits32(&self, p: &[u8]) -> u32 {
        u32::from_le_bytes(self.raw(p))
    }

    /// Appends the value's bytes in little-endian order (the LAS extra-bytes encoding).
    #[inline]
    pub fn push_le(&self, p: &[u8], out: &mut Vec<u8>) {
        let n = datatype::size(self.datatype).unwrap_or(0);
        let s = &p[self.offset..self.offset + n];
        if self.big_endian {
            out.extend(s.iter().rev());
        } else {
            out.extend_from_slice(s);
        }
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// Serialises a PointCloud2 in CDR (little- or big-endian encapsulation) — a test helper
    /// independent of the decoder's code paths (alignment computed by hand per field).
    #[allow(clippy::too_many_arguments)]
    pub fn cdr_cloud(
        big: bool,
        frame: &str,
        (height, width): (u32, u32),
        fields: &[(&str, u32, u8, u32)],
        blob_big: bool,
        point_step: u32,
        row_step: u32,
        data: &[u8],
        dense: bool,
    ) -> Vec<u8> {
        let mut b: Vec<u8> = vec![0, if big { 0 } else { 1 }, 0, 0];
        let pad = |b: &mut Vec<u8>, n: usize| {
            while !(b.len() - 4).is_multiple_of(n) {
                b.push(0);
            }
        };
        let u32b = |v: u32| {
            if big {
                v.to_be_bytes()
            } else {
                v.to_le_bytes()
            }
        };
        let put_u32 = |b: &mut Vec<u8>, v: u32| {
            pad(b, 4);
            b.extend(u32b(v));
        };
        let put_str = |b: &mut Vec<u8>, s: &str| {
            pad(b, 4);
            b.extend(u32b(s.len() as u32 + 1));
            b.extend(s.as_bytes());
            b.push(0);
        };
        put_u32(&mut b, 1_700_000_000); // sec
        put_u32(&mut b, 500); // nanosec
        put_str(&mut b, frame);
        put_u32(&mut b, height);
        put_u32(&mut b, width);
        put_u32(&mut b, fields.len() as u32);
        for (name, off, dt, count) in fields {
            put_str(&mut b, name);
            put_u32(&mut b, *off);
            b.push(*dt);
            put_u32(&mut b, *count);
        }
        b.push(blob_big as u8);
        put_u32(&mut b, point_step);
        put_u32(&mut b, row_step);
        put_u32(&mut b, data.len() as u32);
        b.extend_from_slice(data);
        b.push(dense as u8);
        b
    }

    #[test]
    fn padded_big_endian_blob_in_little_endian_cdr() {
        // Two points of 16 bytes: x f32 @0, ring u16 @4, t f64 @8 — blob big-endian.
        let mut data = Vec::new();
        for (x, ring, t) in [(1.5f32, 7u16, 0.25f64), (-2.0, 300, 0.5)] {
            data.extend(x.to_be_bytes());
            data.extend(ring.to_be_bytes());
            data.extend([0xAA, 0xAA]);
            data.extend(t.to_be_bytes());
        }
        let fields = [
            ("x", 0, datatype::FLOAT32, 1),
            ("ring", 4, datatype::UINT16, 1),
            ("t", 8, datatype::FLOAT64, 1),
        ];
        let msg = cdr_cloud(false, "lidar", (1, 2), &fields, true, 16, 32, &data, true);
        let c = decode(&msg, Encoding::Cdr).unwrap();
        assert_eq!(c.frame_id, "lidar");
        assert_eq!(c.stamp.sec, 1_700_000_000);
        assert_eq!(c.stamp.nsec, 500);
        assert_eq!(c.len(), 2);
        let x = c.accessor(c.field("x").unwrap());
        let ring = c.accessor(c.field("ring").unwrap());
        let t = c.accessor(c.field("t").unwrap());
        assert_eq!(x.get(c.point(1)), -2.0);
        assert_eq!(ring.get(c.point(1)), 300.0);
        assert_eq!(t.get(c.point(0)), 0.25);
        let mut le = Vec::new();
        ring.push_le(c.point(1), &mut le);
        assert_eq!(le, 300u16.to_le_bytes());
    }

    #[test]
    fn organised_rows_with_row_padding() {
        // 2 rows × 2 points, point_step 4 (one f32), row_step 12 (4 bytes of row padding).
        let mut data = Vec::new();
        for row in 0..2 {
            for col in 0..2 {
                data.extend(((row * 10 + col) as f32).to_le_bytes());
            }
            data.extend([0xFF; 4]);
        }
        let fields = [("x", 0, datatype::FLOAT32, 1)];
        let msg = cdr_cloud(true, "l", (2, 2), &fields, false, 4, 12, &data, true);
        let c = decode(&msg, Encoding::Cdr).unwrap();
        let x = c.accessor(&c.fields[0]);
        let v: Vec<f64> = (0..c.len()).map(|i| x.get(c.point(i))).collect();
        assert_eq!(v, vec![0.0, 1.0, 10.0, 11.0]);
    }

    #[test]
    fn inconsistent_geometry_is_rejected() {
        let fields = [("x", 2, datatype::FLOAT32, 1)];
        let msg = cdr_cloud(false, "l", (1, 1), &fields, false, 4, 4, &[0; 4], true);
        let e = decode(&msg, Encoding::Cdr).unwrap_err();
        assert!(e.0.contains("does not fit"), "{e}");
        let fields = [("x", 0, datatype::FLOAT32, 1)];
        let msg = cdr_cloud(false, "l", (2, 2), &fields, false, 4, 8, &[0; 12], true);
        let e = decode(&msg, Encoding::Cdr).unwrap_err();
        assert!(e.0.contains("truncated"), "{e}");
        let fields = [("x", 0, 9, 1)];
        let msg = cdr_cloud(false, "l", (1, 1), &fields, false, 4, 4, &[0; 4], true);
        assert!(decode(&msg, Encoding::Cdr).is_err());
    }

    #[test]
    fn every_datatype_reads_exactly() {
        use datatype::*;
        let cases: [(u8, Vec<u8>, f64); 8] = [
            (INT8, vec![0xFE], -2.0),
            (UINT8, vec![0xFE], 254.0),
            (INT16, (-300i16).to_le_bytes().to_vec(), -300.0),
            (UINT16, 65000u16.to_le_bytes().to_vec(), 65000.0),
            (INT32, (-70000i32).to_le_bytes().to_vec(), -70000.0),
            (UINT32, 4_000_000_000u32.to_le_bytes().to_vec(), 4e9),
            (FLOAT32, 0.1f32.to_le_bytes().to_vec(), 0.1f32 as f64),
            (FLOAT64, 0.1f64.to_le_bytes().to_vec(), 0.1),
        ];
        for (dt, bytes, want) in cases {
            let a = Accessor {
                offset: 1,
                datatype: dt,
                big_endian: false,
            };
            let mut p = vec![0u8];
            p.extend(&bytes);
            assert_eq!(a.get(&p), want, "{}", datatype::name(dt));
            let b = Accessor {
                big_endian: true,
                ..a
            };
            let mut q = vec![0u8];
            q.extend(bytes.iter().rev());
            assert_eq!(b.get(&q), want, "{} big-endian", datatype::name(dt));
        }
    }
}
