//! Round trip: pass-through processing keeps the exact multiset of points with every
//! attribute, for point formats 0, 1, 3, 6, 7, 8 — checked byte for byte here and, where
//! laspy is installed, by an independent reader (scripts/check_roundtrip.py).

mod common;

use common::*;
use std::path::{Path, PathBuf};
use tessera::Config;

fn run(inputs: &[PathBuf], out: &Path, sets: &[&str]) -> tessera::report::Summary {
    // Pass-through: only the statistics stage, which must not change any point.
    let mut sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    sets.push("stages.run=[\"stats\"]".into());
    let cfg = Config::load(None, &sets).unwrap();
    tessera::pipeline::run(inputs, out, &cfg, &|_, _| {}).unwrap()
}

fn check(input: &Path, expect_format: u8, sets: &[&str]) {
    let tmp = tempfile::tempdir().unwrap();
    let s = run(&[input.to_path_buf()], tmp.path(), sets);
    let (fin, mut a) = raw_records(input);
    assert_eq!(fin.to_u8().unwrap(), expect_format, "{}", input.display());
    let tiles = tiles_in(tmp.path());
    assert!(
        tiles.len() >= 2,
        "{}: expected several tiles, got {}",
        input.display(),
        tiles.len()
    );
    let mut b = Vec::new();
    for t in &tiles {
        let r = las::Reader::from_path(t).unwrap();
        assert_eq!(r.header().version(), las::Version::new(1, 4));
        assert_eq!(
            r.header().transforms(),
            las::Reader::from_path(input).unwrap().header().transforms()
        );
        let (fout, recs) = raw_records(t);
        assert_eq!(fout, fin, "{}: format changed", t.display());
        b.extend(recs);
    }
    assert_eq!(s.points_in, a.len() as u64);
    assert_eq!(s.points_out, a.len() as u64);
    assert_eq!(b.len(), a.len(), "{}: point count", input.display());
    a.sort();
    b.sort();
    assert!(
        a == b,
        "{}: records differ after round trip",
        input.display()
    );
    if have_laspy() {
        let out = std::process::Command::new("python3")
            .arg(concat!(
                env!("CARGO_MANIFEST_DIR"),
                "/scripts/check_roundtrip.py"
            ))
            .arg(tmp.path())
            .arg(input)
            .output()
            .unwrap();
        let msg = String::from_utf8_lossy(&out.stdout);
        assert!(
            out.status.success(),
            "laspy check failed for {}: {msg}",
            input.display()
        );
        eprintln!("laspy: {} {msg}", input.display());
    } else {
        eprintln!("SKIP laspy cross-check: python3 -c 'import laspy, lazrs' failed");
    }
}

#[test]
fn format_0_isprs() {
    if let Some(p) = data_file("isprs-filtertest/samp11-utm.laz") {
        check(&p, 0, &["tiling.tile_size_m=60", "tiling.buffer_m=4"]);
    }
}

#[test]
fn format_1_ahn() {
    if let Some(p) = data_file("ahn-amsterdam/ahn_2386_9702.laz") {
        check(&p, 1, &["tiling.tile_size_m=20", "tiling.buffer_m=2"]);
    }
}

#[test]
fn format_3_with_extra_bytes_cyclomedia() {
    if let Some(p) = data_file("cyclomedia-amsterdam-sidewalk/sidewalk_run1_2386_9702.laz") {
        check(
            &p,
            3,
            &[
                "tiling.tile_size_m=25",
                "tiling.buffer_m=2",
                "output.format=las",
            ],
        );
    }
}

#[test]
fn format_3_autzen() {
    if let Some(p) = data_file("pdal-autzen-samples/autzen_trim.laz") {
        check(&p, 3, &["tiling.tile_size_m=300", "tiling.buffer_m=10"]);
    }
}

#[test]
fn format_8_ign() {
    if let Some(p) = data_file("ign-lidarhd/870000_6618000.subset.50mx100m.las") {
        check(&p, 8, &["tiling.tile_size_m=25", "tiling.buffer_m=3"]);
    }
}

#[test]
fn formats_6_and_7_from_laspy() {
    if !have_laspy() {
        eprintln!("SKIP: laspy not installed; formats 6/7 fixtures are written by laspy");
        return;
    }
    let dir = tempfile::tempdir().unwrap();
    let st = std::process::Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scripts/make_fixtures.py"
        ))
        .arg(dir.path())
        .arg("20000")
        .status()
        .unwrap();
    assert!(st.success());
    for (f, n) in [
        ("pf6.laz", 6),
        ("pf7.laz", 7),
        ("pf6.las", 6),
        ("pf7.las", 7),
    ] {
        check(
            &dir.path().join(f),
            n,
            &["tiling.tile_size_m=30", "tiling.buffer_m=3"],
        );
    }
}

#[test]
fn many_files_in_any_order_are_merged_exactly() {
    // The two CycloMedia epochs cover the same tile: points of both files meet in the same
    // output tiles; reading order must not matter.
    let (Some(a), Some(b)) = (
        data_file("cyclomedia-amsterdam-sidewalk/sidewalk_run1_2386_9702.laz"),
        data_file("cyclomedia-amsterdam-sidewalk/sidewalk_run2_2386_9702.laz"),
    ) else {
        return;
    };
    let t1 = tempfile::tempdir().unwrap();
    let t2 = tempfile::tempdir().unwrap();
    let s1 = run(
        &[a.clone(), b.clone()],
        t1.path(),
        &["tiling.tile_size_m=20", "tiling.buffer_m=2"],
    );
    let s2 = run(
        &[b.clone(), a.clone()],
        t2.path(),
        &["tiling.tile_size_m=20", "tiling.buffer_m=2"],
    );
    assert_eq!(s1.points_out, s2.points_out);
    let mut want: Vec<Vec<u8>> = raw_records(&a).1;
    want.extend(raw_records(&b).1);
    want.sort();
    for t in [&t1, &t2] {
        let mut got: Vec<Vec<u8>> = tiles_in(t.path())
            .iter()
            .flat_map(|p| raw_records(p).1)
            .collect();
        got.sort();
        assert!(got == want);
    }
    // Identical tile contents regardless of the order the inputs were given in.
    for (x, y) in tiles_in(t1.path()).iter().zip(tiles_in(t2.path()).iter()) {
        assert_eq!(raw_records(x).1, raw_records(y).1);
    }
}
