//! Tiling: bins streamed points into core tiles plus overlap buffers, spills incomplete tiles
//! to disk, and releases a tile as soon as every input that could touch it has been read.

mod job;
pub use job::*;

pub mod grid;
pub mod load;
pub mod spill;

pub use grid::Grid;
pub use load::{load_tile, split_job, FarCells, FarThin, SplitParams, TileBuffers, FAR_KEEP};
pub use spill::{FinishedTile, Part, SpillPart, SpillSet, TileMap};

use crate::error::Result;
use crate::io::InputFile;
use crate::model::{point_id, RecordLayout, Rect, TileId, TileName};
use std::path::Path;

struct OpenTile {
    /// Inputs not fully read yet whose bounds reach this tile's core+buffer region.
    pending: u32,
    /// Spill slot.
    slot: usize,
}

/// The binning state machine run by the tiler thread.
pub struct Tiler<'a> {
    grid: Grid,
    layout: &'a RecordLayout,
    files: &'a [InputFile],
    /// Per input, where its points must lie ([`InputFile::accepted`]).
    accepted: Vec<Rect>,
    file_done: Vec<bool>,
    spill: SpillSet,
    open: TileMap<OpenTile>,
    /// The last core tile seen: consecutive points almost always share it.
    last: Option<(i64, i64, usize)>,
    /// Cells released since the last [`Tiler::take_releases`] (for the stitcher).
    releases: Vec<CellRelease>,
    /// Buffer points within this distance of a tile's core are counted ([`TileJob::n_near`]).
    near_m: f64,
    /// ... and within this one ([`TileJob::n_kept`]; 0: not counted).
    kept_m: f64,
    /// A task of a distributed run bins only its own cells ([`Tiler::restrict`]).
    scope: Option<&'a std::collections::HashSet<crate::model::CellKey>>,
    /// Core points binned into cells in scope.
    core_points: u64,
}

fn reach(file: &InputFile, layout: &RecordLayout) -> Rect {
    // Header bounds plus the tolerance the reader accepts for points outside them.
    let t = &layout.transforms;
    let tol = 1.5 * t.x.scale.abs().max(t.y.scale.abs()) + 1e-6;
    file.bounds.expanded(tol)
}

impl<'a> Tiler<'a> {
    /// Creates a tiler spilling into `spill_dir` with at most `spill_bytes` buffered.
    pub fn new(
        grid: Grid,
        layout: &'a RecordLayout,
        files: &'a [InputFile],
        spill_dir: &Path,
        spill_bytes: usize,
        (near_m, kept_m): (f64, f64),
    ) -> Self {
        Tiler {
            near_m,
            kept_m,
            grid,
            layout,
            files,
            accepted: files.iter().map(InputFile::accepted).collect(),
            file_done: vec![false; files.len()],
            spill: SpillSet::with_handoff(spill_dir, spill_bytes),
            open: TileMap::default(),
            last: None,
            releases: Vec::new(),
            scope: None,
            core_points: 0,
        }
    }

    /// Bins only points of `cells` (as core or buffer points): a task of a distributed run.
    /// Its tiles get exactly the points they get in a run of the whole region, in the same
    /// order, as long as every input reaching them is read, in the run's order.
    pub fn restrict(&mut self, cells: &'a std::collections::HashSet<crate::model::CellKey>) {
        self.scope = Some(cells);
    }

    /// Core points binned so far (into cells in scope).
    pub fn core_points(&self) -> u64 {
        self.core_points
    }

    /// Number of tiles currently open (receiving points).
    pub fn open_tiles(&self) -> usize {
        self.open.len()
    }

    /// Bins one chunk of records read from input `file` starting at point `first`. Fails on
    /// the first point outside the file's accepted region (the completeness of tiles rests on
    /// the header bounds).
    pub fn push_chunk(&mut self, file: usize, first: u64, records: &[u8]) -> Result<()> {
        let rl = self.layout.record_len;
        let grid = self.grid;
        let b = grid.buffer_m;
        let accepted = self.accepted[file];
        for (i, rec) in records.chunks_exact(rl).enumerate() {
            let p = self.layout.xyz(rec);
            if !InputFile::accepts(&accepted, p) {
                return Err(self.files[file].rejected(first + i as u64, p));
            }
            let [x, y, _] = p;
            let pid = point_id(file, first + i as u64);
            let (ix, iy) = grid.cell(x, y);
            let scope = self.scope;
            let in_scope = |c: (i64, i64)| scope.is_none_or(|s| s.contains(&c));
            if in_scope((ix, iy)) {
                let slot = match self.last {
                    Some((lx, ly, s)) if lx == ix && ly == iy => s,
                    _ => {
                        let s = self.open_slot(TileId::grid(ix, iy));
                        self.last = Some((ix, iy, s));
                        s
                    }
                };
                self.spill.push(slot, Part::Core, pid, rec)?;
                self.core_points += 1;
            }
            if b > 0.0 {
                let r = grid.cell_rect(ix, iy);
                if x < r.x0 + b || x >= r.x1 - b || y < r.y0 + b || y >= r.y1 - b {
                    let mut err = Ok(());
                    let (near_m, kept_m) = (self.near_m, self.kept_m);
                    grid.assign(x, y, |tile, is_core| {
                        if !is_core && err.is_ok() && in_scope((tile.ix, tile.iy)) {
                            let s = self.open_slot(tile);
                            err = self.spill.push(s, Part::Buffer, pid, rec);
                            let r = grid.cell_rect(tile.ix, tile.iy);
                            if r.expanded(near_m).contains(x, y) {
                                self.spill.count_near(s);
                            }
                            if kept_m > 0.0 && r.expanded(kept_m).contains(x, y) {
                                self.spill.count_kept(s);
                            }
                        }
                    });
                    err?;
                }
            }
        }
        Ok(())
    }

    /// The spill slot of a tile, opening the tile (and counting the inputs that may still
    /// reach it) on first use.
    fn open_slot(&mut self, tile: TileId) -> usize {
        if let Some(t) = self.open.get(&tile) {
            return t.slot;
        }
        let region = self
            .grid
            .cell_rect(tile.ix, tile.iy)
            .expanded(self.grid.buffer_m);
        let pending = self
            .files
            .iter()
            .enumerate()
            .filter(|(k, f)| !self.file_done[*k] && reach(f, self.layout).intersects(&region))
            .count() as u32;
        let slot = self.spill.slot(tile);
        self.open.insert(tile, OpenTile { pending, slot });
        slot
    }

    /// Marks input `file` as fully read and returns the tiles that became complete, column by
    /// column and largest first within a column (a deterministic order).
    pub fn file_done(&mut self, file: usize) -> Result<Vec<TileJob>> {
        let ready = self.complete_after(file);
        self.release(ready)
    }

    /// Marks input `file` as fully read and returns the cells that became complete, sorted
    /// (column by column), without releasing them: [`Tiler::release`] them a column at a
    /// time, so that a region completed at once (a one-file region) never holds every job.
    pub fn complete_after(&mut self, file: usize) -> Vec<TileId> {
        self.file_done[file] = true;
        let r = reach(&self.files[file], self.layout);
        let grid = self.grid;
        for (id, t) in self.open.iter_mut() {
            let region = grid.cell_rect(id.ix, id.iy).expanded(grid.buffer_m);
            if r.intersects(&region) {
                t.pending = t.pending.saturating_sub(1);
            }
        }
        let mut v: Vec<TileId> = self
            .open
            .iter()
            .filter(|(_, t)| t.pending == 0)
            .map(|(k, _)| *k)
            .collect();
        v.sort();
        v
    }

    /// Every cell still open (all inputs read), sorted; see [`Tiler::complete_after`].
    pub fn still_open(&self) -> Vec<TileId> {
        let mut v: Vec<TileId> = self.open.keys().copied().collect();
        v.sort();
        v
    }

    /// Releases every open tile (all inputs read).
    pub fn finish(&mut self) -> Result<Vec<TileJob>> {
        let v = self.still_open();
        self.release(v)
    }

    /// The cells released by the calls to [`Tiler::file_done`] and [`Tiler::finish`] since
    /// the last call, each with the neighbouring cells that were still open at its release:
    /// every cell that can share overlap points with a released cell is open at that moment
    /// or was released before (see [`crate::stitch::frontier`]).
    pub fn take_releases(&mut self) -> Vec<CellRelease> {
        std::mem::take(&mut self.releases)
    }

    /// Releases the open cells `ids` (the ones listed by [`Tiler::complete_after`] or
    /// [`Tiler::still_open`]) and returns their jobs, column by column and largest first within
    /// a column.
    pub fn release(&mut self, ids: Vec<TileId>) -> Result<Vec<TileJob>> {
        let mut jobs = Vec::new();
        self.last = None;
        // Neighbours are listed before any tile of the batch leaves `open`, so tiles released
        // together list each other.
        let open_neighbours: Vec<Vec<(i64, i64)>> = ids
            .iter()
            .map(|id| {
                let mut v = Vec::new();
                for dy in -1..=1i64 {
                    for dx in -1..=1i64 {
                        let n = TileId::grid(id.ix + dx, id.iy + dy);
                        if (dx, dy) != (0, 0) && self.open.contains_key(&n) {
                            v.push((n.ix, n.iy));
                        }
                    }
                }
                v
            })
            .collect();
        for (id, open_neighbours) in ids.into_iter().zip(open_neighbours) {
            self.open.remove(&id);
            let done = self.spill.finish(id)?;
            let (n_core, n_buf) = (done.core.points(), done.buf.points());
            let core = self.grid.cell_rect(id.ix, id.iy);
            let mut job = TileJob {
                id,
                name: TileName {
                    id,
                    origin: (core.x0, core.y0),
                },
                core,
                buffer_m: self.grid.buffer_m,
                core_part: done.core,
                buf_part: done.buf,
                n_core,
                n_buf,
                n_near: done.near,
                n_kept: done.kept,
                far_thinned: false,
            };
            self.releases.push(CellRelease {
                cell: (id.ix, id.iy),
                has_core: n_core > 0,
                open_neighbours,
            });
            if n_core == 0 {
                // Only buffer points fell here: nothing to write, the points are written by
                // their own core tiles.
                job.buf_part.release();
                continue;
            }
            jobs.push(job);
        }
        // Column by column, and largest first within a column (ties in id order): with
        // several workers, a big tile started last would leave the others idle at the end of
        // a column; across the whole batch (all of a one-file region at once) the size order
        // scattered the tiles over the grid, and the stitcher held each finished tile until the
        // last of its 3 × 3 block was done: half of a 10,000-cell region at once.
        jobs.sort_by_key(|j| (j.id.ix, std::cmp::Reverse(j.n_core + j.n_buf)));
        Ok(jobs)
    }
}

/// Orders input files so that spatial neighbours are read one after another (Morton order of
/// their centres on the tile grid): tiles then complete early and few stay open.
pub fn schedule(files: &[InputFile], grid: &Grid) -> Vec<usize> {
    let mut keys: Vec<(u64, usize)> = files
        .iter()
        .map(|f| {
            let cx = 0.5 * (f.bounds.x0 + f.bounds.x1);
            let cy = 0.5 * (f.bounds.y0 + f.bounds.y1);
            let (ix, iy) = grid.cell(cx, cy);
            (morton(ix, iy), f.index)
        })
        .collect();
    keys.sort();
    keys.into_iter().map(|(_, i)| i).collect()
}

/// Morton code of a (biased) cell index pair.
pub fn morton(ix: i64, iy: i64) -> u64 {
    fn spread(v: u32) -> u64 {
        let mut x = v as u64;
        x = (x | (x << 16)) & 0x0000_FFFF_0000_FFFF;
        x = (x | (x << 8)) & 0x00FF_00FF_00FF_00FF;
        x = (x | (x << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
        x = (x | (x << 2)) & 0x3333_3333_3333_3333;
        x = (x | (x << 1)) & 0x5555_5555_5555_5555;
        x
    }
    let bx = (ix.wrapping_add(1 << 31)) as u32;
    let by = (iy.wrapping_add(1 << 31)) as u32;
    spread(bx) | (spread(by) << 1)
}
