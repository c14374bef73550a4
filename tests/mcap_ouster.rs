//! Gate: the real Ouster OS1-64 recording (ROS 1 encoding inside MCAP, organised 64 × 2048,
//! point_step 48 with padding, zstd chunks) decodes to exactly what an independent decoder
//! (Python `mcap` + `rosbags`, scripts/mcap_dump_clouds.py) reads, and its LAS conversion
//! keeps every value where LAS has a place for it.

mod common;
mod mcap_common;

use common::data_file;
use mcap_common::*;
use std::path::PathBuf;

const FILE: &str = "mcap-ouster-ros1/ouster_os1_ros1profile.mcap";

#[test]
fn ouster_ros1_clouds_equal_the_independent_decoder() {
    let Some(path) = data_file(FILE) else { return };
    let ours = decode_clouds(&path);
    // Facts from the data set's SOURCE.md, checked without the oracle.
    assert_eq!(ours.len(), 2, "two PointCloud2 messages");
    for c in &ours {
        assert_eq!((c.height, c.width, c.point_step), (64, 2048, 48));
        assert_eq!(c.row_step, 98_304);
        assert_eq!(c.frame_id, "os1_lidar");
        assert!(!c.is_bigendian && c.is_dense);
        assert_eq!(c.values.len(), 131_072);
        let names: Vec<&str> = c.columns.iter().map(|s| s.as_str()).collect();
        assert_eq!(
            names,
            [
                "x",
                "y",
                "z",
                "intensity",
                "t",
                "reflectivity",
                "ring",
                "noise",
                "range"
            ]
        );
    }
    if !have_py_mcap() {
        return;
    }
    let tmp = tempfile::tempdir().unwrap();
    run_script("mcap_dump_clouds.py", &[&path, tmp.path()]);
    let meta: serde_json::Value =
        serde_json::from_slice(&std::fs::read(tmp.path().join("clouds.json")).unwrap()).unwrap();
    let clouds = meta.as_array().unwrap();
    assert_eq!(clouds.len(), ours.len());
    let mut compared = 0usize;
    for (m, c) in clouds.iter().zip(&ours) {
        assert_eq!(m["topic"], c.topic.as_str());
        assert_eq!(m["log_time"].as_u64().unwrap(), c.log_time);
        let stamp = m["stamp_sec"].as_i64().unwrap() as i128 * 1_000_000_000
            + m["stamp_nsec"].as_i64().unwrap() as i128;
        assert_eq!(stamp, c.stamp_ns);
        assert_eq!(m["frame_id"], c.frame_id.as_str());
        assert_eq!(m["height"].as_u64().unwrap(), c.height as u64);
        assert_eq!(m["width"].as_u64().unwrap(), c.width as u64);
        assert_eq!(m["point_step"].as_u64().unwrap(), c.point_step as u64);
        assert_eq!(m["row_step"].as_u64().unwrap(), c.row_step as u64);
        let fields: Vec<(String, u32, u8, u32)> = m["fields"]
            .as_array()
            .unwrap()
            .iter()
            .map(|f| {
                (
                    f[0].as_str().unwrap().to_string(),
                    f[1].as_u64().unwrap() as u32,
                    f[2].as_u64().unwrap() as u8,
                    f[3].as_u64().unwrap() as u32,
                )
            })
            .collect();
        assert_eq!(fields, c.fields);
        let rows = npy_rows(&tmp.path().join(m["npy"].as_str().unwrap()));
        assert_eq!(rows.len(), c.values.len(), "point count");
        for (i, (a, b)) in rows.iter().zip(&c.values).enumerate() {
            for (k, (x, y)) in a.iter().zip(b).enumerate() {
                assert!(
                    same(*x, *y),
                    "cloud {} point {i} field {}: oracle {x}, tessera {y}",
                    c.log_time,
                    c.columns[k]
                );
                compared += 1;
            }
        }
    }
    assert_eq!(compared, 2 * 131_072 * 9);
    eprintln!("ouster: {compared} field values equal to the rosbags/numpy decoder");
}

#[test]
fn ouster_las_conversion_keeps_values_in_their_las_places() {
    let Some(path) = data_file(FILE) else { return };
    let ours = decode_clouds(&path);
    let tmp = tempfile::tempdir().unwrap();
    // The recording has no motion (/tf_static only): place points in the lidar's own frame.
    let p = params(&[
        "mcap.target_frame=\"os1_lidar\"",
        "mcap.min_range_m=0.0",
        "mcap.scale_m=0.0001",
    ]);
    let conv = tessera::io::mcap::convert_file(&path, tmp.path(), &p).unwrap();
    let parts: Vec<PathBuf> = conv.parts.clone();
    let (pts, fields) = read_parts(&parts);
    let r = &conv.report;
    assert_eq!(r.clouds, 2);
    assert_eq!(r.clouds_used, 2);
    assert_eq!(r.points_in_clouds, 262_144);
    assert_eq!(r.points_nan, 0);
    assert_eq!(r.points_written, 262_144);
    assert_eq!(pts.len(), 262_144);
    assert_eq!(r.time_field.as_deref(), Some("t"));
    let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
    assert_eq!(names, ["reflectivity", "ring", "noise", "range"]);
    let mut k = 0;
    for c in &ours {
        for v in &c.values {
            let q = &pts[k];
            k += 1;
            for (a, (got, want)) in q.xyz.iter().zip(v).enumerate() {
                assert!(
                    (got - want).abs() <= 0.5e-4 + 1e-9,
                    "point {k} axis {a}: {got} vs {want}"
                );
            }
            assert_eq!(q.intensity as f64, v[3].round().clamp(0.0, 65535.0));
            // t is UINT32 nanoseconds after the header stamp.
            let want = gps_of(c.stamp_ns + v[4] as i128);
            assert!((q.gps_time - want).abs() < 1e-6, "{} vs {want}", q.gps_time);
            for (name, col) in [("reflectivity", 5), ("ring", 6), ("noise", 7), ("range", 8)] {
                assert_eq!(extra_value(q, &fields, name), v[col], "{name}");
            }
        }
    }
}

#[test]
fn ouster_through_the_whole_pipeline() {
    let Some(path) = data_file(FILE) else { return };
    let tmp = tempfile::tempdir().unwrap();
    let cfg = tessera::Config::load(
        None,
        &[
            "mcap.target_frame=os1_sensor".into(),
            "tiling.tile_size_m=25".into(),
            "tiling.buffer_m=20".into(),
        ],
    )
    .unwrap();
    let out = tmp.path().join("out");
    let s = tessera::pipeline::run(std::slice::from_ref(&path), &out, &cfg, &|_, _| {}).unwrap();
    assert_eq!(s.mcap.len(), 1);
    let r = &s.mcap[0];
    // 0.5 m minimum range drops the no-return beams (reported as (0, 0, 0)).
    assert_eq!(r.points_written + r.points_near + r.points_nan, 262_144);
    assert!(r.points_near > 100_000, "{}", r.points_near);
    assert_eq!(s.points_in, r.points_written);
    assert_eq!(s.points_out, s.points_in);
    let json: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(
        json["mcap"][0]["points_written"].as_u64(),
        Some(r.points_written)
    );
    // The temporary LAS parts are gone.
    assert!(!out.join(".tessera-mcap").exists());
    let ground: u64 = s
        .tile_list
        .iter()
        .filter_map(|t| t.stats.get("ground")?["ground_points"].as_u64())
        .sum();
    // A sensor standing in a street: the road around it is a large share of the returns.
    assert!(
        ground > s.points_out / 10 && ground < s.points_out,
        "{ground} ground of {}",
        s.points_out
    );
    eprintln!(
        "ouster pipeline: {} points in {} tiles, ground stats {ground}",
        s.points_out, s.tiles
    );
}

#[test]
fn info_lists_topics_counts_time_span_and_points() {
    let Some(path) = data_file(FILE) else { return };
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_tessera"))
        .arg("info")
        .arg(&path)
        .output()
        .unwrap();
    assert!(o.status.success());
    let t = String::from_utf8_lossy(&o.stdout);
    for want in [
        "profile \"ros1\"",
        "summary: 2 indexed chunks",
        "time span: 1592833242.605385634 s .. 1592833242.788158073 s (0.183 s)",
        "messages: 273 on 11 topics; PointCloud2 points: 262144 (262144 valid)",
        "topic /os1_cloud_node/points: sensor_msgs/PointCloud2 [ros1], 2 messages",
        "topic /os1_node/lidar_packets: ouster_ros/PacketMsg [ros1], 206 messages",
        "64 × 2048 (organised), frame \"os1_lidar\", point_step 48",
        "ring:UINT8@26",
    ] {
        assert!(t.contains(want), "missing \"{want}\" in:\n{t}");
    }
}
