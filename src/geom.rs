//! Cell geometry shared by the ground filter, the tiler and the stitcher, kept below all three
//! so that none of them imports another for it: a quadtree leaf's grid cell, and the one rule
//! that picks a cell's representative point (the ground filter seeds from it; split tiles keep
//! just that point of their far buffer cells).

use crate::model::{Rect, TileId};

/// The grid cell's core rectangle from one of its quadtree leaves.
pub fn cell_rect(leaf: &TileId, core: &Rect) -> Rect {
    let w = core.width() * (1u64 << leaf.level) as f64;
    let h = (core.y1 - core.y0) * (1u64 << leaf.level) as f64;
    let (mut x0, mut y0) = (core.x0, core.y0);
    for l in 0..leaf.level {
        // Quadrant taken at depth `level - l` (the least significant bits are the deepest).
        let q = (leaf.path >> (2 * l as u64)) & 3;
        let scale = (1u64 << (leaf.level - l)) as f64;
        if q & 1 == 1 {
            x0 -= w / scale;
        }
        if q & 2 == 2 {
            y0 -= h / scale;
        }
    }
    Rect {
        x0,
        y0,
        x1: x0 + w,
        y1: y0 + h,
    }
}

/// Position of a cell's representative in its points sorted by height: the lowest point with
/// `support` more points within `window_m` above it (support grows with the cell's point count,
/// 1 to 8), so that a few isolated low outliers are skipped; the lowest point when none has.
///
/// `count` is the cell's number of points, of which only the lowest `held` are known
/// (`z(j)`, ascending, j < `held`). None when those do not decide it (a choice at or beyond
/// `held - support` is possible). The one rule for `lowest_per_cell` (all points held) and
/// for the far-buffer thinning of split tiles (`tiling::FarThin`), which keeps exactly the
/// point this picks.
pub fn cell_representative(
    count: usize,
    held: usize,
    z: impl Fn(usize) -> f64,
    window_m: f64,
) -> Option<usize> {
    let support = (count / 32).clamp(1, 8);
    let found = (0..held.saturating_sub(support)).find(|&j| z(j + support) - z(j) <= window_m);
    match found {
        Some(j) => Some(j),
        None if held >= count => Some(0),
        None => None,
    }
}

/// Eigen-decomposition of a symmetric 3 × 3 matrix in closed form: eigenvalues ascending and
/// their unit eigenvectors (orthonormal; signs arbitrary).
///
/// Why not nalgebra's iterative `SymmetricEigen`: per-point PCA runs millions of times per
/// tile, and the QR iteration was the largest single cost of the stages after the neighbour
/// search. Here the eigenvalues come from the trigonometric solution of the characteristic
/// cubic (after centring on the mean eigenvalue and scaling, for accuracy), the eigenvector
/// of the eigenvalue farther from the middle one from the best-conditioned cross product of
/// two rows of `A − λI`, and the other two from the 2 × 2 problem left in the plane
/// orthogonal to it, so nearly equal eigenvalues (lines, planes) still give orthonormal
/// vectors. Checked against nalgebra on random and degenerate matrices.
pub fn sym3_eigen(a: [[f64; 3]; 3]) -> ([f64; 3], [[f64; 3]; 3]) {
    let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
    let scale = a.iter().flatten().fold(0.0f64, |m, v| m.max(v.abs()));
    if scale == 0.0 || !scale.is_finite() {
        let d = [a[0][0], a[1][1], a[2][2]];
        return (d, identity);
    }
    let m: [[f64; 3]; 3] = std::array::from_fn(|r| std::array::from_fn(|c| a[r][c] / scale));
    let q = (m[0][0] + m[1][1] + m[2][2]) / 3.0;
    let p1 = m[0][1] * m[0][1] + m[0][2] * m[0][2] + m[1][2] * m[1][2];
    let p2 = (m[0][0] - q).powi(2) + (m[1][1] - q).powi(2) + (m[2][2] - q).powi(2) + 2.0 * p1;
    let p = (p2 / 6.0).sqrt();
    if p < 1e-14 {
        return ([q * scale; 3], identity);
    }
    // B = (M − qI) / p; det(B) / 2 = cos(3φ).
    let b: [[f64; 3]; 3] = std::array::from_fn(|r| {
        std::array::from_fn(|c| (m[r][c] - if r == c { q } else { 0.0 }) / p)
    });
    let det = b[0][0] * (b[1][1] * b[2][2] - b[1][2] * b[2][1])
        - b[0][1] * (b[1][0] * b[2][2] - b[1][2] * b[2][0])
        + b[0][2] * (b[1][0] * b[2][1] - b[1][1] * b[2][0]);
    let phi = (det / 2.0).clamp(-1.0, 1.0).acos() / 3.0;
    let third = 2.0 * std::f64::consts::PI / 3.0;
    let l2 = q + 2.0 * p * phi.cos();
    let l0 = q + 2.0 * p * (phi + third).cos();
    let l1 = 3.0 * q - l0 - l2;
    let mut vals = [l0, l1, l2];
    vals.sort_by(f64::total_cmp);
    // The eigenvalue farther from the middle one is the better separated.
    let (first, rest) = if vals[1] - vals[0] > vals[2] - vals[1] {
        (0, [1, 2])
    } else {
        (2, [0, 1])
    };
    let v = null_vector(&m, vals[first]);
    // Orthonormal basis (u, w) of the plane orthogonal to v, and M restricted to it.
    let u = normalize(any_orthogonal(v));
    let w = cross(v, u);
    let mv = |x: [f64; 3]| -> [f64; 3] { std::array::from_fn(|r| dot(m[r], x)) };
    let (mu, mw) = (mv(u), mv(w));
    let (a11, a12, a22) = (dot(u, mu), dot(u, mw), dot(w, mw));
    // Eigenvector of the 2 × 2 [[a11, a12], [a12, a22]] for its smaller eigenvalue.
    let lo = 0.5 * (a11 + a22) - (0.25 * (a11 - a22).powi(2) + a12 * a12).sqrt();
    let (e1, e2) = if (a11 - lo).abs() >= (a22 - lo).abs() {
        (-a12, a11 - lo)
    } else {
        (a22 - lo, -a12)
    };
    let len = (e1 * e1 + e2 * e2).sqrt();
    let (c, s) = if len > 0.0 {
        (e1 / len, e2 / len)
    } else {
        (1.0, 0.0)
    };
    let small: [f64; 3] = std::array::from_fn(|i| c * u[i] + s * w[i]);
    let large = cross(v, small);
    let mut vecs = [[0.0; 3]; 3];
    vecs[first] = v;
    vecs[rest[0]] = small;
    vecs[rest[1]] = large;
    // Eigenvalues again as Rayleigh quotients vᵀAv: the cubic's roots lose the small
    // eigenvalues of ill-conditioned matrices (a flat patch's λ0) to cancellation, while the
    // vectors are accurate.
    let mut pairs: [(f64, [f64; 3]); 3] =
        std::array::from_fn(|i| (dot(vecs[i], mv(vecs[i])) * scale, vecs[i]));
    pairs.sort_by(|x, y| x.0.total_cmp(&y.0));
    (pairs.map(|p| p.0), pairs.map(|p| p.1))
}

/// A `u32` that orders like [`f32::total_cmp`] orders the floats: negative values (sign bit
/// set) have all bits flipped, the others only the sign bit.
#[inline]
pub fn f32_order_key(x: f32) -> u32 {
    let b = x.to_bits();
    if b >> 31 == 1 {
        !b
    } else {
        b | 0x8000_0000
    }
}

/// Indices `0..n` in ascending order of `keys` ([`f32::total_cmp`]), ties by index: sorted as
/// integers (the float's [`f32_order_key`] above the index).
pub fn ascending_by_f32(keys: impl Iterator<Item = f32>) -> Vec<u32> {
    use rayon::slice::ParallelSliceMut;
    let mut keyed: Vec<u64> = keys
        .enumerate()
        .map(|(i, v)| ((f32_order_key(v) as u64) << 32) | i as u64)
        .collect();
    keyed.par_sort_unstable();
    keyed.into_iter().map(|k| k as u32).collect()
}

fn dot(a: [f64; 3], b: [f64; 3]) -> f64 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

fn cross(a: [f64; 3], b: [f64; 3]) -> [f64; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn normalize(a: [f64; 3]) -> [f64; 3] {
    let l = dot(a, a).sqrt();
    if l > 0.0 {
        a.map(|v| v / l)
    } else {
        [1.0, 0.0, 0.0]
    }
}

/// A vector orthogonal to `v` (unit `v`), from its smallest component's axis.
fn any_orthogonal(v: [f64; 3]) -> [f64; 3] {
    if v[0].abs() <= v[1].abs() && v[0].abs() <= v[2].abs() {
        [0.0, v[2], -v[1]]
    } else if v[1].abs() <= v[2].abs() {
        [v[2], 0.0, -v[0]]
    } else {
        [v[1], -v[0], 0.0]
    }
}

/// Unit vector spanning the null space of `m − λI` for a simple eigenvalue λ: the longest
/// cross product of two of its rows.
fn null_vector(m: &[[f64; 3]; 3], l: f64) -> [f64; 3] {
    let r: [[f64; 3]; 3] =
        std::array::from_fn(|i| std::array::from_fn(|j| m[i][j] - if i == j { l } else { 0.0 }));
    let c = [cross(r[0], r[1]), cross(r[0], r[2]), cross(r[1], r[2])];
    let best = c
        .iter()
        .copied()
        .max_by(|a, b| dot(*a, *a).total_cmp(&dot(*b, *b)))
        .unwrap_or([1.0, 0.0, 0.0]);
    normalize(best)
}

#[cfg(test)]
mod eigen_tests {
    use super::{f32_order_key, sym3_eigen};

    fn check(a: [[f64; 3]; 3]) {
        let (vals, vecs) = sym3_eigen(a);
        let m = nalgebra::Matrix3::from_fn(|r, c| a[r][c]);
        let e = nalgebra::SymmetricEigen::new(m);
        let mut reference: Vec<f64> = e.eigenvalues.iter().copied().collect();
        reference.sort_by(f64::total_cmp);
        let scale = a.iter().flatten().fold(1e-300f64, |m, v| m.max(v.abs()));
        for i in 0..3 {
            assert!(
                (vals[i] - reference[i]).abs() <= 1e-9 * scale,
                "{a:?}: {vals:?} vs {reference:?}"
            );
            // A v = λ v, |v| = 1, and orthogonality.
            let v = vecs[i];
            let av: Vec<f64> = (0..3)
                .map(|r| a[r][0] * v[0] + a[r][1] * v[1] + a[r][2] * v[2])
                .collect();
            for r in 0..3 {
                assert!(
                    (av[r] - vals[i] * v[r]).abs() <= 1e-7 * scale,
                    "{a:?}: vector {i} {v:?}"
                );
            }
            let n: f64 = v.iter().map(|x| x * x).sum();
            assert!((n - 1.0).abs() < 1e-9);
            for (j, w) in vecs.iter().enumerate().take(i) {
                let d: f64 = (0..3).map(|c| v[c] * w[c]).sum();
                assert!(d.abs() < 1e-7, "{a:?}: vectors {i} {j} not orthogonal");
            }
        }
    }

    #[test]
    fn matches_nalgebra() {
        let mut s = 99u64;
        let mut r = || {
            s = s
                .wrapping_mul(6364136223846793005)
                .wrapping_add(1442695040888963407);
            (s >> 11) as f64 / (1u64 << 53) as f64 - 0.5
        };
        for _ in 0..20_000 {
            // Covariances of random point sets: planes, lines and blobs at several scales.
            let kind = (r() + 0.5) * 3.0;
            let sx = 10f64.powf(r() * 6.0);
            let sd = [
                sx,
                sx * if kind < 1.0 { 1e-4 } else { 1.0 },
                sx * if kind < 2.0 { 1e-3 } else { 0.7 },
            ];
            let mut c = [[0.0; 3]; 3];
            for _ in 0..8 {
                let p = [r() * sd[0], r() * sd[1], r() * sd[2]];
                let q = [p[0] + p[1] * 0.3, p[1] - p[2] * 0.2, p[2] + p[0] * 0.1];
                for i in 0..3 {
                    for j in 0..3 {
                        c[i][j] += q[i] * q[j];
                    }
                }
            }
            check(c);
        }
        check([[0.0; 3]; 3]);
        check([[2.0, 0.0, 0.0], [0.0, 2.0, 0.0], [0.0, 0.0, 2.0]]);
        check([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 0.0]]);
        check([[4.0, 1e-9, 0.0], [1e-9, 4.0, 0.0], [0.0, 0.0, 1.0]]);
    }

    #[test]
    fn f32_order_key_orders_like_total_cmp() {
        let v = [
            f32::NEG_INFINITY,
            -3.5,
            -1e-30,
            -0.0,
            0.0,
            1e-40,
            0.25,
            7.0,
            f32::INFINITY,
            f32::NAN,
        ];
        for a in v {
            for b in v {
                assert_eq!(
                    f32_order_key(a).cmp(&f32_order_key(b)),
                    a.total_cmp(&b),
                    "{a} vs {b}"
                );
            }
        }
    }
}
