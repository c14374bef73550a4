//! Region plans (`tessera plan`): from the input headers alone, the grid tiles a run will
//! produce with their estimated point counts, cut into tasks of spatially compact blocks
//! balanced by points — what a cluster job array distributes.
//!
//! Estimate: each input's points are spread uniformly over its header bounds, so a tile gets
//! the share of every input whose bounds overlap its core (by area), at least 1: every tile an
//! input reaches is planned. Tasks: tiles in Morton
//! order (a space-filling curve: consecutive tiles are neighbours, so a task is a compact
//! block, and its inputs and buffers are mostly its own), cut where the running sum of
//! estimated points crosses each multiple of `total / tasks`.
//!
//! Memory: one entry per tile with points (24 bytes) plus one per input; the inputs' headers
//! are read one at a time.

use crate::error::{Error, Result};
use crate::io::input::{expand_paths, scan_file};
use crate::model::Rect;
use crate::tiling::{morton, Grid};
use serde::Serialize;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// One planned tile.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlannedTile {
    /// Grid column and row.
    pub ix: i64,
    /// Grid row.
    pub iy: i64,
    /// Estimated core points.
    pub points: u64,
    /// The task it belongs to (0-based).
    pub task: usize,
}

/// One task: a contiguous run of tiles in Morton order.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct PlannedTask {
    /// Task index (0-based; `SLURM_ARRAY_TASK_ID` style).
    pub index: usize,
    /// Tiles in the task.
    pub tiles: usize,
    /// Estimated core points.
    pub points: u64,
    /// Union of its tiles' cores.
    pub bounds: Option<Rect>,
}

/// A region plan.
#[derive(Debug, Clone, Serialize)]
pub struct RegionPlan {
    /// Grid the tiles are cut on.
    pub tile_size_m: f64,
    /// Buffer each tile carries (its task reads the inputs reaching its core plus this).
    pub buffer_m: f64,
    /// Inputs planned (paths, in the run's order).
    pub inputs: Vec<PathBuf>,
    /// Points announced by the input headers.
    pub points: u64,
    /// Tasks, by index.
    pub tasks: Vec<PlannedTask>,
    /// Every tile an input's bounds overlap (Morton order).
    #[serde(skip)]
    pub tiles: Vec<PlannedTile>,
}

/// Plans `inputs` (LAS/LAZ files or directories) on `grid` into `tasks` tasks.
/// The grid's tile size grows for sparse inputs as a run's does (`sparse_tile_points`,
/// [`crate::tiling::grid::sparse_tile_size`]).
pub fn plan_region(
    inputs: &[PathBuf],
    grid: Grid,
    sparse_tile_points: u64,
    tasks: usize,
) -> Result<RegionPlan> {
    if tasks == 0 {
        return Err(Error::Config("plan: --tasks must be at least 1".into()));
    }
    let paths = expand_paths(inputs)?;
    if let Some(p) = paths.iter().find(|p| crate::io::mcap::is_mcap(p)) {
        return Err(Error::Config(format!(
            "plan: {} is an MCAP drive; region plans read LAS/LAZ headers only (process drives with `tessera run`)",
            p.display()
        )));
    }
    // Absolute paths: the tasks run elsewhere (another working directory, another node).
    let paths = paths
        .iter()
        .map(|p| std::fs::canonicalize(p).map_err(|e| Error::io(p, e)))
        .collect::<Result<Vec<PathBuf>>>()?;
    let mut cells: HashMap<(i64, i64), f64> = HashMap::new();
    let mut total = 0u64;
    // (bounds, accepted region, points) of each input: the grid's size depends on them all.
    let mut extents = Vec::with_capacity(paths.len());
    for (i, p) in paths.iter().enumerate() {
        let f = scan_file(p, i)?;
        total += f.points;
        extents.push((f.bounds, f.accepted(), f.points));
    }
    let grid = Grid {
        tile_size_m: crate::tiling::grid::sparse_tile_size(
            grid.tile_size_m,
            sparse_tile_points,
            extents.iter().map(|e| (e.0, e.2)),
        ),
        ..grid
    };
    for (_, accepted, points) in &extents {
        // Over the region where the file's points may lie (its bounds plus the rounding
        // tolerance the tiler accepts): a cell only a rounded point reaches is planned too.
        spread(accepted, *points, &grid, &mut cells);
    }
    let mut tiles: Vec<PlannedTile> = cells
        .into_iter()
        // Every tile some input's bounds overlap is listed, at least 1 point: it may hold
        // points, and a tile missing from the plan would never be processed.
        .map(|((ix, iy), est)| PlannedTile {
            ix,
            iy,
            points: (est.round() as u64).max(1),
            task: 0,
        })
        .collect();
    tiles.sort_by_key(|t| (morton(t.ix, t.iy), t.ix, t.iy));
    let planned: u64 = tiles.iter().map(|t| t.points).sum();
    let mut out_tasks: Vec<PlannedTask> = (0..tasks)
        .map(|index| PlannedTask {
            index,
            tiles: 0,
            points: 0,
            bounds: None,
        })
        .collect();
    // A tile goes to the task its midpoint (in cumulative points) falls in: contiguous runs,
    // each near total / tasks; a tile larger than a share takes one task alone.
    let mut before = 0u64;
    for t in &mut tiles {
        let mid = before as f64 + t.points as f64 / 2.0;
        t.task = ((mid / planned.max(1) as f64 * tasks as f64) as usize).min(tasks - 1);
        before += t.points;
        let task = &mut out_tasks[t.task];
        task.tiles += 1;
        task.points += t.points;
        let core = grid.cell_rect(t.ix, t.iy);
        task.bounds = Some(match task.bounds {
            None => core,
            Some(b) => Rect {
                x0: b.x0.min(core.x0),
                y0: b.y0.min(core.y0),
                x1: b.x1.max(core.x1),
                y1: b.y1.max(core.y1),
            },
        });
    }
    Ok(RegionPlan {
        tile_size_m: grid.tile_size_m,
        buffer_m: grid.buffer_m,
        inputs: paths,
        points: total,
        tasks: out_tasks,
        tiles,
    })
}

/// Adds `points` spread uniformly over `bounds` to the cells it overlaps. Degenerate bounds
/// (a line or a point) put everything in the cells containing them, equally.
fn spread(bounds: &Rect, points: u64, grid: &Grid, cells: &mut HashMap<(i64, i64), f64>) {
    if points == 0 {
        return;
    }
    let (ix0, iy0) = grid.cell(bounds.x0, bounds.y0);
    let (ix1, iy1) = grid.cell(bounds.x1, bounds.y1);
    let area = bounds.width() * (bounds.y1 - bounds.y0);
    let n_cells = ((ix1 - ix0 + 1) * (iy1 - iy0 + 1)) as f64;
    for ix in ix0..=ix1 {
        for iy in iy0..=iy1 {
            let share = if area > 0.0 {
                let c = grid.cell_rect(ix, iy);
                let w = (c.x1.min(bounds.x1) - c.x0.max(bounds.x0)).max(0.0);
                let h = (c.y1.min(bounds.y1) - c.y0.max(bounds.y0)).max(0.0);
                w * h / area
            } else {
                1.0 / n_cells
            };
            if share > 0.0 {
                *cells.entry((ix, iy)).or_default() += share * points as f64;
            }
        }
    }
}

impl RegionPlan {
    /// Writes `plan.json` (grid, inputs, tasks), `tiles.tsv` (one line per tile: `ix`,
    /// `iy`, estimated points, task) and `config.toml` (`settings`: every effective setting,
    /// which the tasks and the stitch run with) into `dir` (created if missing). Each file is
    /// written whole and renamed into place; an existing plan is never replaced.
    pub fn write(
        &self,
        dir: &Path,
        settings: &std::collections::BTreeMap<String, String>,
    ) -> Result<()> {
        std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
        let json = dir.join("plan.json");
        if json.exists() {
            return Err(Error::Config(format!(
                "{} exists: a plan is never replaced; remove it or choose another directory",
                json.display()
            )));
        }
        let mut tsv = String::from("ix\tiy\tpoints\ttask\n");
        for t in &self.tiles {
            tsv.push_str(&format!("{}\t{}\t{}\t{}\n", t.ix, t.iy, t.points, t.task));
        }
        crate::io::write_atomic(&dir.join("tiles.tsv"), tsv.as_bytes())?;
        let mut toml = String::from(
            "# The settings of this plan's runs (written by `tessera plan`): every task and the\n# stitch use them, so the tasks' tiles are those of one run of the region.\n",
        );
        for (k, v) in settings {
            // Dotted keys: one line per setting, valid TOML.
            let key: Vec<String> = k.split('.').map(|p| format!("{p:?}")).collect();
            toml.push_str(&format!("{} = {v}\n", key.join(".")));
        }
        crate::io::write_atomic(&dir.join("config.toml"), toml.as_bytes())?;
        let body = serde_json::to_vec_pretty(self).map_err(|e| Error::Internal(e.to_string()))?;
        // plan.json last: it marks the plan complete.
        crate::io::write_atomic(&json, &body)
    }
}
