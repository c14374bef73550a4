//! `tessera train`: the labelling classifier from classified point files
//! ([`tessera::pipeline::train`]), written as the model file `label.model` names.

use tessera::cli::TrainArgs;
use tessera::label::model::ClassMap;
use tessera::Config;

/// Trains and saves the model.
pub fn train(a: TrainArgs, quiet: bool) -> anyhow::Result<()> {
    let cfg = Config::load(a.cfg.config.as_deref(), &a.cfg.set)?;
    let maps: Vec<ClassMap> = a
        .class_map
        .iter()
        .map(|p| ClassMap::load(p))
        .collect::<tessera::Result<_>>()?;
    let parent = a
        .out
        .parent()
        .filter(|p| !p.as_os_str().is_empty())
        .unwrap_or(std::path::Path::new("."));
    let (model, rep) = tessera::pipeline::train::train(&a.inputs, &maps, &cfg, parent)?;
    model.save(&a.out)?;
    if !quiet {
        let per: Vec<String> = model
            .classes
            .iter()
            .zip(&model.samples)
            .zip(&model.ground)
            .map(|((c, n), g)| format!("{c}{}: {n}", if *g { " (ground)" } else { "" }))
            .collect();
        println!(
            "{}: {} trees on {} samples ({}); pipeline {:.1} s, forest {:.1} s",
            a.out.display(),
            model.forest.trees.len(),
            model.samples.iter().sum::<usize>(),
            per.join(", "),
            rep.pipeline_s,
            rep.forest_s
        );
    }
    Ok(())
}
