//! The run plan: everything about a run that follows from the configuration, the stages and
//! the scanned inputs, resolved once before any point is read. The reader, tiler, workers and
//! writer each take their part of it, never the whole configuration.
//!
//! Two widths are kept apart here. The **buffer** (`tiling.buffer_m`) is the overlap every
//! tile carries around its core, sized for the stage that needs the most context (the ground
//! filter's seed cells). A stage's **context** (`segment.context_m`, `label.context_m`) is how
//! far beyond the core that stage works, at most the buffer
//! ([`crate::model::stage_context_m`]); the segment stage's context is also the strip in which
//! neighbouring tiles' segments are matched when they are stitched.

use crate::budget::{BudgetPlan, StageMemory};
use crate::config::Config;
use crate::error::{Error, Result};
use crate::io::input::{scan_inputs_skipping, SkippedInput};
use crate::io::output::{Container, SegmentIdType};
use crate::io::{scan_inputs, InputSet, TileWriter};
use crate::model::stage_context_m;
use crate::stages::{Attribute, Stage};
use crate::stitch::StitchParams;
use crate::tiling::{FarThin, Grid, SplitParams};
use std::path::{Path, PathBuf};

/// A run, resolved.
pub struct RunPlan {
    /// The scanned inputs and the run's record layout (the output point format).
    pub set: InputSet,
    /// Inputs left out because they could not be read (`pipeline.keep_going`).
    pub skipped_inputs: Vec<SkippedInput>,
    /// Whether a failed tile is listed and skipped instead of stopping the run.
    pub keep_going: bool,
    /// Tile size and buffer (0 when no stage reads context: buffers only cost).
    pub grid: Grid,
    /// The memory plan (chunk sizes, spill bounds, tile limits).
    pub budget: BudgetPlan,
    /// Stitching, when a stage assigns segment ids and `stitch.enabled`.
    pub stitch: Option<StitchPlan>,
    /// Far-buffer thinning of tiles, when the stages allow it.
    pub far_thin: Option<FarThin>,
    /// Smallest core edge quadtree splitting may produce, metres.
    pub min_tile_size_m: f64,
    /// Whether a stage writes segment ids, and their width in the output.
    pub segment_ids: Option<SegmentIdType>,
    /// How tiles are stored.
    pub container: Container,
    /// Where spill files go (inside the run's work directory).
    pub spill_dir: PathBuf,
    /// The report's raster (reserved in the budget), when the run draws a report.
    pub report_raster: Option<crate::report::overview::Geometry>,
    /// See every record block the tile writer writes (the report's raster, per-class files).
    pub observers: Vec<std::sync::Arc<dyn crate::io::output::WrittenRecords>>,
}

/// What the workers and the writer need to stitch segments across tiles.
pub struct StitchPlan {
    /// Matching parameters.
    pub params: StitchParams,
    /// The overlap strip tiles are matched in: the segment stage's context.
    pub strip_m: f64,
    /// Ordinal of the first point of each input file (prefix sums in input order).
    pub first_ordinal: Vec<u64>,
}

impl StitchPlan {
    /// Position of a point in the run's inputs: dense, deterministic, unique.
    pub fn ordinal(&self, pid: u64) -> u64 {
        let file = crate::model::file_of(pid);
        self.first_ordinal
            .get(file)
            .copied()
            .unwrap_or(u64::MAX >> 1)
            + (pid & ((1 << 40) - 1))
    }
}

impl RunPlan {
    /// Scans `inputs` (LAS/LAZ, MCAP drives already staged) and resolves the run of `stages`
    /// under `cfg`; spill files will go to `work_base/spill`.
    pub fn resolve(
        cfg: &Config,
        stages: &[Box<dyn Stage>],
        inputs: &[PathBuf],
        work_base: &Path,
    ) -> Result<RunPlan> {
        let (set, skipped_inputs) = scan_for_stages(cfg, stages, inputs)?;
        let workers = if cfg.pipeline.threads == 0 {
            std::thread::available_parallelism()
                .map(|n| n.get())
                .unwrap_or(1)
        } else {
            cfg.pipeline.threads
        };
        // Stages run one after the other on a tile and free their working memory before the
        // next starts, so the largest one counts (the plan charges results carried between
        // stages, such as segment labels, to every point).
        let stage_mem: Vec<StageMemory> = stages
            .iter()
            .map(|s| StageMemory {
                context_bytes: s.bytes_per_point(),
                tile_bytes: s.bytes_per_tile_point(),
                context_m: s.context_m(),
            })
            .collect();
        let segmenter = stages
            .iter()
            .find(|s| s.writes().contains(&Attribute::SegmentIds));
        let stitching = segmenter.is_some() && cfg.stitch.enabled;
        let mut budget = BudgetPlan::with_stages(
            cfg.pipeline.memory_budget_mb,
            set.layout.record_len,
            &stage_mem,
            workers,
        )?;
        let report_raster = if cfg.output.report {
            // The report's raster lives for the whole run (drawn as tiles are written): at
            // most 1/8 of the tile memory, so a small budget gets coarser cells, not
            // smaller tiles.
            let share = budget.tile_bytes * budget.tiles_in_flight as u64 / 8;
            let g = crate::report::overview::Geometry::for_bounds_within(
                input_bounds(&set),
                usize::try_from(share / 13).unwrap_or(usize::MAX),
            );
            budget.reserve_outputs(g.bytes(), "the report's raster (output.report = true)")?;
            Some(g)
        } else {
            None
        };
        if stitching {
            budget.reserve_stitch()?;
        }
        // Buffers only cost (spill traffic grows with (tile + 2 buffer)² / tile²): build them
        // only when some stage reads context.
        let buffer_m = if stages.iter().any(|s| s.needs_context()) {
            cfg.tiling.buffer_m
        } else {
            0.0
        };
        let stitch = match segmenter {
            Some(s) if stitching => Some(stitch_plan(cfg, s.as_ref(), &set)),
            _ => None,
        };
        let tile_size_m = crate::tiling::grid::sparse_tile_size(
            cfg.tiling.tile_size_m,
            cfg.tiling.sparse_tile_points,
            set.files.iter().map(|f| (f.bounds, f.points)),
        );
        if tile_size_m != cfg.tiling.tile_size_m {
            tracing::info!(
                "sparse inputs ({} points over their bounds): tiles of {tile_size_m} instead of {} (tiling.sparse_tile_points = {})",
                set.total_points,
                cfg.tiling.tile_size_m,
                cfg.tiling.sparse_tile_points
            );
        }
        // Global ids are point ordinals + 1: u32 while the run has fewer points.
        let id_type = if stitch.is_some() && set.total_points >= u32::MAX as u64 {
            SegmentIdType::U64
        } else {
            SegmentIdType::U32
        };
        Ok(RunPlan {
            grid: Grid {
                tile_size_m,
                buffer_m,
            },
            budget,
            stitch,
            far_thin: far_thin(cfg, stages),
            min_tile_size_m: cfg.tiling.min_tile_size_m,
            segment_ids: segmenter.map(|_| id_type),
            container: Container::parse(&cfg.output.format).unwrap_or(Container::Laz),
            spill_dir: work_base.join("spill"),
            observers: Vec::new(),
            report_raster,
            set,
            skipped_inputs,
            keep_going: cfg.pipeline.keep_going,
        })
    }

    /// The writer of the run's output tiles.
    pub fn tile_writer(&self) -> Result<TileWriter> {
        let mut w = TileWriter::new(
            &self.set.template,
            &self.set.layout,
            self.container,
            self.segment_ids,
        )?;
        for o in &self.observers {
            w.observe(o.clone());
        }
        Ok(w)
    }

    /// Distance from a core within which the tiler counts the buffer points far thinning
    /// keeps whole ([`crate::tiling::TileJob::n_kept`], [`FarThin::count_m`]), so that a
    /// thinned tile's points are bounded by those and its far cells; 0 without thinning.
    pub fn kept_m(&self) -> f64 {
        match self.far_thin {
            Some(f) if f.applies(self.grid.buffer_m) => f.count_m(),
            _ => 0.0,
        }
    }

    /// How a worker splits a job too big for its share of the budget.
    pub fn split_params(&self) -> SplitParams {
        SplitParams {
            min_tile_size_m: self.min_tile_size_m,
            buffer_bytes: self.budget.spill_bytes / self.budget.workers.max(1),
            max_points: self.budget.max_tile_points,
            near_m: self.budget.near_m(),
            far: self.far_thin,
        }
    }
}

/// The region `set` covers: [min x, min y, max x, max y] of its files' headers.
fn input_bounds(set: &InputSet) -> [f64; 4] {
    let mut b = [
        f64::INFINITY,
        f64::INFINITY,
        f64::NEG_INFINITY,
        f64::NEG_INFINITY,
    ];
    for f in set.files.iter().filter(|f| f.points > 0) {
        b[0] = b[0].min(f.bounds.x0);
        b[1] = b[1].min(f.bounds.y0);
        b[2] = b[2].max(f.bounds.x1);
        b[3] = b[3].max(f.bounds.y1);
    }
    b
}

/// Scans the inputs in the output point format: the configured one, else the inputs' own,
/// upgraded to a LAS 1.4 format when a stage writes class codes legacy formats cannot hold
/// or the output is COPC (formats 6, 7, 8 only), with each input's intensity scale when a
/// stage asks for it. With `pipeline.keep_going`, unreadable inputs are left out and returned.
fn scan_for_stages(
    cfg: &Config,
    stages: &[Box<dyn Stage>],
    inputs: &[PathBuf],
) -> Result<(InputSet, Vec<SkippedInput>)> {
    let (mut set, skipped) = scan_for_format(cfg, stages, inputs)?;
    if stages.iter().any(|s| s.needs_intensity_scales()) {
        set.layout.intensity_p99 =
            std::sync::Arc::new(crate::io::input::intensity_scales(&set.files));
    }
    Ok((set, skipped))
}

/// [`scan_for_stages`] up to the point format: the inputs scanned, in a LAS 1.4 format when
/// the stages' class codes or COPC output need one.
fn scan_for_format(
    cfg: &Config,
    stages: &[Box<dyn Stage>],
    inputs: &[PathBuf],
) -> Result<(InputSet, Vec<SkippedInput>)> {
    let requested = cfg.output_point_format()?;
    let (set, skipped) = scan_inputs_skipping(inputs, requested, cfg.pipeline.keep_going)?;
    let max_code = stages.iter().map(|s| s.max_class_code()).max().unwrap_or(0);
    let copc = Container::parse(&cfg.output.format) == Some(Container::Copc);
    let f = &set.layout.format;
    if copc && f.has_waveform {
        return Err(Error::Config(format!(
            "output.format = \"copc\" holds point formats 6, 7 and 8; the inputs carry waveform packets (format {}): write \"laz\" instead",
            f.to_u8().unwrap_or(255)
        )));
    }
    if requested.is_some() || (max_code <= 31 && !copc) || f.is_extended {
        return Ok((set, skipped));
    }
    // Legacy formats hold class codes up to 31; write the LAS 1.4 format with the same
    // attributes (0, 1 → 6; 2, 3 → 7; 4 → 9; 5 → 10) rather than fail or truncate codes.
    let up = match (f.has_color, f.has_waveform) {
        (false, false) => 6,
        (true, false) => 7,
        (false, true) => 9,
        (true, true) => 10,
    };
    let why = if copc {
        "COPC output".to_string()
    } else {
        format!("stages write class codes up to {max_code}")
    };
    tracing::info!(
        "{why}: output point format {} -> {up}",
        f.to_u8().unwrap_or(255)
    );
    // The second scan reads only the inputs the first one kept.
    let kept: Vec<PathBuf> = set.files.iter().map(|f| f.path.clone()).collect();
    Ok((scan_inputs(&kept, Some(up))?, skipped))
}

/// Stitching across the strip of the stage assigning segment ids.
fn stitch_plan(cfg: &Config, segmenter: &dyn Stage, set: &InputSet) -> StitchPlan {
    let mut first_ordinal = Vec::with_capacity(set.files.len());
    let mut acc = 0u64;
    for f in &set.files {
        first_ordinal.push(acc);
        acc += f.points;
    }
    let context_m = segmenter.context_m().unwrap_or(cfg.tiling.buffer_m);
    // The segmenter reads context, so the grid's buffer is `tiling.buffer_m`.
    let strip_m = stage_context_m(context_m, cfg.tiling.buffer_m);
    if strip_m <= 0.0 {
        tracing::warn!(
            "stitching with a 0 m overlap strip ({}.context_m = {context_m}, tiling.buffer_m = {}): segments cannot be matched across borders and keep one id per tile",
            segmenter.name(),
            cfg.tiling.buffer_m
        );
    }
    StitchPlan {
        params: cfg.stitch.clone(),
        strip_m,
        first_ordinal,
    }
}

/// Far-buffer thinning of tiles (as they load and when split): allowed when every stage that
/// reads the whole buffer names its far cells ([`Stage::far_cells`]) and they agree; points
/// within the widest bounded context of the other stages, and at least within
/// `tiling.dense_buffer_m`, are all kept.
fn far_thin(cfg: &Config, stages: &[Box<dyn Stage>]) -> Option<FarThin> {
    if !cfg.tiling.thin_far_buffers {
        return None;
    }
    let readers: Vec<&dyn Stage> = stages
        .iter()
        .filter(|s| s.needs_context())
        .map(|s| s.as_ref())
        .collect();
    let mut cells = None;
    for s in readers.iter().filter(|s| s.context_m().is_none()) {
        let c = s.far_cells()?;
        // Two different representative rules would each need their own points: keep all.
        if cells.is_some_and(|p| p != c) {
            return None;
        }
        cells = Some(c);
    }
    let near_m = readers
        .iter()
        .filter_map(|s| s.context_m())
        .fold(0.0f64, f64::max);
    Some(FarThin {
        near_m: near_m.max(cfg.tiling.dense_buffer_m),
        cells: cells?,
    })
}

/// Makes sure the spill directory exists.
pub(super) fn create_spill_dir(plan: &RunPlan) -> Result<()> {
    std::fs::create_dir_all(&plan.spill_dir).map_err(|e| Error::io(&plan.spill_dir, e))
}
