//! SemanticKITTI (no colour): road vs sidewalk vs terrain from geometry alone — kerbs and
//! roughness (`label.ground.geometry`, src/label/kerbs.rs) — reported as information (issue 5).
//! Ground by the mobile-mapping ground filter, then the labelling stage's ground steps with the
//! geometry rule; scored on the points whose SemanticKITTI class is road (9), sidewalk (11) or
//! terrain (17), with mapping accuracy as in the street-level document's Table 14.
//!
//! The assertion only checks that the scoring ran and that road, the class the rule anchors
//! on, is found (measured 42–53 % mapping accuracy); the figures are for the README. Geometry
//! alone is weak here: the highway frames have no kerb between road and verge, and a 64-beam
//! scan's rings are too far apart to see most kerbs of frame 700.

mod common;

use tessera::ground::{classify_ground, GroundClass, GroundParams};
use tessera::label::ground::smooth_labels;
use tessera::label::kerbs::{classify_by_kerbs, KerbRule};
use tessera::label::{label_ground, GroundLabelParams};
use tessera::segment::features::normals;
use tessera::segment::neighbours::knn_surface;

const ROAD: u8 = 11;
const SIDEWALK: u8 = 65;
const TERRAIN: u8 = 67;

/// Geometry-mode parameters for a 64-beam scan: rings lie 0.2–1 m apart on the road, so the
/// neighbourhood is wider than the street-scene default (0.35 m) and the step limit sits just
/// below a kerb's height. Surface variation at 1 m: road median 0.0001 (p90 0.0024), terrain
/// median 0.0014 (p90 0.016) on kitti_01 frame 0, hence the 0.003 thresholds (of 0.001, 0.002,
/// 0.003, 0.005 tried, the best mean over the four frames).
fn params() -> GroundLabelParams {
    GroundLabelParams {
        k: 16,
        radius_m: 1.0,
        curvature: 0.003,
        max_step_m: 0.06,
        geometry: true,
        rough_variation: 0.003,
        geometry_codes: [ROAD, SIDEWALK, TERRAIN],
        ..Default::default()
    }
}

fn frame(points: &str, labels: &str) -> Option<tessera::eval::labels::LabelEval> {
    let dir = "semantickitti-open3dml";
    let pf = common::data_file(&format!("{dir}/{points}"))?;
    let lf = common::data_file(&format!("{dir}/{labels}"))?;
    let xyz = common::read_npy_points(&pf).unwrap();
    let labels = common::read_npy_labels(&lf).unwrap();
    let ground = classify_ground(&xyz, &GroundParams::mobile()).unwrap();
    let gidx: Vec<usize> = (0..xyz.len())
        .filter(|&i| ground[i] == GroundClass::Ground)
        .collect();
    let pts: Vec<[f64; 3]> = gidx.iter().map(|&i| xyz[i]).collect();
    let p = params();
    let nb = knn_surface(&pts, p.k, p.radius_m);
    let nrm = normals(&pts, &nb, p.radius_m);
    let gl = label_ground(&nrm, None, Some(&pts), &nb, None, 2, &p);
    let rule = KerbRule::from_params(&p, 2);
    let r2 = (p.radius_m * p.radius_m) as f32;
    let mut c = classify_by_kerbs(&pts, &nrm, &nb, r2, &gl.region, gl.regions, &rule);
    smooth_labels(&mut c, &nb, p.smooth_k);
    // Non-ground points count as predicted "other" (1).
    let mut predicted = vec![1u8; xyz.len()];
    for (k, &i) in gidx.iter().enumerate() {
        predicted[i] = c[k];
    }
    let reference: Vec<u8> = labels
        .iter()
        .map(|&l| match l {
            9 => ROAD,
            11 => SIDEWALK,
            17 => TERRAIN,
            _ => 0,
        })
        .collect();
    Some(tessera::eval::labels::evaluate(
        &reference,
        &predicted,
        &[ROAD, SIDEWALK, TERRAIN],
    ))
}

#[test]
fn kitti_road_sidewalk_terrain_from_geometry() {
    let frames = [
        (
            "kitti_01 frame 0",
            "kitti_01_points_000000.npy",
            "kitti_01_labels_000000.npy",
        ),
        (
            "kitti_01 frame 1",
            "kitti_01_points_000001.npy",
            "kitti_01_labels_000001.npy",
        ),
        (
            "kitti_01 frame 2",
            "kitti_01_points_000002.npy",
            "kitti_01_labels_000002.npy",
        ),
        (
            "frame 700 (urban)",
            "points_000700.npy",
            "labels_000700.npy",
        ),
    ];
    for (name, pts, lbl) in frames {
        let Some(e) = frame(pts, lbl) else {
            println!("SKIP: SemanticKITTI data not found");
            return;
        };
        println!(
            "{name} (11 road, 65 sidewalk, 67 terrain; geometry only):\n{}",
            e.table()
        );
        let road = e.row(ROAD).unwrap();
        assert!(
            road.reference > 0 && road.mapping_accuracy > 0.3,
            "{name}: {road:?}"
        );
    }
}

/// Writes the points of a SemanticKITTI frame with `keep(x)` as LAS 1.4 format 6, the
/// SemanticKITTI learning id as the classification (what `scripts/kitti_to_las.py` writes).
fn kitti_las(
    points: &str,
    labels: &str,
    out: &std::path::Path,
    keep: impl Fn(f64) -> bool,
) -> Option<()> {
    let dir = "semantickitti-open3dml";
    let xyz = common::read_npy_points(&common::data_file(&format!("{dir}/{points}"))?).unwrap();
    let lab = common::read_npy_labels(&common::data_file(&format!("{dir}/{labels}"))?).unwrap();
    let mut b = las::Builder::from((1, 4));
    b.point_format = las::point::Format::new(6).unwrap();
    b.transforms = las::Vector {
        x: las::Transform {
            scale: 0.001,
            offset: 0.0,
        },
        y: las::Transform {
            scale: 0.001,
            offset: 0.0,
        },
        z: las::Transform {
            scale: 0.001,
            offset: 0.0,
        },
    };
    let mut w = las::Writer::from_path(out, b.into_header().unwrap()).unwrap();
    for (p, &l) in xyz.iter().zip(&lab) {
        if keep(p[0]) {
            w.write_point(las::Point {
                x: p[0],
                y: p[1],
                z: p[2],
                return_number: 1,
                number_of_returns: 1,
                classification: las::point::Classification::new(l as u8).unwrap(),
                gps_time: Some(0.0),
                ..Default::default()
            })
            .unwrap();
        }
    }
    w.close().unwrap();
    Some(())
}

/// (reference tessera code, predicted code) of every mapped point of `reference` in the
/// run's output `result`.
fn pairs(
    reference: &std::path::Path,
    result: &std::path::Path,
    map: &tessera::label::model::ClassMap,
) -> (Vec<u8>, Vec<u8>) {
    let r = tessera::eval::load_fields(reference, 0.001, &["classification"]).unwrap();
    let s = tessera::eval::load_fields(result, 0.001, &["classification"]).unwrap();
    let m = tessera::eval::match_points(&r.keys, &s.keys, false).unwrap();
    let (mut want, mut got) = (Vec::new(), Vec::new());
    for (k, i) in m.iter().enumerate() {
        let code = map.code_of(r.values[0][k]);
        if let (Some(i), true) = (i, code != 0) {
            want.push(code);
            got.push(s.values[0][*i] as u8);
        }
    }
    (want, got)
}

/// SemanticKITTI classes without colour, the rules against a model trained on other frames
/// (issue 25). Two folds: frame 700 (urban, the only frame with buildings and sidewalks)
/// cut at x = 0 into west and east halves, and the kitti_01 highway frames 0 and 2; fold A
/// trains on {kitti_01 frame 0, 700 west} and scores {kitti_01 frame 2, 700 east}, fold B the
/// other way round. Every scored point is scored once, by a model that never saw its frame
/// half. Scores are pooled over both folds; road / sidewalk / terrain mapping accuracy on
/// frame 700's halves.
///
/// A third variant adds the cars and poles of 13 simulated single 64-beam scans to each
/// fold's training set (`tessera synth --mcap --scans-every`, config/synthetic_objects.toml).
///
/// The gates (F1 building ≥ 0.80, vegetation ≥ 0.85, vehicle ≥ 0.70, pole ≥ 0.50;
/// frame 700 road ≥ 80 %, sidewalk ≥ 60 %, terrain ≥ 70 %) are printed as met or not; the
/// assertions hold what was measured (2026-11-26) so that a change making the classifier
/// worse fails, and the trained model must beat the rules on buildings and vegetation.
#[test]
fn kitti_rules_against_a_model_trained_on_other_frames() {
    let root = std::path::Path::new(env!("CARGO_MANIFEST_DIR"));
    let tmp = tempfile::tempdir().unwrap();
    let d = tmp.path();
    let east = |x: f64| x >= 0.0;
    let west = |x: f64| x < 0.0;
    let made = [
        kitti_las(
            "points_000700.npy",
            "labels_000700.npy",
            &d.join("u700_east.las"),
            east,
        ),
        kitti_las(
            "points_000700.npy",
            "labels_000700.npy",
            &d.join("u700_west.las"),
            west,
        ),
        kitti_las(
            "kitti_01_points_000000.npy",
            "kitti_01_labels_000000.npy",
            &d.join("k01_f0.las"),
            |_| true,
        ),
        kitti_las(
            "kitti_01_points_000002.npy",
            "kitti_01_labels_000002.npy",
            &d.join("k01_f2.las"),
            |_| true,
        ),
    ];
    if made.iter().any(|m| m.is_none()) {
        println!("SKIP: SemanticKITTI data not found");
        return;
    }
    let map =
        tessera::label::model::ClassMap::load(&root.join("config/semantickitti.toml")).unwrap();
    let objects =
        tessera::label::model::ClassMap::load(&root.join("config/synthetic_objects.toml")).unwrap();
    let cfg = tessera::Config::load(Some(&root.join("config/scans_nocolour.toml")), &[]).unwrap();
    // Simulated single scans of a 64-beam scanner on a 120 m synthetic street (seed 5, every
    // 12th revolution: 12 scans), what `tessera synth --mcap --rings 64 --columns 2048
    // --length-m 120 --seed 5 --scans-every 12` writes; their cars and poles only are added
    // to each fold's training set (config/synthetic_objects.toml).
    let scans = d.join("synthetic_scans");
    let lidar = tessera::synth::lidar::LidarParams {
        scene: tessera::synth::SceneParams {
            seed: 5,
            length_m: 120.0,
            ..Default::default()
        },
        rings: 64,
        columns: 2048,
        ..Default::default()
    };
    let st = tessera::synth::write_scans(&lidar, &scans, 12).unwrap();
    assert_eq!(st.files, 13);
    let folds = [
        (
            ["k01_f0.las", "u700_west.las"],
            ["k01_f2.las", "u700_east.las"],
        ),
        (
            ["k01_f2.las", "u700_east.las"],
            ["k01_f0.las", "u700_west.las"],
        ),
    ];
    // [rules, model, model with synthetic objects] × [all scored points, frame 700 only]:
    // (reference, predicted).
    let mut pooled: [[(Vec<u8>, Vec<u8>); 2]; 3] = Default::default();
    for (k, (train, score)) in folds.iter().enumerate() {
        let fold = d.join(format!("fold{k}"));
        std::fs::create_dir_all(&fold).unwrap();
        let inputs: Vec<_> = train.iter().map(|f| d.join(f)).collect();
        let (model, _) =
            tessera::pipeline::train::train(&inputs, std::slice::from_ref(&map), &cfg, &fold)
                .unwrap();
        let model_path = fold.join("model.json");
        model.save(&model_path).unwrap();
        let mut with_scans = inputs.clone();
        with_scans.push(scans.clone());
        let (model, _) = tessera::pipeline::train::train(
            &with_scans,
            &[objects.clone(), map.clone()],
            &cfg,
            &fold,
        )
        .unwrap();
        let synthetic_path = fold.join("model_synthetic.json");
        model.save(&synthetic_path).unwrap();
        let set = |p: &std::path::Path| vec![format!("label.model={:?}", p.display().to_string())];
        for f in score {
            for (m, set) in [vec![], set(&model_path), set(&synthetic_path)]
                .iter()
                .enumerate()
            {
                let c = tessera::Config::load(Some(&root.join("config/scans_nocolour.toml")), set)
                    .unwrap();
                let out = fold.join(format!("{f}.{m}"));
                tessera::pipeline::run(&[d.join(f)], &out, &c, &|_, _| {}).unwrap();
                let (w, g) = pairs(&d.join(f), &out, &map);
                for (part, (want, got)) in pooled[m].iter_mut().enumerate() {
                    if part == 0 || f.starts_with("u700") {
                        want.extend_from_slice(&w);
                        got.extend_from_slice(&g);
                    }
                }
            }
        }
    }
    let classes = map.codes();
    let score = |m: usize, part: usize| {
        let (w, g) = &pooled[m][part];
        tessera::eval::labels::evaluate(w, g, &classes)
    };
    let (building, vegetation, vehicle, pole, road, sidewalk, terrain) = (6, 5, 70, 69, 11, 65, 67);
    let f1_gates = [
        (building, 0.80),
        (vegetation, 0.85),
        (vehicle, 0.70),
        (pole, 0.50),
    ];
    let map_gates = [(road, 0.80), (sidewalk, 0.60), (terrain, 0.70)];
    let mut measured = [[0.0f64; 7]; 3];
    let names = [
        "rules",
        "trained model",
        "trained model + synthetic objects",
    ];
    for (m, name) in names.iter().enumerate() {
        let (all, urban) = (score(m, 0), score(m, 1));
        println!("SemanticKITTI, {name}, all scored points:\n{}", all.table());
        println!("frame 700 halves, {name}:\n{}", urban.table());
        for (j, (c, gate)) in f1_gates.iter().enumerate() {
            let f1 = all.row(*c).unwrap().f1;
            measured[m][j] = f1;
            println!(
                "  {name}: class {c} F1 {f1:.3} (gate {gate}: {})",
                if f1 >= *gate { "met" } else { "NOT met" }
            );
        }
        for (j, (c, gate)) in map_gates.iter().enumerate() {
            let a = urban.row(*c).unwrap().mapping_accuracy;
            measured[m][4 + j] = a;
            println!(
                "  {name}: frame 700 class {c} mapping accuracy {:.1} % (gate {:.0} %: {})",
                100.0 * a,
                100.0 * gate,
                if a >= *gate { "met" } else { "NOT met" }
            );
        }
    }
    let [rules, model, synthetic] = measured;
    assert!(
        model[0] > rules[0] && model[1] > rules[1] && model[3] > rules[3],
        "rules {rules:?}, model {model:?}"
    );
    // Simulated cars and poles are what the real training halves lack (a handful of cars).
    // With the descriptors' grids anchored to the world and read trilinearly (2026-11-28),
    // the vehicle F1 over five grid placements (the world grid shifted by 0 / 0.2 / 0.4 /
    // 0.8 / 1.6 m) was 0.506 / 0.368 / 0.318 / 0.316 / 0.355 without them and 0.380 / 0.540
    // / 0.602 / 0.375 / 0.567 with them: they help at four of the five placements (median
    // 0.540 against 0.355) but not at the world grid itself, and never reach the rules'
    // 0.687. A comparison at one placement tests where voxel edges fall, not the training
    // set (README, issue 25), so the vehicle figures are held by the floors below only.
    // Measured with synthetic objects (2026-11-28, world-anchored interpolated grids): F1
    // building 0.716, vegetation 0.809, vehicle 0.380, pole 0.868; road 74.0 %, sidewalk
    // 29.9 %, terrain 44.5 %.
    let synthetic_floors = [0.67, 0.77, 0.34, 0.80, 0.71, 0.25, 0.42];
    for (j, f) in synthetic_floors.iter().enumerate() {
        assert!(
            synthetic[j] >= *f,
            "model with synthetic objects, measure {j}: {:.3} < {f}",
            synthetic[j]
        );
    }
    // Floors a little under the measured values (see the README's issue-25 table).
    // Measured (default forest, 2026-11-28, world-anchored interpolated grids): F1 building
    // 0.722, vegetation 0.830, vehicle 0.506, pole 0.817; frame 700 mapping accuracy road
    // 75.3 %, sidewalk 26.9 %, terrain 46.1 % (before: 0.689, 0.820, 0.400, 0.707; 75.9,
    // 26.3, 52.0 %). The rules: 0.485, 0.577, 0.687, 0.090; 46.0, 0.0, 41.4 %.
    let floors = [0.68, 0.79, 0.45, 0.77, 0.72, 0.22, 0.43];
    for (j, f) in floors.iter().enumerate() {
        assert!(
            model[j] >= *f,
            "trained model, measure {j}: {:.3} < {f}",
            model[j]
        );
    }
}
