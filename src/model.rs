//! Core data types shared by the stages: tile identities and rectangles, the record layout of
//! the run, and the in-memory tile.
//!
//! Memory layout: a tile keeps its points as raw LAS records in the run's output point format
//! (one contiguous `Vec<u8>`), plus a decoded `xyz` column and a global point id column. Raw
//! records make pass-through bit-exact (every attribute, extra bytes included, survives
//! untouched) and cost ~30–70 bytes per point instead of ~130 for decoded `las::Point`s.

use las::point::Format;
use las::{Transform, Vector};
use serde::Serialize;
use std::fmt;

/// A grid cell (column, row): the unit the tiler releases; quadtree leaves share their cell.
pub type CellKey = (i64, i64);

/// An axis-aligned rectangle in the xy plane, half-open: `[x0, x1) × [y0, y1)`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct Rect {
    /// Minimum x.
    pub x0: f64,
    /// Minimum y.
    pub y0: f64,
    /// Maximum x (exclusive).
    pub x1: f64,
    /// Maximum y (exclusive).
    pub y1: f64,
}

impl Rect {
    /// True if `(x, y)` lies in the half-open rectangle.
    #[inline]
    pub fn contains(&self, x: f64, y: f64) -> bool {
        x >= self.x0 && x < self.x1 && y >= self.y0 && y < self.y1
    }
    /// The rectangle grown by `m` on every side.
    pub fn expanded(&self, m: f64) -> Rect {
        Rect {
            x0: self.x0 - m,
            y0: self.y0 - m,
            x1: self.x1 + m,
            y1: self.y1 + m,
        }
    }
    /// True if the two closed rectangles overlap.
    pub fn intersects(&self, o: &Rect) -> bool {
        self.x0 <= o.x1 && o.x0 <= self.x1 && self.y0 <= o.y1 && o.y0 <= self.y1
    }
    /// Edge length in x.
    pub fn width(&self) -> f64 {
        self.x1 - self.x0
    }
    /// Quadrant `q` (0 = SW, 1 = SE, 2 = NW, 3 = NE).
    pub fn quadrant(&self, q: u8) -> Rect {
        let xm = 0.5 * (self.x0 + self.x1);
        let ym = 0.5 * (self.y0 + self.y1);
        let (x0, x1) = if q & 1 == 0 {
            (self.x0, xm)
        } else {
            (xm, self.x1)
        };
        let (y0, y1) = if q & 2 == 0 {
            (self.y0, ym)
        } else {
            (ym, self.y1)
        };
        Rect { x0, y0, x1, y1 }
    }
}

/// Identity of a tile: its grid cell and, for tiles split by the quadtree, the path of
/// quadrants taken (most significant first).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash, PartialOrd, Ord)]
pub struct TileId {
    /// Grid column.
    pub ix: i64,
    /// Grid row.
    pub iy: i64,
    /// Quadtree depth (0 = an unsplit grid tile).
    pub level: u8,
    /// Quadrant path, two bits per level.
    pub path: u64,
}

impl TileId {
    /// A grid tile.
    pub fn grid(ix: i64, iy: i64) -> Self {
        TileId {
            ix,
            iy,
            level: 0,
            path: 0,
        }
    }
    /// Child quadrant `q` of this tile.
    pub fn child(&self, q: u8) -> Self {
        TileId {
            level: self.level + 1,
            path: (self.path << 2) | q as u64,
            ..*self
        }
    }
}

/// A tile name for logs and file names: `x0_y0` of the grid cell in the input's coordinates
/// (so users can find a tile by its position), plus `_q` and the quadrant digits if split.
#[derive(Debug, Clone, Copy)]
pub struct TileName {
    /// The tile.
    pub id: TileId,
    /// Its grid cell's lower-left corner.
    pub origin: (f64, f64),
}

impl fmt::Display for TileName {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "{}_{}",
            fmt_coord(self.origin.0),
            fmt_coord(self.origin.1)
        )?;
        if self.id.level > 0 {
            write!(f, "_q")?;
            for l in (0..self.id.level).rev() {
                write!(f, "{}", (self.id.path >> (2 * l as u64)) & 3)?;
            }
        }
        Ok(())
    }
}

fn fmt_coord(v: f64) -> String {
    if v.fract() == 0.0 && v.abs() < 1e15 {
        format!("{}", v as i64)
    } else {
        format!("{v:.3}")
    }
}

/// The LAS record layout every point of a run is carried in: the output point format (with
/// its extra bytes) and coordinate transforms.
#[derive(Debug, Clone, PartialEq)]
pub struct RecordLayout {
    /// Point format (with extra bytes count; `is_compressed` false).
    pub format: Format,
    /// Scale/offset of x, y, z.
    pub transforms: Vector<Transform>,
    /// Bytes per record.
    pub record_len: usize,
    /// The extra-bytes attributes of the records (offsets from the start of the extra
    /// bytes), as the inputs' extra-bytes record describes them; empty when unknown.
    pub extras: Vec<ExtraField>,
    /// Per input file (by its index, the high bits of point ids): the 99th percentile of the
    /// intensities of its first points ([`crate::io::input::intensity_scales`]), 0 when they
    /// carry none. Filled only when a stage asks for it ([`crate::stages::Stage::needs_intensity_scales`]);
    /// empty otherwise.
    pub intensity_p99: std::sync::Arc<Vec<u16>>,
    /// Heights are in another unit than x and y by this factor (z in x/y units = z × this;
    /// [`crate::io::crs::UnitsReport::z_to_xy`]): the stages' coordinates
    /// ([`RecordLayout::stage_xyz`]) apply it, the records are left as they are. 1 mostly.
    pub z_to_xy: f64,
}

impl RecordLayout {
    /// Byte offset of red in a record of this layout (green and blue follow), if it has colour.
    pub fn rgb_offset(&self) -> Option<usize> {
        let f = &self.format;
        if !f.has_color {
            return None;
        }
        // LAS 1.4 R15 tables 7-16: legacy formats put colour after the 20-byte core and the
        // optional GPS time; formats 7, 8, 10 after the 30-byte extended core.
        Some(if f.is_extended {
            30
        } else if f.has_gps_time {
            28
        } else {
            20
        })
    }
    /// The red, green and blue of a record, given [`Self::rgb_offset`].
    pub fn rgb_at(record: &[u8], offset: usize) -> [u16; 3] {
        let c = |k: usize| u16::from_le_bytes([record[offset + 2 * k], record[offset + 2 * k + 1]]);
        [c(0), c(1), c(2)]
    }
    /// Builds the layout for a format and transforms.
    pub fn new(mut format: Format, transforms: Vector<Transform>) -> Self {
        format.is_compressed = false;
        RecordLayout {
            record_len: format.len() as usize,
            format,
            transforms,
            extras: Vec::new(),
            intensity_p99: Default::default(),
            z_to_xy: 1.0,
        }
    }

    /// Byte offset in a record of the extra-bytes attribute `name`, and its description.
    pub fn extra(&self, name: &str) -> Option<(usize, &ExtraField)> {
        let start = self.record_len - usize::from(self.format.extra_bytes);
        self.extras
            .iter()
            .find(|f| f.name == name)
            .filter(|f| f.offset + f.size <= usize::from(self.format.extra_bytes))
            .map(|f| (start + f.offset, f))
    }

    /// Decodes x, y, z of one record.
    #[inline]
    pub fn xyz(&self, rec: &[u8]) -> [f64; 3] {
        let r = |o: usize| i32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
        [
            self.transforms.x.direct(r(0)),
            self.transforms.y.direct(r(4)),
            self.transforms.z.direct(r(8)),
        ]
    }

    /// x, y, z of one record as the stages see them: z in the unit of x and y
    /// ([`RecordLayout::z_to_xy`]).
    #[inline]
    pub fn stage_xyz(&self, rec: &[u8]) -> [f64; 3] {
        let [x, y, z] = self.xyz(rec);
        [x, y, z * self.z_to_xy]
    }

    /// The classification code stored in a record.
    #[inline]
    pub fn classification(&self, rec: &[u8]) -> u8 {
        if self.format.is_extended {
            rec[16]
        } else {
            rec[15] & 0x1f
        }
    }

    /// (return number, number of returns) of a record.
    #[inline]
    pub fn returns(&self, rec: &[u8]) -> (u8, u8) {
        if self.format.is_extended {
            (rec[14] & 0x0f, rec[14] >> 4)
        } else {
            (rec[14] & 0x07, (rec[14] >> 3) & 0x07)
        }
    }

    /// Largest classification code the format can store.
    pub fn max_classification(&self) -> u8 {
        if self.format.is_extended {
            255
        } else {
            31
        }
    }

    /// Sets the classification code in a record (flags in legacy formats are kept).
    /// Codes above [`RecordLayout::max_classification`] are an error for the caller to prevent.
    #[inline]
    pub fn set_classification(&self, rec: &mut [u8], class: u8) {
        if self.format.is_extended {
            rec[16] = class;
        } else {
            rec[15] = (rec[15] & 0xe0) | (class & 0x1f);
        }
    }
}

/// A tile in memory: core points first, then buffer points.
#[derive(Debug)]
pub struct Tile {
    /// Identity.
    pub id: TileId,
    /// Printable name.
    pub name: TileName,
    /// Core rectangle; the buffer zone is `core.expanded(buffer_m)`.
    pub core: Rect,
    /// Buffer width (the tiling overlap around the core), metres.
    pub buffer_m: f64,
    /// Raw records, `record_len` bytes each.
    pub records: Vec<u8>,
    /// Global point ids (input file index << 40 | point index in file), one per record.
    pub ids: Vec<u64>,
    /// Decoded coordinates, one per record.
    pub xyz: Vec<[f64; 3]>,
    /// Number of core points (the first `n_core` records).
    pub n_core: usize,
    /// Segment id per record (0 = none) when a segmentation stage ran, else empty.
    pub segments: Vec<u32>,
    /// Segments with core points, when a segmentation stage ran.
    pub segment_table: Vec<SegmentRow>,
}

/// One output segment of a segmentation (region growing), as tiles carry it.
#[derive(Debug, Clone, PartialEq, Serialize, serde::Deserialize)]
pub struct SegmentInfo {
    /// Segment id (1..=N).
    pub id: u32,
    /// Number of points.
    pub n: usize,
    /// Unit normal of the least-squares plane (z ≥ 0, else y ≥ 0, else x ≥ 0).
    pub normal: [f64; 3],
    /// Plane offset in input coordinates: `normal · p = d`.
    pub d: f64,
    /// Mean input colour on an 8-bit scale (0–255), zeros without colour.
    pub mean_rgb: [f64; 3],
    /// RMS orthogonal distance of the members to the plane, metres.
    pub rms: f64,
}

/// One row of a tile's segment table.
#[derive(Debug, Clone, PartialEq)]
pub struct SegmentRow {
    /// The segment (id, plane, colour, all its points in core + buffer).
    pub info: SegmentInfo,
    /// How many of its points are core points of the tile.
    pub core_points: usize,
}

impl Tile {
    /// The zone a stage with context `context_m` works on: the core widened by that context,
    /// as far as the tile's buffer reaches ([`stage_context_m`]).
    pub fn context_zone(&self, context_m: f64) -> Rect {
        self.core
            .expanded(stage_context_m(context_m, self.buffer_m))
    }
    /// The points a stage with context `context_m` works on: the core points and the buffer
    /// points within that context of a core point ([`near_points`]), as far as the buffer
    /// reaches. Measured against the core's points rather than its rectangle, so a tile
    /// whose core the data crosses only in part (a drive's curve or end) does not work on the
    /// strip around the empty rest of its rectangle. (On the demo it changes little: its
    /// 3- and 10-point end tiles hold points on the street's centre line.)
    pub fn context_mask(&self, context_m: f64) -> Vec<bool> {
        let c = stage_context_m(context_m, self.buffer_m);
        near_points(&self.xyz, self.n_core, self.context_zone(context_m), c)
    }
    /// Total points (core + buffer).
    pub fn len(&self) -> usize {
        self.ids.len()
    }
    /// True if the tile holds no points.
    pub fn is_empty(&self) -> bool {
        self.ids.is_empty()
    }
}

/// The context a stage gets: what it asks for (`context_m`, beyond the core), as far as the
/// tiling buffer (`buffer_m`, the overlap the tiles carry) reaches. The one place the two are
/// combined; the run plan and the tiles both use it.
pub fn stage_context_m(context_m: f64, buffer_m: f64) -> f64 {
    context_m.min(buffer_m)
}

/// Flags the points of `xyz` that are among the first `n_core` or lie in `zone` within about
/// `c` of one of those (in x and y). The test is a grid over `zone` whose cells holding a core
/// point are widened by `c`: a superset of the points within `c` (Chebyshev) of a core
/// point, reaching at most `c` plus two cells beyond them. Cells are `c / 8`, coarser only
/// when the zone would need more than 2048 of them a side (≤ 4 M flags) or many more cells
/// than there are points.
pub fn near_points(xyz: &[[f64; 3]], n_core: usize, zone: Rect, c: f64) -> Vec<bool> {
    let n_core = n_core.min(xyz.len());
    let side = (zone.x1 - zone.x0).max(zone.y1 - zone.y0);
    if n_core == 0 || c.is_nan() || c <= 0.0 || !side.is_finite() || side <= 0.0 {
        return (0..xyz.len()).map(|i| i < n_core).collect();
    }
    // Few points in a large zone (sparse inputs get large tiles) also coarsen the cells:
    // the grid never has many more cells than the tile has points.
    let most = (4 * xyz.len() + 65_536) as f64;
    let g = (c / 8.0).max(side / 2048.0).max(side / most.sqrt());
    let nx = ((zone.x1 - zone.x0) / g).ceil().max(1.0) as usize;
    let ny = ((zone.y1 - zone.y0) / g).ceil().max(1.0) as usize;
    let cell = |p: &[f64; 3]| -> Option<(usize, usize)> {
        if !zone.contains(p[0], p[1]) {
            return None;
        }
        let ix = (((p[0] - zone.x0) / g) as usize).min(nx - 1);
        let iy = (((p[1] - zone.y0) / g) as usize).min(ny - 1);
        Some((ix, iy))
    };
    let mut occ = vec![0u32; nx * ny];
    for p in &xyz[..n_core] {
        if let Some((ix, iy)) = cell(p) {
            occ[iy * nx + ix] = 1;
        }
    }
    // Within c of a core point: at most floor(c / g) + 1 cells apart in each axis.
    let r = (c / g).floor() as usize + 1;
    let near = dilate(&dilate(&occ, nx, ny, r, true), nx, ny, r, false);
    xyz.iter()
        .enumerate()
        .map(|(i, p)| i < n_core || cell(p).is_some_and(|(ix, iy)| near[iy * nx + ix] > 0))
        .collect()
}

/// Cells of an `nx × ny` grid with an occupied cell within `r` along rows (`rows`) or columns:
/// counts by a sliding window over prefix sums.
fn dilate(occ: &[u32], nx: usize, ny: usize, r: usize, rows: bool) -> Vec<u32> {
    let (len, lines) = if rows { (nx, ny) } else { (ny, nx) };
    let at = |line: usize, k: usize| if rows { line * nx + k } else { k * nx + line };
    let mut out = vec![0u32; occ.len()];
    let mut prefix = vec![0u32; len + 1];
    for line in 0..lines {
        for k in 0..len {
            prefix[k + 1] = prefix[k] + (occ[at(line, k)] > 0) as u32;
        }
        for k in 0..len {
            let lo = k.saturating_sub(r);
            let hi = (k + r + 1).min(len);
            out[at(line, k)] = prefix[hi] - prefix[lo];
        }
    }
    out
}

/// Builds the global id of point `index` of input file `file`.
#[inline]
pub fn point_id(file: usize, index: u64) -> u64 {
    ((file as u64) << 40) | index
}

/// The input file index of global point id `id` ([`point_id`]).
#[inline]
pub fn file_of(id: u64) -> usize {
    (id >> 40) as usize
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rect(x0: f64, y0: f64, x1: f64, y1: f64) -> Rect {
        Rect { x0, y0, x1, y1 }
    }

    #[test]
    fn near_points_keep_every_point_within_the_context_of_a_core_point() {
        // Core [0, 50)², two core points; context 5.
        let core = rect(0.0, 0.0, 50.0, 50.0);
        let c = 5.0;
        let mut xyz = vec![[10.0, 49.9, 0.0], [49.0, 20.0, 0.0]];
        let n_core = xyz.len();
        // A lattice of buffer points over the zone, 0.37 m apart.
        let mut v = -5.0;
        while v < 55.0 {
            let mut u = -5.0;
            while u < 55.0 {
                if !core.contains(u, v) {
                    xyz.push([u, v, 0.0]);
                }
                u += 0.37;
            }
            v += 0.37;
        }
        let zone = core.expanded(c);
        let m = near_points(&xyz, n_core, zone, c);
        assert!(m[..n_core].iter().all(|&b| b));
        let g = c / 8.0;
        let (mut kept, mut all) = (0, 0);
        for (p, &keep) in xyz.iter().zip(&m).skip(n_core) {
            let d = xyz[..n_core]
                .iter()
                .map(|q| (p[0] - q[0]).abs().max((p[1] - q[1]).abs()))
                .fold(f64::INFINITY, f64::min);
            if zone.contains(p[0], p[1]) && d <= c {
                assert!(keep, "{p:?} is {d} m from a core point");
            }
            if keep {
                assert!(d <= c + 2.0 * g + 1e-9, "{p:?} kept at {d} m");
                kept += 1;
            }
            all += 1;
        }
        // Two small squares of the strip, not the strip around the whole core.
        assert!(kept * 5 < all, "{kept} of {all}");
    }

    #[test]
    fn near_points_degenerate_inputs() {
        let core = rect(0.0, 0.0, 10.0, 10.0);
        let xyz = vec![
            [1.0, 1.0, 0.0],
            [-0.5, 1.0, 0.0],
            [10.5, 1.0, 0.0],
            [f64::NAN, 1.0, 0.0],
        ];
        let zone = core.expanded(2.0);
        assert_eq!(near_points(&xyz, 1, zone, 2.0), [true, true, false, false]);
        // No context: the core points only; no core points: nothing.
        assert_eq!(near_points(&xyz, 1, core, 0.0), [true, false, false, false]);
        assert_eq!(near_points(&xyz, 0, zone, 2.0), [false; 4]);
    }
}

/// One scan as a sensor delivers it: `rows × cols` points in the sensor frame (rows = 1 for an
/// unorganised scan), with optional 16-bit colour and ring numbers.
#[derive(Debug, Clone, Copy)]
pub struct ScanPoints<'a> {
    /// Rows (rings) of an organised scan; 1 for an unorganised one.
    pub rows: usize,
    /// Columns.
    pub cols: usize,
    /// Sensor-frame coordinates; non-finite for missing returns.
    pub xyz: &'a [[f32; 3]],
    /// 16-bit RGB per point, when the scan has colour.
    pub rgb: Option<&'a [[u16; 3]]>,
    /// Ring number per point, when the scan has them: tells row- from column-major layouts.
    pub ring: Option<&'a [u32]>,
}

/// One attribute described by an extra-bytes VLR.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ExtraField {
    /// Attribute name.
    pub name: String,
    /// Data type code (0 = opaque bytes, 1..=10 scalars, 11..=30 deprecated arrays).
    pub data_type: u8,
    /// Byte offset from the start of the extra bytes of a record.
    pub offset: usize,
    /// Size in bytes.
    pub size: usize,
}

/// Name of an ASPRS LAS 1.4 class code, or of tessera's street-level codes (64–71).
pub fn class_name(code: u8) -> &'static str {
    match code {
        0 => "created, never classified",
        1 => "unclassified",
        2 => "ground",
        3 => "low vegetation",
        4 => "medium vegetation",
        5 => "high vegetation",
        6 => "building",
        7 => "low point (noise)",
        8 => "reserved / model key",
        9 => "water",
        10 => "rail",
        11 => "road surface",
        12 => "reserved / overlap",
        13 => "wire guard",
        14 => "wire conductor",
        15 => "transmission tower",
        16 => "wire connector",
        17 => "bridge deck",
        18 => "high noise",
        64 => "cycle path",
        65 => "footpath",
        66 => "kerb",
        67 => "grass / terrain",
        68 => "street furniture",
        69 => "pole",
        70 => "vehicle",
        71 => "lane marking",
        _ => "user class",
    }
}
