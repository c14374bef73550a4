//! Input and output: LAS/LAZ scanning and validation, chunked reading, atomic tile writing.

pub mod input;
pub mod output;

pub use input::{scan_inputs, InputFile, InputSet};
pub use output::{write_atomic, PendingTile, TileWriter};
