//! Training the labelling classifier (`tessera train`): the pipeline runs on the training
//! files exactly as it will at run time (tiles, contexts, ground filter, segmentation, the
//! rules), with the labelling stage in training mode: it hands the descriptors of its core
//! points to a [`Collector`], keyed by the points' global ids, whose reference classes were
//! read from the files first. Then a random forest is grown on a deterministic class-wise
//! sample.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::label::descriptors;
use crate::label::forest::Forest;
use crate::label::model::{ClassMap, Collector, Model, FORMAT};
use crate::stages::label::{LabelSection, LabelStage, NAME};
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// What a training produced besides the model.
#[derive(Debug, Clone)]
pub struct TrainReport {
    /// Seconds running the pipeline over the training files.
    pub pipeline_s: f64,
    /// Seconds growing the forest.
    pub forest_s: f64,
}

/// The training runs' output directory, removed when training ends (also on errors).
struct Scratch(PathBuf);
impl Drop for Scratch {
    fn drop(&mut self) {
        let _ = std::fs::remove_dir_all(&self.0);
    }
}

/// The tessera code of every point of `f`, by the first class map whose field it has.
fn reference_codes(f: &Path, maps: &[ClassMap]) -> Result<Vec<u8>> {
    let mut why = Vec::new();
    for m in maps {
        match crate::eval::load_fields(f, 0.001, &[m.field.as_str()]) {
            Ok(v) => return Ok(v.values[0].iter().map(|&c| m.code_of(c)).collect()),
            Err(Error::Config(e)) => why.push(e),
            Err(e) => return Err(e),
        }
    }
    Err(Error::Config(format!(
        "train: no class map fits {}: {}",
        f.display(),
        why.join("; ")
    )))
}

/// Trains a model on `inputs` (files or directories of LAS/LAZ), their reference classes
/// translated by `maps` (each file uses the first map whose field it has), with the
/// pipeline and forest parameters of `cfg`. `scratch_dir` receives the runs' throw-away tiles.
pub fn train(
    inputs: &[PathBuf],
    maps: &[ClassMap],
    cfg: &Config,
    scratch_dir: &Path,
) -> Result<(Model, TrainReport)> {
    let mut cfg = cfg.clone();
    // The tiles are thrown away: let each run take the point format its input needs (files
    // of one training set may differ) instead of a configured one.
    cfg.output.point_format = toml::Value::String("auto".into());
    let files = crate::io::input::expand_paths(inputs)?;
    let Some(pos) = cfg.stages.run.iter().position(|n| n == NAME) else {
        return Err(Error::Config(
            "train: stages.run must include \"label\"".into(),
        ));
    };
    let section: LabelSection = cfg.stage_section(NAME)?;
    let params = section.train.clone();
    let collector = Arc::new(Collector::new(params.max_samples_per_class));
    let mut stages = crate::stages::build_stages(&cfg.stages.run, &cfg.sections)?;
    stages[pos] = Box::new(LabelStage::for_training(section, collector.clone())?);
    let t = std::time::Instant::now();
    // One run per file: training files come from different sources (a scanner's frames, a
    // synthetic drive's tiles) whose attributes one run could not mix.
    for (run, f) in files.iter().enumerate() {
        collector.set_refs(run as u64, vec![reference_codes(f, maps)?]);
        let work =
            Scratch(scratch_dir.join(format!(".tessera-train-{}-{run}", std::process::id())));
        super::run_with_stages(std::slice::from_ref(f), &work.0, &cfg, &stages, &|_, _| {})?;
    }
    let pipeline_s = t.elapsed().as_secs_f64();
    drop(stages);
    let collector = Arc::try_unwrap(collector)
        .map_err(|_| Error::Internal("train: the collector is still shared".into()))?;
    let set = collector.finish();
    if set.classes.len() < 2 {
        return Err(Error::Config(format!(
            "train: the inputs hold {} of the class maps' classes; at least 2 are needed",
            set.classes.len()
        )));
    }
    let t = std::time::Instant::now();
    let forest = Forest::train(
        &set.x,
        &set.y,
        descriptors::feature_count(),
        set.classes.len(),
        &params,
    );
    let forest_s = t.elapsed().as_secs_f64();
    let model = Model {
        format: FORMAT.into(),
        features: descriptors::feature_names(),
        classes: set.classes,
        ground: set.ground,
        samples: set.samples,
        trained_on: files.iter().map(|f| f.display().to_string()).collect(),
        params,
        forest,
    };
    Ok((
        model,
        TrainReport {
            pipeline_s,
            forest_s,
        },
    ))
}
