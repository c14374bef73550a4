//! The reader's paths agree: the same recording written with an indexed summary and zstd
//! chunks, with lz4 chunks and no summary, and without chunks or summary converts to the same
//! points; the index is used when present (and lets the pose pass skip chunks without poses).

mod common;
mod mcap_common;

use mcap_common::*;
use std::collections::BTreeMap;
use std::path::Path;
use tessera::io::mcap::encode::{pointcloud2, tf_message, POINTCLOUD2_SCHEMA, TFMESSAGE_SCHEMA};
use tessera::io::mcap::pointcloud2::{datatype, PointField};
use tessera::io::mcap::reader::ChannelInfo;
use tessera::io::mcap::tf::{iso_from, TransformStamped};
use tessera::io::mcap::wire::Stamp;
use tessera::io::mcap::{convert_file, McapSource};

const T0: i128 = 1_700_000_000_000_000_000;

fn write(path: &Path, opts: mcap::WriteOptions) {
    let f = std::fs::File::create(path).unwrap();
    let mut w = opts.create(std::io::BufWriter::new(f)).unwrap();
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
    let f32f = |name: &str, offset: u32| PointField {
        name: name.into(),
        offset,
        datatype: datatype::FLOAT32,
        count: 1,
    };
    let fields = [
        f32f("x", 0),
        f32f("y", 4),
        f32f("z", 8),
        f32f("intensity", 12),
    ];
    let mut seq = 0;
    let mut put = |w: &mut mcap::Writer<_>, ch: u16, ns: i128, data: &[u8]| {
        seq += 1;
        let log = (T0 + ns) as u64;
        w.write_to_known_channel(
            &mcap::records::MessageHeader {
                channel_id: ch,
                sequence: seq,
                log_time: log,
                publish_time: log,
            },
            data,
        )
        .unwrap();
    };
    // All poses first (their own chunks), then the clouds.
    for k in 0..=40 {
        let ns = k as i128 * 50_000_000;
        let t = TransformStamped {
            stamp: Stamp::from_nanos(T0 + ns),
            parent: "map".into(),
            child: "lidar".into(),
            iso: iso_from(
                [k as f64 * 0.5, 0.1 * k as f64, 2.0],
                [0.0, 0.0, (0.01 * k as f64).sin(), (0.01 * k as f64).cos()],
            )
            .unwrap(),
        };
        put(&mut w, c_tf, ns, &tf_message(&[t]));
    }
    for k in 1..20 {
        let ns = k as i128 * 100_000_000;
        let mut data = Vec::new();
        for i in 0..500 {
            let a = (i as f32) * 0.0125 + k as f32;
            for v in [8.0 * a.cos(), 8.0 * a.sin(), -1.8, (i * k) as f32] {
                data.extend(v.to_le_bytes());
            }
        }
        let m = pointcloud2(
            Stamp::from_nanos(T0 + ns),
            "lidar",
            1,
            500,
            &fields,
            16,
            &data,
            true,
        );
        put(&mut w, c_pc, ns, &m);
    }
    w.finish().unwrap();
}

#[test]
fn indexed_summary_less_and_unchunked_files_convert_identically() {
    let tmp = tempfile::tempdir().unwrap();
    let variants = [
        (
            "indexed.mcap",
            mcap::WriteOptions::new()
                .compression(Some(mcap::Compression::Zstd))
                .chunk_size(Some(16 * 1024)),
            true,
        ),
        (
            "no_summary_lz4.mcap",
            mcap::WriteOptions::new()
                .compression(Some(mcap::Compression::Lz4))
                .chunk_size(Some(16 * 1024))
                .emit_summary_records(false)
                .emit_chunk_indexes(false)
                .emit_summary_offsets(false),
            false,
        ),
        (
            "unchunked.mcap",
            mcap::WriteOptions::new()
                .use_chunks(false)
                .emit_summary_records(false)
                .emit_summary_offsets(false),
            false,
        ),
    ];
    let mut reference: Option<Vec<[f64; 3]>> = None;
    for (name, opts, indexed) in variants {
        let path = tmp.path().join(name);
        write(&path, opts);
        let work = tmp.path().join(format!("work_{name}"));
        let c = convert_file(&path, &work, &params(&["mcap.scale_m=0.0001"])).unwrap();
        assert_eq!(c.report.indexed, indexed, "{name}");
        assert_eq!(c.report.clouds, 19, "{name}");
        let (pts, _) = read_parts(&c.parts);
        assert_eq!(pts.len(), 19 * 500, "{name}");
        let xyz: Vec<[f64; 3]> = pts.iter().map(|p| p.xyz).collect();
        match &reference {
            None => reference = Some(xyz),
            Some(r) => assert!(r == &xyz, "{name} differs from the indexed file"),
        }
    }
    // With the index, a scan for /tf only never decompresses the cloud chunks.
    let src = McapSource::open(&tmp.path().join("indexed.mcap")).unwrap();
    let mut want = |c: &ChannelInfo| c.topic == "/tf";
    let mut n = 0;
    let mut on = |_m: tessera::io::mcap::reader::MessageRef| -> tessera::Result<()> {
        n += 1;
        Ok(())
    };
    let o = src.scan(&mut want, &mut on, true).unwrap();
    assert_eq!(n, 41);
    assert!(o.chunks_skipped >= 5, "{o:?}");
}

#[test]
fn world_offset_and_crs_note_reach_the_las_parts() {
    let tmp = tempfile::tempdir().unwrap();
    let path = tmp.path().join("drive.mcap");
    write(
        &path,
        mcap::WriteOptions::new().compression(Some(mcap::Compression::Zstd)),
    );
    let conv = |sets: &[&str], name: &str| {
        let c = convert_file(&path, &tmp.path().join(name), &params(sets)).unwrap();
        let r = las::Reader::from_path(&c.parts[0]).unwrap();
        let vlrs: Vec<(String, u16, Vec<u8>)> = r
            .header()
            .vlrs()
            .iter()
            .map(|v| (v.user_id.clone(), v.record_id, v.data.clone()))
            .collect();
        (read_parts(&c.parts).0, vlrs, c.report)
    };
    let (a, _, _) = conv(&["mcap.scale_m=0.0001"], "a");
    let (b, vlrs, rep) = conv(
        &[
            "mcap.scale_m=0.0001",
            "mcap.world_offset=[120000.5, 485000.25, -3.0]",
            "mcap.crs=\"EPSG:28992+5709\"",
        ],
        "b",
    );
    assert_eq!(rep.crs, "EPSG:28992+5709");
    for (p, q) in a.iter().zip(&b) {
        for (k, off) in [120000.5, 485000.25, -3.0].iter().enumerate() {
            assert!(
                (q.xyz[k] - p.xyz[k] - off).abs() < 2e-4,
                "{:?} {:?}",
                p.xyz,
                q.xyz
            );
        }
    }
    assert!(vlrs
        .iter()
        .any(|(u, id, d)| u == "tessera" && *id == 1 && d == b"EPSG:28992+5709"));
    let wkt = "PROJCS[\"Amersfoort / RD New\",GEOGCS[\"Amersfoort\"]]";
    let (_, vlrs, _) = conv(&[&format!("mcap.crs='{wkt}'")], "c");
    let want: Vec<u8> = wkt.bytes().chain([0]).collect();
    assert!(vlrs
        .iter()
        .any(|(u, id, d)| u == "LASF_Projection" && *id == 2112 && *d == want));
}
