//! Top-view rasters of a run's output tiles (class, segment, height, errors against truth),
//! built tile by tile at one fixed resolution: memory is the raster (≤ [`MAX_PIXELS`] cells)
//! plus one chunk of records, whatever the number of points.

use crate::error::{Error, Result};
use crate::io::output::{RecordFields, WrittenRecords, TRUTH_FIELD};
pub use crate::model::class_name;
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Cells of the overview at most (its side follows the region's aspect): 2^21 cells of 12
/// bytes are 24 MiB, the report's whole working memory.
pub const MAX_PIXELS: usize = 1 << 21;
/// Longest side of the overview, pixels.
pub const MAX_SIDE: usize = 2048;
/// Finest cell size, metres (or the unit of the tiles' coordinates).
pub const MIN_CELL: f64 = 0.05;

/// One output tile as the report sees it: file and header bounds.
#[derive(Debug, Clone)]
pub struct TileExtent {
    /// Tile name (file stem).
    pub name: String,
    /// Path of the tile.
    pub path: PathBuf,
    /// min x, min y, max x, max y of its points.
    pub bounds: [f64; 4],
    /// Points in the file.
    pub points: u64,
}

/// Reads the header bounds of `files` (names relative to `dir`).
pub fn tile_extents(dir: &Path, files: &[(String, String)]) -> Result<Vec<TileExtent>> {
    let mut out = Vec::with_capacity(files.len());
    for (name, file) in files {
        let path = dir.join(file);
        let r = las::Reader::from_path(&path).map_err(|e| Error::las(&path, e))?;
        let h = r.header();
        let b = h.bounds();
        out.push(TileExtent {
            name: name.clone(),
            path,
            bounds: [b.min.x, b.min.y, b.max.x, b.max.y],
            points: h.number_of_points(),
        });
    }
    Ok(out)
}

/// The rasters: per cell the highest point's class, segment id and height, and how many of
/// the cell's points disagree with the truth attribute (when the tiles carry one).
pub struct Overview {
    /// Lower-left corner (x, y) of the raster.
    pub origin: [f64; 2],
    /// Cell size.
    pub cell: f64,
    /// Width and height, cells.
    pub width: usize,
    /// Height, cells.
    pub height: usize,
    top_z: Vec<f32>,
    class: Vec<u8>,
    segment: Vec<u32>,
    /// Points per cell and wrong points per cell (saturating), only with truth.
    total: Vec<u16>,
    wrong: Vec<u16>,
    /// Truth attribute found in the tiles.
    pub truth_field: Option<String>,
    /// (truth, result) → points, when the tiles carry truth.
    pub confusion: BTreeMap<(u8, u8), u64>,
    /// Points per class code.
    pub class_points: BTreeMap<u8, u64>,
    /// Points rasterised.
    pub points: u64,
    /// Whether any tile carried a segment id.
    pub has_segments: bool,
}

impl Overview {
    /// An empty raster covering `tiles` (their header bounds).
    pub fn new(tiles: &[TileExtent]) -> Overview {
        let mut b = [
            f64::INFINITY,
            f64::INFINITY,
            f64::NEG_INFINITY,
            f64::NEG_INFINITY,
        ];
        for t in tiles.iter().filter(|t| t.points > 0) {
            b[0] = b[0].min(t.bounds[0]);
            b[1] = b[1].min(t.bounds[1]);
            b[2] = b[2].max(t.bounds[2]);
            b[3] = b[3].max(t.bounds[3]);
        }
        Overview::with_geometry(Geometry::for_bounds(b))
    }

    /// An empty raster of `g`.
    pub fn with_geometry(g: Geometry) -> Overview {
        let n = g.width * g.height;
        Overview {
            origin: g.origin,
            cell: g.cell,
            width: g.width,
            height: g.height,
            top_z: vec![f32::NEG_INFINITY; n],
            class: vec![0; n],
            segment: vec![0; n],
            total: Vec::new(),
            wrong: Vec::new(),
            truth_field: None,
            confusion: BTreeMap::new(),
            class_points: BTreeMap::new(),
            points: 0,
            has_segments: false,
        }
    }

    /// Cell index of (x, y); row 0 is the north edge.
    #[cfg(test)]
    fn index(&self, x: f64, y: f64) -> Option<usize> {
        let c = ((x - self.origin[0]) / self.cell).floor();
        let r = ((y - self.origin[1]) / self.cell).floor();
        if c < 0.0 || r < 0.0 || c >= self.width as f64 || r >= self.height as f64 {
            return None;
        }
        Some((self.height - 1 - r as usize) * self.width + c as usize)
    }

    /// Adds every tile, two or more at a time (rayon's pool): each is rasterised into a patch
    /// covering its own bounds, merged under a lock. Memory: the raster, and per thread one
    /// patch and one chunk of records.
    pub fn add_tiles(&mut self, tiles: &[TileExtent]) -> Result<()> {
        use rayon::prelude::*;
        let geometry = self.geometry();
        let shared = std::sync::Mutex::new(std::mem::replace(self, Overview::placeholder()));
        let res = tiles.par_iter().try_for_each(|t| {
            let patch = Patch::of_tile(&geometry, t)?;
            if let Ok(mut o) = shared.lock() {
                o.merge(patch);
            }
            Ok::<(), Error>(())
        });
        *self = shared
            .into_inner()
            .map_err(|_| Error::Internal("report raster lock poisoned".into()))?;
        res
    }

    fn placeholder() -> Overview {
        Overview::with_geometry(Geometry::for_bounds([0.0, 0.0, 1.0, 1.0]))
    }

    /// Where the raster lies.
    pub fn geometry(&self) -> Geometry {
        Geometry {
            origin: self.origin,
            cell: self.cell,
            width: self.width,
            height: self.height,
        }
    }

    fn merge(&mut self, p: Patch) {
        self.points += p.points;
        self.has_segments |= p.has_segments;
        for (k, &n) in p.class_points.iter().enumerate().filter(|(_, n)| **n > 0) {
            *self.class_points.entry(k as u8).or_default() += n;
        }
        for (k, &n) in p.confusion.iter().enumerate().filter(|(_, n)| **n > 0) {
            *self.confusion.entry(((k >> 8) as u8, k as u8)).or_default() += n;
        }
        if let Some(f) = p.truth_field {
            self.truth_field = Some(f);
            if self.total.is_empty() {
                self.total = vec![0; self.class.len()];
                self.wrong = vec![0; self.class.len()];
            }
        }
        for r in 0..p.rows {
            for c in 0..p.cols {
                let j = r * p.cols + c;
                let i = (p.row0 + r) * self.width + p.col0 + c;
                if !p.total.is_empty() {
                    self.total[i] = self.total[i].saturating_add(p.total[j]);
                    self.wrong[i] = self.wrong[i].saturating_add(p.wrong[j]);
                }
                let cur = (self.top_z[i], self.class[i], self.segment[i]);
                if above((p.top_z[j], p.class[j], p.segment[j]), cur) {
                    self.top_z[i] = p.top_z[j];
                    self.class[i] = p.class[j];
                    self.segment[i] = p.segment[j];
                }
            }
        }
    }

    fn occupied(&self, i: usize) -> bool {
        self.top_z[i] > f32::NEG_INFINITY
    }

    /// Class colours (empty cells white).
    pub fn class_rgb(&self) -> Vec<u8> {
        self.render(|o, i| o.occupied(i).then(|| class_colour(o.class[i])))
    }

    /// Segment ids in random colours (points in no segment grey).
    pub fn segment_rgb(&self) -> Vec<u8> {
        self.render(|o, i| {
            o.occupied(i).then(|| match o.segment[i] {
                0 => [190, 190, 190],
                s => hashed_colour(s),
            })
        })
    }

    /// Height of the highest point, coloured from low (blue) to high (yellow) between the 2nd
    /// and 98th percentiles, shaded by the slope (light from the north-west).
    pub fn height_rgb(&self) -> Vec<u8> {
        let (lo, hi) = self.height_range();
        let span = (hi - lo).max(1e-3);
        let cell = self.cell as f32;
        self.render(|o, i| {
            if !o.occupied(i) {
                return None;
            }
            let z = o.top_z[i];
            let (r, c) = (i / o.width, i % o.width);
            let at = |rr: usize, cc: usize| {
                let j = rr * o.width + cc;
                if o.occupied(j) {
                    o.top_z[j]
                } else {
                    z
                }
            };
            let dzdx =
                (at(r, (c + 1).min(o.width - 1)) - at(r, c.saturating_sub(1))) / (2.0 * cell);
            let dzdy =
                (at(r.saturating_sub(1), c) - at((r + 1).min(o.height - 1), c)) / (2.0 * cell);
            // Lambert shading, sun at azimuth 315°, elevation 45°.
            let (nx, ny, nz) = (-dzdx, -dzdy, 1.0f32);
            let len = (nx * nx + ny * ny + nz * nz).sqrt();
            let (sx, sy, sz) = (-0.5f32, 0.5f32, std::f32::consts::FRAC_1_SQRT_2);
            let shade = ((nx * sx + ny * sy + nz * sz) / len).clamp(0.0, 1.0);
            let t = ((z - lo) / span).clamp(0.0, 1.0);
            let base = ramp(t);
            let k = 0.45 + 0.55 * shade;
            Some(base.map(|v| (f32::from(v) * k).round() as u8))
        })
    }

    /// The error map: cells with wrong points in red (darker: a larger share wrong), cells
    /// with only right points grey; `None` without truth.
    pub fn error_rgb(&self) -> Option<Vec<u8>> {
        if self.total.is_empty() {
            return None;
        }
        Some(self.render(|o, i| {
            if o.total[i] == 0 {
                return o.occupied(i).then_some([225, 225, 225]);
            }
            let f = f32::from(o.wrong[i]) / f32::from(o.total[i]);
            if o.wrong[i] == 0 {
                Some([200, 200, 200])
            } else {
                let f = 0.35 + 0.65 * f;
                Some([
                    (255.0 - 55.0 * f) as u8,
                    (170.0 * (1.0 - f)) as u8,
                    (170.0 * (1.0 - f)) as u8,
                ])
            }
        }))
    }

    /// The 2nd and 98th percentiles of the cells' heights.
    pub fn height_range(&self) -> (f32, f32) {
        let zs = self.top_z.iter().copied().filter(|z| z.is_finite());
        let (mut lo, mut hi) = (f32::INFINITY, f32::NEG_INFINITY);
        for z in zs.clone() {
            lo = lo.min(z);
            hi = hi.max(z);
        }
        if !lo.is_finite() {
            return (0.0, 1.0);
        }
        let bins = 1024usize;
        let span = (hi - lo).max(1e-6);
        let mut hist = vec![0u64; bins];
        let mut n = 0u64;
        for z in zs {
            hist[(((z - lo) / span) * (bins - 1) as f32) as usize] += 1;
            n += 1;
        }
        let at = |q: f64| {
            let want = (q * n as f64).ceil() as u64;
            let mut acc = 0;
            for (b, c) in hist.iter().enumerate() {
                acc += c;
                if acc >= want.max(1) {
                    return lo + span * b as f32 / (bins - 1) as f32;
                }
            }
            hi
        };
        (at(0.02), at(0.98))
    }

    fn render(&self, colour: impl Fn(&Overview, usize) -> Option<[u8; 3]>) -> Vec<u8> {
        let mut rgb = Vec::with_capacity(self.width * self.height * 3);
        for i in 0..self.width * self.height {
            rgb.extend_from_slice(&colour(self, i).unwrap_or([255, 255, 255]));
        }
        rgb
    }

    /// Pixel rectangle (x, y, w, h) of world bounds [min x, min y, max x, max y].
    pub fn pixel_rect(&self, b: [f64; 4]) -> [f64; 4] {
        let x = (b[0] - self.origin[0]) / self.cell;
        let y = self.height as f64 - (b[3] - self.origin[1]) / self.cell;
        [x, y, (b[2] - b[0]) / self.cell, (b[3] - b[1]) / self.cell]
    }
}

/// Where the raster lies (summary.json `report_raster`, so `tessera report` draws the
/// same cells as the run did).
#[derive(Debug, Clone, Copy, Default, PartialEq, serde::Serialize, serde::Deserialize)]
pub struct Geometry {
    /// Lower-left corner (x, y).
    pub origin: [f64; 2],
    /// Cell size.
    pub cell: f64,
    /// Columns.
    pub width: usize,
    /// Rows.
    pub height: usize,
}

impl Geometry {
    /// The raster of a region [min x, min y, max x, max y]: cells of at least [`MIN_CELL`],
    /// at most [`MAX_SIDE`] per side and [`MAX_PIXELS`] in all.
    pub fn for_bounds(b: [f64; 4]) -> Geometry {
        Self::for_bounds_within(b, MAX_PIXELS)
    }

    /// [`Geometry::for_bounds`] with at most `max_cells` cells (at least 64 × 64): coarser
    /// cells under a small memory budget.
    pub fn for_bounds_within(mut b: [f64; 4], max_cells: usize) -> Geometry {
        let max_cells = max_cells.clamp(64 * 64, MAX_PIXELS);
        if !b.iter().all(|v| v.is_finite()) || b[2] < b[0] || b[3] < b[1] {
            b = [0.0, 0.0, 1.0, 1.0];
        }
        let (w, h) = ((b[2] - b[0]).max(MIN_CELL), (b[3] - b[1]).max(MIN_CELL));
        let mut cell = (w.max(h) / MAX_SIDE as f64)
            .max((w * h / max_cells as f64).sqrt())
            .max(MIN_CELL);
        // Rounding the sides up can overshoot the cell budget by a row or column.
        loop {
            // (The tolerance keeps w / cell = 2048.000…1 at 2048.)
            let side = |len: f64| (len / cell - 1e-9).ceil() as usize;
            let (width, height) = (side(w), side(h));
            if width <= MAX_SIDE && height <= MAX_SIDE && width * height <= max_cells {
                return Geometry {
                    origin: [b[0], b[1]],
                    cell,
                    width: width.max(1),
                    height: height.max(1),
                };
            }
            cell *= 1.001;
        }
    }

    /// Memory the raster takes: per cell the top height (f32), class (u8), segment (u32),
    /// points and wrong points (u16 each).
    pub fn bytes(&self) -> u64 {
        (self.width * self.height) as u64 * 13
    }

    /// Whether a raster of this size is one the report would make (a summary is input).
    pub fn is_sane(&self) -> bool {
        self.cell.is_finite()
            && self.cell > 0.0
            && self.origin.iter().all(|v| v.is_finite())
            && (1..=MAX_SIDE).contains(&self.width)
            && (1..=MAX_SIDE).contains(&self.height)
            && self.width * self.height <= MAX_PIXELS
    }

    /// Column and row (row 0 north) of (x, y), clamped into the raster (the tiles' points
    /// lie within their header bounds, which the raster covers).
    fn cell_of(&self, x: f64, y: f64) -> (usize, usize) {
        let c = ((x - self.origin[0]) / self.cell).floor().max(0.0) as usize;
        let r = ((y - self.origin[1]) / self.cell).floor().max(0.0) as usize;
        (
            c.min(self.width - 1),
            self.height - 1 - r.min(self.height - 1),
        )
    }
}

/// One tile's share of the raster.
struct Patch {
    col0: usize,
    row0: usize,
    cols: usize,
    rows: usize,
    top_z: Vec<f32>,
    class: Vec<u8>,
    segment: Vec<u32>,
    total: Vec<u16>,
    wrong: Vec<u16>,
    truth_field: Option<String>,
    /// Points by truth × 256 + result (empty without truth).
    confusion: Vec<u64>,
    /// Points by class code.
    class_points: Vec<u64>,
    points: u64,
    has_segments: bool,
}

impl Patch {
    /// An empty patch covering cells c0..=c1 × r0..=r1.
    fn empty(g: &Geometry, lo: (usize, usize), hi: (usize, usize), f: &RecordFields) -> Patch {
        let (c0, r0) = (lo.0.min(hi.0), lo.1.min(hi.1));
        let (cols, rows) = (lo.0.max(hi.0) - c0 + 1, lo.1.max(hi.1) - r0 + 1);
        debug_assert!(c0 + cols <= g.width && r0 + rows <= g.height);
        let n = cols * rows;
        let truth = f.truth.is_some();
        Patch {
            col0: c0,
            row0: r0,
            cols,
            rows,
            top_z: vec![f32::NEG_INFINITY; n],
            class: vec![0; n],
            segment: vec![0; n],
            total: if truth { vec![0; n] } else { Vec::new() },
            wrong: if truth { vec![0; n] } else { Vec::new() },
            truth_field: truth.then(|| TRUTH_FIELD.to_string()),
            confusion: if truth { vec![0; 1 << 16] } else { Vec::new() },
            class_points: vec![0; 256],
            points: 0,
            has_segments: f.segment.is_some(),
        }
    }

    /// x and y of a record.
    fn xy(f: &RecordFields, rec: &[u8]) -> (f64, f64) {
        let i32_at = |o: usize| i32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
        (
            f.transforms.x.direct(i32_at(0)),
            f.transforms.y.direct(i32_at(4)),
        )
    }

    /// A patch of the records of one written block (whole records of `f`).
    fn of_records(g: &Geometry, f: &RecordFields, records: &[u8]) -> Patch {
        let (mut lo, mut hi) = ((usize::MAX, usize::MAX), (0, 0));
        for rec in records.chunks_exact(f.record_len) {
            let (x, y) = Self::xy(f, rec);
            let (c, r) = g.cell_of(x, y);
            lo = (lo.0.min(c), lo.1.min(r));
            hi = (hi.0.max(c), hi.1.max(r));
        }
        if lo.0 == usize::MAX {
            lo = (0, 0);
        }
        let mut p = Patch::empty(g, lo, hi, f);
        for rec in records.chunks_exact(f.record_len) {
            p.add(g, f, rec);
        }
        p
    }

    /// A patch of a tile file, decoded (a tile the run did not write itself: an earlier,
    /// resumed run's, or `tessera report`).
    fn of_tile(g: &Geometry, t: &TileExtent) -> Result<Patch> {
        crate::io::guard::check_path(&t.path)?;
        let r = las::Reader::from_path(&t.path).map_err(|e| Error::las(&t.path, e))?;
        let h = r.header().clone();
        drop(r);
        let f = RecordFields::of_header(&h);
        let lo = g.cell_of(t.bounds[0], t.bounds[1]);
        let hi = g.cell_of(t.bounds[2], t.bounds[3]);
        let mut p = Patch::empty(g, lo, hi, &f);
        crate::io::output::for_each_record(&t.path, &h, &f, true, &mut |rec| p.add(g, &f, rec))?;
        Ok(p)
    }

    /// Adds one record: counted always, drawn when inside the patch.
    fn add(&mut self, g: &Geometry, f: &RecordFields, rec: &[u8]) {
        let (x, y) = Self::xy(f, rec);
        let z = f
            .transforms
            .z
            .direct(i32::from_le_bytes([rec[8], rec[9], rec[10], rec[11]])) as f32;
        let class = rec[f.class_at] & f.class_mask;
        self.points += 1;
        self.class_points[usize::from(class)] += 1;
        if let Some(o) = f.truth {
            self.confusion[usize::from(rec[o]) << 8 | usize::from(class)] += 1;
        }
        let (c, r) = g.cell_of(x, y);
        if c < self.col0
            || r < self.row0
            || c >= self.col0 + self.cols
            || r >= self.row0 + self.rows
        {
            return; // outside the header's bounds: not drawn
        }
        let j = (r - self.row0) * self.cols + (c - self.col0);
        if let Some(o) = f.truth {
            self.total[j] = self.total[j].saturating_add(1);
            if rec[o] != class {
                self.wrong[j] = self.wrong[j].saturating_add(1);
            }
        }
        let segment = match f.segment {
            // 64-bit ids are folded to 32 bits: only their colour is drawn.
            Some((o, size)) => {
                let lo = u32::from_le_bytes([rec[o], rec[o + 1], rec[o + 2], rec[o + 3]]);
                let hi = if size == 8 {
                    u32::from_le_bytes([rec[o + 4], rec[o + 5], rec[o + 6], rec[o + 7]])
                } else {
                    0
                };
                lo ^ hi.rotate_left(16)
            }
            None => 0,
        };
        if above(
            (z, class, segment),
            (self.top_z[j], self.class[j], self.segment[j]),
        ) {
            self.top_z[j] = z;
            self.class[j] = class;
            self.segment[j] = segment;
        }
    }
}

/// Draws the records a run writes, tile by tile as they are written (no second decoding):
/// the run's [`WrittenRecords`] observer.
pub struct OverviewSink {
    geometry: Geometry,
    state: std::sync::Mutex<(Overview, std::collections::HashSet<String>)>,
}

impl std::fmt::Debug for OverviewSink {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("OverviewSink")
            .field("geometry", &self.geometry)
            .finish()
    }
}

impl OverviewSink {
    /// A sink drawing into a raster of `geometry`.
    pub fn new(geometry: Geometry) -> OverviewSink {
        OverviewSink {
            geometry,
            state: std::sync::Mutex::new((
                Overview::with_geometry(geometry),
                std::collections::HashSet::new(),
            )),
        }
    }

    /// The raster so far and the names of the tiles drawn into it.
    pub fn take(&self) -> (Overview, std::collections::HashSet<String>) {
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        std::mem::replace(
            &mut *st,
            (Overview::placeholder(), std::collections::HashSet::new()),
        )
    }
}

impl WrittenRecords for OverviewSink {
    fn written(&self, tile: &str, fields: &RecordFields, records: &[u8]) -> Result<()> {
        let patch = Patch::of_records(&self.geometry, fields, records);
        let mut st = self.state.lock().unwrap_or_else(|e| e.into_inner());
        st.0.merge(patch);
        if !st.1.contains(tile) {
            st.1.insert(tile.to_string());
        }
        Ok(())
    }
}

/// Whether a point (height, class, segment) is drawn over a cell's current one: the higher
/// wins, ties go to the larger class and segment, so the raster does not depend on the order
/// tiles and blocks arrive in (the run draws while writing, `tessera report` while decoding).
fn above(a: (f32, u8, u32), b: (f32, u8, u32)) -> bool {
    a.0 > b.0 || (a.0 == b.0 && (a.1, a.2) > (b.1, b.2))
}

/// Encodes an RGB raster as PNG.
pub fn png(rgb: &[u8], width: usize, height: usize) -> Result<Vec<u8>> {
    let mut out = Vec::new();
    let mut enc = png::Encoder::new(&mut out, width as u32, height as u32);
    enc.set_color(png::ColorType::Rgb);
    enc.set_depth(png::BitDepth::Eight);
    enc.set_compression(png::Compression::Fast);
    let err = |e: png::EncodingError| Error::Internal(format!("PNG encoding: {e}"));
    let mut w = enc.write_header().map_err(err)?;
    w.write_image_data(rgb).map_err(err)?;
    w.finish().map_err(err)?;
    Ok(out)
}

/// Display colour of a class code.
pub fn class_colour(code: u8) -> [u8; 3] {
    match code {
        0 | 1 => [150, 150, 150],
        2 => [166, 120, 70],
        3 => [170, 220, 120],
        4 => [90, 180, 70],
        5 => [30, 120, 40],
        6 => [220, 70, 60],
        7 | 18 => [255, 0, 255],
        9 => [60, 120, 230],
        10 => [120, 80, 120],
        11 => [70, 70, 80],
        17 => [200, 170, 120],
        64 => [205, 90, 120],
        65 => [230, 200, 140],
        66 => [250, 250, 110],
        67 => [140, 200, 90],
        69 => [40, 170, 230],
        70 => [255, 150, 20],
        71 => [250, 250, 250],
        c => hashed_colour(u32::from(c) + 1000),
    }
}

/// A stable, saturated colour for an id.
fn hashed_colour(id: u32) -> [u8; 3] {
    let mut h = u64::from(id).wrapping_mul(0x9E37_79B9_7F4A_7C15);
    h ^= h >> 29;
    let hue = (h % 360) as f32;
    let s = 0.55 + ((h >> 12) % 40) as f32 / 100.0;
    let v = 0.65 + ((h >> 20) % 35) as f32 / 100.0;
    hsv(hue, s, v)
}

fn hsv(h: f32, s: f32, v: f32) -> [u8; 3] {
    let c = v * s;
    let x = c * (1.0 - ((h / 60.0) % 2.0 - 1.0).abs());
    let (r, g, b) = match (h / 60.0) as u32 {
        0 => (c, x, 0.0),
        1 => (x, c, 0.0),
        2 => (0.0, c, x),
        3 => (0.0, x, c),
        4 => (x, 0.0, c),
        _ => (c, 0.0, x),
    };
    let m = v - c;
    [r, g, b].map(|u| ((u + m) * 255.0).round() as u8)
}

/// Blue → teal → green → yellow ramp.
fn ramp(t: f32) -> [u8; 3] {
    const STOPS: [[f32; 3]; 5] = [
        [48.0, 18.0, 120.0],
        [40.0, 100.0, 160.0],
        [30.0, 160.0, 135.0],
        [120.0, 200.0, 70.0],
        [250.0, 230.0, 40.0],
    ];
    let f = t * (STOPS.len() - 1) as f32;
    let k = (f as usize).min(STOPS.len() - 2);
    let u = f - k as f32;
    let (a, b) = (STOPS[k], STOPS[k + 1]);
    [0, 1, 2].map(|j| (a[j] + (b[j] - a[j]) * u).round() as u8)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn extent(b: [f64; 4]) -> TileExtent {
        TileExtent {
            name: "t".into(),
            path: PathBuf::new(),
            bounds: b,
            points: 1,
        }
    }

    #[test]
    fn raster_size_is_bounded_whatever_the_extent() {
        for b in [
            [0.0, 0.0, 300.0, 17.0],
            [0.0, 0.0, 100_000.0, 100_000.0],
            [0.0, 0.0, 1e6, 10.0],
            [5.0, 5.0, 5.0, 5.0],
        ] {
            let o = Overview::new(&[extent(b)]);
            assert!(
                o.width * o.height <= MAX_PIXELS,
                "{b:?}: {}×{}",
                o.width,
                o.height
            );
            assert!(o.width <= MAX_SIDE && o.height <= MAX_SIDE);
            assert!(o.cell >= MIN_CELL);
            // The extent fits.
            assert!(o.width as f64 * o.cell >= b[2] - b[0] - 1e-9);
            assert!(o.height as f64 * o.cell >= b[3] - b[1] - 1e-9);
        }
        // Under a small budget: at most the cells it allows, the extent still covered.
        for cells in [1usize, 10_000, 200_000] {
            let b = [0.0, 0.0, 100_000.0, 30_000.0];
            let g = Geometry::for_bounds_within(b, cells);
            assert!(g.width * g.height <= cells.max(64 * 64), "{cells}: {g:?}");
            assert!(g.width as f64 * g.cell >= b[2] - b[0] - 1e-9);
            assert!(g.height as f64 * g.cell >= b[3] - b[1] - 1e-9);
            assert_eq!(g.bytes(), 13 * (g.width * g.height) as u64);
        }
        let o = Overview::new(&[extent([0.0, 0.0, 300.0, 17.0])]);
        assert_eq!(o.width, 2048);
        assert_eq!(o.index(0.0, 0.0), Some((o.height - 1) * o.width));
        let top = o.height as f64 * o.cell - 1e-6;
        assert_eq!(o.index(299.99, top), Some(o.width - 1));
        assert_eq!(o.index(-1.0, 0.0), None);
    }

    #[test]
    fn colours_are_distinct_for_the_street_classes() {
        let codes = [2u8, 5, 6, 11, 64, 65, 66, 67, 69, 70, 71];
        for (i, a) in codes.iter().enumerate() {
            for b in &codes[i + 1..] {
                assert_ne!(class_colour(*a), class_colour(*b), "{a} vs {b}");
            }
        }
        assert_eq!(ramp(0.0), [48, 18, 120]);
        assert_eq!(ramp(1.0), [250, 230, 40]);
    }
}
