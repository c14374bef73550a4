//! Pass 2 of the conversion: clouds decoded and placed in parallel, written in order.
//!
//! The scan (the calling thread) copies each cloud message into a pooled buffer for the
//! workers, which decode and place clouds in parallel ([`super::place`]); a writer thread takes
//! the results back in message order, so parts, point order and report do not depend on the
//! thread count. The pools bound the clouds in flight (and so the memory) to a few per worker;
//! a worker takes its output buffer before its job, so the oldest unfinished cloud always has
//! one and the ordered writer can always make progress.

use super::fields::CloudSchema;
use super::parts::{encode_records, las_header, transforms_near, PartWriter};
use super::place::{Placed, Placer, Unusable};
use super::reader::{fmt_ns, ChannelInfo, McapSource, MessageRef, ScanOutcome};
use super::report::{message_type_ok, note, McapReport};
use super::tf::{Limits, TfTree};
use super::wire::Encoding;
use super::{pointcloud2, McapParams, OnError};
use crate::error::{Error, Result};
use crossbeam_channel::{bounded, Receiver, Sender};
use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::sync::atomic::{AtomicBool, Ordering};
use std::sync::{Mutex, OnceLock};

/// A cloud message handed to a worker.
struct Job {
    seq: u64,
    channel: ChannelInfo,
    log_time: u64,
    point_source_id: u16,
    data: Vec<u8>,
}

/// A worker's result, or the scan's verdict on a message no worker needs to see.
struct Done {
    seq: u64,
    channel: ChannelInfo,
    log_time: u64,
    point_source_id: u16,
    outcome: std::result::Result<Placed, Unusable>,
    /// Whether a worker produced it (and so took an output buffer from the pool).
    from_worker: bool,
}

fn encoding_note(c: &ChannelInfo) -> String {
    format!(
        "message encoding \"{}\" (schema {} \"{}\")",
        c.message_encoding, c.schema_encoding, c.schema_name
    )
}

/// The first error of pass 2, from whichever thread hit it; the flag tells the others to stop.
#[derive(Default)]
struct Failure {
    first: Mutex<Option<Error>>,
    failed: AtomicBool,
}

impl Failure {
    /// Keeps `e` unless an earlier error is kept, and raises the stop flag.
    fn fail(&self, e: Error) {
        let mut g = self.first.lock().unwrap_or_else(|q| q.into_inner());
        g.get_or_insert(e);
        self.failed.store(true, Ordering::SeqCst);
    }

    /// True once any thread failed.
    fn failed(&self) -> bool {
        self.failed.load(Ordering::SeqCst)
    }
}

/// Decodes, places and writes every cloud `want` selects; returns how the scan ended and the
/// LAS parts written.
pub(crate) fn place_clouds(
    src: &McapSource,
    p: &McapParams,
    (tf, lim): (&TfTree, Limits),
    work_dir: &Path,
    threads: usize,
    rep: &mut McapReport,
    want: &mut dyn FnMut(&ChannelInfo) -> bool,
) -> Result<(ScanOutcome, Vec<PathBuf>)> {
    let path = src.path();
    let workers = match threads {
        0 => std::thread::available_parallelism()
            .map(|n| n.get())
            .unwrap_or(1),
        n => n,
    }
    .clamp(1, 8);
    let schema: OnceLock<CloudSchema> = OnceLock::new();
    let failure = Failure::default();
    // In flight: one output buffer per worker plus one the writer may hold, and a message per
    // worker waiting in the queue.
    let (job_tx, job_rx) = bounded::<Job>(workers);
    let (done_tx, done_rx) = bounded::<Done>(workers);
    let pool = workers + 1;
    let (free_out_tx, free_out_rx) = bounded::<Placed>(pool);
    let (free_in_tx, free_in_rx) = bounded::<Vec<u8>>(2 * workers + 1);
    for _ in 0..pool {
        let _ = free_out_tx.send(Placed::default());
    }
    let mut scanned = Ok(ScanOutcome::default());
    let mut parts = Vec::new();
    std::thread::scope(|s| {
        for _ in 0..workers {
            let (job_rx, done_tx, free_out_rx, free_in_tx): (
                Receiver<Job>,
                Sender<Done>,
                Receiver<Placed>,
                Sender<Vec<u8>>,
            ) = (
                job_rx.clone(),
                done_tx.clone(),
                free_out_rx.clone(),
                free_in_tx.clone(),
            );
            let schema = &schema;
            s.spawn(move || {
                place_jobs(
                    (tf, lim, p),
                    schema,
                    job_rx,
                    done_tx,
                    free_out_rx,
                    free_in_tx,
                )
            });
        }
        drop(job_rx);
        drop(free_out_rx);
        let writer = {
            let (schema, failure) = (&schema, &failure);
            let rep = &mut *rep;
            s.spawn(move || {
                let sink = Sink {
                    src,
                    work_dir,
                    p,
                    rep,
                    writer: None,
                    records: Vec::new(),
                };
                write_in_order(sink, schema, failure, done_rx, free_out_tx)
            })
        };
        // The scan, on this thread.
        let mut scan = Scan {
            path,
            p,
            schema: &schema,
            failure: &failure,
            seq: 0,
            topics: Vec::new(),
            job_tx,
            done_tx,
            free_in_rx: &free_in_rx,
        };
        scanned = src.scan(
            want,
            &mut |m| scan.on_message(m),
            p.on_error == OnError::Fail,
        );
        // Closes the job and result queues.
        drop(scan);
        parts = writer.join().unwrap_or_default();
    });
    if let Some(e) = failure
        .first
        .into_inner()
        .unwrap_or_else(|q| q.into_inner())
    {
        return Err(e);
    }
    Ok((scanned?, parts))
}

/// A worker: decodes and places the cloud of each job it takes into an output buffer from the
/// pool (taken before the job) and hands the result to the writer.
fn place_jobs(
    (tf, lim, p): (&TfTree, Limits, &McapParams),
    schema: &OnceLock<CloudSchema>,
    job_rx: Receiver<Job>,
    done_tx: Sender<Done>,
    free_out_rx: Receiver<Placed>,
    free_in_tx: Sender<Vec<u8>>,
) {
    let mut placer: Option<Placer> = None;
    while let Ok(mut out) = free_out_rx.recv() {
        let Ok(job) = job_rx.recv() else { break };
        let enc = Encoding::from_channel(&job.channel.message_encoding);
        let outcome = match schema.get() {
            Some(sc) => placer
                .get_or_insert_with(|| Placer::new(tf, lim, p, sc))
                .place(&job.data, enc, &encoding_note(&job.channel), &mut out)
                .map(|()| out),
            None => Err(Unusable {
                kind: "undecodable",
                why: "no layout (internal)".into(),
                stamp: None,
            }),
        };
        let _ = free_in_tx.try_send(job.data);
        let d = Done {
            seq: job.seq,
            channel: job.channel,
            log_time: job.log_time,
            point_source_id: job.point_source_id,
            outcome,
            from_worker: true,
        };
        if done_tx.send(d).is_err() {
            break;
        }
    }
}

/// The writer thread: takes the results back in message order into `sink`, returning output
/// buffers to the pool; returns the LAS parts written (none after a failure, which goes to
/// `failure`).
fn write_in_order(
    mut sink: Sink<'_>,
    schema: &OnceLock<CloudSchema>,
    failure: &Failure,
    done_rx: Receiver<Done>,
    free_out_tx: Sender<Placed>,
) -> Vec<PathBuf> {
    let mut next = 0u64;
    let mut waiting: BTreeMap<u64, Done> = BTreeMap::new();
    for d in done_rx.iter() {
        waiting.insert(d.seq, d);
        while let Some(d) = waiting.remove(&next) {
            next += 1;
            let Some(sc) = schema.get() else {
                // Only unusable clouds come before the layout is known.
                if let Err(u) = d.outcome {
                    if let Err(e) = sink.unusable(&d.channel, d.log_time, u) {
                        failure.fail(e);
                        return Vec::new();
                    }
                }
                continue;
            };
            let r = match d.outcome {
                Ok(mut placed) => {
                    let r = sink.write(sc, &d.channel, d.point_source_id, &mut placed);
                    let _ = free_out_tx.try_send(placed);
                    r
                }
                Err(u) => {
                    if d.from_worker {
                        let _ = free_out_tx.try_send(Placed::default());
                    }
                    sink.unusable(&d.channel, d.log_time, u)
                }
            };
            if let Err(e) = r {
                failure.fail(e);
                return Vec::new();
            }
        }
        if failure.failed() {
            return Vec::new();
        }
    }
    match sink
        .writer
        .as_mut()
        .map(|w| w.close_part().map(|()| w.take_parts()))
    {
        Some(Ok(parts)) => parts,
        Some(Err(e)) => {
            failure.fail(e);
            Vec::new()
        }
        None => Vec::new(),
    }
}

/// The scan side of pass 2 (the calling thread): numbers the cloud messages, fixes the layout
/// from the first decodable cloud and queues the messages for the workers.
struct Scan<'a> {
    path: &'a Path,
    p: &'a McapParams,
    schema: &'a OnceLock<CloudSchema>,
    failure: &'a Failure,
    /// Sequence number of the next message.
    seq: u64,
    /// Cloud topics in order of first appearance (the point source id is the index).
    topics: Vec<String>,
    job_tx: Sender<Job>,
    done_tx: Sender<Done>,
    free_in_rx: &'a Receiver<Vec<u8>>,
}

impl Scan<'_> {
    /// Queues one cloud message for the workers (or, before the layout is known, an
    /// undecodable one straight for the writer).
    fn on_message(&mut self, m: MessageRef) -> Result<()> {
        let (path, p, schema) = (self.path, self.p, self.schema);
        let c = m.channel;
        if self.failure.failed() {
            return Err(Error::Internal("stopped".into()));
        }
        if !message_type_ok(c, &["sensor_msgs/PointCloud2"]) {
            return Err(Error::Config(format!(
                "{}: mcap.cloud_topics names {}, which carries \"{}\", not sensor_msgs/PointCloud2",
                path.display(),
                c.topic,
                c.schema_name
            )));
        }
        let topics = &mut self.topics;
        let psid = match topics.iter().position(|t| *t == c.topic) {
            Some(i) => i,
            None => {
                topics.push(c.topic.clone());
                topics.len() - 1
            }
        } as u16;
        let enc = Encoding::from_channel(&c.message_encoding);
        if schema.get().is_none() {
            // The first decodable cloud fixes the layout of the file's LAS parts.
            let early = match enc.map(|e| pointcloud2::decode(m.data, e)) {
                None => Some(Unusable {
                    kind: "unsupported encoding",
                    why: format!(
                        "{} is not supported; tessera reads \"ros1\" and \"cdr\" (ROS 2)",
                        encoding_note(c)
                    ),
                    stamp: None,
                }),
                Some(Err(e)) => Some(Unusable {
                    kind: "undecodable",
                    why: format!("cannot decode PointCloud2: {e}"),
                    stamp: None,
                }),
                Some(Ok(cl)) => {
                    let sc = CloudSchema::from_cloud(&cl, p).map_err(|e| {
                        Error::bad_input(
                            path,
                            format!("topic {}, cloud stamped {}: {e}", c.topic, cl.stamp),
                        )
                    })?;
                    let _ = schema.set(sc);
                    None
                }
            };
            if let Some(u) = early {
                let d = Done {
                    seq: self.seq,
                    channel: c.clone(),
                    log_time: m.log_time,
                    point_source_id: psid,
                    outcome: Err(u),
                    from_worker: false,
                };
                self.seq += 1;
                return self
                    .done_tx
                    .send(d)
                    .map_err(|_| Error::Internal("stopped".into()));
            }
        }
        let mut data = self.free_in_rx.try_recv().unwrap_or_default();
        data.clear();
        data.extend_from_slice(m.data);
        let job = Job {
            seq: self.seq,
            channel: c.clone(),
            log_time: m.log_time,
            point_source_id: psid,
            data,
        };
        self.seq += 1;
        self.job_tx
            .send(job)
            .map_err(|_| Error::Internal("stopped".into()))
    }
}

/// The writer side of pass 2: LAS parts and the report, in message order.
struct Sink<'a> {
    src: &'a McapSource,
    work_dir: &'a Path,
    p: &'a McapParams,
    rep: &'a mut McapReport,
    writer: Option<PartWriter>,
    records: Vec<u8>,
}

impl Sink<'_> {
    fn unusable(&mut self, c: &ChannelInfo, log_time: u64, u: Unusable) -> Result<()> {
        self.rep.clouds += 1;
        let at = match u.stamp {
            Some(s) => format!("cloud stamped {s} (log time {})", fmt_ns(log_time)),
            None => format!("message at log time {}", fmt_ns(log_time)),
        };
        let why = format!("topic {}, {at}: {}", c.topic, u.why);
        if self.p.on_error == OnError::Fail {
            return Err(Error::bad_input(
                self.src.path(),
                format!("{why} (set mcap.on_error = \"skip\" to skip such clouds)"),
            ));
        }
        *self
            .rep
            .clouds_skipped
            .entry(u.kind.to_string())
            .or_default() += 1;
        note(self.rep, why);
        Ok(())
    }

    fn write(
        &mut self,
        schema: &CloudSchema,
        c: &ChannelInfo,
        point_source_id: u16,
        placed: &mut Placed,
    ) -> Result<()> {
        let rep = &mut *self.rep;
        rep.clouds += 1;
        rep.clouds_used += 1;
        if schema.scan_segment {
            // The scan's number goes into the high bits of every point's segment value, so
            // the value names the scan as well as the segment (the number is the cloud's
            // place in the drive, known only here, in order).
            let scan = rep.clouds_used << super::fields::SCAN_SEGMENT_BITS;
            let (eb, at) = (schema.extra_bytes(), schema.cloud_extra_bytes());
            for rec in placed.extras.chunks_exact_mut(eb) {
                let v = &mut rec[at..at + 8];
                let local = u64::from_le_bytes(v.try_into().unwrap_or([0; 8]));
                v.copy_from_slice(&(scan | local).to_le_bytes());
            }
            match &placed.scan_unsegmented {
                None => {
                    rep.scans_segmented += 1;
                    rep.scan_segments += u64::from(placed.scan_segments);
                }
                Some(why) => {
                    rep.scans_unsegmented += 1;
                    let why = format!(
                        "topic {}, cloud stamped {}: not segmented: {why}",
                        c.topic, placed.stamp
                    );
                    note(rep, why);
                }
            }
        }
        rep.points_in_clouds += placed.points_in;
        rep.points_nan += placed.nan;
        rep.points_near += placed.near;
        rep.clouds_deskewed += placed.deskewed as u64;
        for n in &placed.missing {
            *rep.missing_fields.entry(n.clone()).or_default() += 1;
        }
        if rep.time_field.is_none() && rep.extra_fields.is_empty() {
            rep.time_field = schema.time_field.clone();
            rep.extra_fields = schema.extras.iter().map(|e| e.name.clone()).collect();
        }
        let Some(first) = placed.xyz.first() else {
            return Ok(());
        };
        if self.writer.is_none() {
            let tr = transforms_near(*first, self.p.scale_m);
            let header = las_header(schema, tr, self.p, self.src.path())?;
            let stem = self
                .src
                .path()
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "drive".into());
            self.writer = Some(PartWriter::new(
                self.work_dir,
                stem,
                header,
                self.p.part_points,
            ));
        }
        let Some(w) = self.writer.as_mut() else {
            return Ok(());
        };
        self.records.clear();
        encode_records(
            placed,
            &w.transforms(),
            point_source_id,
            schema.rgb_field.is_some(),
            schema.extra_bytes(),
            &mut self.records,
        )
        .map_err(|e| {
            Error::bad_input(
                self.src.path(),
                format!("topic {}, cloud stamped {}: {e}", c.topic, placed.stamp),
            )
        })?;
        let n = placed.xyz.len() as u64;
        w.write(&self.records, n)?;
        w.maybe_roll()?;
        rep.points_written += n;
        Ok(())
    }
}
