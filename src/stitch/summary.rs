//! Border summaries: what one segmented tile tells the stitcher — its labelled points near the
//! core edges (both sides) and an anchor per local segment — and nothing else.

use super::StitchError;
use crate::geom::cell_rect;
use crate::model::{Rect, Tile, TileId};

/// One labelled point near a tile's core edge.
///
/// Position is kept relative to the tile's core corner as `f32` (sub-millimetre up to 100 km
/// from the corner, far finer than needed: it only decides in which neighbour's overlap a
/// point lies), 24 bytes a record.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct BorderRecord {
    /// Global point id (input file << 40 | index).
    pub pid: u64,
    /// Local segment label (≥ 1).
    pub label: u32,
    /// x − core.x0.
    pub dx: f32,
    /// y − core.y0.
    pub dy: f32,
}

/// Whether `(x, y)`, outside `tile`'s core, lies in a tile after it in the stitching order:
/// grid cells in (ix, iy) order, and within a split cell the quadtree leaves depth first in
/// quadrant order — the order a worker processes them in (see [`tile_before`]). `cell` is the
/// tile's grid cell rectangle.
///
/// Why: the overlap of two tiles is matched on the earlier tile's core points only (its
/// inner records, the later tile's outer records); a tile keeps no outer records of points in
/// later tiles. Those are the records it would otherwise hold until the later tiles arrive,
/// and small leaves of a split cell hold each such point once per leaf whose 5 m zone reaches
/// it (~10× at 1.5 m leaves): 6.7 M frontier records, 154 MiB, on a simulated drive at a
/// 256 MiB budget. Inner records are held once per point.
pub fn later_point(cell: &Rect, tile: &TileId, x: f64, y: f64) -> bool {
    let step = |v: f64, lo: f64, hi: f64| (v >= hi) as i32 - (v < lo) as i32;
    let (dx, dy) = (step(x, cell.x0, cell.x1), step(y, cell.y0, cell.y1));
    if (dx, dy) != (0, 0) {
        return dx > 0 || (dx == 0 && dy > 0);
    }
    // The point's quadrant path at the tile's depth, by the split's midline rule.
    let mut r = *cell;
    let mut path = 0u64;
    for _ in 0..tile.level {
        let (xm, ym) = (0.5 * (r.x0 + r.x1), 0.5 * (r.y0 + r.y1));
        let (east, north) = (x >= xm, y >= ym);
        path = (path << 2) | east as u64 | ((north as u64) << 1);
        r = Rect {
            x0: if east { xm } else { r.x0 },
            x1: if east { r.x1 } else { xm },
            y0: if north { ym } else { r.y0 },
            y1: if north { r.y1 } else { ym },
        };
    }
    path > tile.path
}

/// Whether tile `a` comes before tile `b` in the stitching order of [`later_point`].
pub fn tile_before(a: &TileId, b: &TileId) -> bool {
    if (a.ix, a.iy) != (b.ix, b.iy) {
        return (a.ix, a.iy) < (b.ix, b.iy);
    }
    // Leaves of one cell: compare their quadrant paths at the shallower depth (disjoint
    // leaves differ there).
    let d = a.level.min(b.level);
    let pa = a.path >> (2 * u64::from(a.level - d));
    let pb = b.path >> (2 * u64::from(b.level - d));
    pa < pb
}

const SUMMARY_MAGIC: &[u8; 8] = b"TSBSUM01";

/// Reads little-endian fields from a byte slice; `None` past its end.
struct ByteReader<'a> {
    b: &'a [u8],
    at: usize,
}

impl<'a> ByteReader<'a> {
    fn take(&mut self, n: usize) -> Option<&'a [u8]> {
        let s = self.b.get(self.at..self.at.checked_add(n)?)?;
        self.at += n;
        Some(s)
    }
    fn u64(&mut self) -> Option<u64> {
        Some(u64::from_le_bytes(self.take(8)?.try_into().ok()?))
    }
    fn u32(&mut self) -> Option<u32> {
        Some(u32::from_le_bytes(self.take(4)?.try_into().ok()?))
    }
    /// A count of items of `size` bytes each that must fit in what is left.
    fn len(&mut self, size: usize) -> Option<usize> {
        let n = usize::try_from(self.u64()?).ok()?;
        (n.checked_mul(size)? <= self.b.len() - self.at).then_some(n)
    }
}

/// A tile's border summary.
#[derive(Debug, Clone, PartialEq)]
pub struct BorderSummary {
    /// The tile.
    pub tile: TileId,
    /// Its printable name (errors, logs).
    pub name: String,
    /// Its core rectangle.
    pub core: Rect,
    /// Per local label `l` (index `l - 1`): the smallest ordinal of its core points, or
    /// `u64::MAX` for a segment with buffer points only.
    pub anchors: Vec<u64>,
    /// Labelled core points within `strip_m` of the core edge.
    pub inner: Vec<BorderRecord>,
    /// Labelled buffer points (all within `strip_m` of the core: only those are segmented),
    /// except those in tiles after this one (see [`later_point`]).
    pub outer: Vec<BorderRecord>,
}

impl BorderSummary {
    /// Builds the summary of a segmented tile. `ordinal` maps a global point id to the point's
    /// position in the run's inputs (dense, deterministic).
    pub fn build(
        tile: &Tile,
        strip_m: f64,
        ordinal: impl Fn(u64) -> u64,
    ) -> Result<Self, StitchError> {
        let bad = |reason: String| StitchError::BadSummary {
            tile: tile.name.to_string(),
            reason,
        };
        if tile.segments.len() != tile.len() || tile.xyz.len() != tile.len() {
            return Err(bad(format!(
                "{} segment labels and {} coordinates for {} points",
                tile.segments.len(),
                tile.xyz.len(),
                tile.len()
            )));
        }
        if tile.n_core > tile.len() {
            return Err(bad(format!(
                "{} core points of {}",
                tile.n_core,
                tile.len()
            )));
        }
        let n_labels = tile.segments.iter().copied().max().unwrap_or(0) as usize;
        let mut anchors = vec![u64::MAX; n_labels];
        let core = tile.core;
        // Core points farther than strip_m from every edge cannot lie in any neighbour's
        // segmented zone. A hair of slack keeps points exactly on the strip's edge (the
        // neighbours' zones are half-open; exact geometry is applied when pairs are matched).
        let inside = core.expanded(-(strip_m + 1e-6));
        let record = |i: usize, label: u32| BorderRecord {
            pid: tile.ids[i],
            label,
            dx: (tile.xyz[i][0] - core.x0) as f32,
            dy: (tile.xyz[i][1] - core.y0) as f32,
        };
        let cell = cell_rect(&tile.id, &core);
        let mut inner = Vec::new();
        let mut outer = Vec::new();
        for (i, &label) in tile.segments.iter().enumerate() {
            if label == 0 {
                continue;
            }
            let [x, y, _] = tile.xyz[i];
            if i < tile.n_core {
                let a = &mut anchors[label as usize - 1];
                *a = (*a).min(ordinal(tile.ids[i]));
                if !(inside.x0 < inside.x1 && inside.y0 < inside.y1 && inside.contains(x, y)) {
                    inner.push(record(i, label));
                }
            } else if !later_point(&cell, &tile.id, x, y) {
                outer.push(record(i, label));
            }
        }
        inner.shrink_to_fit();
        outer.shrink_to_fit();
        Ok(BorderSummary {
            tile: tile.id,
            name: tile.name.to_string(),
            core,
            anchors,
            inner,
            outer,
        })
    }

    /// Number of local labels (1..=n).
    pub fn labels(&self) -> usize {
        self.anchors.len()
    }

    /// Absolute xy of a record of this tile.
    #[inline]
    pub fn position(&self, r: &BorderRecord) -> (f64, f64) {
        (self.core.x0 + r.dx as f64, self.core.y0 + r.dy as f64)
    }

    /// Border records held.
    pub fn records(&self) -> usize {
        self.inner.len() + self.outer.len()
    }

    /// Heap bytes held by the summary.
    pub fn bytes(&self) -> usize {
        self.records() * std::mem::size_of::<BorderRecord>() + self.anchors.len() * 8 + 128
    }

    /// The summary as bytes (little-endian), for a run's resume journal and for the border
    /// summaries a task of a distributed run leaves for `tessera stitch`.
    pub fn to_bytes(&self) -> Vec<u8> {
        let mut b =
            Vec::with_capacity(96 + self.name.len() + self.anchors.len() * 8 + self.records() * 20);
        b.extend_from_slice(SUMMARY_MAGIC);
        b.extend_from_slice(&self.tile.ix.to_le_bytes());
        b.extend_from_slice(&self.tile.iy.to_le_bytes());
        b.push(self.tile.level);
        b.extend_from_slice(&self.tile.path.to_le_bytes());
        b.extend_from_slice(&(self.name.len() as u64).to_le_bytes());
        b.extend_from_slice(self.name.as_bytes());
        for v in [self.core.x0, self.core.y0, self.core.x1, self.core.y1] {
            b.extend_from_slice(&v.to_le_bytes());
        }
        b.extend_from_slice(&(self.anchors.len() as u64).to_le_bytes());
        for a in &self.anchors {
            b.extend_from_slice(&a.to_le_bytes());
        }
        for list in [&self.inner, &self.outer] {
            b.extend_from_slice(&(list.len() as u64).to_le_bytes());
            for r in list {
                b.extend_from_slice(&r.pid.to_le_bytes());
                b.extend_from_slice(&r.label.to_le_bytes());
                b.extend_from_slice(&r.dx.to_le_bytes());
                b.extend_from_slice(&r.dy.to_le_bytes());
            }
        }
        b
    }

    /// Reads a summary written by [`BorderSummary::to_bytes`]; `what` names the file in
    /// errors. Truncated or foreign bytes are an error, never a panic or a huge allocation.
    pub fn from_bytes(bytes: &[u8], what: &str) -> Result<Self, StitchError> {
        let bad = |reason: &str| StitchError::BadSummary {
            tile: what.to_string(),
            reason: reason.to_string(),
        };
        let mut r = ByteReader { b: bytes, at: 0 };
        if r.take(SUMMARY_MAGIC.len()) != Some(SUMMARY_MAGIC) {
            return Err(bad("not a tessera border summary"));
        }
        let short = || bad("truncated");
        let tile = TileId {
            ix: r.u64().ok_or_else(short)? as i64,
            iy: r.u64().ok_or_else(short)? as i64,
            level: r.take(1).ok_or_else(short)?[0],
            path: r.u64().ok_or_else(short)?,
        };
        let n = r.len(1).ok_or_else(short)?;
        let name = String::from_utf8(r.take(n).ok_or_else(short)?.to_vec())
            .map_err(|_| bad("tile name is not UTF-8"))?;
        let mut c = [0f64; 4];
        for v in &mut c {
            *v = f64::from_bits(r.u64().ok_or_else(short)?);
        }
        let core = Rect {
            x0: c[0],
            y0: c[1],
            x1: c[2],
            y1: c[3],
        };
        let n = r.len(8).ok_or_else(short)?;
        let anchors = (0..n)
            .map(|_| r.u64().ok_or_else(short))
            .collect::<Result<Vec<u64>, _>>()?;
        let mut lists = [Vec::new(), Vec::new()];
        for list in &mut lists {
            let n = r.len(20).ok_or_else(short)?;
            list.reserve_exact(n);
            for _ in 0..n {
                let pid = r.u64().ok_or_else(short)?;
                let label = r.u32().ok_or_else(short)?;
                let dx = f32::from_bits(r.u32().ok_or_else(short)?);
                let dy = f32::from_bits(r.u32().ok_or_else(short)?);
                list.push(BorderRecord { pid, label, dx, dy });
            }
        }
        if r.at != bytes.len() {
            return Err(bad("trailing bytes"));
        }
        let [inner, outer] = lists;
        let s = BorderSummary {
            tile,
            name,
            core,
            anchors,
            inner,
            outer,
        };
        s.validate()?;
        Ok(s)
    }

    /// Checks that every record's label is one of the tile's labels.
    pub fn validate(&self) -> Result<(), StitchError> {
        let n = self.labels() as u32;
        if let Some(r) = self
            .inner
            .iter()
            .chain(&self.outer)
            .find(|r| r.label == 0 || r.label > n)
        {
            return Err(StitchError::BadSummary {
                tile: self.name.clone(),
                reason: format!(
                    "border record of point {} has label {}, tile has 1..={n}",
                    r.pid, r.label
                ),
            });
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::model::TileName;

    fn tile(points: &[([f64; 2], u32)], n_core: usize) -> Tile {
        let id = TileId::grid(0, 0);
        Tile {
            id,
            name: TileName {
                id,
                origin: (0.0, 0.0),
            },
            core: Rect {
                x0: 0.0,
                y0: 0.0,
                x1: 10.0,
                y1: 10.0,
            },
            buffer_m: 3.0,
            records: Vec::new(),
            ids: (0..points.len() as u64).map(|i| 100 + i).collect(),
            xyz: points.iter().map(|(p, _)| [p[0], p[1], 0.0]).collect(),
            n_core,
            segments: points.iter().map(|(_, l)| *l).collect(),
            segment_table: Vec::new(),
        }
    }

    #[test]
    fn strips_and_anchors() {
        let t = tile(
            &[
                ([5.0, 5.0], 1),   // core, interior: anchor only
                ([0.5, 5.0], 1),   // core, west strip
                ([9.5, 9.5], 2),   // core, NE corner strip
                ([5.0, 1.99], 0),  // unlabelled: nothing
                ([-1.0, 5.0], 1),  // buffer, west cell (earlier): kept
                ([10.5, 10.5], 3), // buffer-only segment, north-east cell (later): dropped
                ([5.0, -1.0], 1),  // south cell (earlier): kept
                ([5.0, 10.5], 2),  // north cell (later): dropped
                ([-1.0, 10.5], 2), // north-west cell (earlier, by ix): kept
            ],
            4,
        );
        let s = BorderSummary::build(&t, 2.0, |pid| pid * 10).unwrap();
        assert_eq!(s.anchors, vec![1000, 1020, u64::MAX]);
        let inner: Vec<(u64, u32)> = s.inner.iter().map(|r| (r.pid, r.label)).collect();
        assert_eq!(inner, vec![(101, 1), (102, 2)]);
        let outer: Vec<(u64, u32)> = s.outer.iter().map(|r| (r.pid, r.label)).collect();
        assert_eq!(outer, vec![(104, 1), (106, 1), (108, 2)]);
        assert_eq!(s.position(&s.outer[0]), (-1.0, 5.0));
        s.validate().unwrap();
    }

    /// The stitching order: cells by (ix, iy), leaves of a split cell depth first in
    /// quadrant order; a point outside a leaf is later exactly when the leaf holding it is.
    #[test]
    fn stitching_order_of_cells_leaves_and_points() {
        let cell = Rect {
            x0: 0.0,
            y0: 0.0,
            x1: 8.0,
            y1: 8.0,
        };
        let root = TileId::grid(0, 0);
        let (sw, se, nw) = (root.child(0), root.child(1), root.child(2));
        let (se_nw, se_ne) = (se.child(2), se.child(3));
        assert!(tile_before(&sw, &se) && tile_before(&se, &nw));
        assert!(tile_before(&se_nw, &se_ne) && tile_before(&se_ne, &nw));
        assert!(tile_before(&sw, &se_nw) && !tile_before(&se_nw, &sw));
        assert!(tile_before(&nw, &TileId::grid(1, 0).child(0)));
        assert!(tile_before(&TileId::grid(0, 1), &TileId::grid(1, 0)));
        // From the south-east leaf's north-west quarter ([4, 6) × [2, 4)):
        assert!(!later_point(&cell, &se_nw, 1.0, 1.0)); // south-west leaf: earlier
        assert!(!later_point(&cell, &se_nw, 5.0, 1.0)); // south-east's south half: earlier
        assert!(later_point(&cell, &se_nw, 7.0, 3.0)); // its north-east sibling: later
        assert!(later_point(&cell, &se_nw, 1.0, 5.0)); // north-west leaf: later
        assert!(later_point(&cell, &se_nw, 9.0, 1.0)); // the next cell east: later
        assert!(!later_point(&cell, &se_nw, 5.0, -1.0)); // the cell south: earlier
    }

    #[test]
    fn summary_bytes_round_trip_and_truncation_is_an_error() {
        let t = tile(&[([0.5, 5.0], 1), ([-1.0, 5.0], 2), ([5.0, 5.0], 2)], 1);
        let s = BorderSummary::build(&t, 2.0, |p| p * 3).unwrap();
        let b = s.to_bytes();
        assert_eq!(BorderSummary::from_bytes(&b, "x").unwrap(), s);
        for cut in 0..b.len() {
            assert!(BorderSummary::from_bytes(&b[..cut], "x").is_err(), "{cut}");
        }
        let mut huge = b.clone();
        let at = SUMMARY_MAGIC.len() + 8 + 8 + 1 + 8;
        huge[at..at + 8].copy_from_slice(&u64::MAX.to_le_bytes());
        assert!(BorderSummary::from_bytes(&huge, "x").is_err());
    }

    #[test]
    fn inconsistent_tile_is_an_error_not_a_panic() {
        let mut t = tile(&[([1.0, 1.0], 1)], 1);
        t.segments.clear();
        assert!(BorderSummary::build(&t, 2.0, |p| p).is_err());
        let mut s = BorderSummary::build(&tile(&[([1.0, 1.0], 1)], 1), 2.0, |p| p).unwrap();
        s.inner[0].label = 7;
        assert!(s.validate().is_err());
    }
}
