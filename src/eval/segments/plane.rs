//! Least-squares planes of segments and angles between them.

use nalgebra::{Matrix3, SymmetricEigen, Vector3};
use std::collections::{BTreeSet, HashMap};

/// Angle between two plane normals in degrees, 0–90 (the sign of a normal is arbitrary).
///
/// `atan2(|a×b|, |a·b|)` rather than `acos`, which loses precision near 0°.
pub fn angle_between_deg(a: &[f64; 3], b: &[f64; 3]) -> f64 {
    let a = Vector3::from(*a);
    let b = Vector3::from(*b);
    a.cross(&b).norm().atan2(a.dot(&b).abs()).to_degrees()
}

/// Least-squares plane normal (unit length) of a point set, or `None` with fewer than three
/// points or (nearly) collinear points.
pub fn plane_normal(points: &[[f64; 3]]) -> Option<[f64; 3]> {
    let mut acc = Moments::default();
    let mean = {
        let mut s = [0.0; 3];
        for p in points {
            for (s, v) in s.iter_mut().zip(p) {
                *s += v;
            }
        }
        let n = points.len() as f64;
        [s[0] / n, s[1] / n, s[2] / n]
    };
    for p in points {
        acc.add(p, &mean);
    }
    acc.normal()
}

/// Scatter matrix of centred coordinates of one segment.
#[derive(Debug, Default, Clone)]
struct Moments {
    n: u64,
    c: [f64; 6], // xx, xy, xz, yy, yz, zz
}

impl Moments {
    fn add(&mut self, p: &[f64; 3], mean: &[f64; 3]) {
        let d = [p[0] - mean[0], p[1] - mean[1], p[2] - mean[2]];
        self.n += 1;
        self.c[0] += d[0] * d[0];
        self.c[1] += d[0] * d[1];
        self.c[2] += d[0] * d[2];
        self.c[3] += d[1] * d[1];
        self.c[4] += d[1] * d[2];
        self.c[5] += d[2] * d[2];
    }

    fn normal(&self) -> Option<[f64; 3]> {
        if self.n < 3 {
            return None;
        }
        let c = &self.c;
        let m = Matrix3::new(c[0], c[1], c[2], c[1], c[3], c[4], c[2], c[4], c[5]);
        let eig = SymmetricEigen::new(m);
        let mut order = [0usize, 1, 2];
        order.sort_by(|&i, &j| eig.eigenvalues[i].total_cmp(&eig.eigenvalues[j]));
        let (small, mid, large) = (
            eig.eigenvalues[order[0]],
            eig.eigenvalues[order[1]],
            eig.eigenvalues[order[2]],
        );
        // A line (or a point) has no plane: the two smallest spreads are both ~0.
        if !large.is_finite() || large <= 0.0 || mid <= 1e-12 * large || !small.is_finite() {
            return None;
        }
        let v = eig.eigenvectors.column(order[0]).normalize();
        Some([v[0], v[1], v[2]])
    }
}

/// Plane normals of the segments in `wanted`, in two passes (means, then centred scatter) so
/// that large georeferenced coordinates do not cancel. Non-finite points are skipped.
pub(super) fn fit_planes(
    labels: &[u32],
    xyz: &[[f64; 3]],
    wanted: &BTreeSet<u32>,
) -> HashMap<u32, [f64; 3]> {
    if wanted.is_empty() {
        return HashMap::new();
    }
    let finite = |p: &[f64; 3]| p.iter().all(|v| v.is_finite());
    let mut sums: HashMap<u32, ([f64; 3], u64)> = HashMap::new();
    for (l, p) in labels.iter().zip(xyz) {
        if wanted.contains(l) && finite(p) {
            let e = sums.entry(*l).or_insert(([0.0; 3], 0));
            for (s, v) in e.0.iter_mut().zip(p) {
                *s += v;
            }
            e.1 += 1;
        }
    }
    let means: HashMap<u32, [f64; 3]> = sums
        .into_iter()
        .map(|(l, (s, n))| (l, [s[0] / n as f64, s[1] / n as f64, s[2] / n as f64]))
        .collect();
    let mut moments: HashMap<u32, Moments> = HashMap::new();
    for (l, p) in labels.iter().zip(xyz) {
        if let Some(mean) = means.get(l) {
            if finite(p) {
                moments.entry(*l).or_default().add(p, mean);
            }
        }
    }
    moments
        .into_iter()
        .filter_map(|(l, m)| m.normal().map(|n| (l, n)))
        .collect()
}
