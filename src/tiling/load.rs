//! Worker side of tiling: load a complete tile from its spill files, or split an over-dense
//! tile into quadrants (quadtree, same buffer width) without loading it.

use super::spill::{for_each_spilled, spill_path, Part, SpillSet};
use super::TileJob;
use crate::error::{Error, Result};
use crate::model::{RecordLayout, Tile, TileName};
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
pub fn split_job(
    job: &TileJob,
    layout: &RecordLayout,
    spill_dir: &Path,
    min_tile_size_m: f64,
    buffer_bytes: usize,
    max_points: u64,
) -> Result<Vec<TileJob>> {
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
    for (path, count, parent_core) in [
        (&job.core_path, job.n_core, true),
        (&job.buf_path, job.n_buf, false),
    ] {
        for_each_spilled(path, rl, count, BLOCK_POINTS, |pid, rec| {
            let [x, y, _] = layout.xyz(rec);
            // A parent core point belongs to exactly one child core, decided by the midlines
            // so that rounding can never drop or duplicate it.
            let core_q = parent_core.then_some((x >= xm) as usize | (((y >= ym) as usize) << 1));
            for (q, (_, rect)) in quads.iter().enumerate() {
                if core_q == Some(q) {
                    set.push(slots[q], Part::Core, pid, rec)?;
                } else if rect.expanded(b).contains(x, y) {
                    set.push(slots[q], Part::Buffer, pid, rec)?;
                }
            }
            Ok(())
        })?;
    }
    remove_spill(job);
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
    Ok(out)
}
