//! Bad input never crashes and never leaves partial output: a clear error naming the file and
//! the problem, exit code 1, no tile (and no temporary file) in the output directory.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

/// A small valid LAS/LAZ written by the las crate.
fn write_valid(path: &Path, n: usize) {
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    b.point_format.is_compressed = path.extension().is_some_and(|e| e == "laz");
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    for i in 0..n {
        let v = i as f64 * 0.37;
        w.write_point(las::Point {
            x: v % 97.0,
            y: (v * 7.0) % 89.0,
            z: v % 5.0,
            gps_time: Some(v),
            intensity: (i % 1000) as u16,
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
}

/// Runs tessera on a good file plus `bad`; expects failure naming `bad` and `needle`.
fn expect_failure(bad: &Path, needle: &str) {
    let dir = bad.parent().unwrap();
    let good = dir.join("good.las");
    write_valid(&good, 5000);
    let out = dir.join("out");
    let o = tessera()
        .args(["-q", "run"])
        .arg(&good)
        .arg(bad)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(
        o.status.code(),
        Some(1),
        "exit code for {}: stderr {err}",
        bad.display()
    );
    let name = bad.file_name().unwrap().to_string_lossy();
    assert!(err.contains(name.as_ref()), "error must name {name}: {err}");
    assert!(
        err.to_lowercase().contains(needle),
        "error must say '{needle}': {err}"
    );
    let left: Vec<PathBuf> = std::fs::read_dir(&out)
        .map(|rd| rd.filter_map(|e| e.ok().map(|e| e.path())).collect())
        .unwrap_or_default();
    assert!(
        left.iter()
            .all(|p| p.is_dir() && !p.ends_with(".tessera-spill")),
        "output left behind for {}: {left:?}",
        bad.display()
    );
    assert!(
        !out.join(".tessera-spill").exists(),
        "spill directory left behind"
    );
}

#[test]
fn truncated_laz() {
    let d = tempfile::tempdir().unwrap();
    let full = d.path().join("full.laz");
    write_valid(&full, 200_000);
    let bytes = std::fs::read(&full).unwrap();
    let bad = d.path().join("truncated.laz");
    std::fs::write(&bad, &bytes[..bytes.len() / 2]).unwrap();
    expect_failure(&bad, "truncated");
}

#[test]
fn wrong_signature() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("notlas.las");
    std::fs::write(
        &bad,
        b"PK\x03\x04 this is a zip file, not a point cloud, padded to be long enough ....",
    )
    .unwrap();
    expect_failure(&bad, "signature");
}

#[test]
fn header_count_larger_than_data() {
    let d = tempfile::tempdir().unwrap();
    for ext in ["las", "laz"] {
        let bad = d.path().join(format!("overcount.{ext}"));
        write_valid(&bad, 3000);
        let mut b = std::fs::read(&bad).unwrap();
        // Legacy point count (LAS 1.2 header offset 107) += 1000.
        let n = u32::from_le_bytes(b[107..111].try_into().unwrap()) + 1000;
        b[107..111].copy_from_slice(&n.to_le_bytes());
        std::fs::write(&bad, &b).unwrap();
        expect_failure(&bad, "announces");
    }
}

#[test]
fn git_lfs_pointer() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("pointer.laz");
    std::fs::write(
        &bad,
        "version https://git-lfs.github.com/spec/v1\noid sha256:4d7a214614ab2935c943f9e0ff69d22eadbb8f32b1258daaa5e2ca24d17e2393\nsize 12345\n",
    )
    .unwrap();
    expect_failure(&bad, "git lfs");
}

#[test]
fn empty_file() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("empty.las");
    std::fs::write(&bad, b"").unwrap();
    expect_failure(&bad, "empty");
}

#[test]
fn nan_scale() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("nan.las");
    write_valid(&bad, 1000);
    let mut b = std::fs::read(&bad).unwrap();
    // x scale factor at header offset 131.
    b[131..139].copy_from_slice(&f64::NAN.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    expect_failure(&bad, "scale");
}

#[test]
fn points_outside_header_bounds() {
    let d = tempfile::tempdir().unwrap();
    let bad = d.path().join("outside.las");
    write_valid(&bad, 1000);
    let mut b = std::fs::read(&bad).unwrap();
    // Max X at header offset 179: shrink it so most points lie outside the announced bounds.
    b[179..187].copy_from_slice(&10.0f64.to_le_bytes());
    std::fs::write(&bad, &b).unwrap();
    expect_failure(&bad, "outside the header bounds");
}

#[test]
fn infeasible_budget_is_an_error_not_an_oom() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("dense.las");
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(0).unwrap();
    let mut w = las::Writer::from_path(&p, b.into_header().unwrap()).unwrap();
    for i in 0..300_000 {
        // Every point at the same xy (a wall of 300 k points): no split can help.
        w.write_point(las::Point {
            x: 5.0,
            y: 5.0,
            z: i as f64 * 0.01,
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let out = d.path().join("out");
    let o = tessera()
        .args(["-q", "run"])
        .arg(&p)
        .args([
            "--memory-budget",
            "64",
            "--set",
            "stages.run=[\"stats\"]",
            "--out",
        ])
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("memory budget infeasible"), "{err}");
    assert!(common::tiles_in(&out).is_empty());
}

#[test]
fn usage_errors_exit_2() {
    let o = tessera()
        .args(["run", "x.las", "--out", "/tmp/x", "--set", "tiling.nope=3"])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2));
    let o = tessera().args(["frobnicate"]).output().unwrap();
    assert_eq!(o.status.code(), Some(2));
}

/// A wrong value in the section of a stage that is not even running is a configuration error
/// (exit 2) found before any input is looked at: here the input does not exist, and the
/// message is about the setting, not the file.
#[test]
fn config_errors_come_before_any_input_is_read() {
    let d = tempfile::tempdir().unwrap();
    for set in [
        "segment.context_m=-1",
        "stages.run=[\"label\", \"ground\"]",
        "stages.run=[\"nope\"]",
    ] {
        let o = std::process::Command::new(env!("CARGO_BIN_EXE_tessera"))
            .args([
                "-q",
                "run",
                "--set",
                "stages.run=[\"stats\"]",
                "--set",
                set,
                "--out",
            ])
            .arg(d.path().join("out"))
            .arg(d.path().join("missing.las"))
            .output()
            .unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(2), "{set}: {err}");
        assert!(!err.contains("missing.las"), "{set}: {err}");
        assert!(!d.path().join("out").exists(), "{set}: output created");
    }
}

/// An error is printed with its causes once each (the library's messages already name their
/// cause; printing the chain used to repeat it: "x.las: No such file …: No such file …").
#[test]
fn error_causes_are_printed_once() {
    let d = tempfile::tempdir().unwrap();
    let missing = d.path().join("missing.las");
    let o = std::process::Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(["-q", "info"])
        .arg(&missing)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(err.contains("missing.las"), "{err}");
    assert_eq!(err.matches("No such file").count(), 1, "{err}");
}

/// Offset of the LASzip VLR's data in a file written by [`write_valid`].
fn laszip_data(b: &[u8]) -> usize {
    let mut pos = usize::from(u16::from_le_bytes([b[94], b[95]]));
    let n = u32::from_le_bytes(b[100..104].try_into().unwrap());
    for _ in 0..n {
        let len = usize::from(u16::from_le_bytes([b[pos + 20], b[pos + 21]]));
        if &b[pos + 2..pos + 16] == b"laszip encoded" {
            return pos + 54;
        }
        pos += 54 + len;
    }
    panic!("no LASzip VLR");
}

/// Regression inputs of `scripts/mutate_cli.py` (issue 23): sizes taken from the file made
/// `las`/`laz` allocate gigabytes (the process aborted) or panic inside a rayon job (the
/// process aborted). Each is a clear error now, from `info` and from `run`.
#[test]
fn hostile_sizes_and_laszip_records_are_errors_not_aborts() {
    let d = tempfile::tempdir().unwrap();
    let full = d.path().join("full.laz");
    write_valid(&full, 3000);
    let b = std::fs::read(&full).unwrap();
    let vlr = laszip_data(&b);
    let table = {
        let at = u32::from_le_bytes(b[96..100].try_into().unwrap()) as usize;
        i64::from_le_bytes(b[at..at + 8].try_into().unwrap()) as usize
    };
    // (file name, byte offset, bytes written there, what the error must say)
    let cases: [(&str, usize, Vec<u8>, &str); 5] = [
        (
            "chunk_size.laz",
            vlr + 12,
            0x7fff_ffffu32.to_le_bytes().to_vec(),
            "claims 2147483647 points",
        ),
        (
            "many_chunks.laz",
            table + 4,
            0x7fff_ffffu32.to_le_bytes().to_vec(),
            "claims 2147483647 chunks",
        ),
        ("no_items.laz", vlr + 32, vec![0, 0], "no items"),
        ("item_version.laz", vlr + 38, vec![7, 0], "version 7"),
        ("item_size.laz", vlr + 36, vec![200, 0], "bytes per point"),
    ];
    for (name, at, bytes, needle) in cases {
        let bad = d.path().join(name);
        let mut m = b.clone();
        m[at..at + bytes.len()].copy_from_slice(&bytes);
        std::fs::write(&bad, &m).unwrap();
        let o = tessera().arg("info").arg(&bad).output().unwrap();
        let err = String::from_utf8_lossy(&o.stderr);
        assert_eq!(o.status.code(), Some(1), "{name}: {err}");
        assert!(err.contains(name) && err.contains(needle), "{name}: {err}");
        expect_failure(&bad, needle);
    }
    // A VLR count of 2^32 - 1 with one VLR there: the points are intact, so they are read
    // (as PDAL and laspy read such headers), with one warning.
    let many = d.path().join("many_vlrs.laz");
    let mut m = b.clone();
    m[100..104].copy_from_slice(&[0xff; 4]);
    std::fs::write(&many, &m).unwrap();
    let out = d.path().join("many.out");
    let o = tessera()
        .args(["run", "--set", "stages.run=[\"stats\"]"])
        .arg(&many)
        .arg("--out")
        .arg(&out)
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert_eq!(
        err.matches("more VLRs than the 1 before").count(),
        1,
        "{err}"
    );
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap();
    assert_eq!(s["points_out"], 3000);
}

/// Fuzzing regression (issue 23, `las_file` target): in a layered chunk (formats 6–10) a
/// layer's byte size bit-flipped to 2^31 made laz 0.13 allocate it before reading (the
/// process aborted at a memory cap). The chunk's layer sizes are checked against the chunk
/// table now, and a valid layered file still reads.
#[test]
fn layered_chunk_layer_sizes_are_bounded_by_the_chunk() {
    let d = tempfile::tempdir().unwrap();
    let full = d.path().join("layered.laz");
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(7).unwrap();
    b.point_format.is_compressed = true;
    let mut w = las::Writer::from_path(&full, b.into_header().unwrap()).unwrap();
    for i in 0..4000u32 {
        let v = f64::from(i) * 0.37;
        w.write_point(las::Point {
            x: v % 97.0,
            y: (v * 7.0) % 89.0,
            z: v % 5.0,
            gps_time: Some(v),
            color: Some(las::Color::new(i as u16, 7, 9)),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let o = tessera().arg("info").arg(&full).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));

    let mut m = std::fs::read(&full).unwrap();
    let points = u32::from_le_bytes(m[96..100].try_into().unwrap()) as usize;
    let record = usize::from(u16::from_le_bytes([m[105], m[106]]));
    // Chunk 0: table offset (8 bytes), raw point, point count, then the layer sizes; the
    // second one is z's.
    let z_layer = points + 8 + record + 4 + 4;
    m[z_layer..z_layer + 4].copy_from_slice(&0x8000_0000u32.to_le_bytes());
    let bad = d.path().join("layer_size.laz");
    std::fs::write(&bad, &m).unwrap();
    let o = tessera().arg("info").arg(&bad).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    assert!(
        err.contains("layer_size.laz") && err.contains("its layers claim"),
        "{err}"
    );
    expect_failure(&bad, "its layers claim");
}

/// Points whose GPS times interleave four far-apart sequences (four scanners of one
/// vehicle), so the LAZ encoder codes "switch sequence" symbols.
fn write_interleaved(path: &Path, format: u8) {
    let mut b = las::Builder::from((1, if format >= 6 { 4 } else { 2 }));
    b.point_format = las::point::Format::new(format).unwrap();
    b.point_format.is_compressed = true;
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    for i in 0..20_000u32 {
        let s = (i.wrapping_mul(2_654_435_761) >> 7) % 4;
        w.write_point(las::Point {
            x: f64::from(i % 97),
            y: f64::from(i % 89),
            z: f64::from(i % 5),
            gps_time: Some(1e8 * f64::from(s + 1) + f64::from(i) * 1e-5),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
}

/// laz 0.13 decoded each "switch GPS-time sequence" symbol by recursing, so a chunk whose
/// bytes decode to switches forever (here: all 0xFF) overflowed the stack and aborted the
/// run (found by fuzzing `las_file`). The patched decoder (vendor/laz) loops with a bound
/// and reports corrupt data; valid switching streams still decode exactly.
#[test]
fn endless_gps_sequence_switches_are_an_error_not_a_stack_overflow() {
    let d = tempfile::tempdir().unwrap();
    for format in [1u8, 6] {
        let good = d.path().join(format!("interleaved{format}.laz"));
        write_interleaved(&good, format);
        let all = las::Reader::from_path(&good).unwrap().read_all().unwrap();
        assert_eq!(all.len(), 20_000);
        for (i, p) in all.points().enumerate() {
            let i = i as u32;
            let s = (i.wrapping_mul(2_654_435_761) >> 7) % 4;
            let want = 1e8 * f64::from(s + 1) + f64::from(i) * 1e-5;
            assert_eq!(p.unwrap().gps_time, Some(want), "format {format} point {i}");
        }

        let mut m = std::fs::read(&good).unwrap();
        let table_at = u32::from_le_bytes(m[96..100].try_into().unwrap()) as usize;
        let record = usize::from(u16::from_le_bytes([m[105], m[106]]));
        let chunks_end = i64::from_le_bytes(m[table_at..table_at + 8].try_into().unwrap());
        // Chunk 0 after its raw first point (formats 6+: also its count and 9 layer sizes).
        let header = if format >= 6 { 4 + 9 * 4 } else { 0 };
        let from = table_at + 8 + record + header;
        m[from..chunks_end as usize].fill(0xFF);
        let bad = d.path().join(format!("switches{format}.laz"));
        std::fs::write(&bad, &m).unwrap();
        expect_failure(&bad, "sequence switches");
    }
}
