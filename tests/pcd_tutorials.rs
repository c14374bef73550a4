//! The PCD reader on the PCL tutorial clouds (`$TESSERA_DATA/pcl-tutorials`, default
//! `../shared/data`), checked against `scripts/check_pcd.py`, an independent Python reader.
//! Skips with a note when the data or Python/numpy is missing.

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;
use tessera::io::pcd::{self, lzf, DataMode, PcdCloud};

fn tutorial_files() -> Option<Vec<PathBuf>> {
    let Some(root) = common::data_dir() else {
        eprintln!("note: data directory not found, skipping PCD tutorial tests");
        return None;
    };
    let dir = root.join("pcl-tutorials");
    let Ok(entries) = std::fs::read_dir(&dir) else {
        eprintln!(
            "note: {} not found, skipping PCD tutorial tests",
            dir.display()
        );
        return None;
    };
    let mut files: Vec<PathBuf> = entries
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|e| e == "pcd"))
        .collect();
    files.sort();
    if files.is_empty() {
        eprintln!("note: no .pcd files in {}, skipping", dir.display());
        return None;
    }
    Some(files)
}

fn read(path: &Path) -> PcdCloud {
    match pcd::read_pcd(path) {
        Ok(c) => c,
        Err(e) => panic!("{e}"),
    }
}

#[test]
fn counts_and_coordinates() {
    let Some(files) = tutorial_files() else {
        return;
    };
    for f in &files {
        let c = read(f);
        let name = f.file_name().and_then(|n| n.to_str()).unwrap_or_default();
        assert_eq!(c.len(), c.header.points, "{name}");
        assert_eq!(c.len(), c.header.width * c.header.height, "{name}");
        // Invalid points of organised clouds are NaN; nothing is infinite.
        assert!(
            c.xyz.iter().flatten().all(|v| v.is_finite() || v.is_nan()),
            "{name}: infinite coordinate"
        );
        // A point is either fully valid or fully invalid.
        assert!(
            c.xyz
                .iter()
                .all(|p| p.iter().all(|v| v.is_nan()) || p.iter().all(|v| v.is_finite())),
            "{name}: partly NaN point"
        );
        assert!(c.finite_count() > 0, "{name}");
        // Numbers stated in SOURCE.md.
        match name {
            "region_growing_rgb_tutorial.pcd" => {
                assert_eq!((c.header.width, c.header.height), (640, 480));
                assert_eq!(c.finite_count(), 259_847);
                assert_eq!(c.header.data, DataMode::BinaryCompressed);
                assert!(c.rgb.is_some());
            }
            "region_growing_tutorial.pcd" => {
                assert_eq!(c.len(), 108_104);
                assert!(c.rgb.is_some());
            }
            "min_cut_segmentation_tutorial.pcd" => {
                assert_eq!(c.len(), 9_311);
                assert_eq!(c.header.data, DataMode::Ascii);
                assert!(c.rgb.is_none());
            }
            _ => {}
        }
        eprintln!(
            "{name}: {} points, {} finite, {:?}",
            c.len(),
            c.finite_count(),
            c.header.data
        );
    }
}

#[test]
fn agrees_with_independent_python_reader() {
    let Some(files) = tutorial_files() else {
        return;
    };
    let script = Path::new(env!("CARGO_MANIFEST_DIR")).join("scripts/check_pcd.py");
    let out = match Command::new("python3").arg(&script).args(&files).output() {
        Ok(o) => o,
        Err(e) => {
            eprintln!("note: cannot run python3 ({e}), skipping the cross-check");
            return;
        }
    };
    let stderr = String::from_utf8_lossy(&out.stderr);
    if !out.status.success() && stderr.contains("No module named 'numpy'") {
        eprintln!("note: numpy is not installed, skipping the cross-check");
        return;
    }
    assert!(out.status.success(), "check_pcd.py failed:\n{stderr}");
    let stdout = String::from_utf8_lossy(&out.stdout);
    let reports: Vec<serde_json::Value> = stdout
        .lines()
        .map(|l| serde_json::from_str(l).expect("check_pcd.py prints JSON lines"))
        .collect();
    assert_eq!(reports.len(), files.len());
    for (f, want) in files.iter().zip(&reports) {
        let c = read(f);
        let name = want["file"].as_str().unwrap_or_default();
        assert_eq!(Some(name), f.file_name().and_then(|n| n.to_str()));
        assert_eq!(want["points"].as_u64(), Some(c.len() as u64), "{name}");
        assert_eq!(want["decoded"].as_u64(), Some(c.len() as u64), "{name}");
        assert_eq!(
            want["finite"].as_u64(),
            Some(c.finite_count() as u64),
            "{name}"
        );
        let finite: Vec<&[f64; 3]> = c
            .xyz
            .iter()
            .filter(|p| p.iter().all(|v| v.is_finite()))
            .collect();
        for (k, key) in ["sum_x", "sum_y", "sum_z"].iter().enumerate() {
            let sum: f64 = finite.iter().map(|p| p[k]).sum();
            let scale: f64 = finite.iter().map(|p| p[k].abs()).sum::<f64>() + 1.0;
            let py = want[*key].as_f64().expect("sum");
            assert!(
                (sum - py).abs() <= 1e-12 * scale,
                "{name} {key}: rust {sum} python {py}"
            );
        }
        // Single values must be bit-identical.
        let first = want["first"].as_array().expect("first");
        let last = want["last"].as_array().expect("last");
        for k in 0..3 {
            assert_eq!(first[k].as_f64(), Some(finite[0][k]), "{name} first");
            assert_eq!(
                last[k].as_f64(),
                Some(finite[finite.len() - 1][k]),
                "{name} last"
            );
        }
        match (&c.rgb, want["sum_rgb"].as_array()) {
            (Some(rgb), Some(py)) => {
                for k in 0..3 {
                    let s: u64 = rgb.iter().map(|c| u64::from(c[k])).sum();
                    assert_eq!(py[k].as_u64(), Some(s), "{name} colour channel {k}");
                }
            }
            (None, None) => {}
            (r, p) => panic!("{name}: rust rgb {:?} vs python {p:?}", r.is_some()),
        }
        assert_ne!(
            want["pcdio"].as_str(),
            Some("disagrees"),
            "{name}: pcdio.py disagrees"
        );
        eprintln!(
            "{name}: agrees with check_pcd.py (pcdio: {})",
            want["pcdio"]
        );
    }
}

/// Re-compress each real `binary_compressed` file with this crate's LZF encoder: the reader
/// must give the same cloud.
#[test]
fn recompressed_tutorial_files_read_the_same() {
    let Some(files) = tutorial_files() else {
        return;
    };
    for f in &files {
        let bytes = std::fs::read(f).expect("read");
        let (header, start, _) = pcd::parse_header(&bytes).expect("header");
        if header.data != DataMode::BinaryCompressed {
            continue;
        }
        let body = &bytes[start..];
        let word =
            |at: usize| u32::from_le_bytes([body[at], body[at + 1], body[at + 2], body[at + 3]]);
        let (csize, usize_) = (word(0) as usize, word(4) as usize);
        let raw = lzf::decompress(&body[8..8 + csize], usize_).expect("lzf");
        let packed = lzf::compress(&raw);
        let mut again = bytes[..start].to_vec();
        again.extend((packed.len() as u32).to_le_bytes());
        again.extend((raw.len() as u32).to_le_bytes());
        again.extend(&packed);
        let a = read(f);
        let b = pcd::parse_pcd(&again).expect("recompressed");
        // NaN != NaN, so compare bit patterns.
        let bits =
            |c: &PcdCloud| -> Vec<[u64; 3]> { c.xyz.iter().map(|p| p.map(f64::to_bits)).collect() };
        assert_eq!(bits(&a), bits(&b));
        assert_eq!(a.rgb, b.rgb);
        eprintln!(
            "{}: PCL {} bytes, ours {} bytes",
            f.display(),
            csize,
            packed.len()
        );
    }
}
