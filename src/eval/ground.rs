//! Ground-filter metrics: ISPRS WG III/3 (Sithole & Vosselman 2004) errors with Cohen's kappa,
//! and precision / recall / F1 for the SemanticKITTI ground-segmentation protocol.

/// ISPRS filter-test scores. Counts follow the cross matrix of Sithole & Vosselman:
/// `a` ground→ground, `b` ground→object (Type I), `c` object→ground (Type II), `d` object→object.
/// All error rates and kappa are in **percent**.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct GroundScores {
    /// Reference ground points (a + b).
    pub n_ground_ref: u64,
    /// Reference object points (c + d).
    pub n_object_ref: u64,
    /// Type I error, % of reference ground rejected as object: b / (a + b).
    pub type1: f64,
    /// Type II error, % of reference object accepted as ground: c / (c + d).
    pub type2: f64,
    /// Total error, % of all points misclassified: (b + c) / n.
    pub total: f64,
    /// Cohen's kappa, %.
    pub kappa: f64,
    /// Ground classified as ground.
    pub a: u64,
    /// Ground classified as object.
    pub b: u64,
    /// Object classified as ground.
    pub c: u64,
    /// Object classified as object.
    pub d: u64,
}

fn pct(num: u64, den: u64) -> f64 {
    if den == 0 {
        0.0
    } else {
        100.0 * num as f64 / den as f64
    }
}

/// Scores a ground classification against a reference (ISPRS WG III/3 definitions).
///
/// Only the first `min(len)` entries are compared if the slices differ in length. Rates with an
/// empty denominator are 0; kappa is 100 when expected agreement is already perfect.
pub fn score_ground(reference_is_ground: &[bool], result_is_ground: &[bool]) -> GroundScores {
    let (mut a, mut b, mut c, mut d) = (0u64, 0u64, 0u64, 0u64);
    for (&r, &g) in reference_is_ground.iter().zip(result_is_ground) {
        match (r, g) {
            (true, true) => a += 1,
            (true, false) => b += 1,
            (false, true) => c += 1,
            (false, false) => d += 1,
        }
    }
    let n = a + b + c + d;
    let kappa = if n == 0 {
        100.0
    } else {
        let nf = n as f64;
        let po = (a + d) as f64 / nf;
        let pe = ((a + b) as f64 * (a + c) as f64 + (c + d) as f64 * (b + d) as f64) / (nf * nf);
        if (1.0 - pe).abs() < f64::EPSILON {
            100.0
        } else {
            100.0 * (po - pe) / (1.0 - pe)
        }
    };
    GroundScores {
        n_ground_ref: a + b,
        n_object_ref: c + d,
        type1: pct(b, a + b),
        type2: pct(c, c + d),
        total: pct(b + c, n),
        kappa,
        a,
        b,
        c,
        d,
    }
}

/// Binary detection scores (ground = positive), precision / recall / F1 in **percent**.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct BinaryScores {
    /// Ground classified as ground.
    pub true_pos: u64,
    /// Non-ground classified as ground.
    pub false_pos: u64,
    /// Ground classified as non-ground.
    pub false_neg: u64,
    /// Non-ground classified as non-ground.
    pub true_neg: u64,
    /// tp / (tp + fp), %.
    pub precision: f64,
    /// tp / (tp + fn), %.
    pub recall: f64,
    /// Harmonic mean of precision and recall, %.
    pub f1: f64,
}

/// Precision, recall and F1 of ground detection. `scored[i] == false` excludes point `i`
/// (e.g. SemanticKITTI vegetation in the Patchwork++ protocol); `None` scores all points.
pub fn precision_recall_f1(
    reference_is_ground: &[bool],
    result_is_ground: &[bool],
    scored: Option<&[bool]>,
) -> BinaryScores {
    let (mut tp, mut fp, mut fn_, mut tn) = (0u64, 0u64, 0u64, 0u64);
    for (i, (&r, &g)) in reference_is_ground.iter().zip(result_is_ground).enumerate() {
        if let Some(s) = scored {
            if !s.get(i).copied().unwrap_or(false) {
                continue;
            }
        }
        match (r, g) {
            (true, true) => tp += 1,
            (false, true) => fp += 1,
            (true, false) => fn_ += 1,
            (false, false) => tn += 1,
        }
    }
    let precision = pct(tp, tp + fp);
    let recall = pct(tp, tp + fn_);
    let f1 = if precision + recall > 0.0 {
        2.0 * precision * recall / (precision + recall)
    } else {
        0.0
    };
    BinaryScores {
        true_pos: tp,
        false_pos: fp,
        false_neg: fn_,
        true_neg: tn,
        precision,
        recall,
        f1,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn isprs_cross_matrix_by_hand() {
        // a=3, b=1, c=2, d=4 → n=10
        let r = [
            true, true, true, true, false, false, false, false, false, false,
        ];
        let g = [
            true, true, true, false, true, true, false, false, false, false,
        ];
        let s = score_ground(&r, &g);
        assert_eq!((s.a, s.b, s.c, s.d), (3, 1, 2, 4));
        assert!((s.type1 - 25.0).abs() < 1e-12);
        assert!((s.type2 - 100.0 / 3.0).abs() < 1e-12);
        assert!((s.total - 30.0).abs() < 1e-12);
        // po = 0.7, pe = (4*5 + 6*5)/100 = 0.5 → kappa = 0.4
        assert!((s.kappa - 40.0).abs() < 1e-9);
    }

    #[test]
    fn prf_with_exclusion() {
        let r = [true, true, false, false];
        let g = [true, false, true, true];
        let scored = [true, true, true, false];
        let s = precision_recall_f1(&r, &g, Some(&scored));
        assert_eq!(
            (s.true_pos, s.false_pos, s.false_neg, s.true_neg),
            (1, 1, 1, 0)
        );
        assert!((s.f1 - 50.0).abs() < 1e-12);
    }
}
