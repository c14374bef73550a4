//! Evaluation built into the product: metrics against reference labels, and point matching
//! between a reference and a result (by order when they line up, else by coordinates).

pub mod ground;

use crate::error::{Error, Result};
use crate::io::input::expand_paths;
use std::collections::HashMap;
use std::path::{Path, PathBuf};

/// Points of one or more LAS/LAZ files: quantised coordinates and classification codes.
#[derive(Debug, Default)]
pub struct LabelledPoints {
    /// Coordinates rounded to the matching precision.
    pub keys: Vec<[i64; 3]>,
    /// Classification codes.
    pub classes: Vec<u8>,
}

/// Reads every point of `path` (a file or a directory of tiles).
pub fn load_points(path: &Path, precision_m: f64) -> Result<LabelledPoints> {
    let files: Vec<PathBuf> = expand_paths(&[path.to_path_buf()])?;
    let mut out = LabelledPoints::default();
    for f in files {
        let mut r = las::Reader::from_path(&f).map_err(|e| Error::las(&f, e))?;
        let data = r.read_all().map_err(|e| Error::las(&f, e))?;
        for p in data.points() {
            let p = p.map_err(|e| Error::las(&f, e))?;
            out.keys.push([
                (p.x / precision_m).round() as i64,
                (p.y / precision_m).round() as i64,
                (p.z / precision_m).round() as i64,
            ]);
            out.classes.push(u8::from(p.classification));
        }
    }
    Ok(out)
}

/// For each reference point, the index of its result point (`None` if it has none). Points are
/// matched by order when both sets have the same length and equal coordinates at every index;
/// otherwise by coordinates (a multiset: duplicates pair up one to one). Unmatched reference
/// points are an error unless `allow_unmatched` (e.g. scoring the ISPRS samples inside a
/// filtered site file): a result must not lose points.
pub fn match_points(
    reference: &LabelledPoints,
    result: &LabelledPoints,
    allow_unmatched: bool,
) -> Result<Vec<Option<usize>>> {
    if reference.keys.len() == result.keys.len() && reference.keys == result.keys {
        return Ok((0..reference.keys.len()).map(Some).collect());
    }
    let mut index: HashMap<[i64; 3], Vec<usize>> = HashMap::with_capacity(result.keys.len());
    for (i, k) in result.keys.iter().enumerate().rev() {
        index.entry(*k).or_default().push(i);
    }
    let mut out = Vec::with_capacity(reference.keys.len());
    let mut missing = 0usize;
    for k in &reference.keys {
        let m = index.get_mut(k).and_then(|v| v.pop());
        missing += m.is_none() as usize;
        out.push(m);
    }
    if missing > 0 && !allow_unmatched {
        return Err(Error::Config(format!(
            "{missing} of {} reference points have no result point at the same coordinates (precision too fine, or a different area?)",
            reference.keys.len()
        )));
    }
    Ok(out)
}

/// Scores ground classification: `reference` and `result` are files or directories; a point is
/// ground in the reference if its class is in `ref_ground`, in the result if in `res_ground`.
/// Returns the scores and the number of reference points scored.
pub fn eval_ground(
    reference: &Path,
    result: &Path,
    ref_ground: &[u8],
    res_ground: &[u8],
    precision_m: f64,
    allow_unmatched: bool,
) -> Result<(ground::GroundScores, usize)> {
    let r = load_points(reference, precision_m)?;
    let s = load_points(result, precision_m)?;
    let m = match_points(&r, &s, allow_unmatched)?;
    let (mut want, mut got) = (Vec::new(), Vec::new());
    for (k, i) in m.iter().enumerate() {
        if let Some(i) = i {
            want.push(ref_ground.contains(&r.classes[k]));
            got.push(res_ground.contains(&s.classes[*i]));
        }
    }
    let n = want.len();
    Ok((ground::score_ground(&want, &got), n))
}
