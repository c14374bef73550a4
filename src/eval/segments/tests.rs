//! Hand-built cases for every instance class and each tolerance boundary.

use super::*;

/// Labels from runs of (reference, result, points).
fn labels(runs: &[(u32, u32, usize)]) -> (Vec<u32>, Vec<u32>) {
    let mut r = Vec::new();
    let mut s = Vec::new();
    for &(a, b, n) in runs {
        r.extend(std::iter::repeat_n(a, n));
        s.extend(std::iter::repeat_n(b, n));
    }
    (r, s)
}

fn row(e: &SegEval, t: f64) -> &ToleranceRow {
    e.rows.iter().find(|r| r.tolerance == t).expect("row")
}

/// (correct, over, under, missed, noise)
fn counts(r: &ToleranceRow) -> (usize, usize, usize, usize, usize) {
    (r.correct, r.over, r.under, r.missed, r.noise)
}

#[test]
fn identical_segmentations_are_all_correct() {
    // Result ids differ from reference ids: only the partition matters.
    let (r, s) = labels(&[(1, 10, 5), (2, 20, 7), (0, 0, 3), (3, 30, 1)]);
    let e = evaluate(&r, &s, None, &THESIS_TOLERANCES);
    assert_eq!((e.reference_segments, e.result_segments), (3, 3));
    for row in &e.rows {
        assert_eq!(counts(row), (3, 0, 0, 0, 0), "T = {}", row.tolerance);
        assert_eq!(row.angle_rmse_deg, None);
    }
}

#[test]
fn correct_detection_boundary_on_reference_side() {
    // Reference 1 has 10 points; result 7 holds exactly 7 of them and nothing else.
    let (r, s) = labels(&[(1, 7, 7), (1, 0, 3)]);
    let e = evaluate(&r, &s, None, &[0.6, 0.7, 0.8]);
    assert_eq!(counts(row(&e, 0.6)), (1, 0, 0, 0, 0));
    // 7 >= 0.7 * 10 holds exactly (it would not with naive f64 arithmetic).
    assert_eq!(counts(row(&e, 0.7)), (1, 0, 0, 0, 0));
    assert_eq!(counts(row(&e, 0.8)), (0, 0, 0, 1, 1));
}

#[test]
fn correct_detection_boundary_on_result_side() {
    // Result 5 has 10 points: all 6 of reference 2, plus 4 unsegmented reference points.
    let (r, s) = labels(&[(2, 5, 6), (0, 5, 4)]);
    let e = evaluate(&r, &s, None, &[0.51, 0.6, 0.7]);
    assert_eq!(counts(row(&e, 0.51)), (1, 0, 0, 0, 0));
    assert_eq!(counts(row(&e, 0.6)), (1, 0, 0, 0, 0));
    assert_eq!(counts(row(&e, 0.7)), (0, 0, 0, 1, 1));
}

#[test]
fn over_segmentation_and_its_boundaries() {
    // Reference 1 (10 points) split into A = 11 (5 points, all inside) and B = 12 (4 inside,
    // 1 outside: 4/5 = 0.8); together they hold 9/10 of reference 1. One point of 1 is unsegmented.
    let (r, s) = labels(&[(1, 11, 5), (1, 12, 4), (1, 0, 1), (0, 12, 1)]);
    let e = evaluate(&r, &s, None, &[0.51, 0.8, 0.9]);
    for t in [0.51, 0.8] {
        let row = row(&e, t);
        assert_eq!(counts(row), (0, 1, 0, 0, 0), "T = {t}");
        assert_eq!(row.over_result_segments, 2);
    }
    // At 0.9 part B no longer lies within reference 1 (0.8 < 0.9): one part is not enough.
    assert_eq!(counts(row(&e, 0.9)), (0, 0, 0, 1, 2));

    // Same parts, but now the sum is the binding condition: 9 of 10 → over up to T = 0.9.
    let (r, s) = labels(&[(1, 11, 5), (1, 12, 4), (1, 0, 1)]);
    let e = evaluate(&r, &s, None, &[0.9, 0.99]);
    assert_eq!(counts(row(&e, 0.9)), (0, 1, 0, 0, 0));
    assert_eq!(counts(row(&e, 0.99)), (0, 0, 0, 1, 2));
    let c = IntersectionMatrix::build(&r, &s)
        .and_then(|m| m.classify(0.9))
        .expect("classify");
    assert_eq!(c.over, vec![(1, vec![11, 12])]);
}

#[test]
fn under_segmentation_and_its_boundaries() {
    // Result 9 (10 points) merges reference 1 (5 points, all in 9) and reference 2 (4 of its 5
    // points in 9, 4/5 = 0.8), plus one unsegmented reference point: Σ = 9/10.
    let (r, s) = labels(&[(1, 9, 5), (2, 9, 4), (2, 0, 1), (0, 9, 1)]);
    let e = evaluate(&r, &s, None, &[0.51, 0.8, 0.9]);
    for t in [0.51, 0.8] {
        let row = row(&e, t);
        assert_eq!(counts(row), (0, 0, 1, 0, 0), "T = {t}");
        assert_eq!(row.under_reference_segments, 2);
    }
    assert_eq!(counts(row(&e, 0.9)), (0, 0, 0, 2, 1));
    let c = IntersectionMatrix::build(&r, &s)
        .and_then(|m| m.classify(0.8))
        .expect("classify");
    assert_eq!(c.under, vec![(9, vec![1, 2])]);
}

#[test]
fn missed_and_noise() {
    // Reference 3 is spread half-and-half over results 21 and 22, each of which is itself half
    // reference 4 / reference 5: nobody holds a majority of anybody except 4 ⊂ 21 and 5 ⊂ 22,
    // which are single parts (no over/under) and not mutual (no correct).
    let (r, s) = labels(&[(3, 21, 2), (3, 22, 2), (4, 21, 2), (5, 22, 2)]);
    let e = evaluate(&r, &s, None, &THESIS_TOLERANCES);
    for row in &e.rows {
        assert_eq!(counts(row), (0, 0, 0, 3, 2), "T = {}", row.tolerance);
    }
    let c = IntersectionMatrix::build(&r, &s)
        .and_then(|m| m.classify(0.51))
        .expect("classify");
    assert_eq!((c.missed, c.noise), (vec![3, 4, 5], vec![21, 22]));
}

#[test]
fn over_beats_correct_when_its_mean_ratio_is_higher() {
    // Reference 1 (10): result 7 = 7 points inside, result 8 = the other 3 inside.
    // correct (1,7): (0.7 + 1)/2 = 0.85; over (1 → 7, 8): (1 + 1)/2 = 1.
    let (r, s) = labels(&[(1, 7, 7), (1, 8, 3)]);
    let c = IntersectionMatrix::build(&r, &s)
        .and_then(|m| m.classify(0.7))
        .expect("classify");
    assert!(c.correct.is_empty());
    assert_eq!(c.over, vec![(1, vec![7, 8])]);
    assert!(c.missed.is_empty() && c.noise.is_empty());
}

#[test]
fn correct_wins_a_tie_with_over() {
    // Reference 1 (32 points): result 7 = 17 points, all inside; result 8 = 4 inside + 3 outside;
    // 11 points of 1 unsegmented. correct: (17/32 + 17/17)/2 = 49/64;
    // over: (21/32 + 21/24)/2 = 49/64 as well → tie → correct, and 8 becomes noise.
    let (r, s) = labels(&[(1, 7, 17), (1, 8, 4), (0, 8, 3), (1, 0, 11)]);
    let c = IntersectionMatrix::build(&r, &s)
        .and_then(|m| m.classify(0.51))
        .expect("classify");
    assert_eq!(c.correct, vec![(1, 7)]);
    assert!(c.over.is_empty());
    assert_eq!(c.noise, vec![8]);
}

#[test]
fn under_beats_correct_when_its_mean_ratio_is_higher() {
    // Result 9 (12) = reference 1 (10) + reference 2 (2). correct (1,9): (1 + 10/12)/2 < 1 = under.
    let (r, s) = labels(&[(1, 9, 10), (2, 9, 2)]);
    let e = evaluate(&r, &s, None, &[0.51, 0.8, 0.9]);
    assert_eq!(counts(row(&e, 0.51)), (0, 0, 1, 0, 0));
    assert_eq!(counts(row(&e, 0.8)), (0, 0, 1, 0, 0));
    // 10/12 < 0.9: no longer correct, but the under-segmentation still holds (12/12, 2/2, 10/10).
    assert_eq!(counts(row(&e, 0.9)), (0, 0, 1, 0, 0));
}

#[test]
fn unsegmented_points_only() {
    let e = evaluate(&[0, 0, 0], &[0, 0, 0], None, &THESIS_TOLERANCES);
    assert_eq!((e.reference_segments, e.result_segments), (0, 0));
    assert!(e.rows.iter().all(|r| counts(r) == (0, 0, 0, 0, 0)));
    let e = evaluate(&[], &[], None, &[0.51]);
    assert_eq!(e.points, 0);
}

#[test]
fn input_errors() {
    assert_eq!(
        try_evaluate(&[1, 2], &[1], None, &[0.6]),
        Err(SegEvalError::LengthMismatch {
            reference: 2,
            result: 1
        })
    );
    assert_eq!(
        try_evaluate(&[1], &[1], Some(&[]), &[0.6]),
        Err(SegEvalError::XyzLengthMismatch { xyz: 0, labels: 1 })
    );
    for t in [0.5, 0.2, 1.01, f64::NAN] {
        assert!(matches!(
            try_evaluate(&[1], &[1], None, &[t]),
            Err(SegEvalError::BadTolerance(_))
        ));
    }
    assert!(try_evaluate(&[1], &[1], None, &[1.0]).is_ok());
}

#[test]
#[should_panic(expected = "segment evaluation")]
fn evaluate_panics_on_bad_input() {
    evaluate(&[1], &[1, 2], None, &[0.6]);
}

/// Two correct pairs whose planes meet at known angles: the shared points lie on the line where
/// the planes intersect, the reference-only points on z = 0, the result-only points on a plane
/// tilted by θ about the x axis.
#[test]
fn angle_rmse_of_matched_planes() {
    let mut r = Vec::new();
    let mut s = Vec::new();
    let mut xyz = Vec::new();
    for (id, theta_deg, x0) in [(1u32, 10.0f64, 0.0), (2, 20.0, 100.0)] {
        let t = theta_deg.to_radians();
        for k in 0..6 {
            xyz.push([x0 + k as f64, 0.0, 0.0]);
            r.push(id);
            s.push(id + 10);
        }
        for x in [x0, x0 + 5.0] {
            xyz.push([x, 1.0, 0.0]);
            r.push(id);
            s.push(0);
            xyz.push([x, 2.0 * t.cos(), 2.0 * t.sin()]);
            r.push(0);
            s.push(id + 10);
        }
    }
    // Each pair: O = 6, R = P = 8 → correct up to T = 0.75.
    let e = evaluate(&r, &s, Some(&xyz), &[0.7, 0.8]);
    let at = row(&e, 0.7);
    assert_eq!((at.correct, at.angle_pairs), (2, 2));
    let want = ((10.0f64.powi(2) + 20.0f64.powi(2)) / 2.0).sqrt();
    let got = at.angle_rmse_deg.expect("rmse");
    assert!((got - want).abs() < 1e-9, "{got} vs {want}");
    assert_eq!(row(&e, 0.8).angle_rmse_deg, None);

    let table = e.table();
    assert!(table.contains("angle_rmse"), "{table}");
    assert!(table.contains(&format!("{want:.2}")), "{table}");
    let json = serde_json::to_value(&e).expect("json");
    assert_eq!(json["rows"][1]["angle_rmse_deg"], serde_json::Value::Null);
}

#[test]
fn plane_fit_is_robust_to_offsets_and_degenerate_sets() {
    // A tilted plane far from the origin (georeferenced coordinates).
    let mut pts = Vec::new();
    for i in 0..5 {
        for j in 0..5 {
            let (x, y) = (i as f64 * 0.5, j as f64 * 0.5);
            pts.push([4.5e5 + x, 5.7e6 + y, 30.0 + 0.25 * x - 0.5 * y]);
        }
    }
    let n = plane_normal(&pts).expect("plane");
    let want: [f64; 3] = [-0.25, 0.5, 1.0];
    let len = (want[0] * want[0] + want[1] * want[1] + want[2] * want[2]).sqrt();
    let want = [want[0] / len, want[1] / len, want[2] / len];
    assert!(angle_between_deg(&n, &want) < 1e-6);
    // Collinear and tiny sets have no plane.
    assert_eq!(
        plane_normal(&[[0.0; 3], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]]),
        None
    );
    assert_eq!(plane_normal(&[[0.0; 3], [1.0, 0.0, 0.0]]), None);
    // Opposite normals are the same plane.
    assert!(angle_between_deg(&[0.0, 0.0, 1.0], &[0.0, 0.0, -1.0]) < 1e-12);
    assert!((angle_between_deg(&[0.0, 0.0, 1.0], &[1.0, 0.0, 0.0]) - 90.0).abs() < 1e-12);
}

#[test]
fn table_has_one_row_per_tolerance() {
    let (r, s) = labels(&[(1, 7, 7), (1, 0, 3)]);
    let e = evaluate(&r, &s, None, &THESIS_TOLERANCES);
    let t = e.table();
    assert_eq!(t.lines().count(), 1 + THESIS_TOLERANCES.len(), "{t}");
    assert!(t
        .lines()
        .nth(1)
        .is_some_and(|l| l.trim_start().starts_with("0.51")));
}

/// Many points and segments: a shuffled-label relabelling with a few splits and merges, checked
/// against counts known by construction.
#[test]
fn large_sparse_case() {
    let segments = 5000u32;
    let per = 400usize;
    let mut r = Vec::with_capacity(segments as usize * per);
    let mut s = Vec::with_capacity(segments as usize * per);
    for n in 1..=segments {
        for k in 0..per {
            r.push(n);
            // Every 10th reference segment is split in two halves (over-segmentation); the
            // rest are relabelled one to one with 1 % unsegmented points.
            let m = if n % 10 == 0 {
                n * 2 + (k % 2) as u32 + 100_000
            } else if k % 100 == 0 {
                0
            } else {
                n * 3 + 7
            };
            s.push(m);
        }
    }
    let e = evaluate(&r, &s, None, &THESIS_TOLERANCES);
    let split = (segments / 10) as usize;
    let whole = segments as usize - split;
    assert_eq!(counts(row(&e, 0.9)), (whole, split, 0, 0, 0));
    // 99 % of each unsplit reference is found: correct up to 0.99 exactly.
    assert_eq!(counts(row(&e, 0.99)), (whole, split, 0, 0, 0));
}
