//! The worker-stage interface (ground, segmentation, labelling plug in here) and the
//! registry entry type. A stage knows its own section of the configuration, never the whole
//! configuration: the registry hands it the raw `[name]` table, the stage parses and checks it.

use crate::error::{Error, Result};
use crate::model::{RecordLayout, Tile};
use serde::de::DeserializeOwned;
use serde::Serialize;
use std::collections::BTreeMap;

/// What a stage reports about one tile (merged into the run summary).
#[derive(Debug, Default, Clone, Serialize, serde::Deserialize)]
pub struct TileReport {
    /// Named statistics, per stage.
    pub stats: BTreeMap<String, serde_json::Value>,
    /// Seconds spent per stage.
    pub seconds: BTreeMap<String, f64>,
    /// Per stage: points worked on, CPU time and peak working memory.
    #[serde(default)]
    pub work: BTreeMap<String, StageWork>,
}

/// What one stage cost on one tile.
#[derive(Debug, Default, Clone, Copy, Serialize, serde::Deserialize)]
pub struct StageWork {
    /// Points the stage worked on (its context points, or the points it selects there);
    /// the whole tile unless the stage says otherwise ([`TileReport::worked_on`]).
    pub points: u64,
    /// Points of the tile (core + buffer).
    pub tile_points: u64,
    /// CPU seconds of the threads that ran it.
    pub cpu_seconds: f64,
    /// Peak heap growth during the stage, bytes (0 when not measured).
    pub peak_bytes: u64,
}

impl TileReport {
    /// Records how many points `stage` worked on (called by the stage; the worker fills in
    /// the rest of [`StageWork`]).
    pub fn worked_on(&mut self, stage: &str, points: usize) {
        self.work.entry(stage.to_string()).or_default().points = points as u64;
    }
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
    /// Whether the stage scales intensities by their input file's level
    /// ([`crate::model::RecordLayout::intensity_p99`]); the pipeline then reads each input's
    /// first points before the run.
    fn needs_intensity_scales(&self) -> bool {
        false
    }
    /// How far beyond the core the stage works, metres (None: the whole buffer). Sizes its
    /// share of the memory budget.
    fn context_m(&self) -> Option<f64> {
        None
    }
    /// For a stage reading the whole buffer (`context_m` None): cells such that, beyond the
    /// other stages' context, the stage only uses one representative point per cell, picked by
    /// [`crate::geom::cell_representative`]. None: it needs every buffer point. Lets
    /// tiles thin their far buffers ([`crate::tiling::FarThin`]).
    fn far_cells(&self) -> Option<crate::tiling::FarCells> {
        None
    }
    /// The per-point attributes the stage writes (segment ids are written as the
    /// `segment_id` attribute and stitched across tiles).
    fn writes(&self) -> &'static [Attribute] {
        &[]
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

/// A per-point result a stage writes and later stages may need. Prerequisites between stages
/// are stated in these terms ([`StageSpec::reads`]), so the order check does not know stage
/// names.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "snake_case")]
pub enum Attribute {
    /// Ground / non-ground / low-noise classes of the ground filter (ASPRS 2, 7).
    GroundClasses,
    /// Per-point segment ids and the segment table.
    SegmentIds,
    /// Object and ground-subclass labels (classification codes).
    Labels,
}

impl std::fmt::Display for Attribute {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str(match self {
            Attribute::GroundClasses => "ground classes",
            Attribute::SegmentIds => "segment ids",
            Attribute::Labels => "labels",
        })
    }
}

/// One entry of the stage registry ([`crate::stages::REGISTRY`], the only list of stages): how
/// to check the stage's configuration section and how to build the stage from it. A stage's
/// section, its checks, its memory model and what it writes all live in its own module.
#[derive(Clone, Copy)]
pub struct StageSpec {
    /// Name used in `stages.run`, in reports and as the name of its `[section]`.
    pub name: &'static str,
    /// Attributes the stage needs: a stage writing each must run earlier in `stages.run`.
    pub reads: &'static [Attribute],
    /// Attributes the stage writes (the same list as its [`Stage::writes`]).
    pub writes: &'static [Attribute],
    /// Whether the stage has a configuration section `[name]`.
    pub has_section: bool,
    /// Parses and checks the stage's section (an empty table when the configuration has
    /// none). Called for every registered stage when the configuration is loaded, whether or
    /// not the stage runs, so a wrong value is reported before any input is read.
    pub validate: fn(&toml::Value) -> Result<()>,
    /// Builds the stage from its section (may load side files, e.g. training samples).
    pub build: fn(&toml::Value) -> Result<Box<dyn Stage>>,
}

impl std::fmt::Debug for StageSpec {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("StageSpec")
            .field("name", &self.name)
            .field("reads", &self.reads)
            .field("writes", &self.writes)
            .finish()
    }
}

/// Deserialises the `[stage]` section `raw` into the stage's section type; errors name the
/// section.
pub fn parse_section<T: DeserializeOwned>(stage: &str, raw: &toml::Value) -> Result<T> {
    raw.clone()
        .try_into()
        .map_err(|e: toml::de::Error| Error::Config(format!("[{stage}]: {}", e.to_string().trim())))
}
