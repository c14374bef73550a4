//! Mobile-mapping drives recorded as MCAP: `sensor_msgs/PointCloud2` in ROS 1 or ROS 2 (CDR)
//! encoding, placed in the world frame with `/tf` + `/tf_static`, `nav_msgs/Odometry` or a
//! trajectory file, and handed to the tiler.
//!
//! ```text
//! recording.mcap ──pass 1: poses──▶ TfTree (/tf, /tf_static | odometry | trajectory CSV)
//!                └─pass 2: clouds─▶ decode PointCloud2 → drop NaN / near points → pose at the
//!                                   cloud's (or each point's) time → world coordinates
//!                                   → LAS 1.4 parts (format 6, or 7 with RGB) in the run's
//!                                   work directory → the normal input set
//! ```
//! Why a temporary LAS and not a direct feed: the tiler must know each input's xy bounds
//! before reading it (a tile is complete once every input that can reach it is done), and an
//! MCAP's georeferenced extent is only known after decoding it. Writing the decoded points
//! once to uncompressed LAS parts (each part a stretch of the drive, so tiles complete as the
//! drive goes on) gives exact header bounds, keeps one reading path for all inputs, and costs
//! one sequential write and read of ~40 bytes per point.
//!
//! Modules: [`wire`] (ROS 1 / CDR primitives), [`pointcloud2`] (the cloud message and field
//! access), [`tf`] (pose messages, transform tree, interpolation), [`trajectory`] (CSV poses),
//! [`reader`] (memory-mapped, chunk-streaming MCAP access), [`fields`] (which cloud fields go
//! where in LAS), [`convert`] (the two passes, staging the inputs of a run), [`report`] (what
//! a conversion reports), [`clouds`] (pass 2: parallel placing, ordered writing), [`place`]
//! (one cloud into the world), [`parts`] (LAS parts), [`encode`] (CDR writing for the
//! simulated drive), [`mod@info`] (`tessera info`).

pub mod clouds;
pub mod convert;
pub mod encode;
pub mod fields;
pub mod info;
pub mod parts;
pub mod place;
pub mod pointcloud2;
pub mod reader;
pub mod report;
pub mod tf;
pub mod trajectory;
pub mod wire;

pub use convert::{convert_file, convert_file_with, stage_inputs, Conversion, StagedInputs};
pub use info::{info, McapInfo};
pub use reader::McapSource;
pub use report::McapReport;

/// The 8 bytes every MCAP file starts (and ends) with.
pub const MAGIC: &[u8] = mcap::MAGIC;

use crate::error::{Error, Result};
use serde::Deserialize;
use std::path::Path;

/// Where poses come from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum PoseSource {
    /// `/tf` (timed) and `/tf_static` (fixed) transforms.
    Tf,
    /// `nav_msgs/Odometry` on `odometry_topic` (plus `/tf_static` for the sensor mount).
    Odometry,
    /// A trajectory file (plus `/tf_static` for the sensor mount).
    Trajectory,
}

/// What to do with a cloud that cannot be used (undecodable, no pose at its time) or with a
/// damaged part of the file.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum OnError {
    /// Stop with an error naming the file, topic and time.
    Fail,
    /// Skip it, count it in `summary.json`, and go on (the run still fails if nothing usable
    /// remains).
    Skip,
}

/// Which extra cloud fields are kept as LAS extra bytes.
#[derive(Debug, Clone, PartialEq, Eq, Deserialize)]
#[serde(untagged)]
pub enum ExtraFields {
    /// `"all"` or `"none"`.
    Keyword(String),
    /// These names (missing ones are an error).
    Names(Vec<String>),
}

/// `[mcap]` settings.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct McapParams {
    /// PointCloud2 topics to read; empty = every PointCloud2 channel.
    pub cloud_topics: Vec<String>,
    /// Frame the points are placed in.
    pub target_frame: String,
    /// Where poses come from.
    pub pose_source: PoseSource,
    /// Topic of timed transforms.
    pub tf_topic: String,
    /// Topic of fixed transforms.
    pub tf_static_topic: String,
    /// `nav_msgs/Odometry` topic (pose_source = "odometry").
    pub odometry_topic: String,
    /// Trajectory CSV (pose_source = "trajectory").
    pub trajectory_file: String,
    /// Frame whose poses the trajectory file gives (in `target_frame`).
    pub trajectory_frame: String,
    /// Per-point pose at each point's own time (needs a time field).
    pub deskew: bool,
    /// Per-point time field: "auto", "" (none) or a field name.
    pub time_field: String,
    /// Seconds per unit of the time field; 0 = auto (1e-9 for integer fields, 1 for floats).
    pub time_unit_s: f64,
    /// Largest gap between two pose samples that is still interpolated, seconds.
    pub max_pose_gap_s: f64,
    /// How far beyond the first/last pose sample the end pose is still used, seconds.
    pub pose_extrapolation_s: f64,
    /// Points closer than this to the sensor origin are dropped (and counted), metres.
    pub min_range_m: f64,
    /// Added to every world coordinate (e.g. the projected origin of a local map frame).
    pub world_offset: [f64; 3],
    /// Coordinate reference system note: WKT is written as the LAS CRS, any other text
    /// (e.g. "EPSG:28992") is kept as a note in the output header and summary.
    pub crs: String,
    /// LAS coordinate resolution of the decoded points, metres.
    pub scale_m: f64,
    /// Field written as LAS intensity (rounded, clamped to 0..=65535).
    pub intensity_field: String,
    /// Fields kept as extra bytes: "all", "none" or a list of names.
    pub extra_fields: ExtraFields,
    /// What to do with unusable clouds and damaged chunks.
    pub on_error: OnError,
    /// Points per temporary LAS part.
    pub part_points: u64,
}

impl McapParams {
    /// Checks value ranges and combinations.
    pub fn validate(&self) -> Result<()> {
        let bad = |m: String| Err(Error::Config(format!("mcap.{m}")));
        if self.target_frame.trim_start_matches('/').is_empty() {
            return bad("target_frame must not be empty".into());
        }
        if self.pose_source == PoseSource::Odometry && self.odometry_topic.is_empty() {
            return bad("odometry_topic is required with pose_source = \"odometry\"".into());
        }
        if self.pose_source == PoseSource::Trajectory
            && (self.trajectory_file.is_empty() || self.trajectory_frame.is_empty())
        {
            return bad(
                "trajectory_file and trajectory_frame are required with pose_source = \"trajectory\""
                    .into(),
            );
        }
        for (k, v) in [
            ("time_unit_s", self.time_unit_s),
            ("max_pose_gap_s", self.max_pose_gap_s),
            ("pose_extrapolation_s", self.pose_extrapolation_s),
            ("min_range_m", self.min_range_m),
        ] {
            if !(v.is_finite() && v >= 0.0) {
                return bad(format!("{k} must be a finite number >= 0, got {v}"));
            }
        }
        if !(self.scale_m.is_finite() && self.scale_m > 0.0 && self.scale_m <= 1.0) {
            return bad(format!("scale_m must be in (0, 1], got {}", self.scale_m));
        }
        if self.world_offset.iter().any(|v| !v.is_finite()) {
            return bad(format!(
                "world_offset must be finite, got {:?}",
                self.world_offset
            ));
        }
        if let ExtraFields::Keyword(k) = &self.extra_fields {
            if k != "all" && k != "none" {
                return bad(format!(
                    "extra_fields must be \"all\", \"none\" or a list of names, got \"{k}\""
                ));
            }
        }
        if self.part_points < 1000 {
            return bad(format!(
                "part_points must be at least 1000, got {}",
                self.part_points
            ));
        }
        Ok(())
    }
}

/// True if `path` starts with the MCAP magic (or, when unreadable, is named `*.mcap`).
pub fn is_mcap(path: &Path) -> bool {
    use std::io::Read;
    let mut head = [0u8; 8];
    // Only regular files are opened: opening a FIFO would block until a writer appears.
    let opened = crate::io::files::open_regular(path).ok();
    match opened
        .ok_or_else(|| std::io::Error::other("not a regular file"))
        .and_then(|mut f| f.read_exact(&mut head))
    {
        Ok(()) => head == mcap::MAGIC,
        Err(_) => has_mcap_extension(path),
    }
}

/// True if the file name ends in `.mcap`.
pub fn has_mcap_extension(path: &Path) -> bool {
    path.extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("mcap"))
}
