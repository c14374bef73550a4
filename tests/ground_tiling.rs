//! Tile edges: with the overlap buffer as TIN context, a tiled run gives the same ground labels
//! for core points as an untiled run (≥ 99.9 % identical) at tile sizes 25, 50 and 100 m, on
//! a real mobile-mapping tile and on a synthetic street scene.

mod common;

use std::path::{Path, PathBuf};
use tessera::Config;

/// (x, y, z raw integers, gps time bits) → classification, sorted.
fn labels(dir: &Path) -> Vec<([i64; 3], u64, u8)> {
    let mut v = Vec::new();
    for t in common::tiles_in(dir) {
        let mut r = las::Reader::from_path(&t).unwrap();
        for p in r.read_all().unwrap().points() {
            let p = p.unwrap();
            v.push((
                [
                    (p.x * 1000.0).round() as i64,
                    (p.y * 1000.0).round() as i64,
                    (p.z * 1000.0).round() as i64,
                ],
                p.gps_time.unwrap_or(0.0).to_bits(),
                u8::from(p.classification),
            ));
        }
    }
    v.sort();
    v
}

fn run(inputs: &[PathBuf], out: &Path, tile: f64, buffer: f64) -> Vec<([i64; 3], u64, u8)> {
    let cfg = Config::load(
        None,
        &[
            format!("tiling.tile_size_m={tile}"),
            format!("tiling.buffer_m={buffer}"),
            "stages.run=[\"ground\"]".into(),
        ],
    )
    .unwrap();
    tessera::pipeline::run(inputs, out, &cfg, &|_, _| {}).unwrap();
    labels(out)
}

/// Buffer width: at least one seed cell of the ground filter (20 m in the mobile set).
const BUFFER_M: f64 = 20.0;

fn check(inputs: &[PathBuf], what: &str) {
    let tmp = tempfile::tempdir().unwrap();
    // Untiled: one tile holds everything (the grid is aligned to multiples of the tile size).
    let base = run(inputs, &tmp.path().join("untiled"), 10_000.0, 0.0);
    let n_ground = base.iter().filter(|p| p.2 == 2).count();
    println!(
        "{what}: untiled run: {n_ground} of {} points ground",
        base.len()
    );
    assert!(n_ground > 0);
    for tile in [25.0, 50.0, 100.0] {
        let got = run(inputs, &tmp.path().join(format!("t{tile}")), tile, BUFFER_M);
        assert_eq!(got.len(), base.len());
        let same = got
            .iter()
            .zip(&base)
            .filter(|(a, b)| a.0 == b.0 && a.1 == b.1 && a.2 == b.2)
            .count();
        let keys_equal = got.iter().zip(&base).all(|(a, b)| a.0 == b.0 && a.1 == b.1);
        assert!(keys_equal, "{what}: tiled output holds different points");
        let frac = same as f64 / base.len() as f64;
        println!("{what}: tile {tile} m, buffer {BUFFER_M} m: {:.4} % identical ground labels ({} points)", 100.0 * frac, base.len());
        assert!(
            frac >= 0.999,
            "{what}: tile {tile} m: only {:.3} % identical",
            100.0 * frac
        );
    }
}

#[test]
fn real_mobile_mapping_tile() {
    if let Some(p) = common::data_file("cyclomedia-amsterdam-sidewalk/sidewalk_run1_2386_9702.laz")
    {
        check(&[p], "cyclomedia run1");
    }
}

#[test]
fn synthetic_street_scene() {
    let tmp = tempfile::tempdir().unwrap();
    let p = tessera::synth::SceneParams {
        seed: 9,
        length_m: 120.0,
        ..Default::default()
    };
    tessera::synth::write_scene(&p, tmp.path(), 40.0).unwrap();
    check(&[tmp.path().to_path_buf()], "synthetic scene");
}
