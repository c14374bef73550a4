//! Multi-cue segmentation in the pipeline (issue 22): a simulated drive (`synth --mcap`, 16
//! rings × 512 columns, truth per point) run with `segment.method = "multicue"` — every scan
//! segmented while decoded, the scans' segments tied into world segments per tile and stitched
//! across tiles — and with region growing on the same drive, scored side by side.

use std::path::Path;
use tessera::synth::drive::write_drive;
use tessera::synth::lidar::LidarParams;
use tessera::synth::scene::truth;
use tessera::synth::SceneParams;

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

fn run(input: &Path, out: &Path, sets: &[&str]) -> tessera::report::Summary {
    let mut all: Vec<String> = vec!["stages.run=[\"ground\", \"segment\", \"stats\"]".into()];
    all.extend(sets.iter().map(|s| s.to_string()));
    let cfg = tessera::Config::load(None, &all).unwrap();
    tessera::pipeline::run(&[input.to_path_buf()], out, &cfg, &|_, _| {}).unwrap()
}

/// Thesis counts against the truth segments of `classes`, at 0.51 and 0.8.
fn score(out: &Path, classes: &[u8]) -> tessera::eval::segments::SegEval {
    let o = tessera::eval::SegEvalOptions {
        ref_field: "gt_segment".into(),
        res_field: "segment_id".into(),
        restrict: Some((
            "gt_class".into(),
            classes.iter().map(|&c| u32::from(c)).collect(),
        )),
        ids_per_file: false,
        precision_m: 0.001,
        allow_unmatched: false,
        tolerances: vec![0.51, 0.8],
    };
    tessera::eval::eval_segments(out, out, &o).unwrap()
}

/// Per point of the output (in a fixed order): the segment id.
fn segment_ids(out: &Path) -> Vec<(i64, i64, i64, u32)> {
    let f = tessera::eval::load_fields(out, 0.001, &["segment_id"]).unwrap();
    let mut v: Vec<(i64, i64, i64, u32)> = f
        .xyz
        .iter()
        .zip(&f.values[0])
        .map(|(p, &s)| {
            let q = |c: f64| (c * 1000.0).round() as i64;
            (q(p[0]), q(p[1]), q(p[2]), s)
        })
        .collect();
    v.sort_unstable();
    v
}

#[test]
fn multicue_drive_segments_every_scan_and_ties_them_into_world_segments() {
    let tmp = tempfile::tempdir().unwrap();
    let p = drive(60.0);
    write_drive(&p, tmp.path()).unwrap();
    let mcap = tmp.path().join("drive.mcap");
    let (rg, mc) = (tmp.path().join("rg"), tmp.path().join("mc"));
    run(&mcap, &rg, &[]);
    let s = run(&mcap, &mc, &["segment.method=\"multicue\""]);
    let r = &s.mcap[0];
    assert_eq!(r.scans_segmented, r.clouds_used, "{r:?}");
    assert_eq!(r.scans_unsegmented, 0);
    assert!(r.scan_segments > 10 * r.scans_segmented, "{r:?}");
    assert!(r.extra_fields.iter().all(|f| f != "scan_segment"));
    // World segments: far fewer than the scans' segments (ties along the drive).
    let world = score(&mc, &[truth::VEHICLE, truth::POLE, truth::BUILDING]);
    eprintln!(
        "{} scans, {} scan segments; world segments on vehicles, poles, buildings:",
        r.scans_segmented, r.scan_segments
    );
    eprint!("{}", world.table());
    assert!((world.result_segments as u64) * 5 < r.scan_segments);
    // Side by side with region growing, per kind of object. Issue 22 asks for multicue at least
    // as good as region growing in correct segments and under-segmentation. Since the world
    // segments are refined on the drive's points together (`segment.tie.refine_voxel_m`,
    // 2026-11-28) it has more correct segments on this 16-ring drive (buildings 99 vs 53,
    // vehicles and poles 6 vs 2 at 0.8; before: 4 and 0), and since the refinement's last
    // rules (`split_apart`, `split_colours`, `attach_grows`, 2026-11-28) no more
    // under-segmentations (0 vs 0; buildings were 1 vs 0): both are gates.
    for (name, classes) in [
        ("vehicles and poles", &[truth::VEHICLE, truth::POLE][..]),
        ("buildings", &[truth::BUILDING][..]),
    ] {
        let (a, b) = (score(&rg, classes), score(&mc, classes));
        eprint!(
            "{name}, region growing:\n{}{name}, multicue:\n{}",
            a.table(),
            b.table()
        );
        let at = |e: &tessera::eval::segments::SegEval| {
            let r = e
                .rows
                .iter()
                .find(|r| (r.tolerance - 0.8).abs() < 1e-9)
                .expect("row at 0.8");
            (r.correct, r.under)
        };
        let ((rg_correct, rg_under), (mc_correct, mc_under)) = (at(&a), at(&b));
        assert!(
            mc_correct >= rg_correct,
            "{name}: multicue {mc_correct} correct world segments at 0.8, region growing {rg_correct}"
        );
        assert!(
            mc_under <= rg_under,
            "{name}: multicue {mc_under} under-segmented world segments at 0.8, region growing {rg_under}"
        );
    }
}

#[test]
fn multicue_output_does_not_depend_on_the_thread_count() {
    let tmp = tempfile::tempdir().unwrap();
    write_drive(&drive(30.0), tmp.path()).unwrap();
    let mcap = tmp.path().join("drive.mcap");
    let (a, b) = (tmp.path().join("t1"), tmp.path().join("t2"));
    run(
        &mcap,
        &a,
        &["segment.method=\"multicue\"", "pipeline.threads=1"],
    );
    run(
        &mcap,
        &b,
        &["segment.method=\"multicue\"", "pipeline.threads=2"],
    );
    let (ia, ib) = (segment_ids(&a), segment_ids(&b));
    assert_eq!(ia.len(), ib.len());
    assert!(ia.iter().any(|v| v.3 != 0));
    assert!(ia == ib, "segment ids differ between 1 and 2 threads");
}

#[test]
fn multicue_on_las_input_is_refused_clearly() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene");
    let params = SceneParams {
        length_m: 20.0,
        ..Default::default()
    };
    tessera::synth::write_scene(&params, &scene, 50.0).unwrap();
    let cfg = tessera::Config::load(None, &["segment.method=\"multicue\"".into()]).unwrap();
    let e = tessera::pipeline::run(&[scene], &tmp.path().join("out"), &cfg, &|_, _| {})
        .unwrap_err()
        .to_string();
    assert!(e.contains("multicue") && e.contains("is not one"), "{e}");
    assert!(!tmp.path().join("out").join("summary.json").exists());
}
