//! SemanticKITTI ground segmentation (Patchwork++ protocol: ground = {9, 10, 11, 12, 17},
//! vegetation 15 excluded), mobile-mapping parameters. Gate: F1 ≥ 97 % on each kitti_01 frame.

mod common;

use tessera::eval::ground::precision_recall_f1;
use tessera::ground::{classify_ground, GroundClass, GroundParams};

fn score(points: &str, labels: &str) -> Option<(usize, tessera::eval::ground::BinaryScores)> {
    let dir = "semantickitti-open3dml";
    let pf = common::data_file(&format!("{dir}/{points}"))?;
    let lf = common::data_file(&format!("{dir}/{labels}"))?;
    let xyz = common::read_npy_points(&pf).unwrap_or_else(|e| panic!("{e}"));
    let labels = common::read_npy_labels(&lf).unwrap_or_else(|e| panic!("{e}"));
    assert_eq!(xyz.len(), labels.len());
    let out = classify_ground(&xyz, &GroundParams::mobile()).unwrap_or_else(|e| panic!("{e}"));
    let result: Vec<bool> = out.iter().map(|c| *c == GroundClass::Ground).collect();
    let reference: Vec<bool> = labels.iter().map(|&l| common::kitti_is_ground(l)).collect();
    let scored: Vec<bool> = labels
        .iter()
        .map(|&l| l != common::KITTI_VEGETATION)
        .collect();
    Some((
        xyz.len(),
        precision_recall_f1(&reference, &result, Some(&scored)),
    ))
}

#[test]
fn kitti_frames_meet_gate() {
    println!("params: {:?}", GroundParams::mobile());
    let mut failures = Vec::new();
    for f in 0..3 {
        let Some((n, s)) = score(
            &format!("kitti_01_points_{f:06}.npy"),
            &format!("kitti_01_labels_{f:06}.npy"),
        ) else {
            return;
        };
        println!(
            "kitti_01 frame {f}: {n} points  P {:.2} %  R {:.2} %  F1 {:.2} %",
            s.precision, s.recall, s.f1
        );
        if s.f1 < 97.0 {
            failures.push((f, s.f1));
        }
    }
    if let Some((n, s)) = score("points_000700.npy", "labels_000700.npy") {
        println!(
            "frame 700 (information): {n} points  P {:.2} %  R {:.2} %  F1 {:.2} %",
            s.precision, s.recall, s.f1
        );
    }
    assert!(failures.is_empty(), "F1 below 97 %: {failures:?}");
}
