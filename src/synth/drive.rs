//! `tessera synth --mcap`: the simulated drive ([`super::lidar`]) written as a ROS 2 MCAP
//! recording — organised `sensor_msgs/PointCloud2` per revolution on `/points` (frame
//! `lidar`), `map → base_link` on `/tf` at 100 Hz and `base_link → lidar` on `/tf_static` —
//! plus the scene's `segments.tsv`.
//!
//! The `map` frame is the scene frame shifted by [`super::WORLD_OFFSET`] (projected
//! coordinates, as the LAS scene), so the drive lands where the LAS scene does.
//!
//! Cloud layout (point_step 48, padded like real drivers): `x y z` FLOAT32 @0/4/8,
//! `intensity` FLOAT32 @16, `t` UINT32 @20 (ns after the header stamp, which is the start of
//! the revolution), `ring` UINT16 @24, `gt_class` UINT8 @26, `gt_segment` UINT32 @28, `rgb`
//! packed FLOAT32 @32. No-returns are NaN points (`is_dense` false). The truth fields become
//! LAS extra bytes of the same names as in the LAS scene, so `tessera eval` scores a processed
//! drive directly.

use super::lidar::{mount, simulate_revolution, LidarParams, Revolution};
use super::{segments, write_segments_tsv, WORLD_OFFSET};
use crate::error::{Error, Result};
use crate::io::mcap::encode::{pointcloud2, tf_message, POINTCLOUD2_SCHEMA, TFMESSAGE_SCHEMA};
use crate::io::mcap::pointcloud2::{datatype, PointField};
use crate::io::mcap::tf::TransformStamped;
use crate::io::mcap::wire::Stamp;
use crate::io::output::tmp_path;
use nalgebra::{Isometry3, Translation3};
use rayon::prelude::*;
use std::collections::BTreeMap;
use std::io::BufWriter;
use std::path::Path;

/// Unix time of the start of every simulated drive (2023-11-14T22:13:20Z).
pub const DRIVE_T0_S: i64 = 1_700_000_000;
/// Rate of the `/tf` poses.
pub const TF_RATE_HZ: f64 = 100.0;
/// Bytes per point of the written clouds.
pub const POINT_STEP: u32 = 48;

/// What `write_drive` produced.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct DriveStats {
    /// Clouds (revolutions) written.
    pub clouds: u64,
    /// Beams fired.
    pub beams: u64,
    /// Returns (valid points).
    pub points: u64,
}

/// The PointCloud2 field table of the simulated sensor.
pub fn fields() -> Vec<PointField> {
    let f = |name: &str, offset: u32, dt: u8| PointField {
        name: name.into(),
        offset,
        datatype: dt,
        count: 1,
    };
    vec![
        f("x", 0, datatype::FLOAT32),
        f("y", 4, datatype::FLOAT32),
        f("z", 8, datatype::FLOAT32),
        f("intensity", 16, datatype::FLOAT32),
        f("t", 20, datatype::UINT32),
        f("ring", 24, datatype::UINT16),
        f("gt_class", 26, datatype::UINT8),
        f("gt_segment", 28, datatype::UINT32),
        f("rgb", 32, datatype::FLOAT32),
    ]
}

/// Absolute stamp of a time given in ns after the drive start.
pub fn stamp_of(ns_after_start: i128) -> Stamp {
    Stamp::from_nanos(DRIVE_T0_S as i128 * 1_000_000_000 + ns_after_start)
}

/// Pose of `base_link` in `map` at `ns` after the start (scene pose + world offset).
pub fn map_pose(p: &LidarParams, ns: i128) -> Isometry3<f64> {
    let o = Translation3::new(WORLD_OFFSET[0], WORLD_OFFSET[1], WORLD_OFFSET[2]);
    o * p.vehicle_pose(ns as f64 * 1e-9)
}

/// The serialised cloud of one revolution.
pub fn cloud_message(p: &LidarParams, rev: &Revolution) -> Vec<u8> {
    let cols = p.columns as usize;
    let step = POINT_STEP as usize;
    let mut data = vec![0u8; rev.beams.len() * step];
    for (i, (b, rec)) in rev
        .beams
        .iter()
        .zip(data.chunks_exact_mut(step))
        .enumerate()
    {
        let (ring, col) = (i / cols, i % cols);
        rec[20..24].copy_from_slice(&p.firing_offset_ns(col as u32).to_le_bytes());
        rec[24..26].copy_from_slice(&(ring as u16).to_le_bytes());
        match b {
            None => {
                for k in 0..3 {
                    rec[4 * k..4 * k + 4].copy_from_slice(&f32::NAN.to_le_bytes());
                }
            }
            Some(r) => {
                for k in 0..3 {
                    rec[4 * k..4 * k + 4].copy_from_slice(&r.sensor[k].to_le_bytes());
                }
                rec[16..20].copy_from_slice(&r.intensity.to_le_bytes());
                rec[26] = r.class;
                rec[28..32].copy_from_slice(&r.segment.to_le_bytes());
                let packed =
                    (u32::from(r.rgb[0]) << 16) | (u32::from(r.rgb[1]) << 8) | u32::from(r.rgb[2]);
                rec[32..36].copy_from_slice(&packed.to_le_bytes());
            }
        }
    }
    pointcloud2(
        stamp_of(rev.start_ns),
        "lidar",
        p.rings,
        p.columns,
        &fields(),
        POINT_STEP,
        &data,
        false,
    )
}

fn tf(ns: i128, parent: &str, child: &str, iso: Isometry3<f64>) -> TransformStamped {
    TransformStamped {
        stamp: stamp_of(ns),
        parent: parent.into(),
        child: child.into(),
        iso,
    }
}

/// Writes `dir/drive.mcap` (zstd chunks, with summary and index) and `dir/segments.tsv`.
pub fn write_drive(p: &LidarParams, dir: &Path) -> Result<DriveStats> {
    p.validate()
        .map_err(|e| Error::Config(format!("synth --mcap: {e}")))?;
    std::fs::create_dir_all(dir).map_err(|e| Error::io(dir, e))?;
    let path = dir.join("drive.mcap");
    let tmp = tmp_path(&path);
    let res = write_mcap(p, &tmp);
    match res {
        Ok(s) => {
            crate::io::output::commit_tmp(&tmp, &path)?;
            write_segments_tsv(dir, &segments(&p.scene))?;
            Ok(s)
        }
        Err(e) => {
            let _ = std::fs::remove_file(&tmp);
            Err(e)
        }
    }
}

fn write_mcap(p: &LidarParams, path: &Path) -> Result<DriveStats> {
    let me = |e: mcap::McapError| Error::bad_input(path, format!("writing MCAP: {e}"));
    let f = std::fs::File::create(path).map_err(|e| Error::io(path, e))?;
    let opts = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .library(format!("tessera synth {}", env!("CARGO_PKG_VERSION")))
        .chunk_size(Some(4 << 20));
    let mut w = opts
        .create(BufWriter::with_capacity(1 << 20, f))
        .map_err(me)?;
    let s_pc = w
        .add_schema(
            "sensor_msgs/msg/PointCloud2",
            "ros2msg",
            POINTCLOUD2_SCHEMA.as_bytes(),
        )
        .map_err(me)?;
    let s_tf = w
        .add_schema(
            "tf2_msgs/msg/TFMessage",
            "ros2msg",
            TFMESSAGE_SCHEMA.as_bytes(),
        )
        .map_err(me)?;
    let none = BTreeMap::new();
    let c_pc = w.add_channel(s_pc, "/points", "cdr", &none).map_err(me)?;
    let c_tf = w.add_channel(s_tf, "/tf", "cdr", &none).map_err(me)?;
    let c_st = w
        .add_channel(s_tf, "/tf_static", "cdr", &none)
        .map_err(me)?;
    let mut seq: BTreeMap<u16, u32> = BTreeMap::new();
    let mut put = |w: &mut mcap::Writer<_>, ch: u16, ns: i128, data: &[u8]| {
        let s = seq.entry(ch).or_insert(0);
        *s += 1;
        let log = (DRIVE_T0_S as i128 * 1_000_000_000 + ns) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: *s,
                log_time: log,
                publish_time: log,
            },
            data,
        )
    };
    put(
        &mut w,
        c_st,
        0,
        &tf_message(&[tf(0, "base_link", "lidar", mount())]),
    )
    .map_err(me)?;
    let revs = p.revolutions();
    let rev_ns = |k: u64| p.revolution_start_ns(k);
    let tf_step = (1e9 / TF_RATE_HZ).round() as i128;
    // Poses cover every firing, one sample beyond the last.
    let tf_end = rev_ns(revs) + tf_step;
    let mut next_tf: i128 = 0;
    let mut stats = DriveStats {
        clouds: 0,
        beams: 0,
        points: 0,
    };
    let batch = (2 * rayon::current_num_threads()).max(2) as u64;
    let mut k = 0;
    while k < revs {
        let ks: Vec<u64> = (k..(k + batch).min(revs)).collect();
        let done: Vec<(Revolution, Vec<u8>)> = ks
            .par_iter()
            .map(|&i| {
                let r = simulate_revolution(p, i);
                let m = cloud_message(p, &r);
                (r, m)
            })
            .collect();
        for (r, msg) in done {
            let end = rev_ns(r.index + 1);
            while next_tf <= end.min(tf_end) {
                let m = tf_message(&[tf(next_tf, "map", "base_link", map_pose(p, next_tf))]);
                put(&mut w, c_tf, next_tf, &m).map_err(me)?;
                next_tf += tf_step;
            }
            // Logged when the revolution ends, as drivers publish.
            put(&mut w, c_pc, end, &msg).map_err(me)?;
            stats.clouds += 1;
            stats.beams += r.beams.len() as u64;
            stats.points += r.beams.iter().filter(|b| b.is_some()).count() as u64;
        }
        k += batch;
    }
    while next_tf <= tf_end {
        let m = tf_message(&[tf(next_tf, "map", "base_link", map_pose(p, next_tf))]);
        put(&mut w, c_tf, next_tf, &m).map_err(me)?;
        next_tf += tf_step;
    }
    w.finish().map_err(me)?;
    Ok(stats)
}
