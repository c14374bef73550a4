//! Inputs in feet (issue 23): an ISPRS sample converted to US survey feet and tagged
//! EPSG:2903 (NAD83(HARN) / New Mexico Central (ftUS)) gets the same ground classification as
//! the metre original, within 0.5 % of the points (gate); the conversion is reported in
//! summary.json; outputs in point formats 6–10 carry the CRS as OGC WKT.

mod common;

use std::collections::HashMap;
use std::path::{Path, PathBuf};
use std::process::Command;

const US_FOOT: f64 = 1200.0 / 3937.0;

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

/// A GeoTIFF key directory (34735) with single-valued u16 keys, plus the double-valued keys
/// `doubles` (in a 34736 record).
fn geokeys(keys: &[(u16, u16)], doubles: &[(u16, f64)]) -> Vec<las::Vlr> {
    let mut v: Vec<u16> = vec![1, 1, 0, (keys.len() + doubles.len()) as u16];
    for (id, value) in keys {
        v.extend([*id, 0, 1, *value]);
    }
    for (k, (id, _)) in doubles.iter().enumerate() {
        v.extend([*id, 34736, 1, k as u16]);
    }
    let vlr = |record_id: u16, data: Vec<u8>| las::Vlr {
        user_id: "LASF_Projection".into(),
        record_id,
        description: String::new(),
        data,
    };
    let mut out = vec![vlr(34735, v.iter().flat_map(|k| k.to_le_bytes()).collect())];
    if !doubles.is_empty() {
        out.push(vlr(
            34736,
            doubles.iter().flat_map(|(_, d)| d.to_le_bytes()).collect(),
        ));
    }
    out
}

/// `src` rewritten in US survey feet: coordinates divided by the foot, at a 0.001 ft scale,
/// with the CRS records replaced by `keys`.
fn to_feet(src: &Path, dst: &Path, keys: &[(u16, u16)]) {
    to_unit(src, dst, US_FOOT, 0.001, &geokeys(keys, &[]));
}

/// `src` with coordinates divided by `unit` (metres), at `scale`, and the CRS records `crs`.
fn to_unit(src: &Path, dst: &Path, unit: f64, scale: f64, crs: &[las::Vlr]) {
    let mut r = las::Reader::from_path(src).unwrap();
    let mut b = las::Builder::from(r.header().clone());
    b.vlrs.retain(|v| !v.is_crs());
    b.vlrs.retain(|v| !las::laz::is_laszip_vlr(v));
    b.vlrs.extend(crs.iter().cloned());
    let t = |o: f64| las::Transform {
        scale,
        offset: (o / unit / 1000.0).round() * 1000.0,
    };
    let h = r.header();
    b.transforms = las::Vector {
        x: t(h.bounds().min.x),
        y: t(h.bounds().min.y),
        z: t(0.0),
    };
    let mut w = las::Writer::from_path(dst, b.into_header().unwrap()).unwrap();
    let data = r.read_all().unwrap();
    for p in data.points() {
        let mut p = p.unwrap();
        p.x /= unit;
        p.y /= unit;
        p.z /= unit;
        w.write_point(p).unwrap();
    }
    w.close().unwrap();
}

/// Class of every output point, keyed by its coordinates in centimetres.
fn classes(out: &Path, metres_per_unit: f64) -> HashMap<[i64; 3], u8> {
    let mut m = HashMap::new();
    for t in common::tiles_in(out) {
        let (xyz, class) = common::read_las(&t).unwrap();
        for (p, c) in xyz.iter().zip(class) {
            let k = p.map(|v| (v * metres_per_unit * 100.0).round() as i64);
            m.insert(k, c);
        }
    }
    m
}

fn run(input: &Path, out: &Path, extra: &[&str]) -> serde_json::Value {
    let cfg = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/airborne.toml");
    let o = tessera()
        .args(["-q", "run"])
        .arg(input)
        .arg("--out")
        .arg(out)
        .arg("--config")
        .arg(&cfg)
        .args(extra.iter().flat_map(|s| ["--set", s]))
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap()
}

#[test]
fn us_feet_input_gives_the_metre_classification() {
    let Some(src) = common::data_file("isprs-filtertest/samp11-utm.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    // The unit from the EPSG code alone (no ProjLinearUnitsGeoKey): the table lookup.
    let feet = d.path().join("samp11-ftUS.laz");
    to_feet(&src, &feet, &[(1024, 1), (3072, 2903)]);

    let sm = run(&src, &d.path().join("m"), &[]);
    let sf = run(&feet, &d.path().join("ft"), &[]);
    assert_eq!(sm["units"]["unit"]["name"], "metre", "{}", sm["units"]);
    assert_eq!(sm["units"]["converted"].as_array().unwrap().len(), 0);
    let u = &sf["units"];
    assert_eq!(u["unit"]["name"], "US survey foot", "{u}");
    let converted: Vec<&str> = u["converted"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v.as_str().unwrap())
        .collect();
    for key in [
        "tiling.tile_size_m",
        "tiling.buffer_m",
        "ground.params.max_distance_m",
        "ground.params.seed_cell_m",
        "label.objects.roof_min_area_m2",
    ] {
        assert!(
            converted.contains(&key),
            "{key} not converted: {converted:?}"
        );
    }
    assert!(
        !converted.iter().any(|k| k.starts_with("mcap.")),
        "{converted:?}"
    );

    let cm = classes(&d.path().join("m"), 1.0);
    let cf = classes(&d.path().join("ft"), US_FOOT);
    assert_eq!(cm.len(), cf.len());
    let n = cm.len();
    let mut differ = 0usize;
    let mut missing = 0usize;
    for (k, c) in &cm {
        match cf.get(k) {
            Some(f) if f == c => {}
            Some(_) => differ += 1,
            None => missing += 1,
        }
    }
    let share = (differ + missing) as f64 / n as f64;
    println!(
        "samp11 in US feet vs metres: {n} points, {differ} classified differently, {missing} unmatched ({:.3} %)",
        share * 100.0
    );
    assert_eq!(missing, 0);
    assert!(
        share <= 0.005,
        "{:.3} % of the points differ (gate 0.5 %)",
        share * 100.0
    );

    // The conversion is complete (no distance escapes it): in a unit of exactly 0.5 m every
    // coordinate and parameter halves exactly in binary floating point, and the classification
    // is identical point for point. (The feet file differs in a few points because its
    // coordinates are rounded to 0.001 ft, up to 0.15 mm, which moves the greedy TIN's ties.)
    let half = d.path().join("samp11-half.laz");
    to_unit(
        &src,
        &half,
        0.5,
        0.02,
        &geokeys(&[(1024, 1), (3076, 32767)], &[(3077, 0.5)]),
    );
    let sh = run(&half, &d.path().join("half"), &[]);
    assert_eq!(sh["units"]["unit"]["metres"], 0.5, "{}", sh["units"]);
    let ch = classes(&d.path().join("half"), 0.5);
    let differ_half = cm.iter().filter(|(k, c)| ch.get(*k) != Some(c)).count();
    println!("samp11 in a 0.5 m unit: {differ_half} points differ");
    assert_eq!(differ_half, 0);

    // Without the conversion (the unit stated wrongly) the classification is not the same:
    // the gate above measures the conversion, not an insensitive filter.
    let wrong = run(&feet, &d.path().join("ft-as-m"), &["crs.units=\"metre\""]);
    assert_eq!(wrong["units"]["source"], "crs.units");
    let cw = classes(&d.path().join("ft-as-m"), US_FOOT);
    let wrong_share = cm.iter().filter(|(k, c)| cw.get(*k) != Some(c)).count() as f64 / n as f64;
    println!(
        "the same with metre parameters: {:.3} % differ",
        wrong_share * 100.0
    );
    assert!(wrong_share > 4.0 * share.max(0.001), "{wrong_share}");
}

fn wkt_of(path: &Path) -> Option<String> {
    let r = las::Reader::from_path(path).unwrap();
    let h = r.header();
    assert!(
        h.all_vlrs().all(|v| !v.is_geotiff_crs()),
        "{}: GeoTIFF keys next to the WKT",
        path.display()
    );
    h.get_wkt_crs_bytes().map(|b| {
        String::from_utf8_lossy(b)
            .trim_end_matches('\0')
            .to_string()
    })
}

#[test]
fn formats_6_to_10_carry_ogc_wkt() {
    let Some(src) = common::data_file("isprs-filtertest/samp71-utm.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let feet = d.path().join("samp71-ftUS.laz");
    to_feet(
        &src,
        &feet,
        &[(1024, 1), (3072, 2903), (3076, 9003), (4099, 9003)],
    );
    for (input, out, epsg) in [(&src, "m6", "32632"), (&feet, "ft6", "2903")] {
        let out: PathBuf = d.path().join(out);
        let s = run(input, &out, &["output.point_format=6"]);
        assert_eq!(s["point_format"], 6);
        let tiles = common::tiles_in(&out);
        assert!(!tiles.is_empty());
        for t in &tiles {
            let wkt = wkt_of(t).unwrap_or_else(|| panic!("{}: no WKT", t.display()));
            assert!(
                wkt.starts_with("PROJCS[") && wkt.contains(&format!("\"EPSG\",\"{epsg}\"")),
                "{wkt}"
            );
            let raw = std::fs::read(t).unwrap();
            let global_encoding = u16::from_le_bytes([raw[6], raw[7]]);
            assert_ne!(global_encoding & 16, 0, "WKT bit not set");
        }
        if std::env::var("CI").as_deref() == Ok("true") {
            assert!(common::have_laspy(), "CI=true: laspy + lazrs are needed");
        }
        if common::have_laspy() {
            let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/check_las14.py");
            let o = Command::new("python3")
                .arg(script)
                .args(&tiles)
                .output()
                .unwrap();
            assert!(
                o.status.success(),
                "{}{}",
                String::from_utf8_lossy(&o.stdout),
                String::from_utf8_lossy(&o.stderr)
            );
        }
    }
}

fn run_default(input: &Path, out: &Path, extra: &[&str]) -> std::process::Output {
    tessera()
        .arg("run")
        .arg(input)
        .arg("--out")
        .arg(out)
        .args(extra.iter().flat_map(|s| ["--set", s]))
        .output()
        .unwrap()
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap()
}

/// CRS records tessera cannot use, or that contradict the coordinates, are warnings naming the
/// file and the unit assumed (laspy and PDAL read such files); coordinates that really are
/// longitudes/latitudes are refused with the CRS found and how to reproject; `crs.units`
/// states the unit instead.
#[test]
fn unusable_crs_records_warn_and_degrees_are_refused() {
    let Some(src) = common::data_file("isprs-filtertest/samp71-utm.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    // Runs, with a warning naming the file and what was left out.
    let warned: [(&str, Vec<las::Vlr>, &str); 2] = [
        (
            "unknown.laz",
            geokeys(&[(1024, 1), (3076, 9999)], &[]),
            "ProjLinearUnitsGeoKey holds 9999, which is not a length unit",
        ),
        (
            "geographic-record.laz",
            geokeys(&[(1024, 2), (2048, 4326)], &[]),
            "are no longitudes/latitudes",
        ),
    ];
    for (name, crs, needle) in warned {
        let p = d.path().join(name);
        to_unit(&src, &p, 1.0, 0.01, &crs);
        let out = d.path().join(format!("{name}.out"));
        let o = run_default(&p, &out, &[]);
        let err = String::from_utf8_lossy(&o.stderr);
        assert!(o.status.success(), "{name}: {err}");
        let warning = err
            .lines()
            .find(|l| l.contains("WARN") && l.contains(needle));
        assert!(
            warning.is_some_and(|w| w.contains(name) && w.contains("metre")),
            "{name}: {err}"
        );
        assert_eq!(summary(&out)["units"]["unit"]["name"], "metre", "{name}");
    }
    // Degrees: refused, naming the CRS and the UTM zone to reproject to (samp71's metres
    // divided by 10^5 read as 4.96° E, 54.22° N: zone 31N).
    let p = d.path().join("degrees.laz");
    to_unit(
        &src,
        &p,
        1e5,
        1e-7,
        &geokeys(&[(1024, 2), (2048, 4326)], &[]),
    );
    let out = d.path().join("degrees.out");
    let o = run_default(&p, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{err}");
    for needle in [
        "degrees.laz",
        "longitude/latitude",
        "EPSG:4326",
        "EPSG:32631",
        "reproject",
    ] {
        assert!(err.contains(needle), "{needle}: {err}");
    }
    assert!(common::tiles_in(&out).is_empty(), "tiles written");
    let o = run_default(&p, &out, &["crs.units=\"metre\""]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert_eq!(summary(&out)["units"]["source"], "crs.units");
}

/// An OGC WKT record of two quote characters (as some writers leave an empty CRS) is a
/// warning, and the file runs in metres.
#[test]
fn an_empty_wkt_record_is_a_warning() {
    let d = tempfile::tempdir().unwrap();
    let p = d.path().join("quotes.las");
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(6).unwrap();
    b.vlrs.push(las::Vlr {
        user_id: "LASF_Projection".into(),
        record_id: 2112,
        description: String::new(),
        data: b"\"\"".to_vec(),
    });
    let mut w = las::Writer::from_path(&p, b.into_header().unwrap()).unwrap();
    for i in 0..400 {
        w.write_point(las::Point {
            x: 1000.0 + (i % 20) as f64,
            y: 2000.0 + (i / 20) as f64,
            z: 10.0,
            gps_time: Some(0.0),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let out = d.path().join("out");
    let o = run_default(&p, &out, &[]);
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(o.status.success(), "{err}");
    assert!(
        err.lines().any(|l| l.contains("WARN")
            && l.contains("quotes.las")
            && l.contains("WKT record is empty")),
        "{err}"
    );
    let s = summary(&out);
    assert_eq!(s["points_out"], 400);
    assert_eq!(s["units"]["unit"]["name"], "metre");
}

/// x/y in US survey feet and heights in metres: the stages see heights in feet, so the
/// classification is that of the same file with its heights in feet (within 0.5 % of the
/// points), and the outputs keep the heights in metres, bit for bit.
#[test]
fn heights_in_another_unit_than_xy_are_scaled_for_the_stages() {
    let Some(src) = common::data_file("isprs-filtertest/samp11-utm.laz") else {
        return;
    };
    let d = tempfile::tempdir().unwrap();
    let feet = d.path().join("feet.laz");
    to_feet(&src, &feet, &[(1024, 1), (3072, 2903)]);
    // The same points with heights back in metres (at the same 1 mm scale) and a vertical
    // unit key saying so.
    let mixed = d.path().join("mixed.laz");
    {
        let mut r = las::Reader::from_path(&feet).unwrap();
        let mut b = las::Builder::from(r.header().clone());
        b.vlrs
            .retain(|v| !v.is_crs() && !las::laz::is_laszip_vlr(v));
        b.vlrs
            .extend(geokeys(&[(1024, 1), (3072, 2903), (4099, 9001)], &[]));
        let mut w = las::Writer::from_path(&mixed, b.into_header().unwrap()).unwrap();
        for p in r.read_all().unwrap().points() {
            let mut p = p.unwrap();
            p.z *= US_FOOT;
            w.write_point(p).unwrap();
        }
        w.close().unwrap();
    }
    let sf = run(&feet, &d.path().join("ft"), &[]);
    let sx = run(&mixed, &d.path().join("mixed"), &[]);
    let u = &sx["units"];
    assert_eq!(u["unit"]["name"], "US survey foot", "{u}");
    assert_eq!(u["vertical_unit"]["name"], "metre", "{u}");
    assert!(
        (u["z_to_xy"].as_f64().unwrap() - 1.0 / US_FOOT).abs() < 1e-9,
        "{u}"
    );
    assert_eq!(sf["units"]["z_to_xy"], 1.0);
    // Keyed by x, y in feet and z in centimetres.
    let key = |out: &Path, z_metres: f64| {
        let mut m = HashMap::new();
        for t in common::tiles_in(out) {
            let (xyz, class) = common::read_las(&t).unwrap();
            for (p, c) in xyz.iter().zip(class) {
                let k = [
                    (p[0] * 1000.0).round() as i64,
                    (p[1] * 1000.0).round() as i64,
                    (p[2] * z_metres * 100.0).round() as i64,
                ];
                m.insert(k, (c, p[2]));
            }
        }
        m
    };
    let a = key(&d.path().join("ft"), US_FOOT);
    let b = key(&d.path().join("mixed"), 1.0);
    assert_eq!(sf["points_out"], sx["points_out"]);
    let n = a.len().max(1);
    let differ = a
        .iter()
        .filter(|(k, (c, _))| b.get(*k).is_none_or(|(d, _)| (*c == 2) != (*d == 2)))
        .count();
    assert!(
        differ * 200 <= n,
        "{differ} of {n} points change ground class between heights in feet and in metres"
    );
    // The outputs' heights are the input's metres.
    let min_z = b.values().map(|v| v.1).fold(f64::INFINITY, f64::min);
    let min_ft = a.values().map(|v| v.1).fold(f64::INFINITY, f64::min);
    assert!((min_z - min_ft * US_FOOT).abs() < 0.002, "{min_z} {min_ft}");
}
