//! Input and output: LAS/LAZ scanning and validation, chunked reading, atomic tile writing,
//! and MCAP drive recordings (decoded and georeferenced into LAS parts, [`mcap`]).

pub mod attributes;
pub mod copc;
pub mod crs;
pub mod detect;
pub mod extra;
pub mod files;
pub mod guard;
pub mod input;
pub mod laswrite;
pub mod mcap;
pub mod output;
pub mod pcd;
pub mod perclass;
pub mod warn;
pub mod workspace;

pub use input::{scan_inputs, InputFile, InputSet};
pub use output::{write_atomic, PendingTile, TileWriter};
