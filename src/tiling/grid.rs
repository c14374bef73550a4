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
}
