//! The worker-stage interface: ground, segmentation, labelling plug in here.

use crate::config::Config;
use crate::error::{Error, Result};
use crate::model::{RecordLayout, Tile};
use serde::Serialize;
use std::collections::BTreeMap;

/// What a stage reports about one tile (merged into the run summary).
#[derive(Debug, Default, Clone, Serialize)]
pub struct TileReport {
    /// Named statistics, per stage.
    pub stats: BTreeMap<String, serde_json::Value>,
    /// Seconds spent per stage.
    pub seconds: BTreeMap<String, f64>,
}

/// One processing step run by the workers on every complete tile (core + buffer points).
///
/// A stage may change records in place (e.g. classification) but must not add, remove or
/// reorder points: results are written for the first `tile.n_core` records.
pub trait Stage: Send + Sync {
    /// Stage name used in configuration and reports.
    fn name(&self) -> &'static str;
    /// Working memory the stage needs per tile point, bytes (an honest upper estimate: it
    /// sizes tiles against the memory budget).
    fn bytes_per_point(&self) -> usize;
    /// Working memory per point of the whole tile, bytes, for stages with a bounded context
    /// (`context_m`) that still build per-point arrays over every tile point; charged on top
    /// of `bytes_per_point` on the context points.
    fn bytes_per_tile_point(&self) -> usize {
        0
    }
    /// Whether the stage reads the buffer points around the core (context). When no stage
    /// does, the pipeline does not build buffers at all.
    fn needs_context(&self) -> bool {
        true
    }
    /// How far beyond the core the stage works, metres (None: the whole buffer). Sizes its
    /// share of the memory budget.
    fn context_m(&self) -> Option<f64> {
        None
    }
    /// For a stage reading the whole buffer (`context_m` None): cells such that, beyond the
    /// other stages' context, the stage only uses one representative point per cell, picked by
    /// [`crate::ground::seeds::cell_representative`]. None: it needs every buffer point. Lets
    /// split tiles thin their far buffers ([`crate::tiling::FarThin`]).
    fn far_cells(&self) -> Option<crate::tiling::FarCells> {
        None
    }
    /// Whether the stage assigns per-point segment ids (written as the `segment_id`
    /// attribute and stitched across tiles).
    fn assigns_segment_ids(&self) -> bool {
        false
    }
    /// Largest classification code the stage may write (codes above 31 need point formats
    /// 6–10; the pipeline then upgrades legacy inputs unless the user chose a format).
    fn max_class_code(&self) -> u8 {
        0
    }
    /// Processes one tile.
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()>;
}

/// One entry of the stage registry ([`REGISTRY`], the only list of stages): how to check the
/// stage's configuration section and how to build it. A stage's section, its checks, its
/// memory model and what it writes all live in its own module.
#[derive(Clone, Copy)]
pub struct StageSpec {
    /// Name used in `stages.run` and in reports.
    pub name: &'static str,
    /// Stages that must run, earlier in `stages.run`, when this one runs.
    pub requires: &'static [&'static str],
    /// Checks the stage's configuration section. Called for every registered stage when the
    /// configuration is loaded, whether or not the stage runs, so a wrong value is reported
    /// before any input is read.
    pub validate: fn(&Config) -> Result<()>,
    /// Builds the stage from its section (may load side files, e.g. training samples).
    pub build: fn(&Config) -> Result<Box<dyn Stage>>,
}

impl std::fmt::Debug for StageSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StageSpec")
            .field("name", &self.name)
            .field("requires", &self.requires)
            .finish()
    }
}

/// Every stage tessera knows, in no particular order. Adding a stage: its module plus one
/// line here.
pub const REGISTRY: &[StageSpec] = &[
    super::stats_stage::SPEC,
    super::ground_stage::SPEC,
    super::segment_stage::SPEC,
    super::label_stage::SPEC,
];

fn spec(name: &str) -> Result<&'static StageSpec> {
    REGISTRY.iter().find(|s| s.name == name).ok_or_else(|| {
        let known: Vec<&str> = REGISTRY.iter().map(|s| s.name).collect();
        Error::Config(format!(
            "stages.run: unknown stage \"{name}\" (known: {})",
            known.join(", ")
        ))
    })
}

/// Checks every registered stage's section, and the stage list: known names, each at most
/// once, prerequisites earlier in the list.
pub fn validate_stages(cfg: &Config) -> Result<()> {
    for s in REGISTRY {
        (s.validate)(cfg)?;
    }
    let run = &cfg.stages.run;
    if run.is_empty() {
        return Err(Error::Config(
            "stages.run must name at least one stage".into(),
        ));
    }
    for (i, name) in run.iter().enumerate() {
        let s = spec(name)?;
        if run[..i].contains(name) {
            return Err(Error::Config(format!("stages.run names \"{name}\" twice")));
        }
        for need in s.requires {
            if !run[..i].iter().any(|r| r == need) {
                return Err(Error::Config(format!(
                    "stages.run: \"{name}\" needs \"{need}\" to run before it"
                )));
            }
        }
    }
    Ok(())
}

/// Builds the stages named in `cfg.stages.run`, each from its own section.
pub fn build_stages(cfg: &Config) -> Result<Vec<Box<dyn Stage>>> {
    cfg.stages
        .run
        .iter()
        .map(|n| (spec(n)?.build)(cfg))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn registry_names_are_unique_prerequisites_registered_and_stages_named_as_listed() {
        let cfg = Config::defaults().unwrap();
        for (i, s) in REGISTRY.iter().enumerate() {
            assert!(
                REGISTRY[..i].iter().all(|o| o.name != s.name),
                "{} registered twice",
                s.name
            );
            for need in s.requires {
                assert!(
                    REGISTRY.iter().any(|o| o.name == *need),
                    "{} requires unregistered {need}",
                    s.name
                );
            }
            // The built stage reports the name it is registered (and configured) under.
            let built = (s.build)(&cfg).unwrap();
            assert_eq!(built.name(), s.name);
        }
    }
}
