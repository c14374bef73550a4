//! COPC output (issue 24): `output.format = "copc"` writes tiles that two independent readers
//! take as COPC — laspy's `CopcReader` (the gate: every point and attribute equal to the
//! same run's LAZ tiles, bounds queries exact, `scripts/check_copc.py`) and the `las`
//! crate's `CopcReader` (every node's points inside the node's cube) — and that plain LAS
//! readers still read as LAZ.

mod common;

use std::path::Path;
use std::process::Command;

fn tessera() -> Command {
    Command::new(env!("CARGO_BIN_EXE_tessera"))
}

fn run(scene: &Path, out: &Path, sets: &[&str]) {
    let mut c = tessera();
    c.args(["-q", "run"]).arg(scene).arg("--out").arg(out);
    for s in sets {
        c.args(["--set", s]);
    }
    let o = c.output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
}

/// The laspy gate: `check_copc.py LAZ_DIR COPC_DIR`.
fn laspy_check(laz: &Path, copc: &Path) {
    if !common::have_laspy() {
        assert!(
            std::env::var("CI").as_deref() != Ok("true"),
            "no laspy/lazrs, and CI=true requires the COPC gate (.ci/run installs them)"
        );
        eprintln!("SKIP laspy COPC check: python3 -c 'import laspy, lazrs' failed");
        return;
    }
    let o = Command::new("python3")
        .arg(concat!(
            env!("CARGO_MANIFEST_DIR"),
            "/scripts/check_copc.py"
        ))
        .arg(laz)
        .arg(copc)
        .output()
        .unwrap();
    let msg = String::from_utf8_lossy(&o.stdout);
    assert!(
        o.status.success(),
        "laspy COPC check failed: {msg}{}",
        String::from_utf8_lossy(&o.stderr)
    );
    eprintln!("laspy: {msg}");
}

/// Reads every COPC tile of `dir` node by node with the `las` crate: nodes partition the
/// points, each inside its cube, and the parent of every node is in the hierarchy.
fn las_crate_check(dir: &Path) -> usize {
    let tiles: Vec<_> = common::tiles_in(dir)
        .into_iter()
        .filter(|p| p.to_string_lossy().ends_with(".copc.laz"))
        .collect();
    assert!(!tiles.is_empty(), "no COPC tiles in {}", dir.display());
    let mut nodes = 0;
    for t in &tiles {
        let mut r = las::CopcReader::from_path(t).unwrap();
        let header = r.header().clone();
        let info = header.copc_info_vlr().unwrap();
        assert_eq!(header.version(), las::Version::new(1, 4));
        assert!((6..=8).contains(&header.point_format().to_u8().unwrap()));
        let entries: Vec<_> = r.hierarchy_entries().collect();
        let keys: std::collections::HashSet<_> = entries.iter().map(|e| e.key).collect();
        let mut total = 0u64;
        for e in &entries {
            assert!(e.point_count > 0, "{}: empty node {:?}", t.display(), e.key);
            if e.key.l > 0 {
                assert!(keys.contains(&e.key.parent()), "{:?} has no parent", e.key);
            }
            let b = e.key.bounds(&info);
            let eps = 1e-9 * info.halfsize.max(1.0);
            let data = r.read_entry(e).unwrap();
            assert_eq!(data.len(), e.point_count as usize);
            for p in data.points() {
                let p = p.unwrap();
                assert!(
                    p.x >= b.min.x - eps
                        && p.x <= b.max.x + eps
                        && p.y >= b.min.y - eps
                        && p.y <= b.max.y + eps
                        && p.z >= b.min.z - eps
                        && p.z <= b.max.z + eps,
                    "{}: point ({}, {}, {}) outside node {:?} {b:?}",
                    t.display(),
                    p.x,
                    p.y,
                    p.z,
                    e.key
                );
            }
            total += e.point_count as u64;
        }
        assert_eq!(total, header.number_of_points(), "{}", t.display());
        // A plain LAS reader reads it as LAZ (the chunk table lists the nodes).
        let mut plain = las::Reader::from_path(t).unwrap();
        assert_eq!(plain.read_all().unwrap().len() as u64, total);
        nodes += entries.len();
    }
    nodes
}

#[test]
fn copc_tiles_equal_the_laz_tiles_and_answer_bounds_queries_exactly() {
    let d = tempfile::tempdir().unwrap();
    let scene = d.path().join("scene");
    let o = tessera()
        .args(["-q", "synth", "--length-m", "40", "--out"])
        .arg(&scene)
        .output()
        .unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    // The full pipeline (segment ids stitched across tiles: the deferred write path) and
    // ground only (tiles written as they finish), each as LAZ and as COPC.
    for (what, stages) in [
        ("full", None),
        ("ground", Some("stages.run=[\"ground\",\"stats\"]")),
    ] {
        let laz = d.path().join(format!("{what}-laz"));
        let copc = d.path().join(format!("{what}-copc"));
        let mut sets: Vec<&str> = stages.into_iter().collect();
        run(&scene, &laz, &sets);
        sets.push("output.format=\"copc\"");
        run(&scene, &copc, &sets);
        let nodes = las_crate_check(&copc);
        assert!(
            nodes > common::tiles_in(&laz).len(),
            "{what}: {nodes} nodes"
        );
        laspy_check(&laz, &copc);
        // The report is drawn from COPC tiles like from LAZ ones.
        let html = std::fs::read_to_string(copc.join("report.html")).unwrap();
        assert!(html.contains("id=\"overview-class\""));
    }
}

#[test]
fn legacy_inputs_are_upgraded_for_copc_and_waveform_formats_are_refused() {
    let d = tempfile::tempdir().unwrap();
    let input = d.path().join("in.laz");
    // Format 1 (legacy): COPC holds 6, 7, 8, so the run writes 6.
    let mut b = las::Builder::from((1, 2));
    b.point_format = las::point::Format::new(1).unwrap();
    b.point_format.is_compressed = true;
    let mut w = las::Writer::from_path(&input, b.into_header().unwrap()).unwrap();
    for i in 0..5000 {
        w.write_point(las::Point {
            x: f64::from(i % 100) * 0.3,
            y: f64::from(i / 100) * 0.3,
            z: f64::from(i % 7) * 0.01,
            return_number: 1,
            number_of_returns: 1,
            gps_time: Some(f64::from(i)),
            ..Default::default()
        })
        .unwrap();
    }
    w.close().unwrap();
    drop(w);
    let out = d.path().join("out");
    run(
        &input,
        &out,
        &["stages.run=[\"ground\"]", "output.format=\"copc\""],
    );
    let tiles = common::tiles_in(&out);
    assert_eq!(tiles.len(), 1);
    let r = las::CopcReader::from_path(&tiles[0]).unwrap();
    assert_eq!(r.header().point_format().to_u8().unwrap(), 6);
    assert_eq!(r.header().number_of_points(), 5000);

    // A forced legacy format cannot be COPC: a configuration error, nothing written.
    let out2 = d.path().join("out2");
    let o = tessera()
        .args(["-q", "run"])
        .arg(&input)
        .arg("--out")
        .arg(&out2)
        .args([
            "--set",
            "output.format=\"copc\"",
            "--set",
            "output.point_format=1",
        ])
        .output()
        .unwrap();
    assert_eq!(o.status.code(), Some(2), "{o:?}");
    let err = String::from_utf8_lossy(&o.stderr);
    assert!(err.contains("copc") && err.contains("6, 7 and 8"), "{err}");
    assert!(common::tiles_in(&out2).is_empty());
}
