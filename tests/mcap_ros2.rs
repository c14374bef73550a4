//! Gate: genuine ROS 2 CDR fixtures written by independent writers
//! (scripts/mcap_make_ros2_fixtures.py: `mcap-ros2-support` for CDR little-endian, `rosbags`
//! for CDR big-endian) decode to exactly the values written — padded and organised layouts,
//! big-endian blobs in big- and little-endian messages, NaN points, zstd and lz4 chunks — and
//! georeference to the coordinates numpy computes from the same poses (with /tf, odometry or a
//! trajectory file; per-point de-skew or one pose per cloud).

mod common;
mod mcap_common;

use mcap_common::*;
use serde_json::Value;
use std::path::PathBuf;
use tessera::io::mcap::convert_file;

struct Fixtures {
    _tmp: tempfile::TempDir,
    dir: PathBuf,
    expected: Value,
}

fn fixtures() -> Option<Fixtures> {
    if !have_py_mcap() {
        return None;
    }
    let tmp = tempfile::tempdir().unwrap();
    let dir = tmp.path().to_path_buf();
    run_script("mcap_make_ros2_fixtures.py", &[&dir]);
    let expected =
        serde_json::from_slice(&std::fs::read(dir.join("expected.json")).unwrap()).unwrap();
    Some(Fixtures {
        _tmp: tmp,
        dir,
        expected,
    })
}

fn clouds_of<'a>(e: &'a Value, file: &str) -> Vec<&'a Value> {
    e["clouds"]
        .as_array()
        .unwrap()
        .iter()
        .filter(|c| c["file"] == file)
        .collect()
}

#[test]
fn ros2_fixtures_decode_to_the_written_values() {
    let Some(fx) = fixtures() else { return };
    let mut total = 0usize;
    for file in ["drive_le.mcap", "organised_be.mcap", "organised_lz4.mcap"] {
        let ours = decode_clouds(&fx.dir.join(file));
        let want = clouds_of(&fx.expected, file);
        assert_eq!(ours.len(), want.len(), "{file}: cloud count");
        // Messages of several topics interleave; compare per topic in order.
        for topic in [
            "/points",
            "/cloud_be",
            "/cloud_le_msg_be_blob",
            "/cloud_lz4",
        ] {
            let a: Vec<_> = ours.iter().filter(|c| c.topic == topic).collect();
            let b: Vec<_> = want.iter().filter(|c| c["topic"] == topic).collect();
            assert_eq!(a.len(), b.len(), "{file} {topic}");
            for (c, w) in a.iter().zip(b) {
                assert_eq!(c.stamp_ns, w["stamp_ns"].as_i64().unwrap() as i128);
                assert_eq!(c.frame_id, w["frame_id"].as_str().unwrap());
                assert_eq!(c.height as u64, w["height"].as_u64().unwrap());
                assert_eq!(c.width as u64, w["width"].as_u64().unwrap());
                assert_eq!(c.point_step as u64, w["point_step"].as_u64().unwrap());
                assert_eq!(c.row_step as u64, w["row_step"].as_u64().unwrap());
                assert_eq!(c.is_bigendian, w["is_bigendian"].as_bool().unwrap());
                assert_eq!(c.is_dense, w["is_dense"].as_bool().unwrap());
                let cols: Vec<&str> = w["columns"]
                    .as_array()
                    .unwrap()
                    .iter()
                    .map(|v| v.as_str().unwrap())
                    .collect();
                let rows = npy_rows(&fx.dir.join(w["raw"].as_str().unwrap()));
                assert_eq!(rows.len(), c.values.len());
                for (k, name) in cols.iter().enumerate() {
                    // The packed rgb float is compared through its bits (the script stored the
                    // u32 it packed).
                    let ci = c.columns.iter().position(|n| n == name).unwrap();
                    for (i, (r, v)) in rows.iter().zip(&c.values).enumerate() {
                        let got = if *name == "rgb" {
                            (v[ci] as f32).to_bits() as f64
                        } else {
                            v[ci]
                        };
                        assert!(
                            same(r[k], got),
                            "{file} {topic} point {i} {name}: written {}, decoded {got}",
                            r[k]
                        );
                        total += 1;
                    }
                }
            }
        }
    }
    eprintln!("ros2 fixtures: {total} values equal to what the independent writers wrote");
    assert_eq!(total, 17 * 240 * 7 + 6 * 15 * 9);
}

#[test]
fn ros2_fixtures_equal_the_rosbags_decoder_too() {
    let Some(fx) = fixtures() else { return };
    for file in ["drive_le.mcap", "organised_be.mcap"] {
        let path = fx.dir.join(file);
        let out = fx.dir.join(format!("dump_{file}"));
        run_script("mcap_dump_clouds.py", &[&path, &out]);
        let meta: Value =
            serde_json::from_slice(&std::fs::read(out.join("clouds.json")).unwrap()).unwrap();
        let ours = decode_clouds(&path);
        let m = meta.as_array().unwrap();
        assert_eq!(m.len(), ours.len());
        for (m, c) in m.iter().zip(&ours) {
            let rows = npy_rows(&out.join(m["npy"].as_str().unwrap()));
            for (a, b) in rows.iter().zip(&c.values) {
                assert!(a.iter().zip(b).all(|(x, y)| same(*x, *y)), "{file}");
            }
        }
    }
}

/// Converts `file` with `sets` and returns the points and attribute table.
fn convert(
    fx: &Fixtures,
    file: &str,
    sets: &[&str],
) -> (
    Vec<LasPoint>,
    Vec<tessera::io::extra::ExtraField>,
    tessera::io::mcap::McapReport,
) {
    let work = tempfile::tempdir_in(&fx.dir).unwrap();
    let p = params(sets);
    let conv = convert_file(&fx.dir.join(file), work.path(), &p).unwrap();
    let (pts, fields) = read_parts(&conv.parts);
    (pts, fields, conv.report)
}

fn world_rows(fx: &Fixtures, key: &str) -> (Vec<[f64; 3]>, Vec<i64>) {
    let mut xyz = Vec::new();
    let mut t = Vec::new();
    for c in clouds_of(&fx.expected, "drive_le.mcap") {
        for r in npy_rows(&fx.dir.join(c[key].as_str().unwrap())) {
            xyz.push([r[0], r[1], r[2]]);
        }
        t.extend(npy_i64(&fx.dir.join(c["time_ns"].as_str().unwrap())));
    }
    (xyz, t)
}

fn max_err(pts: &[LasPoint], want: &[[f64; 3]]) -> f64 {
    assert_eq!(pts.len(), want.len(), "point count");
    pts.iter()
        .zip(want)
        .map(|(p, w)| {
            let d = [p.xyz[0] - w[0], p.xyz[1] - w[1], p.xyz[2] - w[2]];
            (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
        })
        .fold(0.0, f64::max)
}

#[test]
fn drive_georeferenced_with_tf_odometry_or_trajectory_matches_numpy() {
    let Some(fx) = fixtures() else { return };
    let (deskew, times) = world_rows(&fx, "world_deskew");
    let (stamp, _) = world_rows(&fx, "world_stamp");
    let base = ["mcap.min_range_m=0.0", "mcap.scale_m=0.000001"];
    let traj = fx.dir.join("trajectory.csv");
    let traj_set = format!("mcap.trajectory_file=\"{}\"", traj.display());
    type Case<'a> = (&'a str, Vec<String>, &'a Vec<[f64; 3]>);
    let cases: Vec<Case> = vec![
        ("tf, de-skewed", vec![], &deskew),
        (
            "tf, pose at the cloud stamp",
            vec!["mcap.deskew=false".into()],
            &stamp,
        ),
        (
            "odometry, de-skewed",
            vec![
                "mcap.pose_source=\"odometry\"".into(),
                "mcap.odometry_topic=\"/odom\"".into(),
            ],
            &deskew,
        ),
        (
            "trajectory file, de-skewed",
            vec!["mcap.pose_source=\"trajectory\"".into(), traj_set.clone()],
            &deskew,
        ),
    ];
    for (name, extra, want) in cases {
        let mut sets: Vec<&str> = base.to_vec();
        sets.extend(extra.iter().map(|s| s.as_str()));
        let (pts, fields, rep) = convert(&fx, "drive_le.mcap", &sets);
        let e = max_err(&pts, want);
        eprintln!("{name}: max error {e:.2e} m over {} points", pts.len());
        assert!(e < 2e-6, "{name}: max georeferencing error {e} m");
        assert_eq!(rep.points_in_clouds, 17 * 240);
        assert_eq!(rep.points_nan + rep.points_written, 17 * 240);
        assert!(
            rep.points_nan > 100,
            "NaN points counted: {}",
            rep.points_nan
        );
        assert_eq!(
            rep.clouds_deskewed,
            if name.contains("stamp") { 0 } else { 17 }
        );
        // Per-point time → GPS time; ring kept as an extra attribute; RGB unpacked.
        for (p, t) in pts.iter().zip(&times) {
            assert!((p.gps_time - gps_of(*t as i128)).abs() < 1e-6);
        }
        assert_eq!(fields.len(), 1);
        assert_eq!(fields[0].name, "ring");
    }
    // De-skewing matters here: the vehicle moves up to 0.3 m during a sweep.
    let spread = deskew
        .iter()
        .zip(&stamp)
        .map(|(a, b)| ((a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2)).sqrt())
        .fold(0.0, f64::max);
    assert!(spread > 0.1, "{spread}");
    // Attributes against the written values.
    let (pts, fields, _) = convert(&fx, "drive_le.mcap", &base);
    let mut k = 0;
    for c in clouds_of(&fx.expected, "drive_le.mcap") {
        for r in npy_rows(&fx.dir.join(c["raw"].as_str().unwrap())) {
            if r[0].is_nan() {
                continue;
            }
            let p = &pts[k];
            k += 1;
            assert_eq!(p.intensity as f64, r[3].round());
            assert_eq!(extra_value(p, &fields, "ring"), r[4]);
            let bits = r[6] as u32;
            let c8 = |s: u32| ((bits >> s) & 255) as u16 * 257;
            assert_eq!(p.rgb, Some([c8(16), c8(8), c8(0)]));
        }
    }
    assert_eq!(k, pts.len());
}

#[test]
fn organised_big_endian_cloud_keeps_every_field() {
    let Some(fx) = fixtures() else { return };
    for file in ["organised_be.mcap", "organised_lz4.mcap"] {
        let (pts, fields, rep) = convert(
            &fx,
            file,
            &["mcap.min_range_m=0.0", "mcap.scale_m=0.000001"],
        );
        let names: Vec<&str> = fields.iter().map(|f| f.name.as_str()).collect();
        assert_eq!(names, ["ring", "flag", "label", "code"], "{file}");
        assert_eq!(rep.time_field.as_deref(), Some("t"));
        let mut k = 0;
        for c in clouds_of(&fx.expected, file) {
            let stamp = c["stamp_ns"].as_i64().unwrap() as i128;
            for r in npy_rows(&fx.dir.join(c["raw"].as_str().unwrap())) {
                if r[0].is_nan() {
                    continue;
                }
                let p = &pts[k];
                k += 1;
                for (a, (got, want)) in p.xyz.iter().zip(&r).enumerate() {
                    assert!((got - want).abs() <= 5e-7 + 1e-9, "{file} axis {a}");
                }
                assert_eq!(p.intensity as f64, r[3]);
                for (name, col) in [("ring", 4), ("flag", 5), ("label", 7), ("code", 8)] {
                    assert_eq!(extra_value(p, &fields, name), r[col], "{file} {name}");
                }
                assert!((p.gps_time - gps_of(stamp + r[6] as i128)).abs() < 1e-6);
            }
        }
        assert_eq!(k, pts.len());
        assert_eq!(rep.points_nan, rep.clouds, "{file}");
        // Topics become point source ids in order of appearance.
        let ids: std::collections::BTreeSet<u16> = pts.iter().map(|p| p.point_source_id).collect();
        assert_eq!(ids.len(), rep.topics.len());
    }
}
