//! Temporary LAS parts of a decoded drive: the header (point format 6/7 with the clouds' extra
//! fields, adjusted standard GPS time, the CRS note), record encoding, and a writer that starts
//! a new part every `part_points` points.

use super::fields::CloudSchema;
use super::place::Placed;
use super::McapParams;
use crate::error::{Error, Result};
use crate::io::laswrite::LasFile;
use las::point::Format;
use las::{Builder, PointDataBuilder, Transform, Vector, Version, Vlr};
use std::path::{Path, PathBuf};

/// Records buffered before they are handed to the LAS writer.
const FLUSH_POINTS: usize = 1 << 16;

/// Streams LAS parts: one uncompressed LAS 1.4 file per `part_points` points.
pub(crate) struct PartWriter {
    dir: PathBuf,
    stem: String,
    header: las::Header,
    writer: Option<LasFile>,
    current: Option<PathBuf>,
    in_part: u64,
    part_points: u64,
    parts: Vec<PathBuf>,
    buf: Vec<u8>,
    format: Format,
    transforms: Vector<Transform>,
}

impl PartWriter {
    /// A writer of parts named `<stem>.partNNNN.las` in `dir`.
    pub(crate) fn new(dir: &Path, stem: String, header: las::Header, part_points: u64) -> Self {
        let mut format = *header.point_format();
        format.is_compressed = false;
        let transforms = *header.transforms();
        PartWriter {
            dir: dir.to_path_buf(),
            stem,
            header,
            writer: None,
            current: None,
            in_part: 0,
            part_points,
            parts: Vec::new(),
            buf: Vec::new(),
            format,
            transforms,
        }
    }

    /// The coordinate transforms of every part.
    pub(crate) fn transforms(&self) -> Vector<Transform> {
        self.transforms
    }

    /// Parts closed so far.
    pub(crate) fn take_parts(&mut self) -> Vec<PathBuf> {
        std::mem::take(&mut self.parts)
    }

    pub(crate) fn write(&mut self, records: &[u8], n: u64) -> Result<()> {
        if self.writer.is_none() {
            let path = self
                .dir
                .join(format!("{}.part{:04}.las", self.stem, self.parts.len()));
            let w = LasFile::create(&path, self.header.clone(), Default::default())?;
            self.writer = Some(w);
            self.current = Some(path);
            self.in_part = 0;
        }
        self.buf.extend_from_slice(records);
        self.in_part += n;
        if self.buf.len() >= FLUSH_POINTS * self.header.point_format().len() as usize {
            self.flush()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        let (Some(w), Some(path)) = (self.writer.as_mut(), self.current.as_ref()) else {
            return Ok(());
        };
        if self.buf.is_empty() {
            return Ok(());
        }
        let data = PointDataBuilder::new()
            .with_format(self.format)
            .with_transforms(self.transforms)
            .build_from_bytes(std::mem::take(&mut self.buf))
            .map_err(|e| Error::las(path, e))?;
        w.write_points(&data)
    }

    /// Ends the current part if it is full (called between clouds, so a cloud never spans two
    /// parts).
    pub(crate) fn maybe_roll(&mut self) -> Result<()> {
        if self.in_part >= self.part_points {
            self.close_part()?;
        }
        Ok(())
    }

    pub(crate) fn close_part(&mut self) -> Result<()> {
        self.flush()?;
        if let (Some(w), Some(path)) = (self.writer.take(), self.current.take()) {
            w.finish()?;
            self.parts.push(path);
        }
        Ok(())
    }
}

pub(crate) fn las_header(
    schema: &CloudSchema,
    transforms: Vector<Transform>,
    p: &McapParams,
    src: &Path,
) -> Result<las::Header> {
    let mut b = Builder::from((1, 4));
    b.version = Version::new(1, 4);
    b.point_format = schema.format();
    b.transforms = transforms;
    b.gps_time_type = las::GpsTimeType::Standard;
    b.generating_software = format!("tessera {} mcap", env!("CARGO_PKG_VERSION"));
    if let Some(v) = schema.extra_bytes_vlr() {
        b.vlrs.push(v);
    }
    let crs = p.crs.trim();
    let wkt = [
        "PROJCS",
        "PROJCRS",
        "GEOGCS",
        "GEOGCRS",
        "COMPD_CS",
        "COMPOUNDCRS",
        "GEOCCS",
    ]
    .iter()
    .any(|k| crs.starts_with(k));
    if wkt {
        let mut data = crs.as_bytes().to_vec();
        data.push(0);
        b.vlrs.push(Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 2112,
            description: "OGC WKT (mcap.crs)".into(),
            data,
        });
    } else if !crs.is_empty() {
        b.vlrs.push(Vlr {
            user_id: "tessera".into(),
            record_id: 1,
            description: "CRS note (mcap.crs)".into(),
            data: crs.as_bytes().to_vec(),
        });
    }
    b.into_header()
        .map_err(|e| Error::bad_input(src, format!("cannot build the LAS header: {e}")))
}

/// Offsets on a 1 km grid near `first` (z at 0): every coordinate of a drive stays well
/// inside the ±2^31 × scale an i32 record holds.
pub(crate) fn transforms_near(first: [f64; 3], scale: f64) -> Vector<Transform> {
    let t = |v: f64| Transform {
        scale,
        offset: (v / 1000.0).round() * 1000.0,
    };
    Vector {
        x: t(first[0]),
        y: t(first[1]),
        z: Transform { scale, offset: 0.0 },
    }
}

/// Appends the LAS 1.4 records (format 6, or 7 with RGB; extra bytes last) of a placed cloud.
/// Fails, naming the coordinate, when a point cannot be represented at the transforms.
pub(crate) fn encode_records(
    c: &Placed,
    tr: &Vector<Transform>,
    point_source_id: u16,
    rgb: bool,
    extra_bytes: usize,
    out: &mut Vec<u8>,
) -> std::result::Result<(), String> {
    let q = |v: f64, t: &Transform, axis: &str| -> std::result::Result<i32, String> {
        let r = ((v - t.offset) / t.scale).round();
        if r.abs() < 2_147_483_647.0 {
            Ok(r as i32)
        } else {
            Err(format!(
                "{axis} = {v} is too far from the first point for LAS coordinates at scale {} (check the poses, or raise mcap.scale_m)",
                t.scale
            ))
        }
    };
    for (i, (p, (gps, inten, col))) in c.xyz.iter().zip(&c.attrs).enumerate() {
        out.extend(q(p[0], &tr.x, "x")?.to_le_bytes());
        out.extend(q(p[1], &tr.y, "y")?.to_le_bytes());
        out.extend(q(p[2], &tr.z, "z")?.to_le_bytes());
        out.extend(inten.to_le_bytes());
        out.push(0x11); // return 1 of 1
        out.push(0); // classification flags, scanner channel, scan direction, edge
        out.push(0); // classification: never classified
        out.push(0); // user data
        out.extend(0i16.to_le_bytes()); // scan angle
        out.extend(point_source_id.to_le_bytes());
        out.extend(gps.to_le_bytes());
        if rgb {
            for ch in col {
                out.extend(ch.to_le_bytes());
            }
        }
        out.extend_from_slice(&c.extras[i * extra_bytes..(i + 1) * extra_bytes]);
    }
    Ok(())
}
