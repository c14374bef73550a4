//! The memory budget: one knob (`memory_budget_mb`) turned into chunk sizes, spill buffer
//! bounds, channel depths and the largest tile a worker may load.
//!
//! Model (bytes): peak ≈ fixed + reader + spill + tiles_in_flight × max_tile_points ×
//! bytes_per_tile_point. `fixed` covers the binary, thread stacks, allocator slack and the
//! LAZ codecs' own buffers. The whole model is checked end to end by `tests/memory.rs` and
//! `scripts/bench_memory.sh` (peak RSS under the budget and flat with input size).

use crate::error::{Error, Result};
use serde::Serialize;

/// Bytes reserved for what the process needs before any point is held (binary, runtime,
/// codecs). Measured: 11.5 MiB peak RSS for a 7,492-point file (ISPRS samp24, pass-through,
/// at 256 and at 1024 MiB); the rest of the 40 MiB is headroom for codec and I/O buffers that
/// grow with chunk size, and for allocator slack.
pub const FIXED_BYTES: u64 = 40 << 20;

/// Largest memory budget accepted (1 PiB): far above any machine, far below where the plan's
/// byte arithmetic could overflow.
pub const MAX_BUDGET_BYTES: u64 = 1 << 50;

/// The resolved plan.
#[derive(Debug, Clone, Serialize)]
pub struct BudgetPlan {
    /// The budget, bytes.
    pub budget_bytes: u64,
    /// Points per reader chunk.
    pub chunk_points: usize,
    /// Chunks queued between reader and tiler.
    pub chunk_depth: usize,
    /// Bound on spill write buffers, bytes.
    pub spill_bytes: usize,
    /// Worker threads.
    pub workers: usize,
    /// Tiles that may be in memory at once (one per worker).
    pub tiles_in_flight: usize,
    /// Bytes one tile point costs while processed.
    pub bytes_per_tile_point: usize,
    /// Largest tile (core + buffer points) a worker loads when every stage works on the whole
    /// buffer; see [`BudgetPlan::fits`] for the actual test.
    pub max_tile_points: u64,
    /// Bytes one tile may take (the tile share of the budget).
    pub tile_bytes: u64,
    /// Bytes per point every tile point costs whatever the stages (record, id, xyz, carried
    /// results), with slack.
    pub base_bytes_per_point: usize,
    /// Per stage: working memory and how far beyond the core it works.
    pub stages: Vec<StageMemory>,
    /// Reserved for the stitcher's frontier (border summaries of tiles waiting for their
    /// neighbours), bytes; 0 without stitching.
    pub stitch_bytes: u64,
    /// Reserved for what the run's outputs hold whatever the tiles (the report's raster),
    /// bytes; see [`BudgetPlan::reserve_outputs`].
    pub output_bytes: u64,
}

/// A stage's working memory as the plan charges it (see [`BudgetPlan::fits`]); checked against
/// a counting allocator by `tests/stage_memory.rs`.
#[derive(Debug, Clone, Copy, PartialEq, Serialize)]
pub struct StageMemory {
    /// Bytes per point within the stage's context.
    pub context_bytes: usize,
    /// Bytes per point of the whole tile (flags and per-point arrays the stage builds for
    /// every point, even those outside its context).
    pub tile_bytes: usize,
    /// How far beyond the core the stage works, metres (None: the whole buffer).
    pub context_m: Option<f64>,
}

impl StageMemory {
    /// A stage working on the whole tile.
    pub fn whole(bytes_per_point: usize) -> Self {
        StageMemory {
            context_bytes: bytes_per_point,
            tile_bytes: 0,
            context_m: None,
        }
    }
}

impl BudgetPlan {
    /// Plans for `budget_mb`, records of `record_len` bytes, stages needing
    /// `stage_bytes_per_point`, and `workers` threads.
    pub fn new(
        budget_mb: u64,
        record_len: usize,
        stage_bytes_per_point: usize,
        workers: usize,
    ) -> Result<Self> {
        Self::with_stages(
            budget_mb,
            record_len,
            &[StageMemory::whole(stage_bytes_per_point)],
            workers,
        )
    }

    /// Plans for the stages' working memory.
    pub fn with_stages(
        budget_mb: u64,
        record_len: usize,
        stages: &[StageMemory],
        workers: usize,
    ) -> Result<Self> {
        let stage_bytes_per_point = stages
            .iter()
            .map(|s| s.context_bytes + s.tile_bytes)
            .max()
            .unwrap_or(0);
        // Checked: a shift wrapped 17592186044480 MiB (2^44 − 64) to a 64 MiB plan.
        let budget = budget_mb
            .checked_mul(1 << 20)
            .filter(|b| *b <= MAX_BUDGET_BYTES)
            .ok_or_else(|| {
                Error::Config(format!(
                    "pipeline.memory_budget_mb = {budget_mb} is beyond {} MiB (1 PiB)",
                    MAX_BUDGET_BYTES >> 20
                ))
            })?;
        let workers = workers.max(1);
        let usable = budget.saturating_sub(FIXED_BYTES);
        // Reader: ~4 chunks alive (being decoded, queued ×2, being binned).
        let chunk_depth = 2;
        let reader_bytes = usable / 25;
        let chunk_points =
            ((reader_bytes / 4) / (record_len as u64 * 2)).clamp(4096, 1 << 20) as usize;
        let spill_bytes = (usable / 10) as usize;
        // In memory at once: one tile per worker (workers compress their own tiles; only
        // file names travel to the writer).
        let tiles_in_flight = workers;
        // Per point: raw record + id + xyz + the stages' working memory, with 25 % slack for
        // allocator growth.
        let base_bytes_per_point = (record_len + 8 + 24 + 8) * 5 / 4;
        let bytes_per_tile_point = base_bytes_per_point + stage_bytes_per_point * 5 / 4;
        let tile_bytes = usable
            .saturating_sub(reader_bytes)
            .saturating_sub(spill_bytes as u64);
        let tile_bytes = tile_bytes / tiles_in_flight as u64;
        let max_tile_points = tile_bytes / bytes_per_tile_point as u64;
        if max_tile_points < 20_000 {
            return Err(Error::Budget(format!(
                "memory budget {budget_mb} MiB leaves room for only {max_tile_points} points per tile with {workers} workers ({bytes_per_tile_point} bytes per point); use at least {} MiB or fewer threads",
                (FIXED_BYTES + 20_000 * tiles_in_flight as u64 * bytes_per_tile_point as u64 * 100 / 85) >> 20
            )));
        }
        Ok(BudgetPlan {
            budget_bytes: budget,
            chunk_points,
            chunk_depth,
            spill_bytes,
            workers,
            tiles_in_flight,
            bytes_per_tile_point,
            max_tile_points,
            tile_bytes,
            base_bytes_per_point,
            stages: stages.to_vec(),
            stitch_bytes: 0,
            output_bytes: 0,
        })
    }

    /// Distance from the core within which the tiler and the quadtree split count buffer points
    /// ([`crate::tiling::TileJob::n_near`]): the widest bounded stage context.
    pub fn near_m(&self) -> f64 {
        self.stages
            .iter()
            .filter_map(|m| m.context_m)
            .fold(0.0, f64::max)
    }

    /// Whether a tile of `n_core` + `n_buf` points, `n_near` of the buffer points within
    /// [`BudgetPlan::near_m`] of the core, fits its share of the budget. Stages that work only
    /// within their context of the core are charged their context bytes for the core and near
    /// points (counted while binning, so exact whatever the point layout: an estimate from
    /// the context's share of the buffer width undercharged split tiles threefold, whose
    /// thinned buffers are mostly near points) and their tile bytes for every point; 25 %
    /// slack on both. `far`: the tile's far buffer is thinned while it loads.
    pub fn fits(&self, n_core: u64, n_buf: u64, n_near: u64, far: Option<FarLoad>) -> bool {
        self.tile_bytes_needed(n_core, n_buf, n_near, far) <= self.tile_bytes
    }

    /// Bytes a tile of `n_core` + `n_buf` points (`n_near` of them near) takes while processed,
    /// as [`BudgetPlan::fits`] charges it. With `far`, the tile holds its core points, the
    /// `far.kept` buffer points of the zone kept whole and at most `far.cells` far ones, and
    /// while it loads the thinning holds up to `far.held` far points (record and key each, charged like a tile point) and a map entry
    /// per cell; that transient is charged in place of the stages' bytes, which come later.
    pub fn tile_bytes_needed(
        &self,
        n_core: u64,
        n_buf: u64,
        n_near: u64,
        far: Option<FarLoad>,
    ) -> u64 {
        let n = match far {
            Some(f) => n_core + n_buf.min(f.kept + f.cells),
            None => n_core + n_buf,
        };
        let stage = self
            .stages
            .iter()
            .map(|m| {
                let near = match m.context_m {
                    Some(_) => n_core + n_near.min(n_buf),
                    None => n,
                };
                (near * m.context_bytes as u64 + n * m.tile_bytes as u64) * 5 / 4
            })
            .max()
            .unwrap_or(0);
        let loading = far.map_or(0, |f| {
            // Far cells are hash-map entries of the cells points fall in: no more than the
            // buffer's points (a large tile of sparse data has many more cells than points).
            f.held.min(n_buf) * self.base_bytes_per_point as u64
                + f.cells.min(n_buf) * FAR_CELL_BYTES
        });
        n * self.base_bytes_per_point as u64 + stage.max(loading)
    }

    /// Memory tokens (shares of the tile memory, one per worker) a tile needs: 1 for a tile
    /// that [`BudgetPlan::fits`], up to [`BudgetPlan::tiles_in_flight`] for one that runs
    /// alone with the whole tile memory; None when even that is too little.
    pub fn tokens_needed(
        &self,
        n_core: u64,
        n_buf: u64,
        n_near: u64,
        far: Option<FarLoad>,
    ) -> Option<usize> {
        let need = self.tile_bytes_needed(n_core, n_buf, n_near, far);
        let tokens = need.div_ceil(self.tile_bytes.max(1)).max(1);
        (tokens <= self.tiles_in_flight as u64).then_some(tokens as usize)
    }

    /// Takes [`STITCH_SHARE`] of the tile memory for the stitcher's frontier and shrinks each
    /// tile's share (and so the largest tile) accordingly.
    ///
    /// Estimate: a border summary costs at most 24 bytes per tile point (one record per
    /// labelled point within the strip; usually a third of the points or fewer) against
    /// `bytes_per_tile_point` (≈ 500–600 with the segment stage) for a tile in flight, and the
    /// frontier held ~5–7 tiles in the runs measured (`scripts/bench_stitch.sh`, the
    /// metamorphic gate): ≤ 7 × 24 / 550 ≈ 0.3 of one tile's share, under 15 % of the tile
    /// memory with two or more workers. The share is a cap, not an estimate: summaries beyond
    /// it wait in a spill file ([`crate::stitch::spill`]; one worker on a dense street holds
    /// a grid column and more, 63 MB against a 16 MB share at 160 MiB). The run reports the
    /// peak in memory and on disk (`stitch.frontier_bytes_max`, `stitch.spill_bytes_max`).
    pub fn reserve_stitch(&mut self) -> Result<()> {
        let all_tiles = self.tile_bytes * self.tiles_in_flight as u64;
        let reserve = (all_tiles as f64 * STITCH_SHARE) as u64;
        let tile_bytes = (all_tiles - reserve) / self.tiles_in_flight.max(1) as u64;
        let max_tile_points = tile_bytes / self.bytes_per_tile_point.max(1) as u64;
        if max_tile_points < 20_000 {
            return Err(Error::Budget(format!(
                "memory budget {} MiB leaves room for only {max_tile_points} points per tile once the stitcher's share is reserved; raise the budget, use fewer threads or set stitch.enabled = false",
                self.budget_bytes >> 20
            )));
        }
        self.stitch_bytes = reserve;
        self.tile_bytes = tile_bytes;
        self.max_tile_points = max_tile_points;
        Ok(())
    }

    /// Takes `bytes` of the tile memory for `what` (held for the whole run, whatever the
    /// tiles: the report's raster) and shrinks each tile's share accordingly.
    pub fn reserve_outputs(&mut self, bytes: u64, what: &str) -> Result<()> {
        let all_tiles = self.tile_bytes * self.tiles_in_flight as u64;
        let tile_bytes = all_tiles.saturating_sub(bytes) / self.tiles_in_flight.max(1) as u64;
        let max_tile_points = tile_bytes / self.bytes_per_tile_point.max(1) as u64;
        if max_tile_points < 20_000 {
            return Err(Error::Budget(format!(
                "memory budget {} MiB leaves room for only {max_tile_points} points per tile once {what} ({} MiB) is reserved; raise the budget or use fewer threads",
                self.budget_bytes >> 20,
                bytes.div_ceil(1 << 20)
            )));
        }
        self.output_bytes += bytes;
        self.tile_bytes = tile_bytes;
        self.max_tile_points = max_tile_points;
        Ok(())
    }
}

/// Bounds of a tile's far-buffer thinning at load (`crate::tiling::load_tile`), for the charge.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct FarLoad {
    /// Buffer points in the zone kept whole (`TileJob::n_kept`: at least the near ones).
    pub kept: u64,
    /// Most far cells, hence far points kept.
    pub cells: u64,
    /// Most far points held while the representatives are chosen.
    pub held: u64,
}

/// Bytes per far cell while a tile's far buffer is thinned: a hash-map entry (key, count, the
/// held list's header: 48 bytes) at the map's worst load after growth, rounded up.
const FAR_CELL_BYTES: u64 = 128;

/// Share of the tile memory reserved for the stitcher (see [`BudgetPlan::reserve_stitch`]).
pub const STITCH_SHARE: f64 = 0.15;

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn plan_scales_with_budget_and_rejects_tiny() {
        let a = BudgetPlan::new(256, 34, 0, 2).unwrap();
        let b = BudgetPlan::new(1024, 34, 0, 2).unwrap();
        assert!(b.max_tile_points > 3 * a.max_tile_points);
        assert!(a.max_tile_points > 200_000, "{a:?}");
        assert!(BudgetPlan::new(64, 34, 4000, 8).is_err());
        let mut s = b.clone();
        s.reserve_stitch().unwrap();
        assert!(s.stitch_bytes > 0);
        let ratio = s.max_tile_points as f64 / b.max_tile_points as f64;
        assert!((ratio - (1.0 - STITCH_SHARE)).abs() < 0.01, "{ratio}");
    }

    #[test]
    fn stages_with_small_context_admit_larger_buffers() {
        let ctx = StageMemory {
            context_bytes: 400,
            tile_bytes: 0,
            context_m: Some(5.0),
        };
        let p = BudgetPlan::with_stages(1024, 34, &[StageMemory::whole(96), ctx], 2).unwrap();
        let m = p.max_tile_points;
        assert_eq!(p.near_m(), 5.0);
        assert!(p.fits(m / 2, m / 2, m / 8, None));
        // Twice the worst-case limit fits when most points are buffer the stage ignores...
        assert!(p.fits(m / 4, 7 * m / 4, m / 4, None));
        // ...but not when they lie within its context, nor when they are core points.
        assert!(!p.fits(m / 4, 7 * m / 4, 7 * m / 4, None));
        assert!(!p.fits(2 * m, 0, 0, None));
    }

    #[test]
    fn a_far_thinned_buffer_is_charged_for_what_is_kept() {
        let p = BudgetPlan::with_stages(1024, 34, &[StageMemory::whole(96)], 2).unwrap();
        let m = p.max_tile_points;
        let (n_core, n_buf, n_near) = (m / 2, 4 * m, m / 4);
        assert!(!p.fits(n_core, n_buf, n_near, None));
        let thin = FarLoad {
            kept: n_near,
            cells: m / 8,
            held: m / 4,
        };
        // Kept: core + near + one point per far cell; what loading holds stays below the
        // stages' bytes for those.
        assert!(p.fits(n_core, n_buf, n_near, Some(thin)));
        let kept = n_core + n_near + m / 8;
        assert_eq!(
            p.tile_bytes_needed(n_core, n_buf, n_near, Some(thin)),
            p.tile_bytes_needed(kept, 0, 0, None)
        );
        // Points of the kept zone are never thinned.
        let whole = FarLoad {
            kept: n_buf,
            ..thin
        };
        assert!(!p.fits(n_core, n_buf, n_near, Some(whole)));
        // Holding many far points while loading is charged.
        let greedy = FarLoad {
            held: 4 * m,
            ..thin
        };
        assert!(!p.fits(n_core, n_buf, n_near, Some(greedy)));
    }
}
