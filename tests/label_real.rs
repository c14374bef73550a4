//! Labelling on real airborne tiles (issue 5): building F1 against the producers' classes.
//! AHN (Amsterdam, no colour) is the gate: building F1 ≥ 0.85 on both tiles. The IGN LiDAR HD
//! crop's reference leaves a ~38 × 26 m block unclassified (class 1, even the ground), with an
//! ~18 × 18 m hipped-roof house in it that the rules call building: scored on the whole crop
//! those points cap building F1 at 0.833 for any classifier that labels the house. The block
//! is the void polygon `tests/ign_void.geojson` (issue 25), left out of scoring with
//! `eval labels --exclude`; both scores are printed, the whole-crop one held as a regression
//! floor.
//!
//! The trained classifier (issue 25): a model trained by the library behind `tessera train`
//! on one AHN tile labels the other (both ways), and a model trained on both AHN tiles labels
//! the IGN crop (another producer, another country): building F1 ≥ 0.92 on each AHN tile
//! and ≥ 0.90 on IGN with the void excluded. No model is trained on the tile it is scored on.

mod common;

use std::path::Path;
use tessera::eval::{eval_labels, LabelEvalOptions};
use tessera::Config;

fn run_and_score(input: &Path, extra: &[&str]) -> tessera::eval::labels::LabelEval {
    run_and_score_excluding(input, extra, &[]).remove(0)
}

/// Runs the pipeline once and scores it with each of `excludes` (the first score with none).
fn run_and_score_excluding(
    input: &Path,
    extra: &[&str],
    excludes: &[tessera::eval::polygons::Polygons],
) -> Vec<tessera::eval::labels::LabelEval> {
    let tmp = tempfile::tempdir().unwrap();
    let mut set: Vec<String> =
        vec!["stages.run=[\"ground\",\"segment\",\"label\",\"stats\"]".into()];
    set.extend(extra.iter().map(|s| s.to_string()));
    let airborne = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/airborne.toml");
    let cfg = Config::load(Some(&airborne), &set).unwrap();
    tessera::pipeline::run(&[input.to_path_buf()], tmp.path(), &cfg, &|_, _| {}).unwrap();
    std::iter::once(Default::default())
        .chain(excludes.iter().cloned())
        .map(|exclude| {
            let e = eval_labels(
                input,
                tmp.path(),
                &LabelEvalOptions {
                    ref_field: "classification".into(),
                    res_field: "classification".into(),
                    classes: vec![1, 2, 6],
                    map: vec![(2, vec![11, 64, 65, 66, 67])],
                    precision_m: 0.001,
                    allow_unmatched: false,
                    x_range: None,
                    exclude,
                    ref_map: None,
                },
            )
            .unwrap();
            println!("{}:\n{}", input.display(), e.table());
            e
        })
        .collect()
}

#[test]
fn ahn_building_f1() {
    for name in ["ahn_2386_9702.laz", "ahn_2397_9705.laz"] {
        let Some(f) = common::data_file(&format!("ahn-amsterdam/{name}")) else {
            return;
        };
        // Point format 1 cannot hold the user codes (pole 69, vehicle 70): write format 6.
        let e = run_and_score(&f, &["output.point_format=6"]);
        let b = e.row(6).unwrap();
        println!(
            "{name}: building F1 {:.3}, ground F1 {:.3}",
            b.f1,
            e.row(2).unwrap().f1
        );
        assert!(b.f1 >= 0.85, "{name}: building F1 {:.3} < 0.85", b.f1);
    }
}

/// Trains a model with the airborne configuration on `inputs` (reference: the producer's
/// classes through config/asprs.toml), writes it into `dir`, returns its path.
fn train_airborne(inputs: &[std::path::PathBuf], dir: &Path) -> std::path::PathBuf {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let cfg = Config::load(
        Some(&root.join("config/airborne.toml")),
        &["stages.run=[\"ground\",\"segment\",\"label\",\"stats\"]".into()],
    )
    .unwrap();
    let map = tessera::label::model::ClassMap::load(&root.join("config/asprs.toml")).unwrap();
    let (model, _) = tessera::pipeline::train::train(inputs, &[map], &cfg, dir).unwrap();
    let path = dir.join(format!("model{}.json", inputs.len()));
    model.save(&path).unwrap();
    // Only the model is left behind in the scratch directory.
    let left: Vec<_> = std::fs::read_dir(dir).unwrap().collect();
    assert_eq!(left.len(), 1, "{left:?}");
    path
}

#[test]
fn trained_model_building_f1_on_tiles_it_was_not_trained_on() {
    let ahn = ["ahn_2386_9702.laz", "ahn_2397_9705.laz"]
        .map(|n| common::data_file(&format!("ahn-amsterdam/{n}")));
    let ign = common::data_file("ign-lidarhd/870000_6618000.subset.50mx100m.las");
    let (Some(a0), Some(a1), Some(ign)) = (ahn[0].clone(), ahn[1].clone(), ign) else {
        return;
    };
    let void = tessera::eval::polygons::Polygons::from_geojson(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ign_void.geojson"),
    )
    .unwrap();
    let mut failures = Vec::new();
    for (train_on, score_on) in [(&a0, &a1), (&a1, &a0)] {
        let dir = tempfile::tempdir().unwrap();
        let model = train_airborne(std::slice::from_ref(train_on), dir.path());
        let set = format!("label.model={:?}", model.display().to_string());
        let e = run_and_score(score_on, &["output.point_format=6", &set]);
        let b = e.row(6).unwrap();
        println!(
            "model trained on {} -> {}: building F1 {:.3} (precision {:.3}, recall {:.3}), ground F1 {:.3}",
            train_on.file_name().unwrap().to_string_lossy(),
            score_on.file_name().unwrap().to_string_lossy(),
            b.f1,
            b.precision,
            b.recall,
            e.row(2).unwrap().f1
        );
        if b.f1 < 0.92 {
            failures.push(format!(
                "{}: building F1 {:.3} < 0.92",
                score_on.display(),
                b.f1
            ));
        }
    }
    let dir = tempfile::tempdir().unwrap();
    let model = train_airborne(&[a0.clone(), a1.clone()], dir.path());
    let set = format!("label.model={:?}", model.display().to_string());
    let scores = run_and_score_excluding(&ign, &[&set], &[void]);
    let (w, v) = (scores[0].row(6).unwrap(), scores[1].row(6).unwrap());
    println!(
        "model trained on both AHN tiles -> IGN: building F1 {:.3} (whole crop), {:.3} with the void excluded (precision {:.3}, recall {:.3})",
        w.f1, v.f1, v.precision, v.recall
    );
    if v.f1 < 0.90 {
        failures.push(format!(
            "IGN (void excluded): building F1 {:.3} < 0.90",
            v.f1
        ));
    }
    assert!(failures.is_empty(), "{failures:?}");
}

#[test]
fn ign_building_and_ground_f1() {
    let Some(f) = common::data_file("ign-lidarhd/870000_6618000.subset.50mx100m.las") else {
        return;
    };
    let void = tessera::eval::polygons::Polygons::from_geojson(
        &Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ign_void.geojson"),
    )
    .unwrap();
    let scores = run_and_score_excluding(&f, &[], &[void]);
    let (e, v) = (&scores[0], &scores[1]);
    let (b, g) = (e.row(6).unwrap(), e.row(2).unwrap());
    println!(
        "IGN: building F1 {:.3} (precision {:.3}, recall {:.3}), ground F1 {:.3}",
        b.f1, b.precision, b.recall, g.f1
    );
    let (vb, vg) = (v.row(6).unwrap(), v.row(2).unwrap());
    println!(
        "IGN, void excluded ({} of {} points scored): building F1 {:.3} (precision {:.3}, recall {:.3}), ground F1 {:.3}",
        v.points, e.points, vb.f1, vb.precision, vb.recall, vg.f1
    );
    // The void holds the unclassified house and its ground: leaving it out must remove
    // reference class 1 points only, and lift building precision.
    assert!(v.points < e.points);
    assert!(
        vb.precision > b.precision,
        "{:.3} vs {:.3}",
        vb.precision,
        b.precision
    );
    // Regression floor of the rules (0.893); issue 25's gate (≥ 0.90 with the void excluded)
    // is met by the trained model (`trained_model_building_f1_on_tiles_it_was_not_trained_on`).
    assert!(
        vb.f1 >= 0.88,
        "void-excluded building F1 {:.3} fell below the measured 0.893",
        vb.f1
    );

    // The command line: the same exclusion, and a bad polygon file is an error naming it.
    let void_file = Path::new(env!("CARGO_MANIFEST_DIR")).join("tests/ign_void.geojson");
    let eval = |extra: &[&std::ffi::OsStr]| {
        std::process::Command::new(env!("CARGO_BIN_EXE_tessera"))
            .args(["eval", "labels", "--json", "--reference"])
            .arg(&f)
            .arg("--result")
            .arg(&f)
            .args(extra)
            .output()
            .unwrap()
    };
    let points = |o: &std::process::Output| -> u64 {
        assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
        let v: serde_json::Value = serde_json::from_slice(&o.stdout).unwrap();
        v["points"].as_u64().unwrap()
    };
    let all = points(&eval(&[]));
    let kept = points(&eval(&["--exclude".as_ref(), void_file.as_os_str()]));
    assert_eq!((all, kept), (e.points, v.points));
    let bad = tempfile::NamedTempFile::new().unwrap();
    std::fs::write(bad.path(), r#"{"type":"Point","coordinates":[1,2]}"#).unwrap();
    let o = eval(&["--exclude".as_ref(), bad.path().as_os_str()]);
    assert!(!o.status.success());
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(
        err.contains(&*bad.path().to_string_lossy()) && err.contains("Point"),
        "{err}"
    );
    assert!(b.recall >= 0.85, "building recall {:.3}", b.recall);
    assert!(
        b.f1 >= 0.70,
        "building F1 {:.3} fell below the measured 0.72",
        b.f1
    );
}
