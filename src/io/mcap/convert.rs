//! MCAP → georeferenced LAS parts: pass 1 gathers poses, pass 2 decodes, cleans and places
//! the clouds and writes them, streaming, to uncompressed LAS 1.4 files in a work directory.

use super::fields::{unpack_rgb, Bound, CloudSchema};
use super::reader::{fmt_ns, ChannelInfo, McapSource, MessageRef};
use super::tf::{decode_odometry, decode_tf_message, Chain, Iso, Limits, TfTree};
use super::trajectory::read_trajectory;
use super::wire::{Encoding, Stamp};
use super::{is_mcap, pointcloud2, McapParams, OnError, PoseSource};
use crate::error::{Error, Result};
use crate::io::input::expand_paths;
use las::point::Format;
use las::{Builder, PointDataBuilder, Transform, Vector, Version, Vlr, Writer};
use nalgebra::Point3;
use serde::Serialize;
use std::collections::{BTreeMap, HashMap};
use std::fs::File;
use std::io::BufWriter;
use std::path::{Path, PathBuf};
use std::time::Instant;

/// Unix time minus this is LAS "adjusted standard GPS time" (GPS seconds − 1e9): the GPS
/// epoch is 1980-01-06 (Unix 315 964 800) and GPS time is ahead of UTC by the 18 leap seconds
/// inserted since (the count valid since 2017-01-01; earlier drives are off by a second or
/// two, which only shifts all times equally).
pub const UNIX_TO_ADJUSTED_GPS_S: i128 = 315_964_800 - 18 + 1_000_000_000;

/// Reasons kept verbatim in the report (the counts cover the rest).
const MAX_NOTES: usize = 20;
/// Records buffered before they are handed to the LAS writer.
const FLUSH_POINTS: usize = 1 << 16;

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
    /// Temporary LAS parts written.
    pub parts: usize,
    /// Wall time of the conversion, seconds.
    pub seconds: f64,
}

/// The result of converting one recording.
#[derive(Debug, Clone)]
pub struct Conversion {
    /// LAS parts written, in drive order.
    pub parts: Vec<PathBuf>,
    /// What happened.
    pub report: McapReport,
}

fn message_type_ok(c: &ChannelInfo, want: &[&str]) -> bool {
    let t = c.message_type();
    want.iter().any(|w| *w == t)
}

fn encoding_of(path: &Path, c: &ChannelInfo) -> Result<Encoding> {
    Encoding::from_channel(&c.message_encoding).ok_or_else(|| {
        Error::bad_input(
            path,
            format!(
                "topic {}: message encoding \"{}\" (schema {} \"{}\") is not supported; tessera reads \"ros1\" and \"cdr\" (ROS 2)",
                c.topic, c.message_encoding, c.schema_encoding, c.schema_name
            ),
        )
    })
}

/// Pass 1: the transform tree from `/tf`, `/tf_static`, odometry or a trajectory file.
fn gather_poses(
    src: &McapSource,
    p: &McapParams,
    rep: &mut McapReport,
) -> Result<(TfTree, Vec<String>)> {
    let path = src.path();
    let mut tf = TfTree::default();
    let mut topics_seen: Vec<String> = Vec::new();
    if p.pose_source == PoseSource::Trajectory {
        let tp = Path::new(&p.trajectory_file);
        for t in read_trajectory(tp, &p.target_frame, &p.trajectory_frame)? {
            tf.add(&t, false).map_err(|e| Error::bad_input(tp, e))?;
        }
    }
    let is_pose_topic = |c: &ChannelInfo| {
        c.topic == p.tf_static_topic
            || (p.pose_source == PoseSource::Tf && c.topic == p.tf_topic)
            || (p.pose_source == PoseSource::Odometry && c.topic == p.odometry_topic)
    };
    let mut bad_topic: Option<Error> = None;
    let mut want = |c: &ChannelInfo| {
        topics_seen.push(c.topic.clone());
        if !is_pose_topic(c) {
            return false;
        }
        if let Err(e) = encoding_of(path, c) {
            bad_topic.get_or_insert(e);
            return false;
        }
        true
    };
    let mut on_message = |m: MessageRef| -> Result<()> {
        let c = m.channel;
        let enc = encoding_of(path, c)?;
        let fixed = c.topic == p.tf_static_topic;
        let is_odom = p.pose_source == PoseSource::Odometry && c.topic == p.odometry_topic;
        let kinds: &[&str] = if is_odom {
            &["nav_msgs/Odometry"]
        } else {
            &["tf2_msgs/TFMessage", "tf/tfMessage"]
        };
        if !message_type_ok(c, kinds) {
            return Err(Error::bad_input(
                path,
                format!(
                    "topic {} carries \"{}\", expected {}",
                    c.topic,
                    c.schema_name,
                    kinds.join(" or ")
                ),
            ));
        }
        let decoded = if is_odom {
            decode_odometry(m.data, enc).map(|t| vec![t])
        } else {
            decode_tf_message(m.data, enc)
        };
        let ts = match decoded {
            Ok(ts) => ts,
            Err(e) => {
                let why = format!(
                    "topic {}, message at log time {}: cannot decode: {e}",
                    c.topic,
                    fmt_ns(m.log_time)
                );
                if p.on_error == OnError::Fail {
                    return Err(Error::bad_input(path, why));
                }
                rep.pose_messages_skipped += 1;
                note(rep, why);
                return Ok(());
            }
        };
        for t in &ts {
            tf.add(t, fixed).map_err(|e| {
                Error::bad_input(
                    path,
                    format!("topic {}, transform at {}: {e}", c.topic, t.stamp),
                )
            })?;
        }
        Ok(())
    };
    let out = src.scan(&mut want, &mut on_message, p.on_error == OnError::Fail)?;
    if let Some(e) = bad_topic {
        if p.on_error == OnError::Fail {
            return Err(e);
        }
        note(rep, e.to_string());
    }
    handle_damage(src, p, rep, &out.damage, "reading poses")?;
    tf.finish();
    topics_seen.sort();
    topics_seen.dedup();
    Ok((tf, topics_seen))
}

fn note(rep: &mut McapReport, s: String) {
    if rep.notes.len() < MAX_NOTES {
        rep.notes.push(s);
    }
}

fn handle_damage(
    src: &McapSource,
    p: &McapParams,
    rep: &mut McapReport,
    damage: &[String],
    phase: &str,
) -> Result<()> {
    if damage.is_empty() {
        return Ok(());
    }
    if p.on_error == OnError::Fail {
        return Err(Error::bad_input(
            src.path(),
            format!(
                "{phase}: {} (set mcap.on_error = \"skip\" to keep what can be read)",
                damage[0]
            ),
        ));
    }
    for d in damage {
        if !rep.damage.contains(d) {
            rep.damage.push(d.clone());
            tracing::warn!("{}: {phase}: {d}", src.path().display());
        }
    }
    Ok(())
}

/// Streams LAS parts: one uncompressed LAS 1.4 file per `part_points` points.
struct PartWriter {
    dir: PathBuf,
    stem: String,
    header: las::Header,
    writer: Option<Writer<BufWriter<File>>>,
    current: Option<PathBuf>,
    in_part: u64,
    part_points: u64,
    parts: Vec<PathBuf>,
    buf: Vec<u8>,
    format: Format,
    transforms: Vector<Transform>,
}

impl PartWriter {
    fn write(&mut self, records: &[u8], n: u64) -> Result<()> {
        if self.writer.is_none() {
            let path = self
                .dir
                .join(format!("{}.part{:04}.las", self.stem, self.parts.len()));
            let f = File::create(&path).map_err(|e| Error::io(&path, e))?;
            let w = Writer::new(BufWriter::with_capacity(1 << 20, f), self.header.clone())
                .map_err(|e| Error::las(&path, e))?;
            self.writer = Some(w);
            self.current = Some(path);
            self.in_part = 0;
        }
        self.buf.extend_from_slice(records);
        self.in_part += n;
        if self.buf.len() >= FLUSH_POINTS * self.header.point_format().len() as usize {
            self.flush()?;
        }
        Ok(())
    }

    fn flush(&mut self) -> Result<()> {
        let (Some(w), Some(path)) = (self.writer.as_mut(), self.current.as_ref()) else {
            return Ok(());
        };
        if self.buf.is_empty() {
            return Ok(());
        }
        let data = PointDataBuilder::new()
            .with_format(self.format)
            .with_transforms(self.transforms)
            .build_from_bytes(std::mem::take(&mut self.buf))
            .map_err(|e| Error::las(path, e))?;
        w.write_points(&data).map_err(|e| Error::las(path, e))
    }

    /// Ends the current part if it is full (called between clouds, so a cloud never spans two
    /// parts).
    fn maybe_roll(&mut self) -> Result<()> {
        if self.in_part >= self.part_points {
            self.close_part()?;
        }
        Ok(())
    }

    fn close_part(&mut self) -> Result<()> {
        self.flush()?;
        if let (Some(mut w), Some(path)) = (self.writer.take(), self.current.take()) {
            w.close().map_err(|e| Error::las(&path, e))?;
            self.parts.push(path);
        }
        Ok(())
    }
}

fn las_header(
    schema: &CloudSchema,
    transforms: Vector<Transform>,
    p: &McapParams,
    src: &Path,
) -> Result<las::Header> {
    let mut b = Builder::from((1, 4));
    b.version = Version::new(1, 4);
    b.point_format = schema.format();
    b.transforms = transforms;
    b.gps_time_type = las::GpsTimeType::Standard;
    b.generating_software = format!("tessera {} mcap", env!("CARGO_PKG_VERSION"));
    if let Some(v) = schema.extra_bytes_vlr() {
        b.vlrs.push(v);
    }
    let crs = p.crs.trim();
    let wkt = [
        "PROJCS",
        "PROJCRS",
        "GEOGCS",
        "GEOGCRS",
        "COMPD_CS",
        "COMPOUNDCRS",
        "GEOCCS",
    ]
    .iter()
    .any(|k| crs.starts_with(k));
    if wkt {
        let mut data = crs.as_bytes().to_vec();
        data.push(0);
        b.vlrs.push(Vlr {
            user_id: "LASF_Projection".into(),
            record_id: 2112,
            description: "OGC WKT (mcap.crs)".into(),
            data,
        });
    } else if !crs.is_empty() {
        b.vlrs.push(Vlr {
            user_id: "tessera".into(),
            record_id: 1,
            description: "CRS note (mcap.crs)".into(),
            data: crs.as_bytes().to_vec(),
        });
    }
    b.into_header()
        .map_err(|e| Error::bad_input(src, format!("cannot build the LAS header: {e}")))
}

/// How a cloud's per-point time values map to absolute nanoseconds.
#[derive(Debug, Clone, Copy)]
struct TimeMap {
    unit_s: f64,
    absolute: bool,
}

impl TimeMap {
    /// Decides from the cloud's first finite time value: values past 1e6 s are absolute
    /// epoch times, smaller ones offsets from the header stamp. With an automatic unit, a
    /// float field holding more than 1e14 units is taken as nanoseconds (Livox style).
    fn detect(a: &pointcloud2::Accessor, unit_s: f64, auto_unit: bool, v: f64) -> TimeMap {
        let mut unit = unit_s;
        if auto_unit && !pointcloud2::datatype::is_integer(a.datatype) && v.abs() > 1e14 {
            unit = 1e-9;
        }
        TimeMap {
            unit_s: unit,
            absolute: (v * unit).abs() > 1e6,
        }
    }

    #[inline]
    fn to_ns(self, v: f64, stamp_ns: i128) -> i128 {
        let ns = if self.unit_s == 1e-9 {
            v.round() as i128
        } else {
            (v * self.unit_s * 1e9).round() as i128
        };
        if self.absolute {
            ns
        } else {
            stamp_ns + ns
        }
    }
}

/// Everything pass 2 keeps while going through the clouds.
struct CloudPass<'a> {
    src: &'a McapSource,
    p: &'a McapParams,
    tf: &'a TfTree,
    lim: Limits,
    schema: Option<CloudSchema>,
    chains: HashMap<String, std::result::Result<Chain, String>>,
    writer: Option<PartWriter>,
    work_dir: &'a Path,
    topic_index: HashMap<String, u16>,
    // Per-cloud scratch, reused.
    pose_cache: HashMap<i128, Iso>,
    xyz: Vec<[f64; 3]>,
    attrs: Vec<(f64, u16, [u16; 3])>,
    extras: Vec<u8>,
    records: Vec<u8>,
}

/// Why a cloud could not be used: a kind for the counts and a message.
struct Unusable(&'static str, String);

impl CloudPass<'_> {
    fn cloud(&mut self, m: MessageRef, rep: &mut McapReport) -> Result<()> {
        let c = m.channel;
        rep.clouds += 1;
        let Some(enc) = Encoding::from_channel(&c.message_encoding) else {
            let why = format!(
                "message encoding \"{}\" (schema {} \"{}\") is not supported; tessera reads \"ros1\" and \"cdr\" (ROS 2)",
                c.message_encoding, c.schema_encoding, c.schema_name
            );
            return self.unusable(
                c,
                m.log_time,
                None,
                Unusable("unsupported encoding", why),
                rep,
            );
        };
        let cloud = match pointcloud2::decode(m.data, enc) {
            Ok(cl) => cl,
            Err(e) => {
                return self.unusable(
                    c,
                    m.log_time,
                    None,
                    Unusable("undecodable", format!("cannot decode PointCloud2: {e}")),
                    rep,
                )
            }
        };
        rep.points_in_clouds += cloud.len() as u64;
        let stamp = cloud.stamp;
        match self.place(&cloud, c, rep) {
            Ok(()) => Ok(()),
            Err(PlaceError::Unusable(u)) => self.unusable(c, m.log_time, Some(stamp), u, rep),
            Err(PlaceError::Fatal(e)) => Err(e),
        }
    }

    fn unusable(
        &mut self,
        c: &ChannelInfo,
        log_time: u64,
        stamp: Option<Stamp>,
        u: Unusable,
        rep: &mut McapReport,
    ) -> Result<()> {
        let at = match stamp {
            Some(s) => format!("cloud stamped {s} (log time {})", fmt_ns(log_time)),
            None => format!("message at log time {}", fmt_ns(log_time)),
        };
        let why = format!("topic {}, {at}: {}", c.topic, u.1);
        if self.p.on_error == OnError::Fail {
            return Err(Error::bad_input(
                self.src.path(),
                format!("{why} (set mcap.on_error = \"skip\" to skip such clouds)"),
            ));
        }
        *rep.clouds_skipped.entry(u.0.to_string()).or_default() += 1;
        note(rep, why);
        Ok(())
    }

    fn place(
        &mut self,
        cloud: &pointcloud2::PointCloud2,
        c: &ChannelInfo,
        rep: &mut McapReport,
    ) -> std::result::Result<(), PlaceError> {
        let p = self.p;
        if self.schema.is_none() {
            let s = CloudSchema::from_cloud(cloud, p).map_err(|e| {
                PlaceError::Fatal(Error::bad_input(
                    self.src.path(),
                    format!("topic {}, cloud stamped {}: {e}", c.topic, cloud.stamp),
                ))
            })?;
            rep.time_field = s.time_field.clone();
            rep.extra_fields = s.extras.iter().map(|e| e.name.clone()).collect();
            self.schema = Some(s);
        }
        let Some(schema) = self.schema.as_ref() else {
            return Ok(());
        };
        let b: Bound = schema
            .bind(cloud, p.time_unit_s)
            .map_err(|e| PlaceError::Unusable(Unusable("layout", e)))?;
        for n in &b.missing {
            *rep.missing_fields.entry(n.clone()).or_default() += 1;
        }
        let frame = super::tf::normalise(cloud.frame_id).to_string();
        let chain = self
            .chains
            .entry(frame.clone())
            .or_insert_with(|| {
                self.tf
                    .chain(&p.target_frame, &frame)
                    .map_err(|e| e.to_string())
            })
            .clone()
            .map_err(|e| PlaceError::Unusable(Unusable("no transform chain", e)))?;
        let stamp_ns = cloud.stamp.as_nanos();
        let pose_err =
            |e: super::tf::PoseError| PlaceError::Unusable(Unusable("missing pose", e.to_string()));
        let cloud_pose: Iso = self
            .tf
            .eval(&chain, stamp_ns, &self.lim)
            .map_err(pose_err)?;
        let deskew = p.deskew && b.time.is_some() && !chain.is_static;
        let min_r2 = p.min_range_m * p.min_range_m;
        let [ax, ay, az] = b.xyz;
        self.xyz.clear();
        self.attrs.clear();
        self.extras.clear();
        let mut time_map: Option<TimeMap> = None;
        self.pose_cache.clear();
        let mut last_t = i128::MIN;
        let mut pose = cloud_pose;
        let (mut nan, mut near) = (0u64, 0u64);
        let off = p.world_offset;
        for i in 0..cloud.len() {
            let pt = cloud.point(i);
            let (x, y, z) = (ax.get(pt), ay.get(pt), az.get(pt));
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                nan += 1;
                continue;
            }
            if x * x + y * y + z * z < min_r2 {
                near += 1;
                continue;
            }
            let t_ns = match &b.time {
                Some((a, unit)) => {
                    let v = a.get(pt);
                    let tm = *time_map
                        .get_or_insert_with(|| TimeMap::detect(a, *unit, p.time_unit_s == 0.0, v));
                    if !v.is_finite() {
                        stamp_ns
                    } else {
                        tm.to_ns(v, stamp_ns)
                    }
                }
                None => stamp_ns,
            };
            if deskew && t_ns != last_t {
                // Organised clouds repeat each firing time once per ring: evaluate the chain
                // once per distinct time.
                pose = match self.pose_cache.get(&t_ns) {
                    Some(p) => *p,
                    None => {
                        let p = self.tf.eval(&chain, t_ns, &self.lim).map_err(|e| {
                            PlaceError::Unusable(Unusable(
                                "missing pose",
                                format!("point {i} (per-point time): {e}"),
                            ))
                        })?;
                        if self.pose_cache.len() < 1 << 16 {
                            self.pose_cache.insert(t_ns, p);
                        }
                        p
                    }
                };
                last_t = t_ns;
            }
            let w = pose * Point3::new(x, y, z);
            self.xyz.push([w.x + off[0], w.y + off[1], w.z + off[2]]);
            let inten = b
                .intensity
                .map(|a| a.get(pt).round().clamp(0.0, 65535.0) as u16)
                .unwrap_or(0);
            let rgb = b.rgb.map(|a| unpack_rgb(a.bits32(pt))).unwrap_or([0; 3]);
            let gps = (t_ns - UNIX_TO_ADJUSTED_GPS_S * 1_000_000_000) as f64 * 1e-9;
            self.attrs.push((gps, inten, rgb));
            for (e, spec) in b.extras.iter().zip(&schema.extras) {
                match e {
                    Some(a) => a.push_le(pt, &mut self.extras),
                    None => self.extras.extend(std::iter::repeat_n(0u8, spec.size)),
                }
            }
        }
        rep.points_nan += nan;
        rep.points_near += near;
        if deskew {
            rep.clouds_deskewed += 1;
        }
        self.write_cloud(&c.topic).map_err(PlaceError::Fatal)?;
        rep.clouds_used += 1;
        rep.points_written += self.xyz.len() as u64;
        Ok(())
    }

    fn write_cloud(&mut self, topic: &str) -> Result<()> {
        if self.xyz.is_empty() {
            return Ok(());
        }
        let Some(schema) = self.schema.as_ref() else {
            return Ok(());
        };
        if self.writer.is_none() {
            // Offsets on a 1 km grid near the first point keep every coordinate of a drive
            // well inside the ±2^31 × scale an i32 record can hold.
            let first = self.xyz[0];
            let t = |v: f64, s: f64| Transform {
                scale: s,
                offset: (v / 1000.0).round() * 1000.0,
            };
            let transforms = Vector {
                x: t(first[0], self.p.scale_m),
                y: t(first[1], self.p.scale_m),
                z: Transform {
                    scale: self.p.scale_m,
                    offset: 0.0,
                },
            };
            let header = las_header(schema, transforms, self.p, self.src.path())?;
            let stem = self
                .src
                .path()
                .file_stem()
                .map(|s| s.to_string_lossy().into_owned())
                .unwrap_or_else(|| "drive".into());
            let mut format = schema.format();
            format.is_compressed = false;
            self.writer = Some(PartWriter {
                dir: self.work_dir.to_path_buf(),
                stem,
                header,
                writer: None,
                current: None,
                in_part: 0,
                part_points: self.p.part_points,
                parts: Vec::new(),
                buf: Vec::new(),
                format,
                transforms,
            });
        }
        let Some(w) = self.writer.as_mut() else {
            return Ok(());
        };
        let tr = w.transforms;
        let psid = self.topic_index.get(topic).copied().unwrap_or(0);
        let rgb = schema.rgb_field.is_some();
        let eb = schema.extra_bytes();
        self.records.clear();
        for (i, (p, (gps, inten, col))) in self.xyz.iter().zip(&self.attrs).enumerate() {
            let q = |v: f64, t: &Transform, axis: &str| -> Result<i32> {
                let r = ((v - t.offset) / t.scale).round();
                if r.abs() < 2_147_483_647.0 {
                    Ok(r as i32)
                } else {
                    Err(Error::bad_input(
                        self.src.path(),
                        format!(
                            "topic {topic}: {axis} = {v} is too far from the first point for LAS coordinates at scale {} (check the poses, or raise mcap.scale_m)",
                            t.scale
                        ),
                    ))
                }
            };
            let r = &mut self.records;
            r.extend(q(p[0], &tr.x, "x")?.to_le_bytes());
            r.extend(q(p[1], &tr.y, "y")?.to_le_bytes());
            r.extend(q(p[2], &tr.z, "z")?.to_le_bytes());
            r.extend(inten.to_le_bytes());
            r.push(0x11); // return 1 of 1
            r.push(0); // classification flags, scanner channel, scan direction, edge
            r.push(0); // classification: never classified
            r.push(0); // user data
            r.extend(0i16.to_le_bytes()); // scan angle
            r.extend(psid.to_le_bytes()); // point source id: the topic's index
            r.extend(gps.to_le_bytes());
            if rgb {
                for ch in col {
                    r.extend(ch.to_le_bytes());
                }
            }
            r.extend_from_slice(&self.extras[i * eb..(i + 1) * eb]);
        }
        let n = self.xyz.len() as u64;
        w.write(&self.records, n)?;
        w.maybe_roll()
    }
}

enum PlaceError {
    Unusable(Unusable),
    Fatal(Error),
}

/// Converts one recording into LAS parts in `work_dir` (created if needed).
pub fn convert_file(path: &Path, work_dir: &Path, p: &McapParams) -> Result<Conversion> {
    let t0 = Instant::now();
    p.validate()?;
    let src = McapSource::open(path)?;
    if let Some(n) = &src.summary_note {
        tracing::info!("{}: {n}; reading it linearly", path.display());
    }
    std::fs::create_dir_all(work_dir).map_err(|e| Error::io(work_dir, e))?;
    let mut rep = McapReport {
        file: path.to_path_buf(),
        profile: src.profile.clone(),
        target_frame: super::tf::normalise(&p.target_frame).to_string(),
        pose_source: format!("{:?}", p.pose_source).to_lowercase(),
        world_offset: p.world_offset,
        crs: p.crs.clone(),
        ..Default::default()
    };
    let (tf, _) = gather_poses(&src, p, &mut rep)?;
    rep.pose_samples = tf.sample_count();
    let lim = Limits {
        max_gap_ns: (p.max_pose_gap_s * 1e9).round() as i128,
        extrapolate_ns: (p.pose_extrapolation_s * 1e9).round() as i128,
    };
    let mut all_topics: Vec<(String, String)> = Vec::new();
    let mut selected: Vec<String> = Vec::new();
    let mut pass = CloudPass {
        src: &src,
        p,
        tf: &tf,
        lim,
        schema: None,
        chains: HashMap::new(),
        writer: None,
        work_dir,
        topic_index: HashMap::new(),
        pose_cache: HashMap::new(),
        xyz: Vec::new(),
        attrs: Vec::new(),
        extras: Vec::new(),
        records: Vec::new(),
    };
    let mut want = |c: &ChannelInfo| {
        all_topics.push((c.topic.clone(), c.schema_name.clone()));
        let take = if p.cloud_topics.is_empty() {
            message_type_ok(c, &["sensor_msgs/PointCloud2"])
        } else {
            p.cloud_topics.contains(&c.topic)
        };
        if take && !selected.contains(&c.topic) {
            selected.push(c.topic.clone());
        }
        take
    };
    let mut on_message = |m: MessageRef| -> Result<()> {
        if !message_type_ok(m.channel, &["sensor_msgs/PointCloud2"]) {
            return Err(Error::Config(format!(
                "{}: mcap.cloud_topics names {}, which carries \"{}\", not sensor_msgs/PointCloud2",
                path.display(),
                m.channel.topic,
                m.channel.schema_name
            )));
        }
        let n = pass.topic_index.len() as u16;
        pass.topic_index.entry(m.channel.topic.clone()).or_insert(n);
        pass.cloud(m, &mut rep)
    };
    let out = src.scan(&mut want, &mut on_message, p.on_error == OnError::Fail)?;
    rep.indexed = out.indexed;
    handle_damage(&src, p, &mut rep, &out.damage, "reading clouds")?;
    let parts = match pass.writer.as_mut() {
        Some(w) => {
            w.close_part()?;
            std::mem::take(&mut w.parts)
        }
        None => Vec::new(),
    };
    selected.sort();
    rep.topics = selected.clone();
    rep.parts = parts.len();
    rep.seconds = t0.elapsed().as_secs_f64();
    for t in &p.cloud_topics {
        if !all_topics.iter().any(|(a, _)| a == t) {
            let mut avail: Vec<String> = match src.summary_channels() {
                Some(cs) => cs
                    .iter()
                    .map(|c| format!("{} ({})", c.topic, c.schema_name))
                    .collect(),
                None => all_topics
                    .iter()
                    .map(|(t, s)| format!("{t} ({s})"))
                    .collect(),
            };
            avail.sort();
            avail.dedup();
            return Err(Error::Config(format!(
                "{}: mcap.cloud_topics names {t}, which has no messages in the file (topics: {})",
                path.display(),
                avail.join(", ")
            )));
        }
    }
    if rep.points_written == 0 {
        let why = if rep.clouds == 0 {
            if p.cloud_topics.is_empty() {
                "it has no sensor_msgs/PointCloud2 messages".to_string()
            } else {
                "the selected topics have no messages".to_string()
            }
        } else {
            format!(
                "none of its {} clouds gave a usable point (skipped: {:?}, invalid points {}, nearer than min_range_m {}){}",
                rep.clouds,
                rep.clouds_skipped,
                rep.points_nan,
                rep.points_near,
                rep.notes
                    .first()
                    .map(|n| format!("; first problem: {n}"))
                    .unwrap_or_default()
            )
        };
        return Err(Error::bad_input(path, format!("nothing usable: {why}")));
    }
    tracing::info!(
        "{}: {} of {} clouds → {} points in {} LAS part(s) ({} invalid and {} near points dropped) in {:.2} s",
        path.display(),
        rep.clouds_used,
        rep.clouds,
        rep.points_written,
        rep.parts,
        rep.points_nan,
        rep.points_near,
        rep.seconds
    );
    Ok(Conversion { parts, report: rep })
}

/// The run's inputs with every MCAP replaced by its LAS parts. The work directory is removed
/// when this is dropped (also when the run fails).
#[derive(Debug, Default)]
pub struct StagedInputs {
    /// Input paths for the LAS reader.
    pub paths: Vec<PathBuf>,
    /// One report per MCAP input.
    pub reports: Vec<McapReport>,
    work_dir: Option<PathBuf>,
}

impl Drop for StagedInputs {
    fn drop(&mut self) {
        if let Some(d) = &self.work_dir {
            let _ = std::fs::remove_dir_all(d);
        }
    }
}

/// Expands `inputs` and converts every MCAP among them into LAS parts under `work_dir`.
pub fn stage_inputs(inputs: &[PathBuf], work_dir: &Path, p: &McapParams) -> Result<StagedInputs> {
    let paths = expand_paths(inputs)?;
    if !paths.iter().any(|f| is_mcap(f)) {
        return Ok(StagedInputs {
            paths,
            reports: Vec::new(),
            work_dir: None,
        });
    }
    // A crashed earlier run may have left parts behind; they are never reused.
    let _ = std::fs::remove_dir_all(work_dir);
    std::fs::create_dir_all(work_dir).map_err(|e| Error::io(work_dir, e))?;
    let mut staged = StagedInputs {
        paths: Vec::new(),
        reports: Vec::new(),
        work_dir: Some(work_dir.to_path_buf()),
    };
    for (i, f) in paths.iter().enumerate() {
        if is_mcap(f) {
            let conv = convert_file(f, &work_dir.join(format!("{i:05}")), p)?;
            staged.paths.extend(conv.parts);
            staged.reports.push(conv.report);
        } else {
            staged.paths.push(f.clone());
        }
    }
    Ok(staged)
}

/// Where a run keeps the LAS parts of its MCAP inputs: beside the spill directory (which is
/// wiped when the pipeline starts), i.e. `<out>/.tessera-mcap` or `<spill_dir>-mcap`.
pub fn work_dir(out_dir: &Path, spill_dir: &str) -> PathBuf {
    if spill_dir.is_empty() {
        out_dir.join(".tessera-mcap")
    } else {
        PathBuf::from(format!("{}-mcap", spill_dir.trim_end_matches('/')))
    }
}
