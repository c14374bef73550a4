//! `tessera info` for MCAP: topics, message counts, time span, and point counts of the
//! PointCloud2 topics (decoded, so the counts are the real ones, not the summary's claims).

use super::fields::field_list;
use super::pointcloud2;
use super::reader::{fmt_ns, ChannelInfo, McapSource, MessageRef};
use super::wire::Encoding;
use crate::error::Result;
use serde::Serialize;
use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::path::{Path, PathBuf};

/// Facts about one topic.
#[derive(Debug, Clone, Default, Serialize)]
pub struct TopicInfo {
    /// Topic name.
    pub topic: String,
    /// Schema name.
    pub schema: String,
    /// Message encoding.
    pub encoding: String,
    /// Messages read.
    pub messages: u64,
    /// First log time, ns.
    pub first_ns: u64,
    /// Last log time, ns.
    pub last_ns: u64,
    /// PointCloud2 only: points (`width × height`) over all messages.
    pub points: u64,
    /// PointCloud2 only: points with finite x, y, z.
    pub valid_points: u64,
    /// PointCloud2 only: messages that could not be decoded.
    pub undecodable: u64,
    /// PointCloud2 only: shape, frame and fields of the first cloud.
    pub layout: Option<String>,
}

/// Facts about one MCAP file.
#[derive(Debug, Clone, Default, Serialize)]
pub struct McapInfo {
    /// The file.
    pub path: PathBuf,
    /// Size in bytes.
    pub bytes: u64,
    /// Header profile.
    pub profile: String,
    /// Header library.
    pub library: String,
    /// Chunks listed in the summary (None: no usable summary).
    pub indexed_chunks: Option<usize>,
    /// Why the summary was not used.
    pub summary_note: Option<String>,
    /// Topics, by name.
    pub topics: Vec<TopicInfo>,
    /// Damage met while reading.
    pub damage: Vec<String>,
}

/// Reads every message of `path` once and describes the file.
pub fn info(path: &Path) -> Result<McapInfo> {
    let src = McapSource::open(path)?;
    let mut topics: BTreeMap<u16, TopicInfo> = BTreeMap::new();
    let mut want = |c: &ChannelInfo| {
        topics.insert(
            c.id,
            TopicInfo {
                topic: c.topic.clone(),
                schema: c.schema_name.clone(),
                encoding: c.message_encoding.clone(),
                ..Default::default()
            },
        );
        true
    };
    let mut counts: BTreeMap<u16, TopicInfo> = BTreeMap::new();
    let mut on_message = |m: MessageRef| -> Result<()> {
        let c = m.channel;
        let t = counts.entry(c.id).or_default();
        if t.messages == 0 {
            t.first_ns = m.log_time;
        }
        t.messages += 1;
        t.first_ns = t.first_ns.min(m.log_time);
        t.last_ns = t.last_ns.max(m.log_time);
        if c.message_type() != "sensor_msgs/PointCloud2" {
            return Ok(());
        }
        let Some(enc) = Encoding::from_channel(&c.message_encoding) else {
            t.undecodable += 1;
            return Ok(());
        };
        match pointcloud2::decode(m.data, enc) {
            Ok(cl) => {
                t.points += cl.len() as u64;
                let acc: Option<Vec<_>> = ["x", "y", "z"]
                    .iter()
                    .map(|n| cl.field(n).map(|f| cl.accessor(f)))
                    .collect();
                if let Some(a) = acc {
                    t.valid_points += (0..cl.len())
                        .filter(|&i| {
                            let p = cl.point(i);
                            a.iter().all(|a| a.get(p).is_finite())
                        })
                        .count() as u64;
                }
                if t.layout.is_none() {
                    t.layout = Some(format!(
                        "{} × {} ({}), frame \"{}\", point_step {}, {}-endian, dense {}, fields {}",
                        cl.height,
                        cl.width,
                        if cl.height > 1 {
                            "organised"
                        } else {
                            "unorganised"
                        },
                        cl.frame_id,
                        cl.point_step,
                        if cl.is_bigendian { "big" } else { "little" },
                        cl.is_dense,
                        field_list(&cl)
                    ));
                }
            }
            Err(_) => t.undecodable += 1,
        }
        Ok(())
    };
    let out = src.scan(&mut want, &mut on_message, false)?;
    let mut list = Vec::new();
    for (id, mut t) in topics {
        if let Some(c) = counts.remove(&id) {
            t = TopicInfo {
                topic: t.topic,
                schema: t.schema,
                encoding: t.encoding,
                ..c
            };
        }
        list.push(t);
    }
    // A summary may list channels that have no messages.
    if let Some(cs) = src.summary_channels() {
        for c in cs {
            if !list
                .iter()
                .any(|t| t.topic == c.topic && t.schema == c.schema_name)
            {
                list.push(TopicInfo {
                    topic: c.topic,
                    schema: c.schema_name,
                    encoding: c.message_encoding,
                    ..Default::default()
                });
            }
        }
    }
    list.sort_by(|a, b| a.topic.cmp(&b.topic));
    Ok(McapInfo {
        path: path.to_path_buf(),
        bytes: src.len(),
        profile: src.profile.clone(),
        library: src.library.clone(),
        indexed_chunks: src
            .summary()
            .map(|s| s.chunk_indexes.len())
            .filter(|&n| n > 0),
        summary_note: src.summary_note.clone(),
        topics: list,
        damage: out.damage,
    })
}

impl McapInfo {
    /// Human-readable description.
    pub fn to_text(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(s, "file: {} ({} bytes)", self.path.display(), self.bytes);
        let _ = writeln!(
            s,
            "format: MCAP, profile \"{}\", library \"{}\"",
            self.profile, self.library
        );
        match (self.indexed_chunks, &self.summary_note) {
            (Some(n), _) => {
                let _ = writeln!(s, "summary: {n} indexed chunks");
            }
            (None, Some(n)) => {
                let _ = writeln!(s, "summary: not used ({n}); read linearly");
            }
            (None, None) => {
                let _ = writeln!(s, "summary: no chunk index; read linearly");
            }
        }
        let with = self.topics.iter().filter(|t| t.messages > 0);
        let first = with.clone().map(|t| t.first_ns).min();
        let last = with.map(|t| t.last_ns).max();
        if let (Some(a), Some(b)) = (first, last) {
            let _ = writeln!(
                s,
                "time span: {} .. {} ({:.3} s)",
                fmt_ns(a),
                fmt_ns(b),
                (b - a) as f64 * 1e-9
            );
        }
        let total: u64 = self.topics.iter().map(|t| t.messages).sum();
        let points: u64 = self.topics.iter().map(|t| t.points).sum();
        let valid: u64 = self.topics.iter().map(|t| t.valid_points).sum();
        let _ = writeln!(
            s,
            "messages: {total} on {} topics; PointCloud2 points: {points} ({valid} valid)",
            self.topics.len()
        );
        for t in &self.topics {
            let _ = write!(
                s,
                "topic {}: {} [{}], {} messages",
                t.topic, t.schema, t.encoding, t.messages
            );
            if t.messages > 0 {
                let _ = write!(s, ", {} .. {}", fmt_ns(t.first_ns), fmt_ns(t.last_ns));
            }
            if t.points > 0 || t.layout.is_some() || t.undecodable > 0 {
                let _ = write!(s, ", {} points ({} valid)", t.points, t.valid_points);
                if t.undecodable > 0 {
                    let _ = write!(s, ", {} undecodable", t.undecodable);
                }
            }
            let _ = writeln!(s);
            if let Some(l) = &t.layout {
                let _ = writeln!(s, "  cloud: {l}");
            }
        }
        for d in &self.damage {
            let _ = writeln!(s, "damage: {d}");
        }
        s
    }
}
