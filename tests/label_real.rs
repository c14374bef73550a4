//! Labelling on real airborne tiles (issue 5): building F1 against the producers' classes.
//! AHN (Amsterdam, no colour) is the gate: building F1 ≥ 0.85 on both tiles. The IGN LiDAR HD
//! crop is reported; its reference leaves a ~35 × 25 m block unclassified (class 1, even the
//! ground), with an ~18 × 18 m hipped-roof house in it that the rules call building: those
//! 2,770 points cap building F1 at 0.833 for any classifier that labels the house, so the
//! 0.85 gate cannot be met on this reference. The test holds the measured level as a
//! regression floor and prints the figures.

mod common;

use std::path::Path;
use tessera::eval::{eval_labels, LabelEvalOptions};
use tessera::Config;

fn run_and_score(input: &Path, extra: &[&str]) -> tessera::eval::labels::LabelEval {
    let tmp = tempfile::tempdir().unwrap();
    let mut set: Vec<String> =
        vec!["stages.run=[\"ground\",\"segment\",\"label\",\"stats\"]".into()];
    set.extend(extra.iter().map(|s| s.to_string()));
    let airborne = Path::new(env!("CARGO_MANIFEST_DIR")).join("config/airborne.toml");
    let cfg = Config::load(Some(&airborne), &set).unwrap();
    tessera::pipeline::run(&[input.to_path_buf()], tmp.path(), &cfg, &|_, _| {}).unwrap();
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
        },
    )
    .unwrap();
    println!("{}:\n{}", input.display(), e.table());
    e
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

#[test]
fn ign_building_and_ground_f1() {
    let Some(f) = common::data_file("ign-lidarhd/870000_6618000.subset.50mx100m.las") else {
        return;
    };
    let e = run_and_score(&f, &[]);
    let (b, g) = (e.row(6).unwrap(), e.row(2).unwrap());
    println!(
        "IGN: building F1 {:.3} (precision {:.3}, recall {:.3}), ground F1 {:.3}",
        b.f1, b.precision, b.recall, g.f1
    );
    assert!(b.recall >= 0.85, "building recall {:.3}", b.recall);
    assert!(
        b.f1 >= 0.70,
        "building F1 {:.3} fell below the measured 0.72",
        b.f1
    );
}
