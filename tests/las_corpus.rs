//! Real LAS/LAZ files from other readers' test suites (`las-corpus/`, 158 files from PDAL,
//! laspy, las-rs, laz-rs, LASzip, libLAS, lidR, lasR and others): every file laspy reads goes
//! through `tessera info`, a pass-through run and a default run, and is processed with
//! laspy's point count, or refused for a reason listed here as deliberate. No crash, no
//! hang, none over 10 s, and no warning said twice.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::{Command, Output, Stdio};
use std::time::{Duration, Instant};

/// Files refused on purpose: (file, what the message must say, why).
const REFUSED: &[(&str, &str, &str)] = &[
    (
        "PDAL/test__data__autzen__autzen-dd.las",
        "longitude/latitude in degrees",
        "geographic coordinates: distances in degrees mean nothing; the message names the UTM zone",
    ),
    (
        "PDAL/test__data__las__test_epsg_4326_axis.las",
        "longitude/latitude in degrees",
        "geographic coordinates, as above",
    ),
    (
        "PDAL/test__data__las__permutations__1.2-no-points.las",
        "header announces 1065 points but the point data holds 0 points",
        "the header promises 1065 points and the file holds none: reading 0 would lose them silently",
    ),
];

/// Longest a command may take on one of these files.
const LIMIT: Duration = Duration::from_secs(10);

fn corpus() -> Option<(PathBuf, Vec<HashMap<String, String>>)> {
    let dir = common::data_dir()?.join("las-corpus");
    let manifest = dir.join("MANIFEST.tsv");
    let text = match std::fs::read_to_string(&manifest) {
        Ok(t) => t,
        Err(e) if std::env::var("CI").as_deref() == Ok("true") => {
            panic!(
                "{}: {e}; CI=true requires the shared data",
                manifest.display()
            )
        }
        Err(_) => {
            eprintln!("SKIP: {} not found", manifest.display());
            return None;
        }
    };
    let mut lines = text.lines();
    let head: Vec<String> = lines.next()?.split('\t').map(String::from).collect();
    let rows = lines
        .map(|l| {
            head.iter()
                .cloned()
                .zip(l.split('\t').map(String::from))
                .collect()
        })
        .collect();
    Some((dir, rows))
}

/// Runs `tessera ARGS`, killed after [`LIMIT`]; the output and the time taken.
fn tessera(args: &[&std::ffi::OsStr]) -> (Output, Duration) {
    let t = Instant::now();
    let mut child = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .unwrap();
    // Drained on threads, so a chatty run cannot block on a full pipe.
    let mut so = child.stdout.take().unwrap();
    let mut se = child.stderr.take().unwrap();
    let out = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut so, &mut v).ok();
        v
    });
    let err = std::thread::spawn(move || {
        let mut v = Vec::new();
        std::io::Read::read_to_end(&mut se, &mut v).ok();
        v
    });
    let status = loop {
        if let Some(s) = child.try_wait().unwrap() {
            break s;
        }
        if t.elapsed() > LIMIT * 3 {
            child.kill().ok();
            break child.wait().unwrap();
        }
        std::thread::sleep(Duration::from_millis(10));
    };
    let o = Output {
        status,
        stdout: out.join().unwrap(),
        stderr: err.join().unwrap(),
    };
    (o, t.elapsed())
}

fn points_out(out: &Path) -> Option<u64> {
    let s: serde_json::Value =
        serde_json::from_slice(&std::fs::read(out.join("summary.json")).ok()?).ok()?;
    s["points_out"].as_u64()
}

#[test]
fn every_file_laspy_reads_is_processed_or_refused_on_purpose() {
    let Some((dir, rows)) = corpus() else {
        return;
    };
    let tmp = tempfile::tempdir().unwrap();
    let mut failures = Vec::new();
    let mut checked = 0;
    for row in rows.iter().filter(|r| r["laspy_reads"] == "1") {
        let name = row["file"].as_str();
        let path = dir.join(name);
        let want: u64 = row["laspy_points"].parse().unwrap_or(0);
        let refused = REFUSED.iter().find(|r| r.0 == name);
        checked += 1;
        let out = tmp.path().join(format!("o{checked}"));
        let runs: [(&str, Vec<&std::ffi::OsStr>); 3] = [
            ("info", vec!["info".as_ref(), path.as_os_str()]),
            (
                "pass-through",
                vec![
                    "run".as_ref(),
                    path.as_os_str(),
                    "--out".as_ref(),
                    out.as_os_str(),
                    "--overwrite".as_ref(),
                    "--set".as_ref(),
                    "stages.run=[\"stats\"]".as_ref(),
                ],
            ),
            (
                "default run",
                vec![
                    "run".as_ref(),
                    path.as_os_str(),
                    "--out".as_ref(),
                    out.as_os_str(),
                    "--overwrite".as_ref(),
                ],
            ),
        ];
        for (what, args) in runs {
            let (o, took) = tessera(&args);
            let err = String::from_utf8_lossy(&o.stderr);
            let mut fail = |m: String| failures.push(format!("{name} ({what}): {m}"));
            if took > LIMIT {
                fail(format!("took {took:?}"));
            }
            if err.contains("panicked") || o.status.code().is_none() {
                fail(format!("crashed: {err}"));
                continue;
            }
            // Each warning once.
            let mut seen = std::collections::HashSet::new();
            for l in err.lines().filter(|l| l.contains("WARN")) {
                let text = l.split("WARN").nth(1).unwrap_or(l);
                if !seen.insert(text) {
                    fail(format!("warning said twice: {text}"));
                }
            }
            match refused {
                // `info` describes a file without judging its CRS or its point count's
                // consistency in full; only the runs must refuse.
                Some((_, reason, _)) if what != "info" || !o.status.success() => {
                    if o.status.code() != Some(1) || !err.contains(reason) {
                        fail(format!("not refused as listed ({reason}): {err}"));
                    }
                    if what != "info" && !common::tiles_in(&out).is_empty() {
                        fail("refused, but tiles were written".into());
                    }
                }
                _ if !o.status.success() => fail(format!("exit {:?}: {err}", o.status.code())),
                _ if what != "info" && points_out(&out) != Some(want) => fail(format!(
                    "{:?} points out, laspy reads {want}",
                    points_out(&out)
                )),
                _ => {}
            }
        }
    }
    assert!(checked >= 150, "only {checked} laspy-readable files listed");
    assert!(failures.is_empty(), "{}", failures.join("\n"));
}

/// PDAL's Autzen: Oregon Lambert in metres with NAVD88 heights in US survey feet. Its ground
/// classification is the same, within 0.5 % of the points, as that of the same file with its
/// heights converted to metres.
#[test]
fn autzen_with_heights_in_feet_classifies_as_in_metres() {
    let Some(src) = common::data_file("las-corpus/PDAL/test__data__autzen__autzen-bmx-2010.las")
    else {
        return;
    };
    const US_FOOT: f64 = 1200.0 / 3937.0;
    let d = tempfile::tempdir().unwrap();
    let metres = d.path().join("autzen-m.las");
    {
        let mut r = las::Reader::from_path(&src).unwrap();
        let mut b = las::Builder::from(r.header().clone());
        // Without CRS records: x and y are metres, and so now are the heights.
        b.vlrs.retain(|v| !v.is_crs());
        b.evlrs.retain(|v| !v.is_crs());
        b.transforms.z.scale = 0.001;
        b.transforms.z.offset = 0.0;
        let mut w = las::Writer::from_path(&metres, b.into_header().unwrap()).unwrap();
        for p in r.read_all().unwrap().points() {
            let mut p = p.unwrap();
            p.z *= US_FOOT;
            w.write_point(p).unwrap();
        }
        w.close().unwrap();
    }
    let run = |input: &Path, out: &Path| {
        let (o, _) = tessera(&[
            "run".as_ref(),
            input.as_os_str(),
            "--out".as_ref(),
            out.as_os_str(),
        ]);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let mut m = HashMap::new();
        for t in common::tiles_in(out) {
            let (xyz, class) = common::read_las(&t).unwrap();
            for (p, c) in xyz.iter().zip(class) {
                let e = m
                    .entry([(p[0] * 100.0).round() as i64, (p[1] * 100.0).round() as i64])
                    .or_insert([0u32; 2]);
                e[0] += u32::from(c == 2);
                e[1] += 1;
            }
        }
        m
    };
    let a = run(&src, &d.path().join("ft"));
    let b = run(&metres, &d.path().join("m"));
    let n: u32 = a.values().map(|v| v[1]).sum();
    assert_eq!(n, 829, "Autzen's points");
    let differ: u32 = a
        .iter()
        .map(|(k, v)| v[0].abs_diff(b.get(k).map_or(0, |w| w[0])))
        .sum();
    assert!(
        differ as f64 <= 0.005 * n as f64,
        "{differ} of {n} points change ground class"
    );
    let ground: u32 = a.values().map(|v| v[0]).sum();
    assert!(ground > 0 && ground < n, "{ground} of {n} ground");
}

/// A header announcing more VLRs than lie before the point data (as PDAL's
/// `bad_vlr_count.las`): the points are read, with a warning.
#[test]
fn a_vlr_count_larger_than_the_vlrs_present_is_read_with_a_warning() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("bad_vlr_count.las");
    let mut b = las::Builder::from((1, 2));
    b.vlrs.push(las::Vlr {
        user_id: "example".into(),
        record_id: 1,
        description: "one VLR".into(),
        data: vec![7; 10],
    });
    let mut w = las::Writer::from_path(&p, b.into_header().unwrap()).unwrap();
    for i in 0..300 {
        w.write_point(las::Point {
            x: (i % 20) as f64,
            y: (i / 20) as f64,
            z: 1.0,
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let mut bytes = std::fs::read(&p).unwrap();
    bytes[100..104].copy_from_slice(&3u32.to_le_bytes());
    std::fs::write(&p, bytes).unwrap();
    let out = d.path().join("out");
    let (o, _) = tessera(&[
        "run".as_ref(),
        p.as_os_str(),
        "--out".as_ref(),
        out.as_os_str(),
    ]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.lines()
            .filter(|l| l.contains("WARN")
                && l.contains("bad_vlr_count.las")
                && l.contains("more VLRs"))
            .count()
            == 1,
        "{err}"
    );
    assert_eq!(points_out(&out), Some(300));
}
