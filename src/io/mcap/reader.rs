//! Streaming access to an MCAP file through a read-only memory map.
//!
//! Memory stays bounded whatever the file size:
//! - With a summary that indexes chunks, messages are read chunk by chunk
//!   ([`mcap::Summary::stream_chunk`] decompresses one chunk through the crate's streaming
//!   sans-io reader), chunks that hold none of the wanted channels are skipped without being
//!   decompressed, and each chunk's pages are released from the mapping once it is done.
//! - Without one (no summary, no chunk index, or a damaged footer, e.g. a truncated file), the
//!   file is scanned linearly with [`mcap::sans_io::LinearReader`], fed from the map in
//!   bounded slices; its buffers hold at most one record (a chunk is decompressed as a
//!   stream), and the mapped pages behind the read position are released every few MiB.
//!
//! In both cases the resident memory is about one chunk plus one message, not the file.

use crate::error::{Error, Result};
use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::sync::Arc;

/// Bytes fed to the linear reader between two releases of mapped pages.
const RELEASE_EVERY: usize = 32 << 20;
/// Largest slice handed to the linear reader per read request.
const FEED_MAX: usize = 4 << 20;

/// What tessera needs to know about a channel.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ChannelInfo {
    /// Channel id in the file.
    pub id: u16,
    /// Topic name.
    pub topic: String,
    /// Message encoding (`ros1`, `cdr`, ...).
    pub message_encoding: String,
    /// Schema name (`sensor_msgs/PointCloud2`, ...), empty without a schema.
    pub schema_name: String,
    /// Schema encoding (`ros1msg`, `ros2msg`, ...), empty without a schema.
    pub schema_encoding: String,
}

impl ChannelInfo {
    fn from_mcap(c: &mcap::Channel) -> Self {
        ChannelInfo {
            id: c.id,
            topic: c.topic.clone(),
            message_encoding: c.message_encoding.clone(),
            schema_name: c
                .schema
                .as_ref()
                .map(|s| s.name.clone())
                .unwrap_or_default(),
            schema_encoding: c
                .schema
                .as_ref()
                .map(|s| s.encoding.clone())
                .unwrap_or_default(),
        }
    }

    /// The schema name without the ROS 2 `/msg/` infix, so both generations compare equal
    /// (`sensor_msgs/msg/PointCloud2` → `sensor_msgs/PointCloud2`).
    pub fn message_type(&self) -> String {
        self.schema_name.replacen("/msg/", "/", 1)
    }
}

/// One message handed to a scan callback.
#[derive(Debug, Clone, Copy)]
pub struct MessageRef<'a> {
    /// Its channel.
    pub channel: &'a ChannelInfo,
    /// Log time, ns since the epoch.
    pub log_time: u64,
    /// Serialised message.
    pub data: &'a [u8],
}

/// How a scan ended.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ScanOutcome {
    /// Messages handed to the callback.
    pub messages: u64,
    /// Chunks skipped because they hold none of the wanted channels (indexed reading).
    pub chunks_skipped: u64,
    /// Damage met on the way (truncation, corrupt chunk); each entry says where. A linear scan
    /// stops at the first; an indexed scan goes on with the next chunk unless told to stop.
    pub damage: Vec<String>,
    /// Whether the summary's chunk index was used.
    pub indexed: bool,
}

/// An MCAP file opened for streaming.
pub struct McapSource {
    path: PathBuf,
    map: memmap2::Mmap,
    summary: Option<mcap::Summary>,
    /// Why the summary could not be used, when it could not.
    pub summary_note: Option<String>,
    /// `profile` of the header record (`ros1`, `ros2`, ...).
    pub profile: String,
    /// `library` of the header record.
    pub library: String,
}

impl McapSource {
    /// Opens and maps `path`, checks the magic and reads the summary when there is one.
    pub fn open(path: &Path) -> Result<Self> {
        let file = std::fs::File::open(path).map_err(|e| Error::io(path, e))?;
        let map = crate::sys::map_readonly(&file).map_err(|e| Error::io(path, e))?;
        if map.len() < mcap::MAGIC.len() || &map[..mcap::MAGIC.len()] != mcap::MAGIC {
            let shown: String = map[..map.len().min(8)]
                .iter()
                .map(|&b| if b.is_ascii_graphic() { b as char } else { '.' })
                .collect();
            return Err(Error::bad_input(
                path,
                format!(
                    "not an MCAP file: starts with \"{shown}\" ({} bytes), expected the MCAP magic \\x89MCAP0\\r\\n",
                    map.len()
                ),
            ));
        }
        let (summary, summary_note) = match mcap::Summary::read(&map) {
            Ok(Some(s)) => (Some(s), None),
            Ok(None) => (None, Some("the file has no summary section".to_string())),
            Err(e) => (
                None,
                Some(format!(
                    "the summary/footer cannot be read ({e}); the file may be truncated"
                )),
            ),
        };
        let (profile, library) = match mcap::read::LinearReader::new_with_options(
            &map,
            mcap::read::Options::IgnoreEndMagic.into(),
        )
        .ok()
        .and_then(|mut r| r.next())
        {
            Some(Ok(Record::Header(h))) => (h.profile, h.library),
            _ => {
                return Err(Error::bad_input(
                    path,
                    "MCAP file does not start with a header record",
                ))
            }
        };
        Ok(McapSource {
            path: path.to_path_buf(),
            map,
            summary,
            summary_note,
            profile,
            library,
        })
    }

    /// The file's path.
    pub fn path(&self) -> &Path {
        &self.path
    }

    /// File size in bytes.
    pub fn len(&self) -> u64 {
        self.map.len() as u64
    }

    /// True for an empty file (never, once opened: the magic is checked).
    pub fn is_empty(&self) -> bool {
        self.map.is_empty()
    }

    /// The summary, when the file has a readable one.
    pub fn summary(&self) -> Option<&mcap::Summary> {
        self.summary.as_ref()
    }

    /// Channels listed in the summary (sorted by id), if there is one.
    pub fn summary_channels(&self) -> Option<Vec<ChannelInfo>> {
        let s = self.summary.as_ref()?;
        let mut v: Vec<ChannelInfo> = s
            .channels
            .values()
            .map(|c| ChannelInfo::from_mcap(c))
            .collect();
        v.sort_by_key(|c| c.id);
        Some(v)
    }

    fn uses_index(&self) -> bool {
        self.summary
            .as_ref()
            .is_some_and(|s| !s.chunk_indexes.is_empty())
    }

    /// Streams every message of the channels `want` accepts (asked once per channel) to
    /// `on_message`, in file order. Errors from `on_message` stop the scan and are returned;
    /// damage in the file is recorded in the outcome (and stops the scan if `stop_on_damage`).
    pub fn scan(
        &self,
        want: &mut dyn FnMut(&ChannelInfo) -> bool,
        on_message: &mut dyn FnMut(MessageRef) -> Result<()>,
        stop_on_damage: bool,
    ) -> Result<ScanOutcome> {
        if self.uses_index() {
            self.scan_indexed(want, on_message, stop_on_damage)
        } else {
            self.scan_linear(want, on_message)
        }
    }

    fn scan_indexed(
        &self,
        want: &mut dyn FnMut(&ChannelInfo) -> bool,
        on_message: &mut dyn FnMut(MessageRef) -> Result<()>,
        stop_on_damage: bool,
    ) -> Result<ScanOutcome> {
        let Some(summary) = self.summary.as_ref() else {
            return Ok(ScanOutcome::default());
        };
        let mut out = ScanOutcome {
            indexed: true,
            ..Default::default()
        };
        let mut infos: HashMap<u16, (ChannelInfo, bool)> = HashMap::new();
        for (id, c) in &summary.channels {
            let info = ChannelInfo::from_mcap(c);
            let w = want(&info);
            infos.insert(*id, (info, w));
        }
        let mut chunks: Vec<&mcap::records::ChunkIndex> = summary.chunk_indexes.iter().collect();
        chunks.sort_by_key(|c| c.chunk_start_offset);
        for ci in chunks {
            let wanted = ci.message_index_offsets.is_empty()
                || ci
                    .message_index_offsets
                    .keys()
                    .any(|id| infos.get(id).is_some_and(|i| i.1));
            if !wanted {
                out.chunks_skipped += 1;
                continue;
            }
            let res = (|| -> Result<std::result::Result<(), String>> {
                let it = match summary.stream_chunk(&self.map, ci) {
                    Ok(it) => it,
                    Err(e) => return Ok(Err(e.to_string())),
                };
                for m in it {
                    let m = match m {
                        Ok(m) => m,
                        Err(e) => return Ok(Err(e.to_string())),
                    };
                    let Some((info, true)) = infos.get(&m.channel.id) else {
                        continue;
                    };
                    out.messages += 1;
                    on_message(MessageRef {
                        channel: info,
                        log_time: m.log_time,
                        data: &m.data,
                    })?;
                }
                Ok(Ok(()))
            })();
            crate::sys::release_mapped(
                &self.map,
                ci.chunk_start_offset as usize,
                ci.chunk_length as usize,
            );
            if let Err(why) = res? {
                out.damage.push(format!(
                    "chunk at byte {} (messages {} .. {} ns): {why}",
                    ci.chunk_start_offset, ci.message_start_time, ci.message_end_time
                ));
                if stop_on_damage {
                    break;
                }
            }
        }
        Ok(out)
    }

    fn scan_linear(
        &self,
        want: &mut dyn FnMut(&ChannelInfo) -> bool,
        on_message: &mut dyn FnMut(MessageRef) -> Result<()>,
    ) -> Result<ScanOutcome> {
        let mut out = ScanOutcome::default();
        let mut reader = LinearReader::new_with_options(
            LinearReaderOptions::default()
                .with_skip_end_magic(true)
                .with_record_length_limit(self.map.len()),
        );
        let mut acc = mcap::read::ChannelAccumulator::default();
        let mut infos: HashMap<u16, (ChannelInfo, bool)> = HashMap::new();
        let mut pos = 0usize;
        let mut released = 0usize;
        let mut last: Option<(String, u64)> = None;
        let mut past_data_end = false;
        while let Some(ev) = reader.next_event() {
            let ev = match ev {
                Ok(ev) => ev,
                Err(e) => {
                    out.damage.push(damage_text(&e, pos, self.map.len(), &last));
                    break;
                }
            };
            match ev {
                LinearReadEvent::ReadRequest(need) => {
                    let n = need.min(FEED_MAX).min(self.map.len() - pos);
                    reader.insert(n).copy_from_slice(&self.map[pos..pos + n]);
                    reader.notify_read(n);
                    pos += n;
                    if pos - released >= RELEASE_EVERY {
                        crate::sys::release_mapped(&self.map, released, pos - released);
                        released = pos;
                    }
                }
                LinearReadEvent::Record { opcode, data } => {
                    if past_data_end {
                        continue; // the summary repeats schemas and channels
                    }
                    let rec = match mcap::parse_record(opcode, data) {
                        Ok(r) => r,
                        Err(e) => {
                            out.damage.push(damage_text(&e, pos, self.map.len(), &last));
                            break;
                        }
                    };
                    let linked = match rec {
                        Record::Schema { header, data } => {
                            acc.add_schema_from_slice(header, &data).map(|_| ())
                        }
                        Record::Channel(c) => acc.add_channel(c),
                        Record::DataEnd(_) => {
                            past_data_end = true;
                            Ok(())
                        }
                        Record::Message { header, data } => {
                            let id = header.channel_id;
                            if !infos.contains_key(&id) {
                                let Some(c) = acc.get(id) else {
                                    return Err(Error::bad_input(
                                        &self.path,
                                        format!(
                                            "message at log time {} ns refers to channel {id}, which was never defined",
                                            header.log_time
                                        ),
                                    ));
                                };
                                let info = ChannelInfo::from_mcap(&c);
                                let w = want(&info);
                                infos.insert(id, (info, w));
                            }
                            if let Some((info, true)) = infos.get(&id) {
                                out.messages += 1;
                                last = Some((info.topic.clone(), header.log_time));
                                on_message(MessageRef {
                                    channel: info,
                                    log_time: header.log_time,
                                    data: &data,
                                })?;
                            }
                            Ok(())
                        }
                        _ => Ok(()),
                    };
                    if let Err(e) = linked {
                        out.damage.push(damage_text(&e, pos, self.map.len(), &last));
                        break;
                    }
                }
            }
        }
        crate::sys::release_mapped(&self.map, released, self.map.len() - released);
        Ok(out)
    }
}

fn damage_text(
    e: &mcap::McapError,
    pos: usize,
    len: usize,
    last: &Option<(String, u64)>,
) -> String {
    let what = match e {
        mcap::McapError::UnexpectedEof | mcap::McapError::UnexpectedEoc => {
            "truncated: the file ends inside a record".to_string()
        }
        e => e.to_string(),
    };
    let after = match last {
        Some((t, lt)) => format!(", after the message on {t} at log time {}", fmt_ns(*lt)),
        None => String::new(),
    };
    format!("{what} (read {pos} of {len} bytes{after})")
}

/// Formats a log time (ns since the epoch) as seconds.
pub fn fmt_ns(ns: u64) -> String {
    format!("{}.{:09} s", ns / 1_000_000_000, ns % 1_000_000_000)
}

/// Shared channel handle type of the crate, for callers that link channels themselves.
pub type McapChannel = Arc<mcap::Channel<'static>>;
