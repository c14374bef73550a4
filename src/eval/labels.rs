//! Label evaluation (street-level document, chapter 5 §9.2.4, Tables 13–16): confusion matrix
//! of reference classes (rows) against predicted classes (columns, plus `other` for predicted
//! codes outside the scored set), errors of omission and commission and the mapping accuracy
//! per class, with precision, recall and F1.
//!
//! Definitions for a class c with `d` points correct, row total `r` (reference c) and column
//! total `p` (predicted c, over the scored rows): omission = (r − d) / r, commission =
//! (p − d) / p, mapping accuracy = d / (r + p − d) (Table 14: road 8652 / (8973 + 9053 − 8652)
//! = 92 %), precision = d / p, recall = d / r, F1 = 2PR / (P + R).

use serde::Serialize;
use std::fmt::Write;

/// Per-class figures.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ClassRow {
    /// Class code.
    pub class: u8,
    /// Reference points of the class (row total).
    pub reference: u64,
    /// Points predicted as the class among the scored rows (column total).
    pub predicted: u64,
    /// Points of the class predicted correctly.
    pub correct: u64,
    /// Error of omission.
    pub omission: f64,
    /// Error of commission.
    pub commission: f64,
    /// Mapping accuracy.
    pub mapping_accuracy: f64,
    /// Precision.
    pub precision: f64,
    /// Recall.
    pub recall: f64,
    /// F1 score.
    pub f1: f64,
}

/// Result of [`evaluate`].
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct LabelEval {
    /// Scored classes (rows; columns are these plus `other`).
    pub classes: Vec<u8>,
    /// `matrix[row][col]`, the last column is `other`.
    pub matrix: Vec<Vec<u64>>,
    /// Per class.
    pub rows: Vec<ClassRow>,
    /// Points scored.
    pub points: u64,
    /// Share of scored points predicted correctly.
    pub overall_accuracy: f64,
}

fn ratio(a: u64, b: u64) -> f64 {
    if b == 0 {
        f64::NAN
    } else {
        a as f64 / b as f64
    }
}

/// Scores `predicted` against `reference` (same length and order). Only points whose
/// reference class is in `classes` are scored; empty `classes`: every reference class present.
pub fn evaluate(reference: &[u8], predicted: &[u8], classes: &[u8]) -> LabelEval {
    let mut cls: Vec<u8> = if classes.is_empty() {
        let mut seen = [false; 256];
        for &c in reference {
            seen[c as usize] = true;
        }
        (0..=255u8).filter(|&c| seen[c as usize]).collect()
    } else {
        classes.to_vec()
    };
    cls.dedup();
    let mut col_of = [usize::MAX; 256];
    for (k, &c) in cls.iter().enumerate() {
        col_of[c as usize] = k;
    }
    let k = cls.len();
    let mut matrix = vec![vec![0u64; k + 1]; k];
    let mut points = 0;
    for (&r, &p) in reference.iter().zip(predicted) {
        let row = col_of[r as usize];
        if row == usize::MAX {
            continue;
        }
        let col = match col_of[p as usize] {
            usize::MAX => k,
            c => c,
        };
        matrix[row][col] += 1;
        points += 1;
    }
    let mut correct_all = 0;
    let rows = (0..k)
        .map(|i| {
            let d = matrix[i][i];
            correct_all += d;
            let r: u64 = matrix[i].iter().sum();
            let p: u64 = (0..k).map(|j| matrix[j][i]).sum();
            let (prec, rec) = (ratio(d, p), ratio(d, r));
            ClassRow {
                class: cls[i],
                reference: r,
                predicted: p,
                correct: d,
                omission: 1.0 - rec,
                commission: 1.0 - prec,
                mapping_accuracy: ratio(d, r + p - d),
                precision: prec,
                recall: rec,
                f1: if prec + rec > 0.0 {
                    2.0 * prec * rec / (prec + rec)
                } else {
                    0.0
                },
            }
        })
        .collect();
    LabelEval {
        classes: cls,
        matrix,
        rows,
        points,
        overall_accuracy: ratio(correct_all, points),
    }
}

impl LabelEval {
    /// The row of class `c`.
    pub fn row(&self, c: u8) -> Option<&ClassRow> {
        self.rows.iter().find(|r| r.class == c)
    }

    /// Confusion matrix and per-class table, like the document's Tables 13 and 14.
    pub fn table(&self) -> String {
        let mut s = String::new();
        let _ = write!(s, "{:>10}", "ref\\pred");
        for c in &self.classes {
            let _ = write!(s, " {c:>9}");
        }
        let _ = writeln!(s, " {:>9} {:>9}", "other", "total");
        for (i, c) in self.classes.iter().enumerate() {
            let _ = write!(s, "{c:>10}");
            for v in &self.matrix[i] {
                let _ = write!(s, " {v:>9}");
            }
            let _ = writeln!(s, " {:>9}", self.matrix[i].iter().sum::<u64>());
        }
        let _ = writeln!(
            s,
            "\n{:>6} {:>9} {:>9} {:>9} {:>10} {:>11} {:>9} {:>9} {:>7}",
            "class",
            "reference",
            "predicted",
            "correct",
            "omission",
            "commission",
            "mapping",
            "precision",
            "F1"
        );
        let pct = |v: f64| {
            if v.is_nan() {
                "-".to_string()
            } else {
                format!("{:.1}%", 100.0 * v)
            }
        };
        for r in &self.rows {
            let _ = writeln!(
                s,
                "{:>6} {:>9} {:>9} {:>9} {:>10} {:>11} {:>9} {:>9} {:>7.3}",
                r.class,
                r.reference,
                r.predicted,
                r.correct,
                pct(r.omission),
                pct(r.commission),
                pct(r.mapping_accuracy),
                pct(r.precision),
                r.f1
            );
        }
        let _ = writeln!(
            s,
            "overall accuracy {} over {} points",
            pct(self.overall_accuracy),
            self.points
        );
        s
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The document's Table 13 (supervised classification) gives Table 14's figures.
    #[test]
    fn reproduces_document_table_14() {
        // Rows: road, cycle, tiles, grass; columns: road, cycle, tiles, grass, other.
        let t: [[u64; 5]; 4] = [
            [8652, 101, 206, 0, 14],
            [0, 4591, 2, 0, 926],
            [401, 321, 3760, 0, 2],
            [0, 0, 0, 5619, 50],
        ];
        let codes = [11u8, 64, 65, 67];
        let (mut r, mut p) = (Vec::new(), Vec::new());
        for (i, row) in t.iter().enumerate() {
            for (j, &n) in row.iter().enumerate() {
                let pred = if j < 4 { codes[j] } else { 1 };
                r.extend(std::iter::repeat_n(codes[i], n as usize));
                p.extend(std::iter::repeat_n(pred, n as usize));
            }
        }
        let e = evaluate(&r, &p, &codes);
        let road = e.row(11).unwrap();
        assert_eq!(
            (road.reference, road.predicted, road.correct),
            (8973, 9053, 8652)
        );
        let round = |v: f64| (100.0 * v).round();
        assert_eq!(round(road.omission), 4.0);
        assert_eq!(round(road.commission), 4.0);
        assert_eq!(round(road.mapping_accuracy), 92.0);
        let cycle = e.row(64).unwrap();
        assert_eq!(
            (
                round(cycle.omission),
                round(cycle.commission),
                round(cycle.mapping_accuracy)
            ),
            (17.0, 8.0, 77.0)
        );
        let tiles = e.row(65).unwrap();
        assert_eq!(
            (
                round(tiles.omission),
                round(tiles.commission),
                round(tiles.mapping_accuracy)
            ),
            (16.0, 5.0, 80.0)
        );
        let grass = e.row(67).unwrap();
        assert_eq!(
            (
                round(grass.omission),
                round(grass.commission),
                round(grass.mapping_accuracy)
            ),
            (1.0, 0.0, 99.0)
        );
    }
}
