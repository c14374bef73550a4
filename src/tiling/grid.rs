//! The tiling grid: which core tile a point belongs to and which neighbours' buffer zones
//! contain it.

use crate::model::{Rect, TileId};

/// A square grid of core tiles aligned to multiples of `tile_size_m`, with overlap buffers.
#[derive(Debug, Clone, Copy)]
pub struct Grid {
    /// Core edge, metres.
    pub tile_size_m: f64,
    /// Buffer width, metres (< tile size).
    pub buffer_m: f64,
}

/// The core tile edge for inputs of `(bounds, points)`: `tile_size_m`, doubled until a tile
/// at the inputs' mean density (their points over the area of their bounds) is expected to
/// hold `want` points. Dense data keeps `tile_size_m`; a thousand points spread over
/// kilometres (or random coordinates over the whole 32-bit range) get a handful of tiles
/// instead of one per point, each of which costs the stages' fixed work per tile.
/// Doubling keeps the grid aligned to the configured one, and the headers alone decide, so
/// `tessera plan`, its tasks and their stitch cut the same grid. `want` 0 keeps the size.
pub fn sparse_tile_size(
    tile_size_m: f64,
    want: u64,
    inputs: impl Iterator<Item = (Rect, u64)>,
) -> f64 {
    if want == 0 {
        return tile_size_m;
    }
    let (mut points, mut area) = (0.0f64, 0.0f64);
    for (r, n) in inputs.filter(|(_, n)| *n > 0) {
        points += n as f64;
        // Each file covers at least a tile: a file of points on a line is not taken as dense.
        area += (r.x1 - r.x0).max(tile_size_m) * (r.y1 - r.y0).max(tile_size_m);
    }
    if points == 0.0 || !area.is_finite() {
        return tile_size_m;
    }
    let density = points / area;
    let mut s = tile_size_m;
    // At most 2^30 times the configured edge (far beyond the 32-bit coordinate range).
    for _ in 0..30 {
        if density * s * s >= want as f64 {
            break;
        }
        s *= 2.0;
    }
    s
}

impl Grid {
    /// Column/row of the core tile containing `(x, y)`.
    #[inline]
    pub fn cell(&self, x: f64, y: f64) -> (i64, i64) {
        (
            (x / self.tile_size_m).floor() as i64,
            (y / self.tile_size_m).floor() as i64,
        )
    }

    /// Core rectangle of a grid cell.
    pub fn cell_rect(&self, ix: i64, iy: i64) -> Rect {
        let s = self.tile_size_m;
        Rect {
            x0: ix as f64 * s,
            y0: iy as f64 * s,
            x1: (ix + 1) as f64 * s,
            y1: (iy + 1) as f64 * s,
        }
    }

    /// Calls `f(tile, is_core)` for the point's core tile and for every neighbour whose
    /// buffer zone (core expanded by `buffer_m`, half-open) contains it. Because the buffer is
    /// narrower than a tile, only the 8 neighbours can qualify.
    #[inline]
    pub fn assign(&self, x: f64, y: f64, mut f: impl FnMut(TileId, bool)) {
        let (ix, iy) = self.cell(x, y);
        f(TileId::grid(ix, iy), true);
        if self.buffer_m <= 0.0 {
            return;
        }
        let r = self.cell_rect(ix, iy);
        let b = self.buffer_m;
        // Neighbour to the west contains x if x < x0 + b (its expanded x1 is x0 + b), to the
        // east if x >= x1 - b.
        let dxs: [i64; 3] = [-1, 0, 1];
        let okx = [x < r.x0 + b, true, x >= r.x1 - b];
        let oky = [y < r.y0 + b, true, y >= r.y1 - b];
        for (j, dy) in dxs.iter().enumerate() {
            if !oky[j] {
                continue;
            }
            for (i, dx) in dxs.iter().enumerate() {
                if (*dx == 0 && *dy == 0) || !okx[i] {
                    continue;
                }
                f(TileId::grid(ix + dx, iy + dy), false);
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn corner_point_goes_to_four_tiles() {
        let g = Grid {
            tile_size_m: 10.0,
            buffer_m: 1.0,
        };
        let mut got = Vec::new();
        g.assign(10.5, 19.5, |t, c| got.push((t.ix, t.iy, c)));
        got.sort();
        assert_eq!(
            got,
            vec![(0, 1, false), (0, 2, false), (1, 1, true), (1, 2, false)]
        );
        let mut got = Vec::new();
        g.assign(15.0, 15.0, |t, c| got.push((t.ix, t.iy, c)));
        assert_eq!(got, vec![(1, 1, true)]);
        let mut got = Vec::new();
        g.assign(-0.5, 3.0, |t, c| got.push((t.ix, t.iy, c)));
        got.sort();
        assert_eq!(got, vec![(-1, 0, true), (0, 0, false)]);
    }

    #[test]
    fn sparse_inputs_get_larger_tiles_dense_ones_keep_theirs() {
        let r = |x1: f64, y1: f64| Rect {
            x0: 0.0,
            y0: 0.0,
            x1,
            y1,
        };
        // 1 point/m²: a 50 m tile holds 2,500, more than asked.
        assert_eq!(
            super::sparse_tile_size(50.0, 256, [(r(1000.0, 1000.0), 1_000_000)].into_iter()),
            50.0
        );
        // 1,065 points over 3.4 × 4.6 km (PDAL's simple.las): 0.2 points per 50 m tile.
        let s = super::sparse_tile_size(50.0, 256, [(r(3363.0, 4636.0), 1065)].into_iter());
        assert_eq!(s, 3200.0);
        assert!(1065.0 / (3363.0 * 4636.0) * s * s >= 256.0);
        // Off, no points, or no area: the configured size.
        assert_eq!(
            super::sparse_tile_size(50.0, 0, [(r(3363.0, 4636.0), 1065)].into_iter()),
            50.0
        );
        assert_eq!(
            super::sparse_tile_size(50.0, 256, [(r(3363.0, 4636.0), 0)].into_iter()),
            50.0
        );
        // Random 32-bit coordinates: bounded doubling.
        let huge = super::sparse_tile_size(50.0, 256, [(r(4.3e9, 4.3e9), 50_000)].into_iter());
        assert!(huge.is_finite() && huge <= 50.0 * 2f64.powi(30));
    }
}
