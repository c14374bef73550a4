//! The worker-stage interface: ground, segmentation, labelling plug in here.

use crate::error::Result;
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

/// Pass-through stage: leaves points untouched and reports per-tile statistics.
#[derive(Debug, Default)]
pub struct StatsStage;

impl Stage for StatsStage {
    fn name(&self) -> &'static str {
        "stats"
    }
    fn bytes_per_point(&self) -> usize {
        0
    }
    fn needs_context(&self) -> bool {
        false
    }
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()> {
        let core = &tile.xyz[..tile.n_core];
        let (mut zmin, mut zmax, mut zsum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
        for p in core {
            zmin = zmin.min(p[2]);
            zmax = zmax.max(p[2]);
            zsum += p[2];
        }
        let mut counts = [0u64; 256];
        for rec in tile
            .records
            .chunks_exact(layout.record_len)
            .take(tile.n_core)
        {
            counts[layout.classification(rec) as usize] += 1;
        }
        let classes: BTreeMap<u8, u64> = (0..=255u8).zip(counts).filter(|&(_, n)| n > 0).collect();
        let n = core.len().max(1) as f64;
        report.stats.insert(
            "stats".into(),
            serde_json::json!({
                "core_points": tile.n_core,
                "buffer_points": tile.len() - tile.n_core,
                "z_min": zmin, "z_max": zmax, "z_mean": zsum / n,
                "density_per_m2": tile.n_core as f64 / (tile.core.width() * tile.core.width()),
                "classes": classes,
            }),
        );
        Ok(())
    }
}

/// Builds the stages named in `cfg.stages.run`, each from its own section.
pub fn build_stages(cfg: &crate::config::Config) -> Result<Vec<Box<dyn Stage>>> {
    cfg.stages
        .run
        .iter()
        .map(|n| match n.as_str() {
            "stats" => Ok(Box::new(StatsStage) as Box<dyn Stage>),
            "ground" => Ok(
                Box::new(super::ground_stage::GroundStage::new(cfg.ground.clone()))
                    as Box<dyn Stage>,
            ),
            "segment" => Ok(Box::new(super::segment_stage::SegmentStage::new(
                cfg.segment.clone(),
            )?) as Box<dyn Stage>),
            "label" => Ok(
                Box::new(super::label_stage::LabelStage::new(cfg.label.clone())?) as Box<dyn Stage>,
            ),
            other => Err(crate::error::Error::Config(format!(
                "stages.run: unknown stage \"{other}\" (known: ground, segment, label, stats)"
            ))),
        })
        .collect()
}
