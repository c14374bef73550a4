//! `report.html` (issue 24): written by every run, self-contained, opened in headless Chromium
//! (no console messages, a screenshot whose overview shows the classes of the legend), the
//! legend listing exactly the classes in the tiles, and `tessera report DIR` rebuilding it.

mod common;

use std::collections::BTreeSet;
use std::path::{Path, PathBuf};
use std::process::Command;

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

/// Classes in the legend (`data-class` attributes) and their colours.
fn legend(html: &str) -> Vec<(u8, [u8; 3], f64)> {
    let start = html.find("<ul class=\"legend\"").expect("legend");
    let end = start + html[start..].find("</ul>").unwrap();
    html[start..end]
        .split("<li data-class=\"")
        .skip(1)
        .map(|item| {
            let code: u8 = item[..item.find('"').unwrap()].parse().unwrap();
            let rgb = &item[item.find("rgb(").unwrap() + 4..];
            let rgb: Vec<u8> = rgb[..rgb.find(')').unwrap()]
                .split(',')
                .map(|v| v.trim().parse().unwrap())
                .collect();
            let pct = &item[item.rfind('(').unwrap() + 1..item.rfind(" %)").unwrap()];
            (code, [rgb[0], rgb[1], rgb[2]], pct.parse().unwrap())
        })
        .collect()
}

/// Class codes of every point of the tiles in `dir`, read with the las crate.
fn classes_in_tiles(dir: &Path) -> BTreeSet<u8> {
    let mut set = BTreeSet::new();
    for t in common::tiles_in(dir) {
        let mut r = las::Reader::from_path(&t).unwrap();
        for p in r.read_all().unwrap().points() {
            set.insert(u8::from(p.unwrap().classification));
        }
    }
    set
}

/// The `<figure>`s of a page (the pictures and their captions).
fn pictures(h: &str) -> Vec<String> {
    h.split("<figure")
        .skip(1)
        .map(|f| f[..f.find("</figure>").unwrap()].to_string())
        .collect()
}

fn chromium() -> Option<PathBuf> {
    for name in ["chromium", "chromium-browser", "google-chrome", "chrome"] {
        let found = std::env::var_os("PATH").and_then(|paths| {
            std::env::split_paths(&paths)
                .map(|d| d.join(name))
                .find(|p| p.is_file())
        });
        if found.is_some() {
            return found;
        }
    }
    None
}

fn decode_png(path: &Path) -> (usize, usize, Vec<[u8; 3]>) {
    let dec = png::Decoder::new(std::io::BufReader::new(std::fs::File::open(path).unwrap()));
    let mut r = dec.read_info().unwrap();
    let mut buf = vec![0; r.output_buffer_size()];
    let info = r.next_frame(&mut buf).unwrap();
    let step = info.color_type.samples();
    assert!(step >= 3, "screenshot colour type {:?}", info.color_type);
    let px = buf[..info.buffer_size()]
        .chunks_exact(step)
        .map(|c| [c[0], c[1], c[2]])
        .collect();
    (info.width as usize, info.height as usize, px)
}

#[test]
fn demo_report_is_self_contained_and_renders_in_chromium() {
    let d = tempfile::tempdir().unwrap();
    let o = tessera()
        .args(["-q", "demo", "--length-m", "60", "--out"])
        .arg(d.path())
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tiles = d.path().join("tiles");
    let report = tiles.join("report.html");
    let html = std::fs::read_to_string(&report).expect("the demo writes report.html");

    // Self-contained: no script, nothing fetched (every image is a data URI).
    assert!(!html.contains("<script"), "the page has a script");
    for (i, _) in html.match_indices(" src=\"") {
        assert!(
            html[i + 6..].starts_with("data:image/png;base64,"),
            "an image not embedded: {}",
            &html[i..(i + 80).min(html.len())]
        );
    }
    assert!(!html.contains("http://") && !html.contains("https://"));
    for id in [
        "overview-class",
        "overview-segment",
        "overview-height",
        "overview-errors",
        "confusion",
        "memory",
    ] {
        assert!(
            html.contains(&format!("id=\"{id}\"")),
            "no {id} in the report"
        );
    }
    // The legend lists exactly the classes the tiles hold.
    let leg = legend(&html);
    let listed: BTreeSet<u8> = leg.iter().map(|l| l.0).collect();
    assert_eq!(listed, classes_in_tiles(&tiles));
    assert!(listed.len() >= 6, "{listed:?}");
    let summary: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(tiles.join("summary.json")).unwrap())
            .unwrap();
    let report_s = summary["seconds"]["report"]
        .as_f64()
        .expect("seconds.report");
    eprintln!(
        "report {report_s:.2} s, pipeline {:.2} s",
        summary["seconds"]["total"].as_f64().unwrap()
    );

    // `tessera report` decodes the tiles; the run drew while writing: the same pictures.
    let o = tessera().arg("report").arg(&tiles).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let again = std::fs::read_to_string(&report).unwrap();
    assert_eq!(pictures(&html), pictures(&again));
    assert_eq!(pictures(&html).len(), 5, "4 rasters and the memory chart");

    let Some(chrome) = chromium() else {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "no chromium on PATH, and CI=true requires the report's rendering gate (.ci/run installs it)"
        );
        eprintln!("SKIP: no chromium on PATH");
        return;
    };
    let shot = d.path().join("shot.png");
    let profile = d.path().join("chromium-profile");
    let o = Command::new(&chrome)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--hide-scrollbars",
            "--no-first-run",
            "--enable-logging=stderr",
            "--v=0",
            "--window-size=1400,1100",
        ])
        .arg(format!("--user-data-dir={}", profile.display()))
        .arg(format!("--screenshot={}", shot.display()))
        .arg(format!("file://{}", report.display()))
        .output()
        .unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        o.status.success() && shot.is_file(),
        "chromium failed: {err}"
    );
    let console: Vec<&str> = err.lines().filter(|l| l.contains(":CONSOLE")).collect();
    assert!(console.is_empty(), "console messages: {console:?}");

    // The overview is drawn: every class with at least 2 % of the points shows its legend
    // colour on the screen, and most of the first screen is not background.
    let (w, h, px) = decode_png(&shot);
    assert_eq!((w, h), (1400, 1100));
    let white = px.iter().filter(|p| p.iter().all(|&c| c >= 250)).count();
    let coloured = px.iter().filter(|p| {
        let (mx, mn) = (*p.iter().max().unwrap(), *p.iter().min().unwrap());
        mx - mn > 40
    });
    let coloured = coloured.count();
    eprintln!(
        "screenshot {w}×{h}: {:.1} % white, {:.1} % coloured",
        100.0 * white as f64 / px.len() as f64,
        100.0 * coloured as f64 / px.len() as f64
    );
    assert!(
        coloured as f64 > 0.10 * px.len() as f64,
        "the screenshot is nearly blank"
    );
    for (code, rgb, pct) in leg.iter().filter(|l| l.2 >= 2.0) {
        let n = px.iter().filter(|p| *p == rgb).count();
        eprintln!("class {code}: {pct} % of points, {n} pixels");
        // Its legend swatch alone is 14 × 14 = 196 pixels.
        assert!(
            n >= 1000,
            "class {code} ({pct} % of points) covers {n} pixels of its colour {rgb:?} on the screen"
        );
    }
}

/// Synthesises a `length` m street into `dir/scene`; returns the scene and a runner of
/// `tessera run SCENE --out dir/out --set SET [extra...]`.
fn scene_and_runner(
    dir: &Path,
    length: &str,
    set: &'static str,
) -> (PathBuf, PathBuf, impl Fn(&[&str]) -> std::process::Output) {
    let scene = dir.join("scene");
    let o = tessera()
        .args(["-q", "synth", "--length-m", length, "--out"])
        .arg(&scene)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let out = dir.join("out");
    let (sc, ou) = (scene.clone(), out.clone());
    let run = move |extra: &[&str]| {
        tessera()
            .args(["-q", "run"])
            .arg(&sc)
            .arg("--out")
            .arg(&ou)
            .args(["--set", set])
            .args(extra)
            .output()
            .unwrap()
    };
    (scene, out, run)
}

#[test]
fn report_command_rebuilds_the_page_and_overwrite_still_replaces_it() {
    let d = tempfile::tempdir().unwrap();
    let (scene, out, run) = scene_and_runner(d.path(), "30", "stages.run=[\"ground\",\"stats\"]");
    let o = run(&[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let report = out.join("report.html");
    let first = std::fs::read_to_string(&report).unwrap();
    assert!(
        !first.contains("id=\"overview-segment\""),
        "no segments in this run"
    );
    assert!(
        first.contains("id=\"overview-errors\""),
        "the scene carries gt_class"
    );
    std::fs::remove_file(&report).unwrap();

    let o = tessera().arg("report").arg(&out).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let second = std::fs::read_to_string(&report).unwrap();
    // The same pictures and legend (the figures from summary.json may have moved: the
    // summary now also holds the report's own time).
    assert_eq!(pictures(&first).len(), 4, "3 rasters and the memory chart");
    assert_eq!(pictures(&first), pictures(&second));
    assert_eq!(legend(&first), legend(&second));

    // The rebuilt page is recorded as the run's: an --overwrite run replaces it.
    let o = run(&["--overwrite"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(report.is_file());

    // Not a run directory: a clear error, exit 1.
    let o = tessera().arg("report").arg(&scene).output().unwrap();
    assert_eq!(o.status.code(), Some(1));
    assert!(String::from_utf8_lossy(&o.stderr).contains("summary.json"));
}

/// Raw records (uncompressed, as written) of `files`, grouped by class, each group sorted.
fn records_by_class(files: &[PathBuf]) -> std::collections::BTreeMap<u8, Vec<Vec<u8>>> {
    let mut by: std::collections::BTreeMap<u8, Vec<Vec<u8>>> = Default::default();
    for f in files {
        let (fmt, recs) = common::raw_records(f);
        let at = if fmt.is_extended { 16 } else { 15 };
        let mask = if fmt.is_extended { 0xFF } else { 0x1F };
        for r in recs {
            by.entry(r[at] & mask).or_default().push(r);
        }
    }
    for v in by.values_mut() {
        v.sort();
    }
    by
}

/// `output.per_class`: one file per class holding exactly that class's records of all tiles
/// (final segment ids included), listed in summary.json and recorded in the journal (an
/// `--overwrite` run replaces them); the same files when built from the tile files (the
/// path of tiles a resumed run reuses, or a stitch links).
#[test]
fn per_class_files_hold_every_record_of_their_class() {
    let d = tempfile::tempdir().unwrap();
    let (_scene, out, run) = scene_and_runner(d.path(), "40", "output.per_class=true");
    let o = run(&[]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let all = common::tiles_in(&out);
    let (class_files, tiles): (Vec<PathBuf>, Vec<PathBuf>) = all.into_iter().partition(|p| {
        p.file_name()
            .is_some_and(|n| n.to_string_lossy().starts_with("class_"))
    });
    assert!(
        tiles.len() >= 2 && class_files.len() >= 4,
        "{class_files:?}"
    );
    let want = records_by_class(&tiles);
    let got = records_by_class(&class_files);
    assert_eq!(
        want.keys().collect::<Vec<_>>(),
        got.keys().collect::<Vec<_>>()
    );
    for (class, recs) in &want {
        assert!(recs == &got[class], "class {class}: records differ");
    }
    let s: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(out.join("summary.json")).unwrap()).unwrap();
    let listed = s["class_files"].as_array().unwrap();
    assert_eq!(listed.len(), class_files.len());
    for c in listed {
        let code = c["class"].as_u64().unwrap() as u8;
        assert_eq!(c["points"].as_u64().unwrap() as usize, want[&code].len());
        assert!(out.join(c["file"].as_str().unwrap()).is_file());
    }
    let o = run(&["--overwrite"]);
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    assert!(records_by_class(&class_files) == got);

    // The output directory read as input: its tiles once, not the class files again.
    let reread = d.path().join("reread");
    let o = tessera()
        .args(["-q", "run"])
        .arg(&out)
        .arg("--out")
        .arg(&reread)
        .args(["--set", "stages.run=[\"stats\"]"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let s2: serde_json::Value =
        serde_json::from_str(&std::fs::read_to_string(reread.join("summary.json")).unwrap())
            .unwrap();
    let tile_points: usize = want.values().map(Vec::len).sum();
    assert_eq!(s2["points_in"].as_u64().unwrap() as usize, tile_points);

    // Built from the tile files instead (reused / linked tiles): the same records.
    let rebuilt = d.path().join("rebuilt");
    let mut dir = tessera::io::workspace::OutputDir::open(&rebuilt, false).unwrap();
    let header = las::Reader::from_path(&tiles[0]).unwrap().header().clone();
    let c = tessera::io::perclass::ClassFiles::new(&header, true, dir.stage()).unwrap();
    let named: Vec<(String, PathBuf)> = tiles
        .iter()
        .map(|t| {
            (
                t.file_stem().unwrap().to_string_lossy().into_owned(),
                t.clone(),
            )
        })
        .collect();
    c.add_files(&named).unwrap();
    let written = c.finish(&mut dir).unwrap();
    assert_eq!(written.len(), class_files.len());
    let again: Vec<PathBuf> = written.iter().map(|w| rebuilt.join(&w.file)).collect();
    assert!(records_by_class(&again) == got);
}
