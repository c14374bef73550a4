//! Shared helpers for the integration tests.
#![allow(dead_code)]

use std::path::{Path, PathBuf};

/// The shared data directory (`TESSERA_DATA`, default `../shared/data`), if present.
pub fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("TESSERA_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if d.is_dir() {
        Some(d)
    } else {
        eprintln!(
            "SKIP: shared data not found at {} (set TESSERA_DATA)",
            d.display()
        );
        None
    }
}

/// A data file, or `None` (with a message) when the data set is absent.
pub fn data_file(rel: &str) -> Option<PathBuf> {
    let p = data_dir()?.join(rel);
    if p.is_file() {
        Some(p)
    } else {
        eprintln!("SKIP: {} not found", p.display());
        None
    }
}

/// Output tiles (`*.laz`/`*.las`) in a directory, sorted.
pub fn tiles_in(dir: &Path) -> Vec<PathBuf> {
    let mut v: Vec<PathBuf> = std::fs::read_dir(dir)
        .map(|rd| {
            rd.filter_map(|e| e.ok().map(|e| e.path()))
                .filter(|p| {
                    matches!(
                        p.extension().and_then(|e| e.to_str()),
                        Some("laz") | Some("las")
                    )
                })
                .collect()
        })
        .unwrap_or_default();
    v.sort();
    v
}

/// All raw point records of a file, re-encoded with the given transforms so records of
/// different files are comparable byte for byte.
pub fn raw_records(path: &Path) -> (las::point::Format, Vec<Vec<u8>>) {
    let mut r = las::Reader::from_path(path).unwrap();
    let data = r.read_all().unwrap();
    let rl = data.record_len();
    let mut f = *r.header().point_format();
    f.is_compressed = false;
    (
        f,
        data.raw_bytes()
            .chunks_exact(rl)
            .map(|c| c.to_vec())
            .collect(),
    )
}

/// Whether python3 with laspy is available for independent checks.
pub fn have_laspy() -> bool {
    std::process::Command::new("python3")
        .args(["-c", "import laspy, lazrs"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false)
}
