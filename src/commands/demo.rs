//! `tessera demo`: synthesise a street scene, draw training samples from its first 50 m, run
//! the default pipeline and score the labels against the scene's truth.

use anyhow::Context;
use std::path::Path;
use tessera::cli::RunOpts;
use tessera::Config;

/// Runs the demo into `out`.
pub fn demo(out: &Path, length_m: f64, opts: &RunOpts, quiet: bool) -> anyhow::Result<()> {
    let scene_dir = out.join("scene");
    let p = tessera::synth::SceneParams {
        seed: 1,
        length_m,
        ..Default::default()
    };
    let s = tessera::synth::write_scene(&p, &scene_dir, 50.0)
        .with_context(|| format!("synthesising the demo scene into {}", scene_dir.display()))?;
    tracing::info!("demo scene: {} points in {} files", s.points, s.files);
    // Training samples as a user would draw them: the first 50 m of the drive, the four
    // surface classes of the street-level document, from the scene's truth.
    let mut overrides = opts.overrides();
    let first = scene_dir.join("scene_00000.laz");
    if !overrides.iter().any(|o| o.starts_with("label.samples")) && first.is_file() {
        let mut set = tessera::label::samples::from_classified_points(&first, "gt_class", 5.0, 30)?;
        set.samples.retain(|s| [11, 64, 65, 67].contains(&s.class));
        let path = out.join("samples.json");
        set.save(&path)?;
        tracing::info!(
            "demo: {} training samples from the first 50 m: {}",
            set.samples.len(),
            path.display()
        );
        overrides.push(format!("label.samples={:?}", path.display().to_string()));
    }
    // The demo's own tiles directory: an earlier demo's tiles are replaced (only the files
    // its journal lists).
    overrides.push("output.overwrite=true".into());
    let cfg = Config::load(opts.cfg.config.as_deref(), &overrides)?;
    let tiles = out.join("tiles");
    super::run::process(std::slice::from_ref(&scene_dir), &tiles, &cfg, quiet)?;
    if cfg.stages.run.iter().any(|s| s == "label") {
        let e = tessera::eval::eval_labels(
            &scene_dir,
            &tiles,
            &tessera::eval::LabelEvalOptions {
                ref_field: "gt_class".into(),
                res_field: "classification".into(),
                classes: vec![11, 64, 65, 67, 6, 5, 69, 70],
                map: Vec::new(),
                precision_m: 0.001,
                allow_unmatched: false,
                x_range: Some((
                    tessera::synth::WORLD_OFFSET[0] + 50.0,
                    tessera::synth::WORLD_OFFSET[0] + length_m,
                )),
                exclude: Default::default(),
                ref_map: None,
            },
        )?;
        if !quiet {
            println!(
                "demo: labels against the scene's truth beyond the first 50 m (11 road, 64 cycle path, 65 footpath, 67 grass, 6 building, 5 tree, 69 pole, 70 vehicle):\n{}",
                e.table()
            );
        }
    }
    Ok(())
}
