//! Labelling gate (issue 5) on the synthetic street scene: ground subclasses from training
//! samples drawn from the first half of the drive (x < 200 m), scored on the second half.
//! Mapping accuracy (street-level document Table 14) ≥ 95 % for road, cycle path, footpath
//! and grass after smoothing. Non-ground classes are printed for information.

use tessera::eval::{eval_labels, LabelEvalOptions};
use tessera::label::samples::{from_classified_points, SampleSet};
use tessera::synth::{SceneParams, WORLD_OFFSET};
use tessera::Config;

const ROAD: u8 = 11;
const CYCLE: u8 = 64;
const FOOTPATH: u8 = 65;
const GRASS: u8 = 67;

#[test]
fn street_subclasses_from_samples_of_another_part() {
    let tmp = tempfile::tempdir().unwrap();
    let scene = tmp.path().join("scene");
    // 150 pts/m² at 5 m keeps the test quick; the shadows, wet patches and colour noise are
    // those of the default scene.
    let params = SceneParams {
        length_m: 400.0,
        points_per_m2: 150.0,
        ..SceneParams::default()
    };
    tessera::synth::write_scene(&params, &scene, 50.0).unwrap();
    let mut files: Vec<_> = std::fs::read_dir(&scene)
        .unwrap()
        .map(|e| e.unwrap().path())
        .filter(|p| p.extension().is_some_and(|e| e == "laz"))
        .collect();
    files.sort();
    assert_eq!(files.len(), 8);

    // Training samples: 5 m blocks of the document's four classes in the first four files
    // (x < 200 m). Kerbs and lane markings get no samples: concrete kerbs look like light
    // tiles, and the document left them out too.
    let mut set = SampleSet::default();
    for f in &files[..4] {
        let s = from_classified_points(f, "gt_class", 5.0, 30).unwrap();
        set.samples.extend(
            s.samples
                .into_iter()
                .filter(|s| [ROAD, CYCLE, FOOTPATH, GRASS].contains(&s.class)),
        );
    }
    println!("{} training samples", set.samples.len());
    let samples = tmp.path().join("samples.json");
    set.save(&samples).unwrap();

    let out = tmp.path().join("out");
    let cfg = Config::load(
        None,
        &[
            "stages.run=[\"ground\",\"segment\",\"label\",\"stats\"]".into(),
            format!("label.samples={:?}", samples.display().to_string()),
        ],
    )
    .unwrap();
    tessera::pipeline::run(std::slice::from_ref(&scene), &out, &cfg, &|_, _| {}).unwrap();

    let x0 = WORLD_OFFSET[0] + 200.0;
    let opts = |classes: Vec<u8>| LabelEvalOptions {
        ref_field: "gt_class".into(),
        res_field: "classification".into(),
        classes,
        map: Vec::new(),
        precision_m: 0.001,
        allow_unmatched: false,
        x_range: Some((x0, x0 + 200.0)),
        exclude: Default::default(),
        ref_map: None,
    };
    let e = eval_labels(&scene, &out, &opts(vec![ROAD, CYCLE, FOOTPATH, GRASS])).unwrap();
    println!("ground subclasses, x in [200, 400) m:\n{}", e.table());
    let ng = eval_labels(&scene, &out, &opts(vec![5, 6, 69, 70])).unwrap();
    println!("non-ground classes (information):\n{}", ng.table());
    for c in [ROAD, CYCLE, FOOTPATH, GRASS] {
        let r = e.row(c).unwrap();
        assert!(
            r.mapping_accuracy >= 0.95,
            "class {c}: mapping accuracy {:.1} %",
            100.0 * r.mapping_accuracy
        );
    }
}
