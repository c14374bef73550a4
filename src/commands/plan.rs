//! `tessera plan`: a region plan from the input headers (see [`tessera::region`]).

use std::path::{Path, PathBuf};
use tessera::cli::ConfigOpts;
use tessera::tiling::Grid;
use tessera::Config;

/// Plans `inputs` into `tasks` tasks and writes the plan into `out`.
pub fn plan(
    inputs: &[PathBuf],
    out: &Path,
    tasks: usize,
    opts: &ConfigOpts,
    quiet: bool,
) -> anyhow::Result<()> {
    let cfg = Config::load(opts.config.as_deref(), &opts.set)?;
    // The grid in the inputs' unit, as the tasks will cut it (the plan keeps the settings in
    // metres; each task converts them the same way).
    let expanded = tessera::io::input::expand_paths(inputs)?;
    let (unit_cfg, _) = tessera::pipeline::units::for_inputs(&cfg, &expanded)?;
    let grid = Grid {
        tile_size_m: unit_cfg.tiling.tile_size_m,
        buffer_m: unit_cfg.tiling.buffer_m,
    };
    let plan =
        tessera::region::plan_region(inputs, grid, unit_cfg.tiling.sparse_tile_points, tasks)?;
    plan.write(out, &cfg.effective)?;
    if !quiet {
        println!(
            "{} inputs, {} points, {} tiles in {} tasks ({} m tiles); {}",
            plan.inputs.len(),
            plan.points,
            plan.tiles.len(),
            plan.tasks.len(),
            plan.tile_size_m,
            out.join("plan.json").display()
        );
        for t in &plan.tasks {
            println!(
                "  task {:>4}: {:>6} tiles, {:>12} points",
                t.index, t.tiles, t.points
            );
        }
    }
    Ok(())
}
