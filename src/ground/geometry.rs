//! Small geometric helpers of the TIN filter: facet tests, plane fits, Morton keys and the
//! tile's local frame. Pure functions, unit-tested with hand-computed values.

/// Geometry of one facet relative to a query point.
pub(super) struct FacetTest {
    /// Perpendicular distance of the point to the facet plane (metres, >= 0).
    pub(super) dist: f64,
    /// Sine of the largest angle between the facet plane and the lines point→vertex.
    pub(super) max_sin_angle: f64,
    /// Whether all three (xy) edges are shorter than `min_edge_m`.
    pub(super) all_edges_short: bool,
    /// Tangent of the facet's slope against the horizontal (infinite for a vertical facet).
    pub(super) slope_tan: f64,
}

/// Vertical offset of `p` above the plane through `v` (negative: below).
pub(super) fn height_above(v: &[[f64; 3]; 3], p: [f64; 3]) -> f64 {
    let n = normal(v);
    // n.z is twice the signed xy area of the facet: never 0 for a Delaunay face.
    if n[2] == 0.0 {
        return p[2] - v[0][2];
    }
    let d = n[0] * (p[0] - v[0][0]) + n[1] * (p[1] - v[0][1]) + n[2] * (p[2] - v[0][2]);
    d / n[2]
}

/// Whether `p` lies in the xy triangle `v` (boundary included), either orientation.
pub(super) fn in_triangle(v: &[[f64; 3]; 3], p: [f64; 3]) -> bool {
    let side =
        |a: &[f64; 3], b: &[f64; 3]| (b[0] - a[0]) * (p[1] - a[1]) - (b[1] - a[1]) * (p[0] - a[0]);
    let (s0, s1, s2) = (side(&v[0], &v[1]), side(&v[1], &v[2]), side(&v[2], &v[0]));
    (s0 >= 0.0 && s1 >= 0.0 && s2 >= 0.0) || (s0 <= 0.0 && s1 <= 0.0 && s2 <= 0.0)
}

pub(super) fn normal(v: &[[f64; 3]; 3]) -> [f64; 3] {
    let a = [v[1][0] - v[0][0], v[1][1] - v[0][1], v[1][2] - v[0][2]];
    let b = [v[2][0] - v[0][0], v[2][1] - v[0][1], v[2][2] - v[0][2]];
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

pub(super) fn facet_test(v: &[[f64; 3]; 3], p: [f64; 3], min_edge_m: f64) -> FacetTest {
    let n = normal(v);
    let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
    let d = n[0] * (p[0] - v[0][0]) + n[1] * (p[1] - v[0][1]) + n[2] * (p[2] - v[0][2]);
    let dist = if len > 0.0 {
        (d / len).abs()
    } else {
        f64::INFINITY
    };
    let mut max_sin_angle: f64 = 0.0;
    for w in v {
        let r = ((p[0] - w[0]).powi(2) + (p[1] - w[1]).powi(2) + (p[2] - w[2]).powi(2)).sqrt();
        let s = if r > 0.0 { dist / r } else { 0.0 };
        max_sin_angle = max_sin_angle.max(s);
    }
    let e2 = min_edge_m * min_edge_m;
    let short = |a: &[f64; 3], b: &[f64; 3]| (a[0] - b[0]).powi(2) + (a[1] - b[1]).powi(2) < e2;
    FacetTest {
        dist,
        max_sin_angle,
        all_edges_short: short(&v[0], &v[1]) && short(&v[1], &v[2]) && short(&v[2], &v[0]),
        slope_tan: if n[2] != 0.0 {
            (n[0] * n[0] + n[1] * n[1]).sqrt() / n[2].abs()
        } else {
            f64::INFINITY
        },
    }
}

/// Least-squares plane through `pts` as (centroid, dz/dx, dz/dy); `None` with fewer than 3
/// points or a degenerate (collinear) layout.
pub(super) fn plane_fit(pts: &[[f64; 3]]) -> Option<([f64; 3], f64, f64)> {
    if pts.len() < 3 {
        return None;
    }
    let n = pts.len() as f64;
    let mut m = [0.0; 3];
    for p in pts {
        for k in 0..3 {
            m[k] += p[k] / n;
        }
    }
    let (mut sxx, mut sxy, mut syy, mut sxz, mut syz) = (0.0, 0.0, 0.0, 0.0, 0.0);
    for p in pts {
        let (dx, dy, dz) = (p[0] - m[0], p[1] - m[1], p[2] - m[2]);
        sxx += dx * dx;
        sxy += dx * dy;
        syy += dy * dy;
        sxz += dx * dz;
        syz += dy * dz;
    }
    let det = sxx * syy - sxy * sxy;
    if det.abs() <= 1e-9 * (sxx * syy).max(1e-12) {
        return None;
    }
    Some((
        m,
        (sxz * syy - syz * sxy) / det,
        (syz * sxx - sxz * sxy) / det,
    ))
}

/// Least-squares plane through `pts` evaluated at (x, y); also returns the z range of `pts`.
/// `None` with fewer than 3 points or a degenerate (collinear) layout.
pub(super) fn plane_at(pts: &[[f64; 3]], x: f64, y: f64) -> Option<(f64, f64, f64)> {
    let (m, b, c) = plane_fit(pts)?;
    let lo = pts.iter().map(|p| p[2]).fold(f64::INFINITY, f64::min);
    let hi = pts.iter().map(|p| p[2]).fold(f64::NEG_INFINITY, f64::max);
    Some((m[2] + b * (x - m[0]) + c * (y - m[1]), lo, hi))
}

/// Interleaves the low 20 bits of `x` and `y` (Morton / Z-order key).
pub(super) fn morton(x: u32, y: u32) -> u64 {
    fn spread(v: u32) -> u64 {
        let mut v = u64::from(v & 0xF_FFFF);
        v = (v | (v << 16)) & 0x0000_FFFF_0000_FFFF;
        v = (v | (v << 8)) & 0x00FF_00FF_00FF_00FF;
        v = (v | (v << 4)) & 0x0F0F_0F0F_0F0F_0F0F;
        v = (v | (v << 2)) & 0x3333_3333_3333_3333;
        v = (v | (v << 1)) & 0x5555_5555_5555_5555;
        v
    }
    spread(x) | (spread(y) << 1)
}

/// Local frame of a tile: origin and Morton quantisation.
pub(super) struct Frame {
    pub(super) origin: [f64; 2],
    pub(super) scale: f64,
}

impl Frame {
    pub(super) fn local(&self, p: &[f64; 3]) -> [f64; 3] {
        [p[0] - self.origin[0], p[1] - self.origin[1], p[2]]
    }
    pub(super) fn key(&self, x: f64, y: f64) -> u64 {
        let q = |v: f64| ((v * self.scale).max(0.0) as u32).min(0xF_FFFF);
        morton(q(x), q(y))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn facet_distance_and_angle_by_hand() {
        // Horizontal facet z = 0; point 1 m above (3, 4): distance 1. The largest angle is at
        // the nearest vertex (0, 0), 3D distance sqrt(9 + 16 + 1): sin = 1 / sqrt(26).
        let v = [[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [0.0, 10.0, 0.0]];
        let t = facet_test(&v, [3.0, 4.0, 1.0], 0.5);
        assert!((t.dist - 1.0).abs() < 1e-12);
        assert!((t.max_sin_angle - 1.0 / 26f64.sqrt()).abs() < 1e-12);
        assert!(!t.all_edges_short);
        assert!(facet_test(&v, [3.0, 4.0, 1.0], 20.0).all_edges_short);
        // Tilted facet z = x: the point (1, 1, 2) is 1 m above vertically, 1/sqrt(2) normal.
        let w = [[0.0, 0.0, 0.0], [10.0, 0.0, 10.0], [0.0, 10.0, 0.0]];
        assert!((height_above(&w, [1.0, 1.0, 2.0]) - 1.0).abs() < 1e-12);
        let t = facet_test(&w, [1.0, 1.0, 2.0], 0.0);
        assert!((t.dist - 0.5f64.sqrt()).abs() < 1e-12);
    }

    #[test]
    fn plane_fit_recovers_plane() {
        let pts: Vec<[f64; 3]> = [(0.0, 0.0), (4.0, 1.0), (1.0, 5.0), (3.0, 3.0)]
            .iter()
            .map(|&(x, y)| [x, y, 2.0 + 0.5 * x - 0.25 * y])
            .collect();
        let (z, lo, hi) = plane_at(&pts, 10.0, 10.0).expect("non-degenerate");
        assert!((z - (2.0 + 5.0 - 2.5)).abs() < 1e-9);
        assert!(lo <= hi);
        let line = [[0.0, 0.0, 0.0], [1.0, 1.0, 1.0], [2.0, 2.0, 2.0]];
        assert!(plane_at(&line, 0.0, 1.0).is_none());
    }

    #[test]
    fn in_triangle_includes_boundary_and_both_orientations() {
        let ccw = [[0.0, 0.0, 0.0], [2.0, 0.0, 0.0], [0.0, 2.0, 0.0]];
        let cw = [ccw[0], ccw[2], ccw[1]];
        for v in [ccw, cw] {
            assert!(in_triangle(&v, [0.5, 0.5, 9.0]));
            assert!(in_triangle(&v, [1.0, 1.0, 0.0])); // on the hypotenuse
            assert!(in_triangle(&v, [0.0, 0.0, 0.0])); // a vertex
            assert!(!in_triangle(&v, [1.5, 1.5, 0.0]));
            assert!(!in_triangle(&v, [-0.1, 0.5, 0.0]));
        }
    }

    #[test]
    fn morton_interleaves() {
        assert_eq!(morton(0, 0), 0);
        assert_eq!(morton(1, 0), 1);
        assert_eq!(morton(0, 1), 2);
        assert_eq!(morton(3, 3), 15);
        assert!(morton(0xF_FFFF, 0xF_FFFF) < 1 << 40);
    }
}
