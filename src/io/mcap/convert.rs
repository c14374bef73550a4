//! MCAP → georeferenced LAS parts: pass 1 gathers poses, pass 2 decodes, cleans and places
//! the clouds and writes them, streaming, to uncompressed LAS 1.4 files in a work directory.

use super::reader::{fmt_ns, ChannelInfo, McapSource, MessageRef};
use super::report::{message_type_ok, note};
use super::tf::{decode_odometry, decode_tf_message, Limits, TfTree};
use super::trajectory::read_trajectory;
use super::wire::Encoding;
use super::{is_mcap, McapParams, OnError, PoseSource};
use crate::error::{Error, Result};
use crate::io::input::expand_paths;
use std::path::{Path, PathBuf};
use std::time::Instant;

pub use super::place::UNIX_TO_ADJUSTED_GPS_S;
pub use super::report::McapReport;

/// The result of converting one recording.
#[derive(Debug, Clone)]
pub struct Conversion {
    /// LAS parts written, in drive order.
    pub parts: Vec<PathBuf>,
    /// What happened.
    pub report: McapReport,
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

/// Converts one recording into LAS parts in `work_dir` (created if needed), placing clouds on
/// every core.
pub fn convert_file(path: &Path, work_dir: &Path, p: &McapParams) -> Result<Conversion> {
    convert_file_with(path, work_dir, p, 0)
}

/// [`convert_file`] with `threads` workers placing clouds (0 = one per core).
pub fn convert_file_with(
    path: &Path,
    work_dir: &Path,
    p: &McapParams,
    threads: usize,
) -> Result<Conversion> {
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
    let (out, parts) =
        super::clouds::place_clouds(&src, p, (&tf, lim), work_dir, threads, &mut rep, &mut want)?;
    rep.indexed = out.indexed;
    handle_damage(&src, p, &mut rep, &out.damage, "reading clouds")?;
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

/// Expands `inputs` and converts every MCAP among them into LAS parts under `work_dir`, with
/// `threads` workers (0 = one per core).
pub fn stage_inputs(
    inputs: &[PathBuf],
    work_dir: &Path,
    p: &McapParams,
    threads: usize,
) -> Result<StagedInputs> {
    let paths = expand_paths(inputs)?;
    if !paths.iter().any(|f| is_mcap(f)) {
        return Ok(StagedInputs {
            paths,
            reports: Vec::new(),
            work_dir: None,
        });
    }
    // `work_dir` must be new: it is removed with the staged inputs. The pipeline passes a
    // subdirectory of its own fresh work directory.
    std::fs::create_dir(work_dir).map_err(|e| Error::io(work_dir, e))?;
    let mut staged = StagedInputs {
        paths: Vec::new(),
        reports: Vec::new(),
        work_dir: Some(work_dir.to_path_buf()),
    };
    for (i, f) in paths.iter().enumerate() {
        if is_mcap(f) {
            let conv = convert_file_with(f, &work_dir.join(format!("{i:05}")), p, threads)?;
            staged.paths.extend(conv.parts);
            staged.reports.push(conv.report);
        } else {
            staged.paths.push(f.clone());
        }
    }
    Ok(staged)
}
