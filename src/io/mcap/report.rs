//! What happened to one MCAP input ([`McapReport`], written into `summary.json`) and the
//! small helpers both conversion passes use to fill it.

use super::reader::ChannelInfo;
use serde::Serialize;
use std::collections::BTreeMap;
use std::path::PathBuf;

/// Reasons kept verbatim in the report (the counts cover the rest).
const MAX_NOTES: usize = 20;

/// What happened to one MCAP input (written into `summary.json`).
#[derive(Debug, Clone, Default, Serialize)]
pub struct McapReport {
    /// The recording.
    pub file: PathBuf,
    /// MCAP profile (`ros1`, `ros2`, ...).
    pub profile: String,
    /// Whether the summary's chunk index was used (else a linear scan).
    pub indexed: bool,
    /// Cloud topics read.
    pub topics: Vec<String>,
    /// Frame the points were placed in.
    pub target_frame: String,
    /// `tf`, `odometry` or `trajectory`.
    pub pose_source: String,
    /// Timed pose samples available.
    pub pose_samples: usize,
    /// Pose messages that could not be decoded (`on_error = "skip"`).
    pub pose_messages_skipped: u64,
    /// Clouds read.
    pub clouds: u64,
    /// Clouds written.
    pub clouds_used: u64,
    /// Clouds skipped (`on_error = "skip"`), by reason kind.
    pub clouds_skipped: BTreeMap<String, u64>,
    /// Clouds whose points were placed with per-point poses.
    pub clouds_deskewed: u64,
    /// Points in the clouds read (`width × height`).
    pub points_in_clouds: u64,
    /// Points written (the run's input points).
    pub points_written: u64,
    /// Invalid (non-finite) points dropped.
    pub points_nan: u64,
    /// Points nearer than `min_range_m` dropped.
    pub points_near: u64,
    /// Per-point time field, if any.
    pub time_field: Option<String>,
    /// Fields kept as extra bytes.
    pub extra_fields: Vec<String>,
    /// Clouds lacking an extra field of the layout (written as 0), by field.
    pub missing_fields: BTreeMap<String, u64>,
    /// The first skipped clouds and damaged places, with topic and time.
    pub notes: Vec<String>,
    /// Damage found in the file (truncation, corrupt chunks).
    pub damage: Vec<String>,
    /// World offset added.
    pub world_offset: [f64; 3],
    /// CRS note.
    pub crs: String,
    /// Scans segmented while decoded (`segment.method = "multicue"`).
    pub scans_segmented: u64,
    /// Segments found in them.
    pub scan_segments: u64,
    /// Scans that could not be segmented (their points carry no segment), with the first
    /// reasons in `notes`.
    pub scans_unsegmented: u64,
    /// Temporary LAS parts written.
    pub parts: usize,
    /// Wall time of the conversion, seconds.
    pub seconds: f64,
}

/// True if the channel carries one of the message types `want`.
pub(crate) fn message_type_ok(c: &ChannelInfo, want: &[&str]) -> bool {
    let t = c.message_type();
    want.iter().any(|w| *w == t)
}

/// Keeps `s` as a note of the report (the first [`MAX_NOTES`] only).
pub(crate) fn note(rep: &mut McapReport, s: String) {
    if rep.notes.len() < MAX_NOTES {
        rep.notes.push(s);
    }
}
