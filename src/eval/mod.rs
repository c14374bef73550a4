//! Evaluation built into the product: metrics against reference labels, and point matching
//! between a reference and a result (by order when they line up, else by coordinates).

pub mod ground;
pub mod labels;
pub mod polygons;
pub mod segments;

use crate::error::{Error, Result};
use crate::io::attributes::{field_source, field_value, FieldSource};
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
    let f = load_fields(path, precision_m, &["classification"])?;
    Ok(LabelledPoints {
        keys: f.keys,
        // Classification codes are read from a u8 field.
        classes: f.values[0].iter().map(|&c| c as u8).collect(),
    })
}

/// For each reference point, the index of its result point (`None` if it has none). Points are
/// matched by order when both sets have the same length and equal coordinates at every index;
/// otherwise by coordinates (a multiset: duplicates pair up one to one). Unmatched reference
/// points are an error unless `allow_unmatched` (e.g. scoring the ISPRS samples inside a
/// filtered site file): a result must not lose points.
pub fn match_points(
    reference: &[[i64; 3]],
    result: &[[i64; 3]],
    allow_unmatched: bool,
) -> Result<Vec<Option<usize>>> {
    if reference == result && !reference.is_empty() {
        return Ok((0..reference.len()).map(Some).collect());
    }
    // First result index per key, later duplicates chained through `next` (in index order, so
    // duplicates pair up in file order). A `Vec` per key, with copies of the keys, took the
    // demo command to 1,031 MiB peak; this to 784 MiB.
    const END: usize = usize::MAX;
    let mut head: HashMap<[i64; 3], usize> = HashMap::with_capacity(result.len());
    let mut next = vec![END; result.len()];
    for (i, k) in result.iter().enumerate().rev() {
        if let Some(h) = head.insert(*k, i) {
            next[i] = h;
        }
    }
    let mut out = Vec::with_capacity(reference.len());
    let mut missing = 0usize;
    for k in reference {
        let m = match head.get_mut(k) {
            Some(h) if *h != END => {
                let i = *h;
                *h = next[i];
                Some(i)
            }
            _ => None,
        };
        missing += m.is_none() as usize;
        out.push(m);
    }
    let n = reference.len();
    let matched = n - missing;
    // Whatever `allow_unmatched` says: scoring a handful of coincidences (or nothing, which
    // made kappa 100 %) would report a number about a different pair of files.
    if n == 0 || (matched as f64) < MIN_MATCHED_FRACTION * n as f64 {
        return Err(Error::Data(format!(
            "only {matched} of {n} reference points have a result point at the same coordinates (at least {:.0} % must match): the reference and the result are not the same points (a different area or sample, or a different coordinate precision?)",
            100.0 * MIN_MATCHED_FRACTION
        )));
    }
    if missing > 0 && !allow_unmatched {
        return Err(Error::Data(format!(
            "{missing} of {n} reference points have no result point at the same coordinates (precision too fine, or a different area? --allow-unmatched scores the matched ones)"
        )));
    }
    Ok(out)
}

/// Fewest reference points that must find their result point, as a fraction, even with
/// `allow_unmatched` (which is for a reference that is a subset or nearly the same set, e.g.
/// an ISPRS sample inside its site file).
pub const MIN_MATCHED_FRACTION: f64 = 0.5;

/// Most points of a file set whose rounded coordinates may coincide with a *different* point
/// before the match precision counts as coarser than the data.
pub const MAX_MERGED_FRACTION: f64 = 0.01;

/// Checks a matching precision: a finite, positive distance in metres.
pub fn check_precision(precision_m: f64) -> Result<()> {
    if precision_m.is_finite() && precision_m > 0.0 {
        Ok(())
    } else {
        Err(Error::Config(format!(
            "--match-precision-m {precision_m}: must be a finite distance > 0 m (e.g. 0.001)"
        )))
    }
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
    let m = match_points(&r.keys, &s.keys, allow_unmatched)?;
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

/// Points of one or more LAS/LAZ files with named per-point attributes.
#[derive(Debug, Default)]
pub struct FieldPoints {
    /// Coordinates rounded to the matching precision.
    pub keys: Vec<[i64; 3]>,
    /// Coordinates.
    pub xyz: Vec<[f64; 3]>,
    /// Index of the file each point came from (in the sorted file list).
    pub file: Vec<u32>,
    /// One column per requested field.
    pub values: Vec<Vec<u32>>,
}

/// Reads every point of `path` (a file or a directory of tiles) with the attributes `fields`.
pub fn load_fields(path: &Path, precision_m: f64, fields: &[&str]) -> Result<FieldPoints> {
    check_precision(precision_m)?;
    let files: Vec<PathBuf> = expand_paths(&[path.to_path_buf()])?;
    let mut out = FieldPoints {
        values: vec![Vec::new(); fields.len()],
        ..Default::default()
    };
    for (fi, f) in files.iter().enumerate() {
        // The same validated reader as the pipeline (regular files only, the right point
        // count of LAS 1.4 headers).
        let file = crate::io::input::scan_file(f, fi)?;
        let src: Vec<FieldSource> = fields
            .iter()
            .map(|n| field_source(f, &file.header, n))
            .collect::<Result<_>>()?;
        let layout =
            crate::model::RecordLayout::new(*file.header.point_format(), *file.header.transforms());
        // Keys in metres whatever the file's unit (a feet CRS): the precision is metres, and
        // a reference in feet matches a result in feet (or in metres).
        let k = crate::io::crs::metres_per_unit(&file.header) / precision_m;
        crate::io::input::read_file_chunks(
            &file,
            &layout,
            1 << 18,
            || None,
            |_, pd| {
                for p in pd.points() {
                    let p = p.map_err(|e| Error::las(f, e))?;
                    out.keys.push([
                        (p.x * k).round() as i64,
                        (p.y * k).round() as i64,
                        (p.z * k).round() as i64,
                    ]);
                    out.xyz.push([p.x, p.y, p.z]);
                    out.file.push(fi as u32);
                    for (col, s) in out.values.iter_mut().zip(&src) {
                        col.push(field_value(f, &p, *s)?);
                    }
                }
                Ok(())
            },
        )?;
    }
    check_resolution(path, precision_m, &out.keys, &out.xyz)?;
    Ok(out)
}

/// Fails when the precision merges distinct points: more than [`MAX_MERGED_FRACTION`] of the
/// points round to the same key as a point with other coordinates. Then matching by key would
/// pair different points (a precision of 1e9 m made every point match every other).
fn check_resolution(
    path: &Path,
    precision_m: f64,
    keys: &[[i64; 3]],
    xyz: &[[f64; 3]],
) -> Result<()> {
    // u32 indices halve this sort's memory; larger point sets are refused, not wrapped.
    let n = u32::try_from(keys.len()).map_err(|_| {
        Error::Data(format!(
            "{}: {} points is more than one evaluation can match (at most {})",
            path.display(),
            keys.len(),
            u32::MAX
        ))
    })?;
    let mut order: Vec<u32> = (0..n).collect();
    order.sort_unstable_by_key(|&i| keys[i as usize]);
    let mut merged = 0usize;
    for run in order.chunk_by(|&a, &b| keys[a as usize] == keys[b as usize]) {
        if run.len() > 1 {
            let first = xyz[run[0] as usize];
            if run.iter().any(|&i| xyz[i as usize] != first) {
                merged += run.len();
            }
        }
    }
    if merged as f64 > MAX_MERGED_FRACTION * keys.len() as f64 {
        return Err(Error::Data(format!(
            "{}: at a match precision of {precision_m} m, {merged} of {} points round to the same coordinates as a different point; the precision is coarser than the point spacing, so matching would pair different points (use a finer --match-precision-m)",
            path.display(),
            keys.len()
        )));
    }
    Ok(())
}

/// Options of [`eval_segments`].
#[derive(Clone, Debug)]
pub struct SegEvalOptions {
    /// Reference attribute holding segment ids (0 = none).
    pub ref_field: String,
    /// Result attribute holding segment ids (0 = none).
    pub res_field: String,
    /// Score only reference points whose attribute `.0` is one of `.1` (e.g. `gt_class` = 6).
    pub restrict: Option<(String, Vec<u32>)>,
    /// Result ids are local to each file (tiles segmented independently): make them unique
    /// per file before scoring.
    pub ids_per_file: bool,
    /// Coordinate precision for matching points, metres.
    pub precision_m: f64,
    /// Score only reference points found in the result.
    pub allow_unmatched: bool,
    /// Tolerances (each in (0.5, 1]).
    pub tolerances: Vec<f64>,
}

/// Scores a segmentation against reference segments (Hoover et al. / Sapkota §5.2, see
/// [`segments`]). Points are matched as in [`match_points`].
pub fn eval_segments(
    reference: &Path,
    result: &Path,
    o: &SegEvalOptions,
) -> Result<segments::SegEval> {
    let mut ref_fields = vec![o.ref_field.as_str()];
    if let Some((f, _)) = &o.restrict {
        ref_fields.push(f);
    }
    let r = load_fields(reference, o.precision_m, &ref_fields)?;
    let s = load_fields(result, o.precision_m, &[o.res_field.as_str()])?;
    let m = match_points(&r.keys, &s.keys, o.allow_unmatched)?;
    let mut ids: HashMap<(u32, u32), u32> = HashMap::new();
    let (mut want, mut got, mut xyz) = (Vec::new(), Vec::new(), Vec::new());
    for (k, i) in m.iter().enumerate() {
        let Some(i) = *i else { continue };
        if let Some((_, keep)) = &o.restrict {
            if !keep.contains(&r.values[1][k]) {
                continue;
            }
        }
        let raw = s.values[0][i];
        let id = if raw == 0 {
            0
        } else if o.ids_per_file {
            let next = ids.len() as u32 + 1;
            *ids.entry((s.file[i], raw)).or_insert(next)
        } else {
            raw
        };
        want.push(r.values[0][k]);
        got.push(id);
        xyz.push(r.xyz[k]);
    }
    segments::try_evaluate(&want, &got, Some(&xyz), &o.tolerances)
        .map_err(|e| Error::Config(format!("segment evaluation: {e}")))
}

/// Options of [`eval_labels`].
#[derive(Clone, Debug)]
pub struct LabelEvalOptions {
    /// Reference attribute with class codes (`classification` or an extra-bytes name).
    pub ref_field: String,
    /// Result attribute with class codes.
    pub res_field: String,
    /// Scored reference classes (empty: all present).
    pub classes: Vec<u8>,
    /// Result codes mapped onto another code before scoring, e.g. (2, [11, 64, 65, 67]) to
    /// score ground subclasses as ground.
    pub map: Vec<(u8, Vec<u8>)>,
    /// Coordinate precision for matching points, metres.
    pub precision_m: f64,
    /// Score only reference points found in the result.
    pub allow_unmatched: bool,
    /// Score only reference points with x in this range (e.g. away from training samples).
    pub x_range: Option<(f64, f64)>,
    /// Reference points inside these polygons are not scored (areas the reference leaves
    /// unclassified; `--exclude FILE.geojson`).
    pub exclude: polygons::Polygons,
    /// Reference codes translated to tessera codes before scoring (unmapped: not scored);
    /// with no `classes` given, the map's classes are scored.
    pub ref_map: Option<crate::label::model::ClassMap>,
}

/// Scores class labels (confusion matrix, omission, commission, mapping accuracy, F1; see
/// [`labels`]). Points are matched as in [`match_points`].
pub fn eval_labels(
    reference: &Path,
    result: &Path,
    o: &LabelEvalOptions,
) -> Result<labels::LabelEval> {
    let r = load_fields(reference, o.precision_m, &[o.ref_field.as_str()])?;
    let s = load_fields(result, o.precision_m, &[o.res_field.as_str()])?;
    let m = match_points(&r.keys, &s.keys, o.allow_unmatched)?;
    let mut lut: [u8; 256] = std::array::from_fn(|i| i as u8);
    for (to, from) in &o.map {
        for &f in from {
            lut[f as usize] = *to;
        }
    }
    let code = |v: u32, path: &Path| {
        u8::try_from(v).map_err(|_| {
            Error::Config(format!("{}: value {v} is not a class code", path.display()))
        })
    };
    let (mut want, mut got) = (Vec::new(), Vec::new());
    for (k, i) in m.iter().enumerate() {
        let Some(i) = *i else { continue };
        if let Some((x0, x1)) = o.x_range {
            let x = r.xyz[k][0];
            if !(x >= x0 && x < x1) {
                continue;
            }
        }
        if !o.exclude.is_empty() && o.exclude.contains(r.xyz[k][0], r.xyz[k][1]) {
            continue;
        }
        let w = match &o.ref_map {
            Some(m) => match m.code_of(r.values[0][k]) {
                0 => continue,
                c => c,
            },
            None => code(r.values[0][k], reference)?,
        };
        want.push(w);
        got.push(lut[code(s.values[0][i], result)? as usize]);
    }
    let classes = match &o.ref_map {
        Some(m) if o.classes.is_empty() => m.codes(),
        _ => o.classes.clone(),
    };
    Ok(labels::evaluate(&want, &got, &classes))
}

#[cfg(test)]
mod tests {
    use super::match_points;

    #[test]
    fn match_points_pairs_duplicates_in_order_and_reports_missing() {
        let a = [1, 2, 3];
        let b = [4, 5, 6];
        // Same order: matched by index.
        assert_eq!(
            match_points(&[a, b], &[a, b], false).unwrap(),
            vec![Some(0), Some(1)]
        );
        // Shuffled with duplicates: a multiset, duplicates in file order.
        let r = [a, b, a, a];
        let s = [b, a, a, [7, 7, 7], a];
        assert_eq!(
            match_points(&r, &s, false).unwrap(),
            vec![Some(1), Some(0), Some(2), Some(4)]
        );
        // One more `a` than the result holds: an error, or None when allowed.
        let r = [a, a, a, a];
        assert!(match_points(&r, &s, false).is_err());
        assert_eq!(
            match_points(&r, &s, true).unwrap(),
            vec![Some(1), Some(2), Some(4), None]
        );
    }
}
