//! Levels of the terrain along the tile border, used to place the TIN's virtual vertices.

use super::geometry::Frame;
use super::seeds::Grid;

/// A side of the tile's bounding box.
#[derive(Clone, Copy)]
pub(super) enum Side {
    West,
    East,
    South,
    North,
}

/// Low level (robust minimum) of the points in the strip along each side of the tile, per
/// seed-grid cell along that side.
pub(super) struct BorderLevels {
    /// Per side, per cell along the side: 2nd lowest z (the lowest may be a spike), if any.
    levels: [Vec<Option<f64>>; 4],
}

impl BorderLevels {
    pub(super) fn new(
        points: &[[f64; 3]],
        frame: &Frame,
        grid: &Grid,
        max_x: f64,
        max_y: f64,
        quantile: f64,
        strip_max_m: f64,
    ) -> Self {
        if quantile > 0.0 {
            return Self::quantile(points, frame, grid, max_x, max_y, quantile, strip_max_m);
        }
        // The strip is a fraction of a seed cell: narrow enough to hold the terrain right at
        // the border, wide enough to hold a few points.
        let strip_m = (0.2 * grid.cell_m).min(strip_max_m);
        let mut two_lowest: [Vec<[f64; 2]>; 4] = [
            vec![[f64::INFINITY; 2]; grid.ny],
            vec![[f64::INFINITY; 2]; grid.ny],
            vec![[f64::INFINITY; 2]; grid.nx],
            vec![[f64::INFINITY; 2]; grid.nx],
        ];
        fn keep_two(t: &mut [f64; 2], z: f64) {
            if z < t[0] {
                t[1] = t[0];
                t[0] = z;
            } else if z < t[1] {
                t[1] = z;
            }
        }
        let mut push = |side: usize, cell: usize, z: f64| {
            if let Some(t) = two_lowest[side].get_mut(cell) {
                keep_two(t, z);
            }
        };
        for_each_in_strips(points, frame, grid, (max_x, max_y), strip_m, &mut push);
        let robust_low = |t: [f64; 2]| {
            if t[1].is_finite() {
                Some(t[1])
            } else if t[0].is_finite() {
                Some(t[0])
            } else {
                None
            }
        };
        let levels = two_lowest.map(|side| side.into_iter().map(robust_low).collect());
        BorderLevels { levels }
    }

    /// Like [`BorderLevels::new`], with the `quantile` of the strip's heights as its level
    /// (dense scans, where a cluster of low outliers defeats the 2nd lowest point).
    fn quantile(
        points: &[[f64; 3]],
        frame: &Frame,
        grid: &Grid,
        max_x: f64,
        max_y: f64,
        quantile: f64,
        strip_max_m: f64,
    ) -> Self {
        let strip_m = (0.2 * grid.cell_m).min(strip_max_m);
        let mut zs: [Vec<Vec<f64>>; 4] = [
            vec![Vec::new(); grid.ny],
            vec![Vec::new(); grid.ny],
            vec![Vec::new(); grid.nx],
            vec![Vec::new(); grid.nx],
        ];
        let mut push = |side: usize, cell: usize, z: f64| {
            if let Some(t) = zs[side].get_mut(cell) {
                t.push(z);
            }
        };
        for_each_in_strips(points, frame, grid, (max_x, max_y), strip_m, &mut push);
        let level = |mut t: Vec<f64>| {
            if t.is_empty() {
                return None;
            }
            let k = ((t.len() - 1) as f64 * quantile).floor() as usize;
            let (_, z, _) = t.select_nth_unstable_by(k, f64::total_cmp);
            Some(*z)
        };
        let levels = zs.map(|side| side.into_iter().map(level).collect());
        BorderLevels { levels }
    }

    pub(super) fn level(&self, side: Side, cell: usize) -> Option<f64> {
        let i = match side {
            Side::West => 0,
            Side::East => 1,
            Side::South => 2,
            Side::North => 3,
        };
        self.levels[i].get(cell).copied().flatten()
    }
}

/// Calls `push(side, cell, local z)` for every point within `strip_m` of a side of the local
/// bounding box `[0, max_x] × [0, max_y]` (sides: 0 west, 1 east — by grid row; 2 south,
/// 3 north — by grid column).
fn for_each_in_strips(
    points: &[[f64; 3]],
    frame: &Frame,
    grid: &Grid,
    (max_x, max_y): (f64, f64),
    strip_m: f64,
    push: &mut impl FnMut(usize, usize, f64),
) {
    for p in points {
        let l = frame.local(p);
        let (ix, iy) = grid.cell_xy(p[0], p[1]);
        if l[0] <= strip_m {
            push(0, iy, l[2]);
        }
        if l[0] >= max_x - strip_m {
            push(1, iy, l[2]);
        }
        if l[1] <= strip_m {
            push(2, ix, l[2]);
        }
        if l[1] >= max_y - strip_m {
            push(3, ix, l[2]);
        }
    }
}
