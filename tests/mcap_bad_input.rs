//! Gate: bad MCAP input never panics. A truncated file, an unknown message encoding or a
//! missing transform at a cloud's stamp is a clear error naming the file, topic and time (exit
//! 1), or — with `mcap.on_error = "skip"` — is skipped and counted in `summary.json`; when
//! nothing usable remains the run still fails. No temporary parts are left behind.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output};
use tessera::io::mcap::encode::{pointcloud2, tf_message, POINTCLOUD2_SCHEMA, TFMESSAGE_SCHEMA};
use tessera::io::mcap::pointcloud2::{datatype, PointField};
use tessera::io::mcap::tf::{iso_from, TransformStamped};
use tessera::io::mcap::wire::Stamp;

const T0: i128 = 1_700_000_000_000_000_000;

fn tessera(args: &[&str], inputs: &[&Path], out: &Path) -> Output {
    let mut c = Command::new(env!("CARGO_BIN_EXE_tessera"));
    c.args(["-q", "run"]);
    for i in inputs {
        c.arg(i);
    }
    c.arg("--out").arg(out).args(args);
    c.output().unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap()
}

fn no_leftovers(out: &Path) {
    assert!(
        !out.join(".tessera-mcap").exists(),
        "temporary LAS parts left in {}",
        out.display()
    );
}

/// A small cloud of `n` points on a 10 m circle, in frame `lidar`.
fn cloud(ns: i128, n: usize) -> Vec<u8> {
    let f = |name: &str, offset: u32| PointField {
        name: name.into(),
        offset,
        datatype: datatype::FLOAT32,
        count: 1,
    };
    let mut data = Vec::new();
    for i in 0..n {
        let a = i as f32 * 0.1;
        for v in [10.0 * a.cos(), 10.0 * a.sin(), -1.5f32] {
            data.extend(v.to_le_bytes());
        }
    }
    pointcloud2(
        Stamp::from_nanos(T0 + ns),
        "lidar",
        1,
        n as u32,
        &[f("x", 0), f("y", 4), f("z", 8)],
        12,
        &data,
        true,
    )
}

fn tf_at(ns: i128, x: f64) -> Vec<u8> {
    tf_message(&[TransformStamped {
        stamp: Stamp::from_nanos(T0 + ns),
        parent: "map".into(),
        child: "lidar".into(),
        iso: iso_from([x, 0.0, 2.0], [0.0, 0.0, 0.0, 1.0]).unwrap(),
    }])
}

/// Writes an MCAP with /tf samples at `tf_ns` and clouds at `cloud_ns` (plus, optionally, a
/// PointCloud2 channel with the message encoding `odd` carrying one message).
fn write(path: &Path, tf_ns: &[i128], cloud_ns: &[i128], odd: Option<&str>) {
    let f = std::fs::File::create(path).unwrap();
    let mut w = mcap::WriteOptions::new()
        .compression(Some(mcap::Compression::Zstd))
        .profile("ros2")
        .chunk_size(Some(4096))
        .create(std::io::BufWriter::new(f))
        .unwrap();
    let none = BTreeMap::new();
    let s_pc = w
        .add_schema(
            "sensor_msgs/msg/PointCloud2",
            "ros2msg",
            POINTCLOUD2_SCHEMA.as_bytes(),
        )
        .unwrap();
    let s_tf = w
        .add_schema(
            "tf2_msgs/msg/TFMessage",
            "ros2msg",
            TFMESSAGE_SCHEMA.as_bytes(),
        )
        .unwrap();
    let c_pc = w.add_channel(s_pc, "/points", "cdr", &none).unwrap();
    let c_tf = w.add_channel(s_tf, "/tf", "cdr", &none).unwrap();
    let mut msgs: Vec<(i128, u16, Vec<u8>)> = Vec::new();
    for &t in tf_ns {
        msgs.push((t, c_tf, tf_at(t, t as f64 * 1e-9)));
    }
    for &t in cloud_ns {
        msgs.push((t, c_pc, cloud(t, 200)));
    }
    if let Some(enc) = odd {
        let s = w
            .add_schema("sensor_msgs/msg/PointCloud2", "jsonschema", b"{}")
            .unwrap();
        let c = w.add_channel(s, "/points_json", enc, &none).unwrap();
        msgs.push((300_000_000, c, b"{\"height\": 1}".to_vec()));
    }
    msgs.sort_by_key(|m| m.0);
    for (i, (t, ch, data)) in msgs.iter().enumerate() {
        let log = (T0 + t) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: *ch,
                sequence: i as u32,
                log_time: log,
                publish_time: log,
            },
            data,
        )
        .unwrap();
    }
    w.finish().unwrap();
}

fn every(step_ms: i128, to_ms: i128) -> Vec<i128> {
    (0..=to_ms / step_ms)
        .map(|k| k * step_ms * 1_000_000)
        .collect()
}

#[test]
fn truncated_recording() {
    let tmp = tempfile::tempdir().unwrap();
    let full = tmp.path().join("full.mcap");
    write(&full, &every(50, 3000), &every(100, 2900), None);
    let bytes = std::fs::read(&full).unwrap();
    let cut = tmp.path().join("cut.mcap");
    std::fs::write(&cut, &bytes[..bytes.len() * 6 / 10]).unwrap();
    let out = tmp.path().join("out");
    let o = tessera(&[], &[&cut], &out);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("cut.mcap") && e.contains("truncated"), "{e}");
    assert!(
        e.contains("/points") || e.contains("/tf"),
        "names a topic: {e}"
    );
    assert!(e.contains("log time 17000000"), "names a time: {e}");
    assert!(!e.contains("panicked"), "{e}");
    no_leftovers(&out);
    // Skipping keeps what was read before the cut and says so.
    let out2 = tmp.path().join("out2");
    let o = tessera(&["--set", "mcap.on_error=\"skip\""], &[&cut], &out2);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out2);
    let m = &s["mcap"][0];
    assert!(!m["damage"].as_array().unwrap().is_empty(), "{m}");
    let used = m["clouds_used"].as_u64().unwrap();
    assert!(used > 5 && used < 30, "{m}");
    assert_eq!(s["points_in"].as_u64(), Some(used * 200));
    no_leftovers(&out2);
    // Cut before any message: nothing usable, even when skipping.
    let tiny = tmp.path().join("tiny.mcap");
    std::fs::write(&tiny, &bytes[..300]).unwrap();
    let o = tessera(
        &["--set", "mcap.on_error=\"skip\""],
        &[&tiny],
        &tmp.path().join("o3"),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("tiny.mcap") && e.contains("nothing usable"),
        "{e}"
    );
    // `info` describes a truncated file instead of failing.
    let o = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .arg("info")
        .arg(&cut)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&o.stdout);
    assert!(o.status.success(), "{}", stderr(&o));
    assert!(text.contains("damage: truncated"), "{text}");
}

#[test]
fn unknown_message_encoding() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("json.mcap");
    write(&f, &every(50, 1000), &every(100, 800), Some("json"));
    let out = tmp.path().join("out");
    let o = tessera(&[], &[&f], &out);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("json.mcap") && e.contains("/points_json") && e.contains("\"json\""),
        "{e}"
    );
    assert!(e.contains("log time 1700000000.300000000"), "{e}");
    no_leftovers(&out);
    let out2 = tmp.path().join("out2");
    let o = tessera(&["--set", "mcap.on_error=\"skip\""], &[&f], &out2);
    assert!(o.status.success(), "{}", stderr(&o));
    let m = &summary(&out2)["mcap"][0];
    assert_eq!(
        m["clouds_skipped"]["unsupported encoding"].as_u64(),
        Some(1)
    );
    assert_eq!(m["clouds_used"].as_u64(), Some(9));
    // Only the unknown encoding selected: nothing usable.
    let o = tessera(
        &[
            "--set",
            "mcap.on_error=\"skip\"",
            "--set",
            "mcap.cloud_topics=[\"/points_json\"]",
        ],
        &[&f],
        &tmp.path().join("out3"),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("nothing usable"), "{e}");
    // A topic that is not in the file is a configuration error (exit 2) listing the topics.
    let o = tessera(
        &["--set", "mcap.cloud_topics=[\"/velodyne_points\"]"],
        &[&f],
        &tmp.path().join("out4"),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(2), "{e}");
    assert!(
        e.contains("/velodyne_points") && e.contains("/points (sensor_msgs/msg/PointCloud2)"),
        "{e}"
    );
}

#[test]
fn missing_transform_at_a_stamp() {
    let tmp = tempfile::tempdir().unwrap();
    let f = tmp.path().join("gap.mcap");
    // Poses for 0..1 s, clouds at 0.1..0.9 s and one at 2.5 s.
    let mut clouds = every(100, 900);
    clouds.retain(|&t| t > 0);
    clouds.push(2_500_000_000);
    write(&f, &every(50, 1000), &clouds, None);
    let out = tmp.path().join("out");
    let o = tessera(&[], &[&f], &out);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("gap.mcap")
            && e.contains("/points")
            && e.contains("1700000002.500000000")
            && e.contains("map → lidar"),
        "{e}"
    );
    no_leftovers(&out);
    let out2 = tmp.path().join("out2");
    let o = tessera(&["--set", "mcap.on_error=\"skip\""], &[&f], &out2);
    assert!(o.status.success(), "{}", stderr(&o));
    let s = summary(&out2);
    let m = &s["mcap"][0];
    assert_eq!(m["clouds_skipped"]["missing pose"].as_u64(), Some(1), "{m}");
    assert_eq!(m["clouds_used"].as_u64(), Some(9));
    assert_eq!(s["points_out"].as_u64(), Some(9 * 200));
    assert!(
        m["notes"][0].as_str().unwrap().contains("1700000002.5"),
        "{m}"
    );
    // Allowing 1.5 s of extrapolation places the last cloud too.
    let out3 = tmp.path().join("out3");
    let o = tessera(&["--set", "mcap.pose_extrapolation_s=1.5"], &[&f], &out3);
    assert!(o.status.success(), "{}", stderr(&o));
    assert_eq!(summary(&out3)["points_out"].as_u64(), Some(10 * 200));
    // Poses only after every cloud: nothing usable, even when skipping.
    let late = tmp.path().join("late.mcap");
    let tf: Vec<i128> = every(50, 1000).iter().map(|t| t + 5_000_000_000).collect();
    write(&late, &tf, &every(100, 500), None);
    let o = tessera(
        &["--set", "mcap.on_error=\"skip\""],
        &[&late],
        &tmp.path().join("o4"),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("nothing usable") && e.contains("missing pose"),
        "{e}"
    );
}

#[test]
fn not_an_mcap_and_unknown_frames() {
    let tmp = tempfile::tempdir().unwrap();
    let f: PathBuf = tmp.path().join("junk.mcap");
    std::fs::write(&f, b"\x89MCAP0\r\nthis is not a record stream at all").unwrap();
    let o = tessera(&[], &[&f], &tmp.path().join("o1"));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(e.contains("junk.mcap") && !e.contains("panicked"), "{e}");
    let g = tmp.path().join("text.mcap");
    std::fs::write(&g, b"hello").unwrap();
    let o = tessera(&[], &[&g], &tmp.path().join("o2"));
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("text.mcap") && e.contains("not an MCAP file"),
        "{e}"
    );
    // A target frame the recording does not have.
    let h = tmp.path().join("ok.mcap");
    write(&h, &every(50, 1000), &every(100, 900), None);
    let o = tessera(
        &["--set", "mcap.target_frame=\"utm\""],
        &[&h],
        &tmp.path().join("o3"),
    );
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("\"utm\"") && e.contains("frames: lidar, map"),
        "{e}"
    );
}

/// Fuzzing regressions (issue 23): a length prefix inside a record (the header's profile
/// string, a chunk's compression string, the summary's records) made the `mcap` crate
/// allocate up to 4 GiB and the process abort. Each is a clear error or counted damage now.
#[test]
fn length_prefixes_past_their_record_are_errors_not_aborts() {
    let tmp = tempfile::tempdir().unwrap();
    let full = tmp.path().join("full.mcap");
    write(&full, &every(50, 1000), &every(100, 900), None);
    let bytes = std::fs::read(&full).unwrap();
    // The first record after the magic is the header: opcode, length, profile string.
    let mut bad = bytes.clone();
    bad[8 + 9..8 + 13].copy_from_slice(&0xfffe_fffcu32.to_le_bytes());
    let p = tmp.path().join("header.mcap");
    std::fs::write(&p, &bad).unwrap();
    let out = tmp.path().join("out1");
    let o = tessera(&[], &[&p], &out);
    let e = stderr(&o);
    assert_eq!(o.status.code(), Some(1), "{e}");
    assert!(
        e.contains("header.mcap") && e.contains("header record"),
        "{e}"
    );
    assert!(!e.contains("memory allocation"), "{e}");
    // Every string length of every top-level record set past its record: never an abort.
    let mut at = 8usize;
    let mut k = 0;
    while at + 9 <= bytes.len() - 8 {
        let op = bytes[at];
        let len = u64::from_le_bytes(bytes[at + 1..at + 9].try_into().unwrap()) as usize;
        // Records whose body starts with a string (header, metadata) or has one after a
        // fixed part (schema 2, channel 4, chunk 28, chunk index: see the guard).
        let field = match op {
            0x01 | 0x0C => Some(0),
            0x03 => Some(2),
            0x04 => Some(4),
            0x06 => Some(28),
            _ => None,
        };
        if let Some(f) = field.filter(|&f| f + 4 <= len) {
            let mut bad = bytes.clone();
            bad[at + 9 + f..at + 13 + f].copy_from_slice(&0xffff_ff00u32.to_le_bytes());
            let p = tmp.path().join(format!("rec{k}.mcap"));
            std::fs::write(&p, &bad).unwrap();
            let out = tmp.path().join(format!("out_rec{k}"));
            let o = tessera(&["--set", "mcap.on_error=\"skip\""], &[&p], &out);
            let e = stderr(&o);
            assert!(
                o.status.code() == Some(0) || (o.status.code() == Some(1) && e.contains("error")),
                "record 0x{op:02x} at {at}: {:?} {e}",
                o.status
            );
            assert!(
                !e.contains("memory allocation") && !e.contains("panicked"),
                "{e}"
            );
            no_leftovers(&out);
            k += 1;
        }
        at += 9 + len;
    }
    assert!(k >= 3, "{k} records mutated");
}
