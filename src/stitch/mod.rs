//! Cross-tile stitching: one global segment id per real-world segment, at fixed memory.
//!
//! Every tile is segmented on its core plus a strip of `strip_m` (`segment.context_m`, capped
//! by the tiling buffer) beyond it, and every point's result comes from its **core** tile. So
//! where two tiles overlap, each overlap point carries two labels: the one from its core tile
//! and the one from the tile that saw it as buffer. Two local segments are the same real
//! segment when they share enough overlap points ([`pairs`]); a union–find over
//! (tile, local segment) nodes ([`components`]) joins them transitively.
//!
//! The flow, all on the writer thread ([`Stitcher`]):
//! 1. the tiler announces each released grid cell and the cells that could share overlap
//!    points with it (those open in the tiler at that moment, see [`CellRelease`]);
//! 2. a worker sends, per processed tile, a [`BorderSummary`]: its labelled points within
//!    `strip_m` of its core edges (inside and outside), keyed by global point id, and the
//!    smallest point ordinal of each local segment; it writes the tile's core points with
//!    local ids to a temporary file;
//! 3. when both tiles of a neighbouring pair have arrived, their summaries are matched and
//!    segments unioned; when a cell and every cell relevant to it are complete, its tiles
//!    *close* (their summaries are dropped: the frontier); a component whose tiles are all
//!    closed can no longer grow, is final and gets its id;
//! 4. a closed tile whose segments are all final is handed back to be written with global ids
//!    (its temporary file is read once).
//!
//! **Global ids** are `1 +` the smallest point ordinal (position of the point in the run's
//! inputs, in input order) among the core points of the component. They depend only on which
//! points form the segment — not on threads, scheduling or, when the segmentation agrees, on
//! the tile size.

pub mod components;
pub mod frontier;
pub mod pairs;
pub mod spill;
pub mod summary;
pub use crate::error::StitchError;
pub use crate::model::CellKey;
pub use crate::tiling::CellRelease;
pub use frontier::{Ready, Stitcher};
pub use summary::{BorderRecord, BorderSummary};
#[cfg(test)]
mod tests;

mod params;
pub use params::*;
