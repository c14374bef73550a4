//! Gate: a simulated drive (`synth --mcap`: spinning LiDAR ray-cast against the synthetic
//! street, ROS 2 MCAP with PointCloud2 + /tf) decodes and georeferences to the truth positions
//! of its returns within 1 mm, and the whole pipeline's ground and segment results are scored
//! against the scene's truth classes and segments carried by every point.

mod common;
mod mcap_common;

use mcap_common::*;
use std::path::Path;
use tessera::synth::drive::write_drive;
use tessera::synth::lidar::{simulate_revolution, LidarParams};
use tessera::synth::scene::truth;
use tessera::synth::{SceneParams, WORLD_OFFSET};

fn drive(length_m: f64) -> LidarParams {
    LidarParams {
        scene: SceneParams {
            seed: 7,
            length_m,
            ..Default::default()
        },
        rings: 16,
        columns: 512,
        ..Default::default()
    }
}

/// Truth world positions, classes and segments of every return, in cloud order.
fn truth_returns(p: &LidarParams) -> Vec<([f64; 3], u8, u32)> {
    let mut v = Vec::new();
    for k in 0..p.revolutions() {
        for r in simulate_revolution(p, k).beams.iter().flatten() {
            let w = [
                r.world[0] + WORLD_OFFSET[0],
                r.world[1] + WORLD_OFFSET[1],
                r.world[2] + WORLD_OFFSET[2],
            ];
            v.push((w, r.class, r.segment));
        }
    }
    v
}

fn errors(pts: &[LasPoint], want: &[([f64; 3], u8, u32)]) -> (f64, f64) {
    assert_eq!(pts.len(), want.len(), "point count");
    let mut e: Vec<f64> = pts
        .iter()
        .zip(want)
        .map(|(p, (w, _, _))| {
            ((p.xyz[0] - w[0]).powi(2) + (p.xyz[1] - w[1]).powi(2) + (p.xyz[2] - w[2]).powi(2))
                .sqrt()
        })
        .collect();
    e.sort_by(f64::total_cmp);
    (e[e.len() / 2], e[e.len() - 1])
}

#[test]
fn simulated_drive_georeferences_to_the_truth_within_a_millimetre() {
    let tmp = tempfile::tempdir().unwrap();
    let p = drive(30.0);
    let stats = write_drive(&p, tmp.path()).unwrap();
    let mcap = tmp.path().join("drive.mcap");
    let want = truth_returns(&p);
    assert_eq!(stats.points, want.len() as u64);
    assert_eq!(stats.clouds, p.revolutions());
    let conv = |sets: &[&str]| {
        let work = tempfile::tempdir_in(tmp.path()).unwrap();
        let c = tessera::io::mcap::convert_file(&mcap, work.path(), &params(sets)).unwrap();
        let (pts, fields) = read_parts(&c.parts);
        (pts, fields, c.report)
    };
    let base = ["mcap.min_range_m=0.0", "mcap.scale_m=0.00001"];
    let (pts, fields, rep) = conv(&base);
    let (median, max) = errors(&pts, &want);
    eprintln!(
        "drive: {} points, georeferencing error median {median:.2e} m, max {max:.2e} m",
        pts.len()
    );
    assert!(max < 1e-3, "max error {max} m");
    assert_eq!(rep.clouds_deskewed, stats.clouds);
    assert_eq!(rep.points_nan, stats.beams - stats.points);
    // Truth fields travel as extra bytes, in order.
    for (q, (_, class, seg)) in pts.iter().zip(&want) {
        assert_eq!(extra_value(q, &fields, "gt_class"), *class as f64);
        assert_eq!(extra_value(q, &fields, "gt_segment"), *seg as f64);
    }
    // Without de-skewing, the ~0.8 m the vehicle moves per revolution shows.
    let (pts2, _, _) = conv(&[base[0], base[1], "mcap.deskew=false"]);
    let (_, max2) = errors(&pts2, &want);
    assert!(max2 > 0.3, "without de-skew the max error is only {max2} m");
}

/// Ground classes of the scene (ASPRS 11 road and the user codes of the ground layout).
fn is_ground_truth(c: u32) -> bool {
    [
        truth::ROAD,
        truth::LANE_MARKING,
        truth::KERB,
        truth::CYCLE_PATH,
        truth::FOOTPATH,
        truth::GRASS,
    ]
    .contains(&(c as u8))
}

#[test]
fn simulated_drive_through_the_pipeline_is_scored_against_the_truth() {
    let tmp = tempfile::tempdir().unwrap();
    let p = drive(60.0);
    let stats = write_drive(&p, tmp.path()).unwrap();
    let out = tmp.path().join("out");
    let cfg = tessera::Config::load(
        None,
        &["stages.run=[\"ground\", \"segment\", \"stats\"]".into()],
    )
    .unwrap();
    let s =
        tessera::pipeline::run(&[tmp.path().join("drive.mcap")], &out, &cfg, &|_, _| {}).unwrap();
    let r = &s.mcap[0];
    // Every return is processed: the 0.5 m minimum range drops nothing on this drive.
    assert_eq!(r.points_written, stats.points);
    assert_eq!(r.points_near, 0);
    assert_eq!(s.points_out, stats.points);
    // Ground: Type I / II, total error and kappa against the truth classes.
    let f = tessera::eval::load_fields(&out, 0.001, &["gt_class", "classification"]).unwrap();
    let want: Vec<bool> = f.values[0].iter().map(|&c| is_ground_truth(c)).collect();
    let got: Vec<bool> = f.values[1].iter().map(|&c| c == 2).collect();
    let g = tessera::eval::ground::score_ground(&want, &got);
    eprintln!(
        "drive ground: Type I {:.2} %, Type II {:.2} %, total {:.2} %, kappa {:.2} % over {} points",
        g.type1,
        g.type2,
        g.total,
        g.kappa,
        want.len()
    );
    assert!(g.total < 3.0 && g.kappa > 93.0, "{g:?}");
    // Segments: Hoover/Sapkota counts against the truth segments (thesis tolerances).
    let o = tessera::eval::SegEvalOptions {
        ref_field: "gt_segment".into(),
        res_field: "segment_id".into(),
        restrict: Some(("gt_class".into(), vec![u32::from(truth::BUILDING)])),
        ids_per_file: true,
        precision_m: 0.001,
        allow_unmatched: false,
        tolerances: vec![0.51, 0.8],
    };
    let e = tessera::eval::eval_segments(&out, &out, &o).unwrap();
    eprint!("drive facade segments:\n{}", e.table());
    let row = &e.rows[0];
    let big = big_building_segments(&out);
    eprintln!("{big} building segments with >= 200 points");
    assert!(
        row.correct * 2 >= big,
        "{} correct facade/window/door segments at 0.51, {big} segments with >= 200 points",
        row.correct
    );
    report_to(&out.join("summary.json"));
}

/// Building segments with at least 200 points (the ones a planar region grower can find).
fn big_building_segments(out: &Path) -> usize {
    let f = tessera::eval::load_fields(out, 0.001, &["gt_class", "gt_segment"]).unwrap();
    let mut n = std::collections::HashMap::new();
    for (c, s) in f.values[0].iter().zip(&f.values[1]) {
        if *c == u32::from(truth::BUILDING) {
            *n.entry(*s).or_insert(0usize) += 1;
        }
    }
    n.values().filter(|&&k| k >= 200).count()
}

fn report_to(summary: &Path) {
    let j: serde_json::Value = serde_json::from_slice(&std::fs::read(summary).unwrap()).unwrap();
    assert!(j["mcap"][0]["points_written"].as_u64().unwrap() > 0);
}

#[test]
fn placing_clouds_in_parallel_keeps_the_output_identical() {
    let tmp = tempfile::tempdir().unwrap();
    let p = drive(12.0);
    write_drive(&p, tmp.path()).unwrap();
    let mcap = tmp.path().join("drive.mcap");
    let files = |threads: usize| {
        let work = tmp.path().join(format!("t{threads}"));
        let c = tessera::io::mcap::convert_file_with(&mcap, &work, &params(&[]), threads).unwrap();
        c.parts
            .iter()
            .map(|f| std::fs::read(f).unwrap())
            .collect::<Vec<_>>()
    };
    let one = files(1);
    assert!(!one.is_empty());
    // LAS headers carry no creation time that differs between runs of the same day; compare
    // the whole files.
    assert!(one == files(3), "3 workers wrote different parts than 1");
}
