//! Worker side of tiling: load a complete tile from its spill files, or split an over-dense
//! tile into quadrants (quadtree, same buffer width) without loading it.

use super::spill::{for_each_spilled, spill_path, Part, SpillSet};
use super::TileJob;
use crate::error::{Error, Result};
use crate::model::{RecordLayout, Rect, Tile, TileName};
use std::path::Path;

/// Points read per block when streaming spill files.
const BLOCK_POINTS: usize = 16 * 1024;

/// Reads a tile's spill files into memory (core points first) and deletes them.
pub fn load_tile(job: &TileJob, layout: &RecordLayout) -> Result<Tile> {
    let n = (job.n_core + job.n_buf) as usize;
    let rl = layout.record_len;
    let mut records = Vec::with_capacity(n * rl);
    let mut ids = Vec::with_capacity(n);
    let mut xyz = Vec::with_capacity(n);
    for (path, count) in [(&job.core_path, job.n_core), (&job.buf_path, job.n_buf)] {
        for_each_spilled(path, rl, count, BLOCK_POINTS, |id, rec| {
            records.extend_from_slice(rec);
            ids.push(id);
            xyz.push(layout.xyz(rec));
            Ok(())
        })?;
    }
    remove_spill(job);
    Ok(Tile {
        id: job.id,
        name: job.name,
        core: job.core,
        buffer_m: job.buffer_m,
        records,
        ids,
        xyz,
        n_core: job.n_core as usize,
        segments: Vec::new(),
        segment_table: Vec::new(),
    })
}

fn remove_spill(job: &TileJob) {
    let _ = std::fs::remove_file(&job.core_path);
    let _ = std::fs::remove_file(&job.buf_path);
}

/// Splits a tile into its four quadrants, streaming its spill files into the children's.
/// Children without core points are dropped (their buffer points are written by their own
/// core tiles). Fails when the quadrants would be narrower than `min_tile_size_m`.
///
/// With `far` set, a child's buffer points farther than `far.near_m` from its core are thinned
/// to the lowest [`FAR_KEEP`] points of each `far.cell_m` cell (see [`FarThin`]); the second
/// value returned counts the buffer point copies dropped that way.
pub fn split_job(
    job: &TileJob,
    layout: &RecordLayout,
    spill_dir: &Path,
    min_tile_size_m: f64,
    buffer_bytes: usize,
    max_points: u64,
    far: Option<FarThin>,
) -> Result<(Vec<TileJob>, u64)> {
    let half = job.core.width() / 2.0;
    if half < min_tile_size_m {
        return Err(Error::Budget(format!(
            "tile {}: {} points (core {} + buffer {}) in {:.3} m × {:.3} m exceed the {} points a tile may hold at this memory budget, and splitting further would go below tiling.min_tile_size_m = {} m; raise --memory-budget or lower tiling.buffer_m",
            job.name,
            job.n_core + job.n_buf,
            job.n_core,
            job.n_buf,
            job.core.width(),
            job.core.width(),
            max_points,
            min_tile_size_m
        )));
    }
    let quads: Vec<_> = (0u8..4)
        .map(|q| (job.id.child(q), job.core.quadrant(q)))
        .collect();
    let rl = layout.record_len;
    let mut set = SpillSet::new(spill_dir, buffer_bytes);
    let slots: Vec<usize> = quads.iter().map(|(cid, _)| set.slot(*cid)).collect();
    let b = job.buffer_m;
    let xm = 0.5 * (job.core.x0 + job.core.x1);
    let ym = 0.5 * (job.core.y0 + job.core.y1);
    let outer: Vec<Rect> = quads.iter().map(|(_, r)| r.expanded(b)).collect();
    let near: Vec<Option<Rect>> = quads
        .iter()
        .map(|(_, r)| far.filter(|f| f.near_m < b).map(|f| r.expanded(f.near_m)))
        .collect();
    let mut keepers: Vec<FarKeeper> = (0..4)
        .map(|_| FarKeeper::new(far.map_or(1.0, |f| f.cell_m), rl))
        .collect();
    for (path, count, parent_core) in [
        (&job.core_path, job.n_core, true),
        (&job.buf_path, job.n_buf, false),
    ] {
        for_each_spilled(path, rl, count, BLOCK_POINTS, |pid, rec| {
            let [x, y, z] = layout.xyz(rec);
            // A parent core point belongs to exactly one child core, decided by the midlines
            // so that rounding can never drop or duplicate it.
            let core_q = parent_core.then_some((x >= xm) as usize | (((y >= ym) as usize) << 1));
            for q in 0..4 {
                if core_q == Some(q) {
                    set.push(slots[q], Part::Core, pid, rec)?;
                } else if outer[q].contains(x, y) {
                    match near[q] {
                        Some(n) if !n.contains(x, y) => keepers[q].offer(x, y, z, pid, rec),
                        _ => set.push(slots[q], Part::Buffer, pid, rec)?,
                    }
                }
            }
            Ok(())
        })?;
    }
    remove_spill(job);
    let mut thinned = 0;
    for (q, keeper) in keepers.into_iter().enumerate() {
        thinned += keeper.offered - keeper.kept() as u64;
        keeper.drain(|pid, rec| set.push(slots[q], Part::Buffer, pid, rec))?;
    }
    let mut out = Vec::new();
    let mut total_core = 0;
    for (cid, rect) in quads {
        let (n_core, n_buf) = set.finish(cid)?;
        total_core += n_core;
        let child = TileJob {
            id: cid,
            name: TileName {
                id: cid,
                origin: job.name.origin,
            },
            core: rect,
            buffer_m: b,
            core_path: spill_path(spill_dir, cid, Part::Core),
            buf_path: spill_path(spill_dir, cid, Part::Buffer),
            n_core,
            n_buf,
        };
        if n_core == 0 {
            remove_spill(&child);
        } else {
            out.push(child);
        }
    }
    if total_core != job.n_core {
        return Err(Error::Internal(format!(
            "tile {}: split kept {total_core} of {} core points",
            job.name, job.n_core
        )));
    }
    Ok((out, thinned))
}

/// Lowest points kept per far cell by [`FarThin`]. More than one so that the ground filter's
/// choice of a cell's representative (the lowest point with another point close above it)
/// still skips an isolated low outlier.
pub const FAR_KEEP: usize = 8;

/// Thinning of the far part of a split child's buffer.
///
/// Why: a quadtree child keeps the parent's buffer width (the ground filter needs a whole seed
/// cell of context), so a deep split of a dense tile would otherwise copy and load the full
/// buffer for every small child: at four levels a 3 m core carried a 43 m square of buffer
/// (~200× its own points) and the split never converged on a simulated drive. Stages other
/// than the ground filter work within their context of the core and keep every point there;
/// beyond it the ground filter (with `densify_cell_m` > 0) only seeds and densifies from one
/// low point per `densify_cell_m` cell, so the lowest [`FAR_KEEP`] points of each such cell
/// (aligned to the same absolute grid) carry most of what it needs. Not all: the TIN's
/// densification order and cell representatives shift a little, and the change ripples
/// inwards; keeping full density to 5 m (the segment/label context) changed 0.03 % of the
/// ground labels and 0.8 % of the segmentation of the CycloMedia tile split at 400 MiB
/// against an untiled run (tests/stitch_metamorphic.rs), to 10 m 0.006 % and 0.17 %, to 15 m
/// nothing (100 % / 100 %) — hence `tiling.split_dense_buffer_m` = 15 of the 20 m buffer.
/// Buffer points are never written, only core points are, so no output point is lost.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FarThin {
    /// Buffer points within this distance of the child's core are all kept, metres (at least
    /// the stages' contexts and `tiling.split_dense_buffer_m`).
    pub near_m: f64,
    /// Cell of the far-zone grid, metres (aligned to absolute multiples).
    pub cell_m: f64,
}

/// A kept far point: height, point id, slab slot.
type Kept = (f64, u64, u32);

/// The lowest [`FAR_KEEP`] points per cell of one child's far buffer, records in a slab.
struct FarKeeper {
    cell_m: f64,
    rl: usize,
    /// Per cell: kept (z, point id, slab slot), sorted by (z, point id).
    cells: std::collections::HashMap<(i64, i64), Vec<Kept>>,
    slab: Vec<u8>,
    offered: u64,
}

impl FarKeeper {
    fn new(cell_m: f64, rl: usize) -> Self {
        FarKeeper {
            cell_m,
            rl,
            cells: Default::default(),
            slab: Vec::new(),
            offered: 0,
        }
    }

    fn kept(&self) -> usize {
        self.slab.len() / self.rl
    }

    fn offer(&mut self, x: f64, y: f64, z: f64, pid: u64, rec: &[u8]) {
        self.offered += 1;
        let key = (
            (x / self.cell_m).floor() as i64,
            (y / self.cell_m).floor() as i64,
        );
        let cell = self.cells.entry(key).or_default();
        // Sorted by (z, point id): the result does not depend on the order points arrive in.
        let pos = cell.partition_point(|e| (e.0, e.1) < (z, pid));
        if cell.len() < FAR_KEEP {
            let slot = (self.slab.len() / self.rl) as u32;
            self.slab.extend_from_slice(rec);
            cell.insert(pos, (z, pid, slot));
        } else if pos < FAR_KEEP {
            // Evict the highest and reuse its slab slot.
            let (_, _, slot) = cell.pop().unwrap_or((0.0, 0, 0));
            let at = slot as usize * self.rl;
            self.slab[at..at + self.rl].copy_from_slice(rec);
            cell.insert(pos, (z, pid, slot));
        }
    }

    /// Hands the kept points over ordered by cell, then height (deterministic).
    fn drain(self, mut f: impl FnMut(u64, &[u8]) -> Result<()>) -> Result<()> {
        let mut cells: Vec<_> = self.cells.into_iter().collect();
        cells.sort_unstable_by_key(|c| c.0);
        for (_, kept) in cells {
            for (_, pid, slot) in kept {
                let at = slot as usize * self.rl;
                f(pid, &self.slab[at..at + self.rl])?;
            }
        }
        Ok(())
    }
}
