//! `tessera plan`: tiles with estimated points from the headers alone, cut into tasks that
//! cover every tile once, are contiguous on the Morton curve (compact blocks) and balanced by
//! points.

use std::path::Path;
use std::process::Command;

/// A 4 × 3 block layout of 100 m × 100 m LAS files, one point per m² each.
fn write_region(dir: &Path) -> u64 {
    std::fs::create_dir_all(dir).unwrap();
    let mut total = 0;
    for bx in 0..4 {
        for by in 0..3 {
            let mut b = las::Builder::from((1, 2));
            b.point_format = las::point::Format::new(0).unwrap();
            let p = dir.join(format!("block_{bx}_{by}.las"));
            let mut w = las::Writer::from_path(&p, b.into_header().unwrap()).unwrap();
            for i in 0..100 {
                for j in 0..100 {
                    w.write_point(las::Point {
                        x: bx as f64 * 100.0 + i as f64 + 0.5,
                        y: by as f64 * 100.0 + j as f64 + 0.5,
                        z: 1.0,
                        ..Default::default()
                    })
                    .unwrap();
                    total += 1;
                }
            }
            w.close().unwrap();
        }
    }
    total
}

fn plan(inputs: &Path, out: &Path, tasks: usize) -> std::process::Output {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(["-q", "plan"])
        .arg(inputs)
        .arg("--out")
        .arg(out)
        .args(["--tasks", &tasks.to_string()])
        .output()
        .unwrap()
}

fn morton(ix: i64, iy: i64) -> u64 {
    tessera::tiling::morton(ix, iy)
}

#[test]
fn plan_covers_every_tile_once_in_balanced_morton_contiguous_tasks() {
    let d = tempfile::tempdir().unwrap();
    let inputs = d.path().join("in");
    let total = write_region(&inputs);
    for n in [1usize, 3, 4, 7] {
        let out = d.path().join(format!("plan{n}"));
        let o = plan(&inputs, &out, n);
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let json: serde_json::Value =
            serde_json::from_slice(&std::fs::read(out.join("plan.json")).unwrap()).unwrap();
        assert_eq!(json["points"], total);
        assert_eq!(json["inputs"].as_array().unwrap().len(), 12);
        let tsv = std::fs::read_to_string(out.join("tiles.tsv")).unwrap();
        let rows: Vec<(i64, i64, u64, usize)> = tsv
            .lines()
            .skip(1)
            .map(|l| {
                let f: Vec<&str> = l.split('\t').collect();
                (
                    f[0].parse().unwrap(),
                    f[1].parse().unwrap(),
                    f[2].parse().unwrap(),
                    f[3].parse().unwrap(),
                )
            })
            .collect();
        // 400 m × 300 m on the default 50 m grid: 48 tiles of 2,500 points each.
        assert_eq!(rows.len(), 48, "{n} tasks");
        let mut cells: Vec<(i64, i64)> = rows.iter().map(|r| (r.0, r.1)).collect();
        cells.sort();
        cells.dedup();
        assert_eq!(cells.len(), 48, "a tile listed twice");
        assert!(rows.iter().all(|r| r.2 == 2500), "{rows:?}");
        assert_eq!(rows.iter().map(|r| r.2).sum::<u64>(), total);
        // Tasks: every one used, contiguous on the Morton curve (the file's order), in
        // increasing task order, and balanced within one tile of the mean.
        assert!(rows
            .windows(2)
            .all(|w| morton(w[0].0, w[0].1) < morton(w[1].0, w[1].1)));
        assert!(rows.windows(2).all(|w| w[0].3 <= w[1].3));
        let tasks = json["tasks"].as_array().unwrap();
        assert_eq!(tasks.len(), n);
        let mean = total as f64 / n as f64;
        for t in tasks {
            let p = t["points"].as_u64().unwrap() as f64;
            assert!(t["tiles"].as_u64().unwrap() > 0, "{t}");
            assert!((p - mean).abs() <= 2500.0, "task {t} vs mean {mean}");
        }
        assert_eq!(
            tasks
                .iter()
                .map(|t| t["points"].as_u64().unwrap())
                .sum::<u64>(),
            total
        );
    }
    // Deterministic, and an existing plan is never replaced.
    let again = d.path().join("again");
    assert!(plan(&inputs, &again, 7).status.success());
    for f in ["plan.json", "tiles.tsv"] {
        let a = std::fs::read(d.path().join("plan7").join(f)).unwrap();
        let b = std::fs::read(again.join(f)).unwrap();
        // plan.json names the input paths, identical here.
        assert_eq!(a, b, "{f}");
    }
    let o = plan(&inputs, &again, 7);
    assert_eq!(o.status.code(), Some(2));
    assert!(String::from_utf8_lossy(&o.stderr).contains("never replaced"));
}

/// A sparse file (2 points whose bounds reach 4 tiles) still plans all 4 tiles: a tile left
/// out of a plan would never be processed. (With `tiling.sparse_tile_points` at its default
/// the two points make one larger tile, as a run cuts them.)
#[test]
fn every_tile_an_input_reaches_is_planned() {
    let d = tempfile::tempdir().unwrap();
    let inputs = d.path().join("in");
    std::fs::create_dir_all(&inputs).unwrap();
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(0).unwrap();
    let mut w =
        las::Writer::from_path(inputs.join("sparse.las"), b.into_header().unwrap()).unwrap();
    for (x, y) in [(10.0, 10.0), (90.0, 90.0)] {
        w.write_point(las::Point {
            x,
            y,
            z: 0.0,
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    let grown = d.path().join("grown");
    assert!(plan(&inputs, &grown, 2).status.success());
    let tsv = std::fs::read_to_string(grown.join("tiles.tsv")).unwrap();
    assert_eq!(tsv.lines().count(), 2, "{tsv}");
    let out = d.path().join("plan");
    let o = Command::new(env!("CARGO_BIN_EXE_tessera"))
        .args(["-q", "plan"])
        .arg(&inputs)
        .arg("--out")
        .arg(&out)
        .args(["--tasks", "2", "--set", "tiling.sparse_tile_points=0"])
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let tsv = std::fs::read_to_string(out.join("tiles.tsv")).unwrap();
    let mut cells: Vec<String> = tsv
        .lines()
        .skip(1)
        .map(|l| l.split('\t').take(2).collect::<Vec<_>>().join(","))
        .collect();
    cells.sort();
    assert_eq!(cells, ["0,0", "0,1", "1,0", "1,1"]);
    assert!(
        tsv.lines()
            .skip(1)
            .all(|l| l.split('\t').nth(2) == Some("1")),
        "{tsv}"
    );
}
