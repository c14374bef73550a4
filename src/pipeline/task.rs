//! Tasks of a distributed run: `tessera plan` cuts a region into tasks of grid cells,
//! `tessera run --plan DIR --task I` processes one task, `tessera stitch DIR` joins them.
//!
//! A plan directory holds:
//! - `plan.json` — inputs (absolute paths, in the run's order), grid, tasks;
//! - `tiles.tsv` — every planned grid cell with its estimated points and its task;
//! - `config.toml` — the effective configuration every task and the stitch use (the same
//!   settings everywhere is what makes the tasks' tiles those of one run);
//! - `tasks/task-NNNNN/` — each task's output directory: its tiles (without stitching) or its
//!   deferred tiles and border summaries (in its resume journal), and its `summary.json` once
//!   it finished. A task is a resumable run like any other: rerun after a crash, it continues.
//!
//! A task reads only the inputs whose bounds (widened by the buffer) reach its cells, in the
//! run's order, and bins only points of its cells: each of its tiles gets exactly the points,
//! in the same order, that a single run of the region gives it, so the stages compute the
//! same results.

use crate::error::{Error, Result};
use crate::io::InputFile;
use crate::model::CellKey;
use crate::tiling::Grid;
use serde::Deserialize;
use std::collections::HashSet;
use std::io::BufRead;
use std::path::{Path, PathBuf};

/// The part of `plan.json` runs need.
#[derive(Debug, Clone, Deserialize)]
pub struct PlanFile {
    /// Inputs, in the run's order.
    pub inputs: Vec<PathBuf>,
    /// Points the input headers announce.
    pub points: u64,
    /// Tasks (only their number matters here).
    pub tasks: Vec<serde_json::Value>,
}

impl PlanFile {
    /// Reads `dir/plan.json`.
    pub fn load(dir: &Path) -> Result<PlanFile> {
        let path = dir.join("plan.json");
        let text = crate::io::files::read_text_bounded(&path, 1 << 30)?;
        serde_json::from_str(&text).map_err(|e| {
            Error::Config(format!(
                "{}: not a tessera plan ({e}); write one with `tessera plan`",
                path.display()
            ))
        })
    }

    /// The configuration every task and the stitch run with.
    pub fn config_path(dir: &Path) -> PathBuf {
        dir.join("config.toml")
    }
}

/// The output directory of task `index`.
pub fn task_dir(plan_dir: &Path, index: usize) -> PathBuf {
    plan_dir.join("tasks").join(format!("task-{index:05}"))
}

/// Task index from the first of the job-array variables cluster engines set
/// (`SLURM_ARRAY_TASK_ID`, Kubernetes `JOB_COMPLETION_INDEX`, `AWS_BATCH_JOB_ARRAY_INDEX`).
pub fn task_from_env() -> Result<Option<usize>> {
    for var in [
        "SLURM_ARRAY_TASK_ID",
        "JOB_COMPLETION_INDEX",
        "AWS_BATCH_JOB_ARRAY_INDEX",
    ] {
        if let Ok(v) = std::env::var(var) {
            return v
                .trim()
                .parse()
                .map(Some)
                .map_err(|_| Error::Config(format!("{var}={v:?} is not a task index")));
        }
    }
    Ok(None)
}

/// One task's cells.
#[derive(Debug, Clone)]
pub struct TaskScope {
    /// Task index.
    pub index: usize,
    /// Its grid cells.
    pub cells: HashSet<CellKey>,
}

impl TaskScope {
    /// Task `index`'s cells from `dir/tiles.tsv` (streamed: only this task's are kept).
    pub fn load(dir: &Path, index: usize) -> Result<TaskScope> {
        let path = dir.join("tiles.tsv");
        let f = std::fs::File::open(&path).map_err(|e| Error::io(&path, e))?;
        let mut cells = HashSet::new();
        for (n, line) in std::io::BufReader::new(f).lines().enumerate() {
            let line = line.map_err(|e| Error::io(&path, e))?;
            if n == 0 {
                continue;
            }
            let bad = || {
                Error::Config(format!(
                    "{}: line {} is not `ix iy points task`",
                    path.display(),
                    n + 1
                ))
            };
            let v: Vec<&str> = line.split('\t').collect();
            if v.len() != 4 {
                return Err(bad());
            }
            let task: usize = v[3].parse().map_err(|_| bad())?;
            if task == index {
                let ix: i64 = v[0].parse().map_err(|_| bad())?;
                let iy: i64 = v[1].parse().map_err(|_| bad())?;
                cells.insert((ix, iy));
            }
        }
        Ok(TaskScope { index, cells })
    }

    /// Whether the task must read input `f`: its points' region, widened by the buffer,
    /// reaches one of the task's cells.
    pub fn reads(&self, f: &InputFile, grid: &Grid) -> bool {
        let r = f.accepted().expanded(grid.buffer_m + 1e-3);
        let (ix0, iy0) = grid.cell(r.x0, r.y0);
        let (ix1, iy1) = grid.cell(r.x1, r.y1);
        let span = (ix1 - ix0 + 1).saturating_mul(iy1 - iy0 + 1);
        if span <= self.cells.len() as i64 {
            (ix0..=ix1).any(|ix| (iy0..=iy1).any(|iy| self.cells.contains(&(ix, iy))))
        } else {
            self.cells
                .iter()
                .any(|&(ix, iy)| (ix0..=ix1).contains(&ix) && (iy0..=iy1).contains(&iy))
        }
    }
}
