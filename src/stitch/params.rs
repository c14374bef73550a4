//! The stitcher's parameters (`[stitch]` section) and statistics.

use serde::{Deserialize, Serialize};

/// `[stitch]` configuration section.
#[derive(Debug, Clone, PartialEq, Deserialize, Serialize)]
#[serde(deny_unknown_fields)]
pub struct StitchParams {
    /// Stitch segments across tile borders when the segment stage runs (false: segment ids
    /// stay local to each tile, 1..=N).
    pub enabled: bool,
    /// Two segments of neighbouring tiles merge only if they share at least this many
    /// overlap points …
    pub min_shared_points: usize,
    /// … and more than this fraction of *each* segment's overlap points (its points in the
    /// overlap of the two tiles); 0.5 = a strict majority of both, one-to-one. See [`super::pairs`].
    pub majority_fraction: f64,
}

impl Default for StitchParams {
    fn default() -> Self {
        StitchParams {
            enabled: true,
            min_shared_points: 5,
            majority_fraction: 0.5,
        }
    }
}

impl StitchParams {
    /// Checks ranges; says which key is wrong.
    pub fn validate(&self) -> Result<(), String> {
        if self.min_shared_points == 0 {
            return Err("stitch.min_shared_points must be ≥ 1".into());
        }
        if !(self.majority_fraction > 0.0 && self.majority_fraction < 1.0) {
            return Err(format!(
                "stitch.majority_fraction must be in (0, 1), got {}",
                self.majority_fraction
            ));
        }
        Ok(())
    }
}

/// Stitching statistics (the `stitch` object of `summary.json`).
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct StitchStats {
    /// Overlap strip width used, metres.
    pub strip_m: f64,
    /// The merge thresholds used.
    pub min_shared_points: usize,
    /// The merge thresholds used.
    pub majority_fraction: f64,
    /// Tiles stitched.
    pub tiles: u64,
    /// Neighbouring tile pairs whose overlaps were matched.
    pub tile_pairs: u64,
    /// Overlap points labelled by both tiles of a pair.
    pub shared_points: u64,
    /// Segment pairs sharing at least one overlap point.
    pub candidate_pairs: u64,
    /// Candidate pairs that passed the thresholds.
    pub accepted_pairs: u64,
    /// Candidate pairs below the thresholds (kept apart).
    pub rejected_pairs: u64,
    /// Unions that joined two different components.
    pub merges: u64,
    /// Local segments (with core points) across all tiles.
    pub local_segments: u64,
    /// Final global segments with core points.
    pub global_segments: u64,
    /// Global segments with core points in two or more tiles (crossing a border).
    pub segments_crossing_borders: u64,
    /// Largest number of tiles a global segment has core points in.
    pub max_tiles_per_segment: u64,
    /// Most tiles whose border summaries were held at once (the frontier).
    pub frontier_tiles_max: u64,
    /// Most border records held at once (in memory and spilled).
    pub frontier_records_max: u64,
    /// Most bytes of border summaries held in memory at once (the rest is spilled).
    pub frontier_bytes_max: u64,
    /// Most union–find nodes (segments of components not yet final) held at once.
    pub open_nodes_max: u64,
    /// Most closed tiles waiting for a component to become final before being written.
    pub waiting_tiles_max: u64,
    /// Border summaries moved to the spill file (the frontier beyond its memory share).
    pub spilled_summaries: u64,
    /// Bytes written to the spill file.
    pub spill_bytes_written: u64,
    /// Spilled summaries read back to be matched with an arriving neighbour.
    pub spill_reads: u64,
    /// Bytes read back from the spill file.
    pub spill_bytes_read: u64,
    /// Most bytes of summaries waiting in the spill file at once.
    pub spill_bytes_max: u64,
}
