//! The `[mcap]` configuration section (pose source, error policy, extra fields) and MCAP file detection.

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

/// Segments one scan while it is decoded: the segment per point (0 = none, 1..) and the
/// number of segments, or why the scan cannot be segmented. The conversion knows no
/// segmentation method; the run hands one in (`segment.method = "multicue"`).
pub trait ScanSegmenter: Send + Sync + std::fmt::Debug {
    /// Segments `scan`.
    fn segment(&self, scan: crate::model::ScanPoints<'_>) -> Result<(Vec<u32>, u32), String>;
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
    /// Segment each scan while it is decoded ([`crate::segment::multicue`]) and keep the
    /// per-scan segments as the `scan_segment` attribute. Not a key of `[mcap]`: set by the
    /// run when `segment.method = "multicue"`.
    #[serde(skip)]
    pub scan_segments: Option<std::sync::Arc<dyn ScanSegmenter>>,
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
