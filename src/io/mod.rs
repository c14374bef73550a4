//! Input and output: LAS/LAZ scanning and validation, chunked reading, atomic tile writing.

pub mod extra;
pub mod input;
pub mod output;
pub mod pcd;

pub use input::{scan_inputs, InputFile, InputSet};
pub use output::{write_atomic, PendingTile, TileWriter};
