//! What the tiler hands on: cell releases (for the stitcher) and tile jobs (for the workers).

use super::spill::SpillPart;
use crate::model::{CellKey, Rect, TileId, TileName};

/// The tiler's release of one grid cell (what the stitcher needs to know which tiles can
/// still share overlap points).
#[derive(Debug, Clone, PartialEq)]
pub struct CellRelease {
    /// The cell.
    pub cell: CellKey,
    /// Whether it has core points (it becomes a worker job) or not (nothing will arrive).
    pub has_core: bool,
    /// Neighbouring cells (of the 8) still open in the tiler at release time.
    pub open_neighbours: Vec<CellKey>,
}

/// A complete tile waiting for a worker: its points are in spill files and, for tiles released
/// while their buffers still held points, partly in memory.
#[derive(Debug)]
pub struct TileJob {
    /// Identity.
    pub id: TileId,
    /// Printable name.
    pub name: TileName,
    /// Core rectangle.
    pub core: Rect,
    /// Buffer width.
    pub buffer_m: f64,
    /// Core points.
    pub core_part: SpillPart,
    /// Buffer points.
    pub buf_part: SpillPart,
    /// Core points (in `core_part`).
    pub n_core: u64,
    /// Buffer points (in `buf_part`).
    pub n_buf: u64,
    /// Of those, the points within `near_m` of the core (the stages' widest bounded context):
    /// what those stages hold (`BudgetPlan::fits`).
    pub n_near: u64,
    /// Of the buffer points, those within [`crate::tiling::FarThin::count_m`] of the core,
    /// which far thinning keeps whole (0 when the run does not thin).
    pub n_kept: u64,
    /// Whether the far part of the buffer holds only cell representatives already (a split
    /// child, [`crate::tiling::FarThin`]); a grid tile's buffer is thinned while it loads.
    pub far_thinned: bool,
}
