//! Segment evaluation after Hoover et al. (1996), as adapted to point clouds by Sapkota (2008,
//! §5.2): an intersection matrix between reference and result segments, the five instance
//! classes (correct detection, over-segmentation, under-segmentation, missed, noise) at a set of
//! tolerances, and the RMSE of the angles between the planes of correctly detected pairs.
//!
//! # Definitions
//! Let `R_n` be the size (points) of reference segment `n`, `P_m` the size of result segment `m`
//! and `O_mn` the number of points labelled `n` in the reference and `m` in the result. Label `0`
//! means "no segment" on either side: such points count towards no segment and no overlap. For a
//! tolerance `T` in (0.5, 1]:
//!
//! - **correct detection** of `n` by `m`: `O_mn >= T·P_m` and `O_mn >= T·R_n`;
//! - **over-segmentation** of `n` into `m_1..m_k` (`k >= 2`): every `O_(m_i)n >= T·P_(m_i)` and
//!   `Σ O_(m_i)n >= T·R_n`;
//! - **under-segmentation** of `n_1..n_k` (`k >= 2`) into `m`: every `O_m(n_i) >= T·R_(n_i)` and
//!   `Σ O_m(n_i) >= T·P_m`;
//! - **missed**: a reference segment in no accepted instance of the three above;
//! - **noise**: a result segment in no accepted instance.
//!
//! These are Hoover's inequalities (`>=`); the thesis writes them with `>` (its eq. 5.2). The two
//! differ only when a ratio equals `T` exactly. Tolerances are compared exactly as decimal numbers
//! (quantised to 10⁻⁹), so 7 of 10 points meets `T = 0.7` although `0.7 * 10.0 > 7.0` in `f64`.
//!
//! # Which segments take part, and conflicts
//! Because `T > 0.5`, a result segment can hold a `T`-share of at most one reference segment (its
//! *home*), and vice versa. The over-segmentation of `n` uses **all** result segments whose home
//! is `n`, the under-segmentation of `m` all reference segments whose home is `m` (if a subset
//! satisfies the sum, the whole set does too).
//!
//! Hoover's definitions let one segment take part in more than one instance: when `m` and `n` are
//! each other's home, `(m, n)` can be a correct detection *and* part of the over-segmentation of
//! `n` *and* part of the under-segmentation of `m`. One can show that these three are the only
//! possible overlaps. Following the thesis (eq. 5.4 and the text after 5.5), each candidate has a
//! score, the mean of its two ratios — `(ΣO/ΣR + ΣO/ΣP) / 2` — and the candidate with the higher
//! score wins. **Ties** are broken in the fixed order correct detection, then over-segmentation,
//! then under-segmentation (a replacement must be strictly better, as in the thesis). Scores are
//! compared as exact fractions, so the outcome does not depend on rounding or on hash order.
//!
//! # Geometric accuracy
//! For every accepted correct pair, a least-squares plane is fitted to all points of the reference
//! segment and, independently, to all points of the result segment (normal = eigenvector of the
//! smallest eigenvalue of the covariance of the centred coordinates). The angle between the two
//! normals (sign ignored, 0–90°) enters an RMSE per tolerance. Segments with fewer than three
//! finite points, or whose points are (nearly) collinear, have no plane and are left out of the
//! RMSE; [`ToleranceRow::angle_pairs`] says how many pairs it used.

use serde::Serialize;
use std::cmp::Ordering;
use std::collections::{BTreeMap, BTreeSet, HashMap};
use std::fmt::Write as _;

mod plane;

use plane::fit_planes;
pub use plane::{angle_between_deg, plane_normal};

/// The tolerances of the thesis tables (5-3 … 5-8).
pub const THESIS_TOLERANCES: [f64; 6] = [0.51, 0.6, 0.7, 0.8, 0.9, 0.99];

/// Tolerances are compared as integers in parts per 10⁹.
const TOL_SCALE: f64 = 1e9;

/// Errors of segment evaluation: mismatched inputs or an unusable tolerance.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum SegEvalError {
    /// The two label arrays do not describe the same points.
    #[error(
        "reference has {reference} labels but result has {result}: both must label the same \
         points in the same order"
    )]
    LengthMismatch {
        /// Number of reference labels.
        reference: usize,
        /// Number of result labels.
        result: usize,
    },
    /// Coordinates were given for a different number of points than the labels.
    #[error("{xyz} coordinates given for {labels} labelled points")]
    XyzLengthMismatch {
        /// Number of coordinates.
        xyz: usize,
        /// Number of labels.
        labels: usize,
    },
    /// A tolerance outside (0.5, 1]: the definitions need a strict majority.
    #[error("tolerance {0} is outside (0.5, 1]: the Hoover definitions need a strict majority")]
    BadTolerance(f64),
}

/// The sparse intersection matrix between reference and result segments, with segment sizes.
///
/// Memory is proportional to the number of segments plus the number of non-zero cells, not to
/// the product of the segment counts.
#[derive(Debug, Clone, Default)]
pub struct IntersectionMatrix {
    reference_sizes: HashMap<u32, u64>,
    result_sizes: HashMap<u32, u64>,
    /// Non-zero `O_mn`, keyed by (reference, result).
    overlap: HashMap<(u32, u32), u64>,
    /// For each result segment: the reference segment it overlaps most (ties: smallest id).
    best_reference: HashMap<u32, (u32, u64)>,
    /// For each reference segment: the result segment it overlaps most (ties: smallest id).
    best_result: HashMap<u32, (u32, u64)>,
}

impl IntersectionMatrix {
    /// Counts segment sizes and overlaps; label 0 is "no segment" on both sides.
    pub fn build(reference: &[u32], result: &[u32]) -> Result<Self, SegEvalError> {
        if reference.len() != result.len() {
            return Err(SegEvalError::LengthMismatch {
                reference: reference.len(),
                result: result.len(),
            });
        }
        let mut m = IntersectionMatrix::default();
        // Labels usually come in runs (points are stored segment by segment, or along a scan
        // line), so counting runs saves most hash-map updates on large inputs.
        let mut run: Option<((u32, u32), u64)> = None;
        for (&n, &o) in reference.iter().zip(result) {
            match &mut run {
                Some((pair, count)) if *pair == (n, o) => *count += 1,
                _ => {
                    if let Some((pair, count)) = run.take() {
                        m.add_run(pair, count);
                    }
                    run = Some(((n, o), 1));
                }
            }
        }
        if let Some((pair, count)) = run {
            m.add_run(pair, count);
        }
        for (&(n, o), &c) in &m.overlap {
            update_best(m.best_reference.entry(o).or_insert((n, c)), n, c);
            update_best(m.best_result.entry(n).or_insert((o, c)), o, c);
        }
        Ok(m)
    }

    fn add_run(&mut self, (n, o): (u32, u32), count: u64) {
        if n != 0 {
            *self.reference_sizes.entry(n).or_insert(0) += count;
        }
        if o != 0 {
            *self.result_sizes.entry(o).or_insert(0) += count;
        }
        if n != 0 && o != 0 {
            *self.overlap.entry((n, o)).or_insert(0) += count;
        }
    }

    /// Number of distinct non-zero reference labels.
    pub fn reference_segments(&self) -> usize {
        self.reference_sizes.len()
    }

    /// Number of distinct non-zero result labels.
    pub fn result_segments(&self) -> usize {
        self.result_sizes.len()
    }

    /// Points in reference segment `n` (`R_n`); 0 if absent.
    pub fn reference_size(&self, n: u32) -> u64 {
        self.reference_sizes.get(&n).copied().unwrap_or(0)
    }

    /// Points in result segment `m` (`P_m`); 0 if absent.
    pub fn result_size(&self, m: u32) -> u64 {
        self.result_sizes.get(&m).copied().unwrap_or(0)
    }

    /// Points shared by reference segment `n` and result segment `m` (`O_mn`).
    pub fn overlap(&self, n: u32, m: u32) -> u64 {
        self.overlap.get(&(n, m)).copied().unwrap_or(0)
    }

    /// Number of non-zero cells of the matrix.
    pub fn nonzero_cells(&self) -> usize {
        self.overlap.len()
    }

    /// Classifies all segments at one tolerance (see the module docs for the rules).
    pub fn classify(&self, tolerance: f64) -> Result<Classification, SegEvalError> {
        if tolerance.is_nan() || tolerance <= 0.5 || tolerance > 1.0 {
            return Err(SegEvalError::BadTolerance(tolerance));
        }
        let t = Threshold::new(tolerance);

        // Homes: result → reference holding a T-share of it, and reference → result.
        let mut home_of_result: BTreeMap<u32, u32> = BTreeMap::new();
        for (&m, &(n, o)) in &self.best_reference {
            if t.met(o, self.result_size(m)) {
                home_of_result.insert(m, n);
            }
        }
        let mut home_of_reference: BTreeMap<u32, u32> = BTreeMap::new();
        for (&n, &(m, o)) in &self.best_result {
            if t.met(o, self.reference_size(n)) {
                home_of_reference.insert(n, m);
            }
        }

        let mut candidates: Vec<Candidate> = Vec::new();
        // Correct detections: mutual homes.
        for (&m, &n) in &home_of_result {
            if home_of_reference.get(&n) == Some(&m) {
                let o = self.overlap(n, m);
                candidates.push(Candidate {
                    kind: Kind::Correct,
                    references: vec![n],
                    results: vec![m],
                    score: Score::new(o, self.reference_size(n), o, self.result_size(m)),
                });
            }
        }
        // Over-segmentation: ≥ 2 result segments at home in one reference segment.
        let mut parts_of_reference: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (&m, &n) in &home_of_result {
            parts_of_reference.entry(n).or_default().push(m);
        }
        for (n, parts) in parts_of_reference {
            if parts.len() < 2 {
                continue;
            }
            let sum_o: u64 = parts.iter().map(|&m| self.overlap(n, m)).sum();
            let sum_p: u64 = parts.iter().map(|&m| self.result_size(m)).sum();
            let r = self.reference_size(n);
            if t.met(sum_o, r) {
                candidates.push(Candidate {
                    kind: Kind::Over,
                    references: vec![n],
                    results: parts,
                    score: Score::new(sum_o, r, sum_o, sum_p),
                });
            }
        }
        // Under-segmentation: ≥ 2 reference segments at home in one result segment.
        let mut parts_of_result: BTreeMap<u32, Vec<u32>> = BTreeMap::new();
        for (&n, &m) in &home_of_reference {
            parts_of_result.entry(m).or_default().push(n);
        }
        for (m, parts) in parts_of_result {
            if parts.len() < 2 {
                continue;
            }
            let sum_o: u64 = parts.iter().map(|&n| self.overlap(n, m)).sum();
            let sum_r: u64 = parts.iter().map(|&n| self.reference_size(n)).sum();
            let p = self.result_size(m);
            if t.met(sum_o, p) {
                candidates.push(Candidate {
                    kind: Kind::Under,
                    references: parts,
                    results: vec![m],
                    score: Score::new(sum_o, sum_r, sum_o, p),
                });
            }
        }

        // Best score first; ties by kind (correct, over, under), then by the smallest ids.
        candidates.sort_by(|a, b| {
            b.score
                .cmp(&a.score)
                .then(a.kind.cmp(&b.kind))
                .then_with(|| a.references.cmp(&b.references))
                .then_with(|| a.results.cmp(&b.results))
        });
        let mut used_ref: BTreeSet<u32> = BTreeSet::new();
        let mut used_res: BTreeSet<u32> = BTreeSet::new();
        let mut out = Classification {
            tolerance,
            ..Classification::default()
        };
        for c in candidates {
            if c.references.iter().any(|n| used_ref.contains(n))
                || c.results.iter().any(|m| used_res.contains(m))
            {
                continue;
            }
            used_ref.extend(&c.references);
            used_res.extend(&c.results);
            match c.kind {
                Kind::Correct => out.correct.push((c.references[0], c.results[0])),
                Kind::Over => out.over.push((c.references[0], c.results)),
                Kind::Under => out.under.push((c.results[0], c.references)),
            }
        }
        out.correct.sort_unstable();
        out.over.sort();
        out.under.sort();
        out.missed = sorted_keys(&self.reference_sizes, &used_ref);
        out.noise = sorted_keys(&self.result_sizes, &used_res);
        Ok(out)
    }
}

fn update_best(best: &mut (u32, u64), id: u32, count: u64) {
    if count > best.1 || (count == best.1 && id < best.0) {
        *best = (id, count);
    }
}

fn sorted_keys(sizes: &HashMap<u32, u64>, used: &BTreeSet<u32>) -> Vec<u32> {
    let mut v: Vec<u32> = sizes
        .keys()
        .filter(|k| !used.contains(k))
        .copied()
        .collect();
    v.sort_unstable();
    v
}

/// `count >= T · size`, evaluated exactly with `T` quantised to 10⁻⁹.
#[derive(Clone, Copy)]
struct Threshold {
    parts_per_billion: u128,
}

impl Threshold {
    fn new(t: f64) -> Self {
        Threshold {
            parts_per_billion: (t * TOL_SCALE).round() as u128,
        }
    }

    fn met(self, count: u64, size: u64) -> bool {
        size > 0
            && u128::from(count) * (TOL_SCALE as u128) >= self.parts_per_billion * u128::from(size)
    }
}

/// Candidate kinds in tie-breaking order.
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord)]
enum Kind {
    Correct,
    Over,
    Under,
}

struct Candidate {
    kind: Kind,
    references: Vec<u32>,
    results: Vec<u32>,
    score: Score,
}

/// `a/b + c/d` (twice the mean ratio), kept as a fraction for exact comparison.
#[derive(Clone, Copy, Debug)]
struct Score {
    num: u128,
    den: u128,
}

impl Score {
    fn new(a: u64, b: u64, c: u64, d: u64) -> Self {
        let (a, b, c, d) = (a as u128, b as u128, c as u128, d as u128);
        Score {
            num: a * d + c * b,
            den: b * d,
        }
    }

    fn as_f64(self) -> f64 {
        self.num as f64 / self.den as f64
    }
}

impl Ord for Score {
    fn cmp(&self, other: &Self) -> Ordering {
        match (
            self.num.checked_mul(other.den),
            other.num.checked_mul(self.den),
        ) {
            (Some(l), Some(r)) => l.cmp(&r),
            // Only with segments of billions of points; f64 is then as good as it gets.
            _ => self.as_f64().total_cmp(&other.as_f64()),
        }
    }
}

impl PartialOrd for Score {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

impl PartialEq for Score {
    fn eq(&self, other: &Self) -> bool {
        self.cmp(other) == Ordering::Equal
    }
}

impl Eq for Score {}

/// Instances at one tolerance; every list is sorted by segment id.
#[derive(Debug, Clone, Default, PartialEq, Serialize)]
pub struct Classification {
    /// The tolerance `T`.
    pub tolerance: f64,
    /// Correct detections as (reference, result).
    pub correct: Vec<(u32, u32)>,
    /// Over-segmentations as (reference, result segments it was split into).
    pub over: Vec<(u32, Vec<u32>)>,
    /// Under-segmentations as (result, reference segments merged into it).
    pub under: Vec<(u32, Vec<u32>)>,
    /// Reference segments in no instance.
    pub missed: Vec<u32>,
    /// Result segments in no instance.
    pub noise: Vec<u32>,
}

/// Counts at one tolerance: one row of thesis Tables 5-3 … 5-8.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ToleranceRow {
    /// The tolerance `T`.
    pub tolerance: f64,
    /// Instances of correct detection.
    pub correct: usize,
    /// Instances of over-segmentation (reference segments split up).
    pub over: usize,
    /// Result segments taking part in over-segmentations.
    pub over_result_segments: usize,
    /// Instances of under-segmentation (result segments merging several references).
    pub under: usize,
    /// Reference segments taking part in under-segmentations.
    pub under_reference_segments: usize,
    /// Missed reference segments.
    pub missed: usize,
    /// Noise result segments.
    pub noise: usize,
    /// Correct pairs with a plane on both sides (the angles in the RMSE).
    pub angle_pairs: usize,
    /// RMSE of the angles between matched planes, degrees; `None` without coordinates or pairs.
    pub angle_rmse_deg: Option<f64>,
}

/// Result of [`evaluate`]: segment counts and one row per tolerance.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct SegEval {
    /// Points compared.
    pub points: usize,
    /// Distinct non-zero reference labels.
    pub reference_segments: usize,
    /// Distinct non-zero result labels.
    pub result_segments: usize,
    /// One row per requested tolerance, in the order given.
    pub rows: Vec<ToleranceRow>,
}

impl SegEval {
    /// A plain-text table in the layout of thesis Tables 5-3 … 5-8: one row per tolerance.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = writeln!(
            s,
            "{:>9} {:>9} {:>7} {:>7} {:>5} {:>5} {:>6} {:>5} {:>6} {:>10}",
            "tolerance",
            "reference",
            "result",
            "correct",
            "over",
            "under",
            "missed",
            "noise",
            "planes",
            "angle_rmse"
        );
        for r in &self.rows {
            let angle = match r.angle_rmse_deg {
                Some(a) => format!("{a:.2}"),
                None => "-".to_string(),
            };
            let _ = writeln!(
                s,
                "{:>9} {:>9} {:>7} {:>7} {:>5} {:>5} {:>6} {:>5} {:>6} {:>10}",
                format!("{}", r.tolerance),
                self.reference_segments,
                self.result_segments,
                r.correct,
                r.over,
                r.under,
                r.missed,
                r.noise,
                r.angle_pairs,
                angle
            );
        }
        s
    }
}

/// Evaluates `result` segment labels against `reference` labels of the same points (0 = no
/// segment) at each tolerance, with angle RMSEs when `xyz` is given.
///
/// ```
/// use tessera::eval::segments::{evaluate, THESIS_TOLERANCES};
/// // Reference segment 1 is found as result 5 except for one unsegmented point;
/// // reference segment 2 is split into results 6 and 7.
/// let reference = [1, 1, 1, 1, 2, 2, 2, 2];
/// let result = [5, 5, 5, 0, 6, 6, 7, 7];
/// let e = evaluate(&reference, &result, None, &THESIS_TOLERANCES);
/// assert_eq!((e.rows[0].correct, e.rows[0].over), (1, 1)); // T = 0.51
/// assert_eq!((e.rows[5].missed, e.rows[5].noise), (1, 1)); // T = 0.99
/// println!("{}", e.table());
/// ```
///
/// # Panics
/// If the label slices differ in length, `xyz` has another length, or a tolerance is outside
/// (0.5, 1]. Use [`try_evaluate`] to get these as errors.
pub fn evaluate(
    reference: &[u32],
    result: &[u32],
    xyz: Option<&[[f64; 3]]>,
    tolerances: &[f64],
) -> SegEval {
    match try_evaluate(reference, result, xyz, tolerances) {
        Ok(e) => e,
        Err(e) => panic!("segment evaluation: {e}"),
    }
}

/// [`evaluate`] returning input errors instead of panicking.
pub fn try_evaluate(
    reference: &[u32],
    result: &[u32],
    xyz: Option<&[[f64; 3]]>,
    tolerances: &[f64],
) -> Result<SegEval, SegEvalError> {
    if let Some(p) = xyz {
        if p.len() != reference.len() {
            return Err(SegEvalError::XyzLengthMismatch {
                xyz: p.len(),
                labels: reference.len(),
            });
        }
    }
    let matrix = IntersectionMatrix::build(reference, result)?;
    let classes = tolerances
        .iter()
        .map(|&t| matrix.classify(t))
        .collect::<Result<Vec<_>, _>>()?;

    // Planes only for segments that are in some correct pair.
    let (ref_planes, res_planes) = match xyz {
        Some(p) => {
            let want_ref: BTreeSet<u32> = classes
                .iter()
                .flat_map(|c| c.correct.iter().map(|&(n, _)| n))
                .collect();
            let want_res: BTreeSet<u32> = classes
                .iter()
                .flat_map(|c| c.correct.iter().map(|&(_, m)| m))
                .collect();
            (
                fit_planes(reference, p, &want_ref),
                fit_planes(result, p, &want_res),
            )
        }
        None => (HashMap::new(), HashMap::new()),
    };

    let rows = classes
        .iter()
        .map(|c| {
            let mut sum_sq = 0.0;
            let mut pairs = 0usize;
            for (n, m) in &c.correct {
                if let (Some(a), Some(b)) = (ref_planes.get(n), res_planes.get(m)) {
                    let ang = angle_between_deg(a, b);
                    sum_sq += ang * ang;
                    pairs += 1;
                }
            }
            ToleranceRow {
                tolerance: c.tolerance,
                correct: c.correct.len(),
                over: c.over.len(),
                over_result_segments: c.over.iter().map(|(_, v)| v.len()).sum(),
                under: c.under.len(),
                under_reference_segments: c.under.iter().map(|(_, v)| v.len()).sum(),
                missed: c.missed.len(),
                noise: c.noise.len(),
                angle_pairs: pairs,
                angle_rmse_deg: (pairs > 0).then(|| (sum_sq / pairs as f64).sqrt()),
            }
        })
        .collect();
    Ok(SegEval {
        points: reference.len(),
        reference_segments: matrix.reference_segments(),
        result_segments: matrix.result_segments(),
        rows,
    })
}

#[cfg(test)]
mod tests;
