//! Cell geometry shared by the ground filter, the tiler and the stitcher, kept below all three
//! so that none of them imports another for it: a quadtree leaf's grid cell, and the one rule
//! that picks a cell's representative point (the ground filter seeds from it; split tiles keep
//! just that point of their far buffer cells).

use crate::model::{Rect, TileId};

/// The grid cell's core rectangle from one of its quadtree leaves.
pub fn cell_rect(leaf: &TileId, core: &Rect) -> Rect {
    let w = core.width() * (1u64 << leaf.level) as f64;
    let h = (core.y1 - core.y0) * (1u64 << leaf.level) as f64;
    let (mut x0, mut y0) = (core.x0, core.y0);
    for l in 0..leaf.level {
        // Quadrant taken at depth `level - l` (the least significant bits are the deepest).
        let q = (leaf.path >> (2 * l as u64)) & 3;
        let scale = (1u64 << (leaf.level - l)) as f64;
        if q & 1 == 1 {
            x0 -= w / scale;
        }
        if q & 2 == 2 {
            y0 -= h / scale;
        }
    }
    Rect {
        x0,
        y0,
        x1: x0 + w,
        y1: y0 + h,
    }
}

/// Position of a cell's representative in its points sorted by height: the lowest point with
/// `support` more points within `window_m` above it (support grows with the cell's point count,
/// 1 to 8), so that a few isolated low outliers are skipped; the lowest point when none has.
///
/// `count` is the cell's number of points, of which only the lowest `held` are known
/// (`z(j)`, ascending, j < `held`). None when those do not decide it (a choice at or beyond
/// `held - support` is possible). The one rule for `lowest_per_cell` (all points held) and
/// for the far-buffer thinning of split tiles (`tiling::FarThin`), which keeps exactly the
/// point this picks.
pub fn cell_representative(
    count: usize,
    held: usize,
    z: impl Fn(usize) -> f64,
    window_m: f64,
) -> Option<usize> {
    let support = (count / 32).clamp(1, 8);
    let found = (0..held.saturating_sub(support)).find(|&j| z(j + support) - z(j) <= window_m);
    match found {
        Some(j) => Some(j),
        None if held >= count => Some(0),
        None => None,
    }
}
