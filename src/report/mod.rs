//! Run summary (`summary.json`), process memory figures and the run's `report.html`.

pub mod html;
pub mod overview;

use crate::budget::BudgetPlan;
use serde::Serialize;
use std::collections::BTreeMap;

/// Peak resident set size of this process so far (VmHWM), MiB; `None` where /proc is absent.
pub fn peak_rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmHWM:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// Resident memory sampled over a run (report.html draws it against the budget): every
/// 0.25 s at first; when 512 samples are taken, every other one is dropped and the interval
/// doubles, so a night-long run keeps at most 512.
pub struct MemorySampler {
    stop: std::sync::Arc<std::sync::atomic::AtomicBool>,
    handle: Option<std::thread::JoinHandle<Vec<[f64; 2]>>>,
}

impl MemorySampler {
    /// Starts sampling (VmRSS of this process, MiB, against seconds since the start).
    pub fn start() -> MemorySampler {
        use std::sync::atomic::{AtomicBool, Ordering};
        let stop = std::sync::Arc::new(AtomicBool::new(false));
        let flag = stop.clone();
        let handle = std::thread::Builder::new()
            .name("tessera-rss".into())
            .spawn(move || {
                let t0 = std::time::Instant::now();
                let mut every = std::time::Duration::from_millis(250);
                let mut samples: Vec<[f64; 2]> = Vec::new();
                let mut next = t0;
                while !flag.load(Ordering::Relaxed) {
                    if std::time::Instant::now() >= next {
                        if let Some(mb) = rss_mb() {
                            samples.push([t0.elapsed().as_secs_f64(), mb]);
                        }
                        if samples.len() >= 512 {
                            samples = samples.into_iter().step_by(2).collect();
                            every *= 2;
                        }
                        next += every;
                    }
                    std::thread::sleep(std::time::Duration::from_millis(50));
                }
                if let Some(mb) = rss_mb() {
                    samples.push([t0.elapsed().as_secs_f64(), mb]);
                }
                samples
            })
            .ok();
        MemorySampler { stop, handle }
    }

    /// Stops and returns the samples (seconds, MiB).
    pub fn finish(mut self) -> Vec<[f64; 2]> {
        self.stop.store(true, std::sync::atomic::Ordering::Relaxed);
        self.handle
            .take()
            .and_then(|h| h.join().ok())
            .unwrap_or_default()
    }
}

/// Current resident set size (VmRSS), MiB.
fn rss_mb() -> Option<f64> {
    let s = std::fs::read_to_string("/proc/self/status").ok()?;
    let line = s.lines().find(|l| l.starts_with("VmRSS:"))?;
    let kb: f64 = line.split_whitespace().nth(1)?.parse().ok()?;
    Some(kb / 1024.0)
}

/// One written tile.
#[derive(Debug, Clone, Serialize)]
pub struct TileSummary {
    /// Tile name.
    pub name: String,
    /// Output file name.
    pub file: String,
    /// Core points written.
    pub points: u64,
    /// Buffer points seen as context.
    pub buffer_points: u64,
    /// Per-stage statistics.
    pub stats: BTreeMap<String, serde_json::Value>,
    /// Wall seconds per stage on this tile (empty for a tile a resumed run reused).
    #[serde(skip_serializing_if = "BTreeMap::is_empty")]
    pub seconds: BTreeMap<String, f64>,
}

/// The run summary written to `summary.json`.
#[derive(Debug, Clone, Serialize, Default)]
pub struct Summary {
    /// tessera version.
    pub version: String,
    /// Input files read (skipped inputs not counted).
    pub inputs: usize,
    /// Points announced by the input headers (all read).
    pub points_in: u64,
    /// Core points written (equal to `points_in`, less `points_failed` in a keep-going run).
    pub points_out: u64,
    /// Points the reader read (checked equal to `points_in`, the headers' promise).
    #[serde(default)]
    pub points_read: u64,
    /// Output tiles written.
    pub tiles: usize,
    /// Grid tiles that were split by the quadtree to fit the budget.
    pub tiles_split: usize,
    /// Names of the split grid tiles.
    pub split_tiles: Vec<String>,
    /// Buffer point copies tiles dropped beyond the stages' context as they loaded or split
    /// (`tiling.thin_far_buffers`); never core points.
    pub buffer_points_thinned: u64,
    /// Wall seconds per phase and summed worker seconds per stage.
    pub seconds: BTreeMap<String, f64>,
    /// Per stage, over the tiles this run processed: points worked on, CPU time, peak
    /// working memory.
    pub stages: BTreeMap<String, StageTotals>,
    /// Peak resident set size (VmHWM), MiB.
    pub peak_rss_mb: f64,
    /// Configured memory budget, MiB.
    pub memory_budget_mb: u64,
    /// Overlap buffer used, metres (0 when no stage reads context).
    pub buffer_m: f64,
    /// Most tiles open in the tiler at once.
    pub max_open_tiles: usize,
    /// The resolved budget plan.
    pub budget: Option<BudgetPlan>,
    /// Output point format and record length.
    pub point_format: u8,
    /// Cross-tile stitching statistics (runs with the segment stage and stitching on).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub stitch: Option<crate::stitch::StitchStats>,
    /// Written tiles, by name: every tile when there are at most [`TILE_LIST_INLINE`], else
    /// empty (the tile table holds them all).
    pub tile_list: Vec<TileSummary>,
    /// The tile table: one JSON line per written tile ([`TileSummary`]), in the order the tiles
    /// were written (see [`TileTable`]).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub tile_table: Option<String>,
    /// MCAP inputs: decoding, georeferencing, skipped clouds and dropped points.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub mcap: Vec<crate::io::mcap::McapReport>,
    /// The inputs' linear unit and the distance parameters converted to it.
    pub units: Option<crate::io::crs::UnitsReport>,
    /// Inputs left out because they could not be read (`pipeline.keep_going`; their points
    /// are not in `points_in`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub skipped_inputs: Vec<crate::io::input::SkippedInput>,
    /// Tiles whose processing failed (`pipeline.keep_going`): not written.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub failed_tiles: Vec<FailedTile>,
    /// Core points of the failed tiles (`points_out + points_failed == points_in`).
    #[serde(skip_serializing_if = "is_zero")]
    pub points_failed: u64,
    /// Tiles a resumed run took from the journal of the interrupted run it continues.
    #[serde(default)]
    pub tiles_reused: usize,
    /// Tiles this run processed (all of them, unless it resumed an interrupted run).
    #[serde(default)]
    pub tiles_recomputed: usize,
    /// Per-class files written (`output.per_class`).
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub class_files: Vec<crate::io::perclass::ClassFile>,
    /// Resident memory over the run: (seconds, MiB) samples.
    #[serde(skip_serializing_if = "Vec::is_empty")]
    pub memory_timeline: Vec<[f64; 2]>,
    /// The cells of report.html's rasters (`tessera report` draws the same).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub report_raster: Option<overview::Geometry>,
}

/// File name of the tile table in the output directory.
pub const TILE_TABLE: &str = "tiles.jsonl";

/// Most tiles listed in `summary.json` itself; a larger run lists them only in its tile table.
/// A summary of a province run (10^5–10^6 tiles) would otherwise be hundreds of MB, built in
/// memory at the end of the run.
pub const TILE_LIST_INLINE: usize = 1000;

/// The tile table being written: each booked tile is appended as one JSON line, so the run
/// keeps no per-tile books in memory (only the first [`TILE_LIST_INLINE`], for the summary).
pub struct TileTable {
    path: std::path::PathBuf,
    w: std::io::BufWriter<std::fs::File>,
    rows: usize,
    inline: Vec<TileSummary>,
}

impl TileTable {
    /// Starts the table in `stage` (the run's staging directory).
    pub fn create(stage: &std::path::Path) -> crate::error::Result<TileTable> {
        let path = stage.join(TILE_TABLE);
        let f = std::fs::File::create(&path).map_err(|e| crate::error::Error::io(&path, e))?;
        Ok(TileTable {
            path,
            w: std::io::BufWriter::with_capacity(64 << 10, f),
            rows: 0,
            inline: Vec::new(),
        })
    }

    /// Appends one tile.
    pub fn push(&mut self, t: TileSummary) -> crate::error::Result<()> {
        use std::io::Write;
        serde_json::to_writer(&mut self.w, &t)
            .map_err(std::io::Error::from)
            .and_then(|_| self.w.write_all(b"\n"))
            .map_err(|e| crate::error::Error::io(&self.path, e))?;
        self.rows += 1;
        if self.rows <= TILE_LIST_INLINE {
            self.inline.push(t);
        } else if self.rows == TILE_LIST_INLINE + 1 {
            // Past the inline limit the table alone lists the tiles.
            self.inline = Vec::new();
        }
        Ok(())
    }

    /// Tiles in the table.
    pub fn rows(&self) -> usize {
        self.rows
    }

    /// Flushes the table: its staged path, and the tiles by name when there are at most
    /// [`TILE_LIST_INLINE`] (else none).
    pub fn finish(mut self) -> crate::error::Result<(std::path::PathBuf, Vec<TileSummary>)> {
        use std::io::Write;
        self.w
            .flush()
            .and_then(|_| self.w.get_ref().sync_all())
            .map_err(|e| crate::error::Error::io(&self.path, e))?;
        self.inline.sort_by(|a, b| a.name.cmp(&b.name));
        Ok((self.path, self.inline))
    }
}

pub use crate::io::workspace::for_each_tile;

/// One stage's cost over a run (summary.json `stages`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct StageTotals {
    /// Points the stage worked on, summed over tiles: a point in several tiles' contexts
    /// counts once per tile.
    pub points: u64,
    /// Those points per input point (1.0: every point once; more: repeated context work).
    pub points_per_input_point: f64,
    /// Wall seconds of the workers in the stage, summed over tiles.
    pub seconds: f64,
    /// CPU seconds of the threads that ran it.
    pub cpu_seconds: f64,
    /// CPU microseconds per input point.
    pub cpu_us_per_input_point: f64,
    /// Largest peak heap growth during the stage on one tile, bytes (0: not measured).
    pub peak_bytes: u64,
    /// Largest peak heap growth per tile point (core + buffer) on a tile of at least 10,000
    /// points, bytes (0: not measured).
    pub bytes_per_point_peak: f64,
}

impl StageTotals {
    /// Adds one tile's figures.
    pub fn add(&mut self, w: &crate::stages::StageWork, seconds: f64) {
        self.points += w.points;
        self.seconds += seconds;
        self.cpu_seconds += w.cpu_seconds;
        self.peak_bytes = self.peak_bytes.max(w.peak_bytes);
        if w.tile_points >= 10_000 {
            let b = w.peak_bytes as f64 / w.tile_points as f64;
            self.bytes_per_point_peak = self.bytes_per_point_peak.max(b);
        }
    }

    /// Fills in the per-input-point figures.
    pub fn finish(&mut self, points_in: u64) {
        let n = points_in.max(1) as f64;
        self.points_per_input_point = self.points as f64 / n;
        self.cpu_us_per_input_point = self.cpu_seconds * 1e6 / n;
    }
}

/// A tile a `keep_going` run left out, and why.
#[derive(Debug, Clone, Serialize, serde::Deserialize)]
pub struct FailedTile {
    /// Tile name (a split tile's leaf, or the job whose split failed).
    pub tile: String,
    /// Its core points, not written.
    pub points: u64,
    /// What went wrong.
    pub error: String,
}

fn is_zero(n: &u64) -> bool {
    *n == 0
}

impl Summary {
    /// Whether the run left anything out (inputs or tiles, `pipeline.keep_going`).
    pub fn is_incomplete(&self) -> bool {
        !self.skipped_inputs.is_empty() || !self.failed_tiles.is_empty()
    }
}
