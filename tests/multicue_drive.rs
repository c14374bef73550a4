//! Multi-cue segmentation in the pipeline (issue 22): a simulated drive (`synth --mcap`, 16
//! rings × 512 columns, truth per point) run with `segment.method = "multicue"` — every scan
//! segmented while decoded, the scans' segments tied into world segments per tile and stitched
//! across tiles — and with region growing on the same drive, scored side by side; and the
//! per-scan segmentation against each cue alone and region growing on the benchmark's drive.

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

/// Thesis counts at tolerance 0.8 summed over scans: correct, under.
#[derive(Default, Debug)]
struct PerScan {
    correct: usize,
    under: usize,
}

impl PerScan {
    fn add(&mut self, truth: &[u32], labels: &[u32]) {
        let e = tessera::eval::segments::evaluate(truth, labels, None, &[0.8]);
        self.correct += e.rows[0].correct;
        self.under += e.rows[0].under;
    }
}

/// Issue 22's per-scan gate, on the benchmark's drive (32 rings × 1,024 columns, 60 m, seed 7:
/// the scans `cargo bench --bench multicue` scores from the MCAP file, here simulated in
/// memory): thesis counts at tolerance 0.8 summed over the scans, reference segments with
/// fewer than `min_points` returns in a scan left out. The integration finds more correct
/// segments than each cue alone and than region growing on the same returns, and
/// under-segments no more than region growing (2026-11-29: 1,227 correct and 3 under;
/// colour alone 1,086; region growing 901 and 3).
#[test]
fn per_scan_integration_beats_each_cue_and_region_growing() {
    use tessera::segment::features::{rgb_to_lab, LabFormula};
    use tessera::segment::multicue::{
        segment_scan, without_small_segments, MulticueParams, Order, RangeImage,
    };
    let p = LidarParams {
        scene: SceneParams {
            seed: 7,
            length_m: 60.0,
            ..Default::default()
        },
        ..Default::default()
    };
    let (rows, cols) = (p.rings as usize, p.columns as usize);
    let mp = MulticueParams::default();
    let sp = tessera::segment::SegParams::default();
    let (mut integrated, mut region) = (PerScan::default(), PerScan::default());
    let mut cues: Vec<PerScan> = Vec::new();
    for k in 0..p.revolutions() {
        let rev = tessera::synth::lidar::simulate_revolution(&p, k);
        let nan = [f32::NAN; 3];
        let xyz: Vec<[f32; 3]> = rev
            .beams
            .iter()
            .map(|b| b.map_or(nan, |r| r.sensor))
            .collect();
        let rgb: Vec<[u8; 3]> = rev
            .beams
            .iter()
            .map(|b| b.map_or([0; 3], |r| r.rgb))
            .collect();
        let lab: Vec<[f32; 3]> = rgb
            .iter()
            .map(|c| rgb_to_lab(c.map(|v| v as f64 / 255.0), LabFormula::Srgb).map(|v| v as f32))
            .collect();
        let img = RangeImage::organised(rows, cols, &xyz, Some(&lab), Order::RowMajor).unwrap();
        let seg = segment_scan(&img, &mp);
        // The returns in the image, and their reference segments without the small ones.
        let in_image = img.to_points(&vec![1; img.len()], xyz.len());
        let idx: Vec<usize> = (0..xyz.len()).filter(|&i| in_image[i] == 1).collect();
        let mut truth: Vec<u32> = idx.iter().map(|&i| rev.beams[i].unwrap().segment).collect();
        without_small_segments(&mut truth, mp.min_points);
        let pick = |l: &[u32]| -> Vec<u32> { idx.iter().map(|&i| l[i]).collect() };
        integrated.add(&truth, &pick(&seg.point_labels(&img, xyz.len())));
        let single = seg.cue_point_labels(&img, xyz.len(), mp.min_points);
        cues.resize_with(single.len(), PerScan::default);
        for (c, labels) in cues.iter_mut().zip(&single) {
            c.add(&truth, &pick(labels));
        }
        let pts: Vec<[f64; 3]> = idx.iter().map(|&i| xyz[i].map(f64::from)).collect();
        let rgb16: Vec<[u16; 3]> = idx.iter().map(|&i| rgb[i].map(u16::from)).collect();
        let rg = tessera::segment::segment_at(&pts, Some(&rgb16), None, &sp, Some([0.0; 3]))
            .expect("region growing");
        region.add(&truth, &rg.labels);
    }
    println!("per scan: integrated {integrated:?}, cues {cues:?}, region growing {region:?}");
    assert_eq!(cues.len(), 3, "range, normals and colour");
    for c in &cues {
        assert!(
            integrated.correct > c.correct,
            "a single cue did as well: {c:?}"
        );
    }
    assert!(
        integrated.correct >= region.correct && integrated.under <= region.under,
        "integrated {integrated:?} against region growing {region:?}"
    );
}
