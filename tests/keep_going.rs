//! `--keep-going`: an unreadable input or a failed tile is listed in summary.json and the rest
//! of the run finishes (exit code 3); without it the same run stops with exit 1 and leaves no
//! tiles. Every point is accounted for: written, in a failed tile, or in a skipped input.

mod common;

use std::path::Path;
use std::process::{Command, Output};

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

/// A sparse 1 point/m² ground grid over [0, 150) × [0, 100) m, plus (with `wall`) that many
/// points stacked at (5, 5): a tile no split can make fit a small budget.
fn write_scene(path: &Path, wall: usize) -> u64 {
    write_scene_at(path, wall, 0.0)
}

/// [`write_scene`] moved `x0` metres east.
fn write_scene_at(path: &Path, wall: usize, x0: f64) -> u64 {
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(0).unwrap();
    let mut w = las::Writer::from_path(path, b.into_header().unwrap()).unwrap();
    let mut n = 0u64;
    for ix in 0..150 {
        for iy in 0..100 {
            w.write_point(las::Point {
                x: x0 + ix as f64 + 0.5,
                y: iy as f64 + 0.5,
                z: 0.01 * ((ix * 7 + iy * 3) % 11) as f64,
                ..Default::default()
            })
            .unwrap();
            n += 1;
        }
    }
    for i in 0..wall {
        w.write_point(las::Point {
            x: x0 + 5.0,
            y: 5.0,
            z: i as f64 * 0.001,
            ..Default::default()
        })
        .unwrap();
        n += 1;
    }
    w.close().unwrap();
    n
}

fn run(inputs: &Path, out: &Path, extra: &[&str]) -> Output {
    tessera()
        .args(["-q", "run"])
        .arg(inputs)
        .arg("--out")
        .arg(out)
        .args(extra)
        .output()
        .unwrap()
}

fn summary(out: &Path) -> serde_json::Value {
    serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap()).unwrap()
}

fn stderr(o: &Output) -> String {
    String::from_utf8_lossy(&o.stderr).into_owned()
}

#[test]
fn unreadable_input_is_skipped_and_listed() {
    let d = tempfile::tempdir().unwrap();
    let inputs = d.path().join("in");
    std::fs::create_dir(&inputs).unwrap();
    let good = write_scene(&inputs.join("a.las"), 0);
    // Not a LAS file at all, and a LAS file cut inside its point records.
    std::fs::write(inputs.join("b.laz"), b"this is not a point cloud").unwrap();
    let full = std::fs::read(inputs.join("a.las")).unwrap();
    std::fs::write(inputs.join("c.las"), &full[..full.len() / 2]).unwrap();
    let stats = ["--set", "stages.run=[\"stats\"]"];

    // Without --keep-going the first bad input stops the run before any tile is written.
    let out = d.path().join("strict");
    let o = run(&inputs, &out, &stats);
    assert_eq!(o.status.code(), Some(1), "{}", stderr(&o));
    assert!(stderr(&o).contains("b.laz"), "{}", stderr(&o));
    assert!(common::tiles_in(&out).is_empty());

    let out = d.path().join("keep");
    let mut args = stats.to_vec();
    args.push("--keep-going");
    let o = run(&inputs, &out, &args);
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    assert!(err.contains("2 unreadable input(s)"), "{err}");
    let s = summary(&out);
    let skipped: Vec<&str> = s["skipped_inputs"]
        .as_array()
        .unwrap()
        .iter()
        .map(|v| v["path"].as_str().unwrap())
        .collect();
    assert_eq!(skipped.len(), 2, "{s}");
    assert!(
        skipped[0].ends_with("b.laz") && skipped[1].ends_with("c.las"),
        "{skipped:?}"
    );
    assert!(s["skipped_inputs"][1]["error"]
        .as_str()
        .unwrap()
        .contains("c.las"));
    assert_eq!(s["points_in"], good);
    assert_eq!(s["points_out"], good);
    assert_eq!(s["points_failed"].as_u64().unwrap_or(0), 0, "{s}");
    assert!(!common::tiles_in(&out).is_empty());
}

#[test]
fn failed_tile_is_listed_and_the_rest_is_written() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("wall.las");
    let wall = 300_000;
    let total = write_scene(&input, wall);
    // 64 MiB with stats, 128 MiB with ground + segment (and stitching): the 300 k-point wall
    // at one xy exceeds even the whole tile memory (a tile needing several workers' shares
    // runs alone with their memory tokens: at 256 MiB this wall now fits) and no split can
    // help; the other tiles fit.
    for (name, budget, stages) in [
        ("stats", "64", "stages.run=[\"stats\"]"),
        ("segment", "128", "stages.run=[\"ground\", \"segment\"]"),
    ] {
        let base = ["--memory-budget", budget, "--set", stages];
        let strict = d.path().join(format!("{name}-strict"));
        let o = run(&input, &strict, &base);
        assert_eq!(o.status.code(), Some(1), "{name}: {}", stderr(&o));
        assert!(
            stderr(&o).contains("memory budget infeasible"),
            "{}",
            stderr(&o)
        );
        // No summary: the run did not finish. The tiles of the cells it finished stay with
        // its resume journal (issue 20): rerun with --keep-going, the same run continues.
        assert!(!strict.join("summary.json").exists());
        let left = common::tiles_in(&strict).len();
        let log = std::fs::read_to_string(strict.join(".tessera-resume/log")).unwrap_or_default();
        assert!(left == 0 || !log.is_empty(), "tiles left without a journal");
        // Tiles of journaled cells (a split cell's leaves committed before its last leaf
        // finished are not: they are redone).
        let journaled: u64 = log
            .lines()
            .map(|l| serde_json::from_str::<serde_json::Value>(l).unwrap())
            .filter_map(|e| e["tiles"].as_array().map(|t| t.len() as u64))
            .sum();
        let mut args = base.to_vec();
        args.push("--keep-going");
        let o = run(&input, &strict, &args);
        assert_eq!(o.status.code(), Some(3), "{name}: {}", stderr(&o));
        assert_eq!(
            summary(&strict)["tiles_reused"].as_u64().unwrap(),
            journaled
        );

        let out = d.path().join(name);
        let o = run(&input, &out, &args);
        let err = stderr(&o);
        assert_eq!(o.status.code(), Some(3), "{name}: {err}");
        assert!(err.contains("failed tile(s)"), "{err}");
        let s = summary(&out);
        let failed = s["failed_tiles"].as_array().unwrap();
        // With stats only the wall's tile fails. With segment, split leaves near the wall
        // carry it as context (within segment.context_m) and fail too; each is listed.
        if name == "stats" {
            assert_eq!(failed.len(), 1, "{s}");
        }
        assert!(
            !failed.is_empty() && s["tiles"].as_u64().unwrap() > 0,
            "{s}"
        );
        for f in failed {
            let e = f["error"].as_str().unwrap();
            assert!(e.contains("memory budget infeasible"), "{f}");
        }
        // The wall and the grid points of the failed tiles' cores are the failed points;
        // every other point is written exactly once.
        let lost: u64 = failed.iter().map(|f| f["points"].as_u64().unwrap()).sum();
        // The wall's grid tile was split (down to the smallest size) before it failed: the
        // split is booked like any other.
        assert_eq!(s["split_tiles"].as_array().unwrap().len(), 1, "{name}: {s}");
        assert!(lost >= wall as u64, "{lost}");
        assert_eq!(s["points_in"], total);
        assert_eq!(s["points_failed"].as_u64().unwrap(), lost);
        assert_eq!(s["points_out"].as_u64().unwrap() + lost, total);
        let written: u64 = common::tiles_in(&out)
            .iter()
            .map(|t| {
                las::Reader::from_path(t)
                    .unwrap()
                    .header()
                    .number_of_points()
            })
            .sum();
        assert_eq!(written + lost, total, "{name}");
        // The resumed run ended with the same tiles as the uninterrupted one.
        let bytes = |dir: &Path| -> Vec<Vec<u8>> {
            common::tiles_in(dir)
                .iter()
                .map(|t| std::fs::read(t).unwrap())
                .collect()
        };
        assert!(
            bytes(&strict) == bytes(&out),
            "{name}: resumed tiles differ"
        );
        assert_eq!(
            common::tiles_in(&out).len(),
            s["tiles"].as_u64().unwrap() as usize
        );
    }
}

/// A stage that panics on the tile holding (5, 5): a bug in a stage, or a dependency's panic
/// on data it did not expect.
struct PanicsOnOneTile;

impl tessera::stages::Stage for PanicsOnOneTile {
    fn name(&self) -> &'static str {
        "panics"
    }
    fn bytes_per_point(&self) -> usize {
        0
    }
    fn needs_context(&self) -> bool {
        false
    }
    fn process(
        &self,
        tile: &mut tessera::model::Tile,
        _layout: &tessera::model::RecordLayout,
        _report: &mut tessera::stages::TileReport,
    ) -> tessera::Result<()> {
        if tile.core.contains(5.0, 5.0) {
            panic!("index out of bounds in a dependency");
        }
        Ok(())
    }
}

#[test]
fn a_stage_panic_fails_its_tile_not_the_process() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("grid.las");
    let total = write_scene(&input, 0);
    let stages: Vec<Box<dyn tessera::stages::Stage>> = vec![Box::new(PanicsOnOneTile)];
    let inputs = [input];

    let cfg = tessera::Config::load(None, &[]).unwrap();
    let e = tessera::pipeline::run_with_stages(
        &inputs,
        &d.path().join("strict"),
        &cfg,
        &stages,
        &|_, _| {},
    )
    .unwrap_err()
    .to_string();
    assert!(
        e.contains("stage panics") && e.contains("panicked: index out of bounds"),
        "{e}"
    );
    assert!(!d.path().join("strict/summary.json").exists());

    let cfg = tessera::Config::load(None, &["pipeline.keep_going=true".into()]).unwrap();
    let out = d.path().join("keep");
    let s = tessera::pipeline::run_with_stages(&inputs, &out, &cfg, &stages, &|_, _| {}).unwrap();
    assert_eq!(s.failed_tiles.len(), 1, "{:?}", s.failed_tiles);
    assert!(s.failed_tiles[0].error.contains("panicked"));
    assert_eq!(s.points_in, total);
    assert_eq!(s.points_out + s.points_failed, total);
    assert_eq!(
        s.points_failed, 2500,
        "the 50 m × 50 m tile at the origin holds 2,500 grid points"
    );
    assert!(s.is_incomplete());
}

/// A distributed run whose input became unreadable after planning: each task that should read
/// it leaves it out, and `tessera stitch` finishes the region with exit code 3, lists the
/// input once, and accounts for every point the tasks read.
#[test]
fn a_task_that_skips_an_input_is_accounted_for_by_the_stitch() {
    let d = tempfile::tempdir().unwrap();
    let inputs = d.path().join("in");
    std::fs::create_dir(&inputs).unwrap();
    let good = write_scene(&inputs.join("a.las"), 0);
    // b.las: the same grid 150 m further east.
    write_scene_at(&inputs.join("b.las"), 0, 150.0);
    let plan = d.path().join("plan");
    let o = tessera()
        .args(["-q", "plan", "--tasks", "2", "--out"])
        .arg(&plan)
        .arg(&inputs)
        .args([
            "--set",
            "stages.run=[\"stats\"]",
            "--set",
            "pipeline.keep_going=true",
        ])
        .output()
        .unwrap();
    assert!(o.status.success(), "plan: {}", stderr(&o));
    // b.las is cut inside its point records after planning.
    let full = std::fs::read(inputs.join("b.las")).unwrap();
    std::fs::write(inputs.join("b.las"), &full[..full.len() / 2]).unwrap();
    for task in ["0", "1"] {
        let o = tessera()
            .args(["-q", "run", "--plan"])
            .arg(&plan)
            .args(["--task", task])
            .output()
            .unwrap();
        assert!(o.status.success(), "task {task}: {}", stderr(&o));
    }
    let o = tessera()
        .args(["-q", "stitch"])
        .arg(&plan)
        .output()
        .unwrap();
    let err = stderr(&o);
    assert_eq!(o.status.code(), Some(3), "{err}");
    let s = summary(&plan);
    let skipped = s["skipped_inputs"].as_array().unwrap();
    assert_eq!(skipped.len(), 1, "{s}");
    assert!(skipped[0]["path"].as_str().unwrap().ends_with("b.las"));
    assert_eq!(s["points_in"], good, "{s}");
    assert_eq!(s["points_out"], good, "{s}");
    assert!(!common::tiles_in(&plan).is_empty());
}
