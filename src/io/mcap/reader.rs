//! Streaming access to an MCAP file through a read-only memory map.
//!
//! Memory stays bounded whatever the file size:
//! - Records are decoded by the crate's sans-io [`mcap::sans_io::LinearReader`], fed from the
//!   map in slices of at most 4 MiB. It decompresses a chunk as a stream into a buffer that
//!   holds at most one record, and hands out messages borrowed from that buffer (no copy per
//!   message). Mapped pages behind the read position are released every 32 MiB (and after
//!   every chunk), since touched file pages count in the resident set until reclaimed.
//! - With a summary that indexes chunks, only the chunk records holding a wanted channel are
//!   fed (the others are never decompressed), and damage inside one chunk (bad CRC, corrupt
//!   compressed data) costs that chunk only.
//! - Without one (no summary, no chunk index, or a damaged footer, e.g. a truncated file), the
//!   whole file is fed from the start; a truncation ends the scan with a note of where.
//!
//! Either way the resident memory is about one chunk plus one message, not the file.

use crate::error::{Error, Result};
use mcap::records::Record;
use mcap::sans_io::{LinearReadEvent, LinearReader, LinearReaderOptions};
use std::collections::HashMap;
use std::path::{Path, PathBuf};

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
        let file = crate::io::files::open_regular(path)?;
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
        // Length prefixes are checked before the `mcap` crate allocates by them: here the
        // header record, which is parsed next.
        if let Err(e) = super::guard::check_first_record(&map[mcap::MAGIC.len()..]) {
            return Err(Error::bad_input(
                path,
                format!("MCAP file does not start with a readable header record: {e}"),
            ));
        }
        let summary_checked = super::guard::check_summary(&map);
        let (summary, summary_note) = match summary_checked.map(|()| mcap::Summary::read(&map)) {
            Err(e) => (
                None,
                Some(format!(
                    "the summary cannot be read ({e}); the file may be damaged"
                )),
            ),
            Ok(r) => match r {
                Ok(Some(s)) => (Some(s), None),
                Ok(None) => (None, Some("the file has no summary section".to_string())),
                Err(e) => (
                    None,
                    Some(format!(
                        "the summary/footer cannot be read ({e}); the file may be truncated"
                    )),
                ),
            },
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
        let mut out = ScanOutcome::default();
        let mut st = ScanState {
            infos: HashMap::new(),
            acc: mcap::read::ChannelAccumulator::default(),
            last: None,
        };
        let Some(summary) = self.summary.as_ref().filter(|_| self.uses_index()) else {
            self.read_ranges(
                &[(0, self.map.len())],
                false,
                &mut st,
                want,
                on_message,
                &mut out,
            )?;
            return Ok(out);
        };
        out.indexed = true;
        for (id, c) in &summary.channels {
            let info = ChannelInfo::from_mcap(c);
            let w = want(&info);
            st.infos.insert(*id, (info, w));
        }
        let mut chunks: Vec<&mcap::records::ChunkIndex> = summary.chunk_indexes.iter().collect();
        chunks.sort_by_key(|c| c.chunk_start_offset);
        let mut ranges = Vec::new();
        for ci in chunks {
            let wanted = ci.message_index_offsets.is_empty()
                || ci
                    .message_index_offsets
                    .keys()
                    .any(|id| st.infos.get(id).is_some_and(|i| i.1));
            let (a, len) = (ci.chunk_start_offset as usize, ci.chunk_length as usize);
            if !wanted {
                out.chunks_skipped += 1;
            } else if a.checked_add(len).is_none_or(|e| e > self.map.len()) {
                out.damage.push(format!(
                    "chunk index points at bytes {a}..{} beyond the end of the {}-byte file",
                    a.saturating_add(len),
                    self.map.len()
                ));
            } else {
                ranges.push((a, a + len));
            }
        }
        if stop_on_damage && !out.damage.is_empty() {
            return Ok(out);
        }
        // One reader over the wanted chunk records, fed back to back; after damage inside a
        // chunk, a fresh reader resumes at the next chunk.
        let mut i = 0;
        while i < ranges.len() {
            let before = out.damage.len();
            let done = self.read_ranges(&ranges[i..], true, &mut st, want, on_message, &mut out)?;
            if out.damage.len() == before || stop_on_damage {
                break;
            }
            i += done + 1; // skip the damaged chunk
        }
        Ok(out)
    }

    /// Feeds `ranges` of the map to one sans-io reader and dispatches its records. Returns the
    /// number of ranges fully consumed (all of them unless damage stopped the reader).
    fn read_ranges(
        &self,
        ranges: &[(usize, usize)],
        chunks_only: bool,
        st: &mut ScanState,
        want: &mut dyn FnMut(&ChannelInfo) -> bool,
        on_message: &mut dyn FnMut(MessageRef) -> Result<()>,
        out: &mut ScanOutcome,
    ) -> Result<usize> {
        // Records inside chunks may be larger than the (compressed) file: the limit only
        // guards against absurd lengths from corrupt data.
        let biggest_chunk = self
            .summary
            .iter()
            .flat_map(|s| s.chunk_indexes.iter().map(|c| c.uncompressed_size as usize))
            .max()
            .unwrap_or(0);
        // The chunk indexes are the file's word too: a chunk may be as big as it says only
        // up to 1 GiB (or the file's size), so a corrupt index cannot make the reader
        // allocate more.
        let limit = (1usize << 30)
            .max(self.map.len())
            .max(biggest_chunk.min(1 << 30));
        let mut opts = LinearReaderOptions::default()
            .with_validate_chunk_crcs(true)
            .with_record_length_limit(limit);
        if chunks_only {
            opts = opts.with_skip_start_magic(true).with_skip_end_magic(true);
        }
        let mut reader = LinearReader::new_with_options(opts);
        let (mut r, mut pos) = (0usize, ranges.first().map(|x| x.0).unwrap_or(0));
        let mut released = pos;
        let mut past_data_end = false;
        let mut at_eof = false;
        let release = |from: usize, to: usize| {
            if to > from {
                crate::sys::release_mapped(&self.map, from, to - from);
            }
        };
        while let Some(ev) = reader.next_event() {
            let ev = match ev {
                Ok(ev) => ev,
                Err(e) => {
                    out.damage
                        .push(damage_text(&e, pos, self.map.len(), &st.last));
                    release(released, pos);
                    return Ok(r);
                }
            };
            match ev {
                LinearReadEvent::ReadRequest(need) => {
                    while r < ranges.len() && pos >= ranges[r].1 {
                        release(released, ranges[r].1);
                        r += 1;
                        if r < ranges.len() {
                            pos = ranges[r].0;
                            released = pos;
                        }
                    }
                    if r == ranges.len() {
                        if chunks_only || at_eof {
                            return Ok(r); // every wanted chunk read, or the file has ended
                        }
                        reader.notify_read(0); // end of file: the reader checks it ends well
                        at_eof = true;
                        continue;
                    }
                    let n = need.min(FEED_MAX).min(ranges[r].1 - pos);
                    reader.insert(n).copy_from_slice(&self.map[pos..pos + n]);
                    reader.notify_read(n);
                    pos += n;
                    if pos - released >= RELEASE_EVERY {
                        release(released, pos);
                        released = pos;
                    }
                }
                LinearReadEvent::Record { opcode, data } => {
                    if past_data_end {
                        continue; // the summary repeats schemas and channels
                    }
                    if let Err(e) = super::guard::check_record(opcode, data) {
                        out.damage.push(format!("at byte {pos}: {e}"));
                        release(released, pos);
                        return Ok(r);
                    }
                    let rec = match mcap::parse_record(opcode, data) {
                        Ok(rec) => rec,
                        Err(e) => {
                            out.damage
                                .push(damage_text(&e, pos, self.map.len(), &st.last));
                            release(released, pos);
                            return Ok(r);
                        }
                    };
                    let linked = match rec {
                        Record::Schema { header, data } => {
                            st.acc.add_schema_from_slice(header, &data).map(|_| ())
                        }
                        Record::Channel(c) => st.acc.add_channel(c),
                        Record::DataEnd(_) => {
                            past_data_end = true;
                            Ok(())
                        }
                        Record::Message { header, data } => {
                            let id = header.channel_id;
                            if !st.infos.contains_key(&id) {
                                let Some(c) = st.acc.get(id) else {
                                    return Err(Error::bad_input(
                                        &self.path,
                                        format!(
                                            "message at log time {} refers to channel {id}, which was never defined",
                                            fmt_ns(header.log_time)
                                        ),
                                    ));
                                };
                                let info = ChannelInfo::from_mcap(&c);
                                let w = want(&info);
                                st.infos.insert(id, (info, w));
                            }
                            if let Some((info, true)) = st.infos.get(&id) {
                                out.messages += 1;
                                st.last = Some((info.topic.clone(), header.log_time));
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
                        out.damage
                            .push(damage_text(&e, pos, self.map.len(), &st.last));
                        release(released, pos);
                        return Ok(r);
                    }
                }
            }
        }
        release(released, pos);
        Ok(ranges.len())
    }
}

/// Channel bookkeeping shared by the readers of one scan.
struct ScanState {
    infos: HashMap<u16, (ChannelInfo, bool)>,
    acc: mcap::read::ChannelAccumulator<'static>,
    last: Option<(String, u64)>,
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
