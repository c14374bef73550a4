//! Library error type: every variant names the file, tile or setting involved and says what
//! was expected, so a nightly run's log is enough to act on a failure.

use std::path::PathBuf;

/// Result alias used throughout the library.
pub type Result<T, E = Error> = std::result::Result<T, E>;

/// Everything that can go wrong in tessera's library code.
#[derive(Debug, thiserror::Error)]
pub enum Error {
    /// An input file could not be used; `reason` says what was wrong.
    #[error("input {path}: {reason}")]
    BadInput {
        /// The offending file.
        path: PathBuf,
        /// What was wrong with it.
        reason: String,
    },
    /// A LAS/LAZ library error while reading or writing a file.
    #[error("{path}: {source}")]
    Las {
        /// The file being read or written.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: las::Error,
    },
    /// An operating-system I/O error on a file or directory.
    #[error("{path}: {source}")]
    Io {
        /// The file or directory involved.
        path: PathBuf,
        /// The underlying error.
        #[source]
        source: std::io::Error,
    },
    /// The configuration is invalid.
    #[error("configuration: {0}")]
    Config(String),
    /// The memory budget cannot be met for this input and these settings.
    #[error("memory budget infeasible: {0}")]
    Budget(String),
    /// A processing stage failed on a tile.
    #[error("tile {tile}: stage {stage}: {source}")]
    Stage {
        /// Tile name.
        tile: String,
        /// Stage name.
        stage: &'static str,
        /// What went wrong (the stage's own error, kept as the cause).
        #[source]
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The run stopped because another part of the pipeline failed first; that failure is
    /// the one reported (this one only unwinds the part that noticed).
    #[error("run cancelled after another failure")]
    Cancelled,
    /// Cross-tile stitching failed (an invariant of the message flow or a summary).
    #[error(transparent)]
    Stitch(#[from] StitchError),
    /// The output directory cannot be used as it is (held by another run, or holding files
    /// tessera will not remove without being told to).
    #[error("output directory {path}: {reason}")]
    OutputDir {
        /// The directory.
        path: PathBuf,
        /// Why, and what to do.
        reason: String,
        /// Whether the user's command decides it (e.g. `--overwrite` missing): exit code 2.
        usage: bool,
    },
    /// The data cannot give a meaningful answer (e.g. an evaluation whose reference and
    /// result are not the same points).
    #[error("{0}")]
    Data(String),
    /// An internal invariant was violated (a bug): the run stops rather than lose data.
    #[error("internal error: {0}")]
    Internal(String),
    /// The run finished and its outputs are complete, but its peak resident memory went over
    /// the memory budget it was given: a job under a hard cap of that size would have been
    /// killed. The budget plan missed memory this input needs.
    #[error("the run finished and its outputs are complete, but its peak memory ({peak_mb:.0} MiB) went over the memory budget ({budget_mb} MiB): under a hard cap of that size it would have been killed. The budget plan missed memory this input needs; raise --memory-budget, and please report it with {}", summary.display())]
    OverBudget {
        /// Peak resident set size, MiB.
        peak_mb: f64,
        /// The budget, MiB.
        budget_mb: u64,
        /// The run's summary.json.
        summary: PathBuf,
    },
    /// A `keep_going` run finished, but left inputs or tiles out (listed in its summary).
    #[error("the run finished without {skipped} unreadable input(s) and {failed} failed tile(s) ({points} core points not written); they are listed in {}", summary.display())]
    Incomplete {
        /// Inputs left out.
        skipped: usize,
        /// Tiles left out.
        failed: usize,
        /// Core points of the failed tiles.
        points: u64,
        /// The run's summary.json.
        summary: PathBuf,
    },
}

impl Error {
    /// Shorthand for [`Error::Io`].
    pub fn io(path: impl Into<PathBuf>, source: std::io::Error) -> Self {
        Error::Io {
            path: path.into(),
            source,
        }
    }
    /// Shorthand for [`Error::Las`].
    pub fn las(path: impl Into<PathBuf>, source: las::Error) -> Self {
        Error::Las {
            path: path.into(),
            source,
        }
    }
    /// Shorthand for [`Error::BadInput`].
    pub fn bad_input(path: impl Into<PathBuf>, reason: impl Into<String>) -> Self {
        Error::BadInput {
            path: path.into(),
            reason: reason.into(),
        }
    }
    /// The process exit code for this error: 2 for usage and configuration errors, 3 for a
    /// `--keep-going` run that finished but left inputs or tiles out, 1 otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            Error::Incomplete { .. } => 3,
            Error::OverBudget { .. } => 4,
            e if e.is_usage() => 2,
            _ => 1,
        }
    }
    /// True for errors caused by the user's input or settings rather than by processing.
    pub fn is_usage(&self) -> bool {
        matches!(
            self,
            Error::Config(_) | Error::OutputDir { usage: true, .. }
        )
    }
}

/// Errors of the stitcher: violated invariants of the message flow or of a summary (bugs or
/// corrupted state, never user input), reported instead of writing wrong ids. Defined here,
/// below the stitcher, so that I/O and the error type need not know the stitcher.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum StitchError {
    /// A tile arrived for a cell the tiler never released.
    #[error("stitch: tile {tile} arrived for cell {cell:?}, which was not released")]
    UnknownCell {
        /// Tile name.
        tile: String,
        /// Its cell.
        cell: crate::model::CellKey,
    },
    /// A summary is inconsistent with its tile.
    #[error("stitch: tile {tile}: {reason}")]
    BadSummary {
        /// Tile name.
        tile: String,
        /// What is wrong.
        reason: String,
    },
    /// The run ended with cells that never completed.
    #[error("stitch: {0} cell(s) never completed (first {1:?})")]
    Incomplete(usize, crate::model::CellKey),
    /// A segment id does not fit the output attribute.
    #[error("stitch: segment id {0} does not fit the 32-bit segment_id attribute")]
    IdOverflow(u64),
    /// The frontier's spill file could not be written or read back.
    #[error("stitch: frontier spill file: {0}")]
    Spill(String),
}
