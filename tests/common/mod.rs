//! Shared helpers for the integration tests.
#![allow(dead_code)]

pub mod house;

use std::path::{Path, PathBuf};

/// The shared data directory (`TESSERA_DATA`, default `../shared/data`), if present.
pub fn data_dir() -> Option<PathBuf> {
    let d = std::env::var_os("TESSERA_DATA")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("../shared/data"));
    if d.is_dir() {
        Some(d)
    } else if std::env::var("CI").as_deref() == Ok("true") {
        // Under CI the real-data gates must run: missing data fails them instead of a SKIP.
        panic!(
            "shared data not found at {} (set TESSERA_DATA); CI=true requires it",
            d.display()
        );
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
    } else if std::env::var("CI").as_deref() == Ok("true") {
        panic!(
            "{} not found; CI=true requires the shared data",
            p.display()
        );
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

/// Points (x, y, z) and ASPRS classification codes of a LAS/LAZ file.
pub fn read_las(path: &Path) -> Result<(Vec<[f64; 3]>, Vec<u8>), String> {
    let mut reader =
        las::Reader::from_path(path).map_err(|e| format!("{}: {e}", path.display()))?;
    let data = reader
        .read_all()
        .map_err(|e| format!("{}: {e}", path.display()))?;
    let mut xyz = Vec::with_capacity(data.len());
    let mut class = Vec::with_capacity(data.len());
    for p in data.points() {
        let p = p.map_err(|e| format!("{}: {e}", path.display()))?;
        xyz.push([p.x, p.y, p.z]);
        class.push(u8::from(p.classification));
    }
    Ok((xyz, class))
}

/// Minimal .npy reader (format 1.x/2.x/3.x, little-endian, C order): returns dtype descr,
/// shape and the raw data bytes.
pub fn read_npy(path: &Path) -> Result<(String, Vec<usize>, Vec<u8>), String> {
    let bytes = std::fs::read(path).map_err(|e| format!("{}: {e}", path.display()))?;
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(format!("{}: not a .npy file", path.display()));
    }
    let major = bytes[6];
    let (hlen, hstart) = if major == 1 {
        (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10)
    } else {
        if bytes.len() < 12 {
            return Err(format!("{}: truncated header", path.display()));
        }
        (
            u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize,
            12,
        )
    };
    let header = std::str::from_utf8(
        bytes
            .get(hstart..hstart + hlen)
            .ok_or_else(|| format!("{}: truncated header", path.display()))?,
    )
    .map_err(|e| format!("{}: {e}", path.display()))?;
    let field = |key: &str| -> Result<&str, String> {
        let at = header
            .find(key)
            .ok_or_else(|| format!("{}: header lacks {key}", path.display()))?;
        Ok(&header[at + key.len()..])
    };
    let descr_rest = field("'descr':")?.trim_start();
    let descr = descr_rest
        .trim_start_matches('\'')
        .split('\'')
        .next()
        .unwrap_or("")
        .to_string();
    if field("'fortran_order':")?.trim_start().starts_with("True") {
        return Err(format!("{}: fortran order not supported", path.display()));
    }
    let shape_rest = field("'shape':")?;
    let open = shape_rest.find('(').ok_or("bad shape")?;
    let close = shape_rest.find(')').ok_or("bad shape")?;
    let shape = shape_rest[open + 1..close]
        .split(',')
        .map(str::trim)
        .filter(|s| !s.is_empty())
        .map(|s| s.parse::<usize>().map_err(|e| format!("shape: {e}")))
        .collect::<Result<Vec<_>, _>>()?;
    Ok((descr, shape, bytes[hstart + hlen..].to_vec()))
}

/// N×3 float32 points of a .npy file.
pub fn read_npy_points(path: &Path) -> Result<Vec<[f64; 3]>, String> {
    let (descr, shape, data) = read_npy(path)?;
    if descr != "<f4" || shape.len() != 2 || shape[1] != 3 {
        return Err(format!(
            "{}: expected <f4 N×3, got {descr} {shape:?}",
            path.display()
        ));
    }
    let f = |c: &[u8]| f64::from(f32::from_le_bytes([c[0], c[1], c[2], c[3]]));
    let vals: Vec<f64> = data.chunks_exact(4).take(shape[0] * 3).map(f).collect();
    if vals.len() != shape[0] * 3 {
        return Err(format!("{}: truncated data", path.display()));
    }
    Ok(vals.chunks_exact(3).map(|c| [c[0], c[1], c[2]]).collect())
}

/// N or N×1 int32 labels of a .npy file.
pub fn read_npy_labels(path: &Path) -> Result<Vec<i32>, String> {
    let (descr, shape, data) = read_npy(path)?;
    if descr != "<i4" || shape.is_empty() || shape.iter().skip(1).any(|&d| d != 1) {
        return Err(format!(
            "{}: expected <i4 N or N×1, got {descr} {shape:?}",
            path.display()
        ));
    }
    let out: Vec<i32> = data
        .chunks_exact(4)
        .take(shape[0])
        .map(|c| i32::from_le_bytes([c[0], c[1], c[2], c[3]]))
        .collect();
    if out.len() != shape[0] {
        return Err(format!("{}: truncated data", path.display()));
    }
    Ok(out)
}

/// The 15 ISPRS reference samples.
pub const ISPRS_SAMPLES: [&str; 15] = [
    "samp11", "samp12", "samp21", "samp22", "samp23", "samp24", "samp31", "samp41", "samp42",
    "samp51", "samp52", "samp53", "samp54", "samp61", "samp71",
];

/// SemanticKITTI ground labels (Patchwork++ convention).
pub fn kitti_is_ground(label: i32) -> bool {
    matches!(label, 9 | 10 | 11 | 12 | 17)
}

/// SemanticKITTI vegetation, excluded from scoring.
pub const KITTI_VEGETATION: i32 = 15;

/// A command running `exe` under `/usr/bin/time -v` when it is installed (its maximum resident
/// set size then appears on stderr, see [`max_rss_kb`]); the flag says whether it is.
pub fn timed(exe: &str) -> (std::process::Command, bool) {
    if Path::new("/usr/bin/time").exists() {
        let mut c = std::process::Command::new("/usr/bin/time");
        c.arg("-v").arg(exe);
        (c, true)
    } else {
        (std::process::Command::new(exe), false)
    }
}

/// Checks that a `tessera run … --out OUT` exited 0 (its stderr otherwise is the message) and
/// returns OUT's summary.json with the run's stderr (where [`max_rss_kb`] finds its figure).
pub fn run_summary(o: &std::process::Output, out: &Path) -> (serde_json::Value, String) {
    let err = String::from_utf8_lossy(&o.stderr).to_string();
    assert!(o.status.success(), "{err}");
    let summary = serde_json::from_slice(&std::fs::read(out.join("summary.json")).unwrap())
        .unwrap_or_else(|e| panic!("{}: {e}", out.join("summary.json").display()));
    (summary, err)
}

/// The maximum resident set size `/usr/bin/time -v` printed, KiB.
pub fn max_rss_kb(stderr: &str) -> Option<f64> {
    stderr
        .lines()
        .find(|l| l.contains("Maximum resident set size"))
        .and_then(|l| l.split(':').nth(1))
        .and_then(|v| v.trim().parse().ok())
}
