//! Per-point and per-region features: plane moments and least-squares planes (PCA), local
//! normals and curvature, and colour (storage depth, vector median filter, CIELab).

use rayon::prelude::*;
use serde::{Deserialize, Serialize};

use super::neighbours::Neighbours;

/// A plane `n · x = d` with unit normal `n`.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Plane {
    /// Unit normal.
    pub n: [f64; 3],
    /// Offset along the normal.
    pub d: f64,
}

impl Plane {
    /// Signed distance of `p` to the plane.
    #[inline]
    pub fn signed(&self, p: &[f64; 3]) -> f64 {
        self.n[0] * p[0] + self.n[1] * p[1] + self.n[2] * p[2] - self.d
    }

    /// The plane through `a`, `b` and `c` (normal `(b − a) × (c − a)`, normalised); `None` when
    /// the three are (nearly) collinear: that cross product shorter than `min_cross`.
    pub fn through(a: &[f64; 3], b: &[f64; 3], c: &[f64; 3], min_cross: f64) -> Option<Plane> {
        let u = [b[0] - a[0], b[1] - a[1], b[2] - a[2]];
        let v = [c[0] - a[0], c[1] - a[1], c[2] - a[2]];
        let n = [
            u[1] * v[2] - u[2] * v[1],
            u[2] * v[0] - u[0] * v[2],
            u[0] * v[1] - u[1] * v[0],
        ];
        let len = (n[0] * n[0] + n[1] * n[1] + n[2] * n[2]).sqrt();
        if len < min_cross {
            return None;
        }
        let n = [n[0] / len, n[1] / len, n[2] / len];
        Some(Plane {
            n,
            d: n[0] * a[0] + n[1] * a[1] + n[2] * a[2],
        })
    }

    /// Absolute distance of `p` to the plane.
    #[inline]
    pub fn dist(&self, p: &[f64; 3]) -> f64 {
        self.signed(p).abs()
    }

    /// Angle between the two planes' normals, in degrees, in [0, 90].
    pub fn angle_deg(&self, o: &Plane) -> f64 {
        let c = (self.n[0] * o.n[0] + self.n[1] * o.n[1] + self.n[2] * o.n[2]).abs();
        c.min(1.0).acos().to_degrees()
    }
}

/// Orients a normal canonically — z ≥ 0, or y ≥ 0 when z is ~0, or x ≥ 0 when both are — so
/// reported planes do not flip sign between runs.
pub fn orient(n: [f64; 3]) -> [f64; 3] {
    let flip = if n[2].abs() > 1e-9 {
        n[2] < 0.0
    } else if n[1].abs() > 1e-9 {
        n[1] < 0.0
    } else {
        n[0] < 0.0
    };
    if flip {
        [-n[0], -n[1], -n[2]]
    } else {
        n
    }
}

/// (centroid, eigenvalues ascending, matching unit eigenvectors) of a point set.
pub type Eigen = ([f64; 3], [f64; 3], [[f64; 3]; 3]);

/// First and second moments of a point set, relative to a fixed origin (keeps the sums small
/// and exact enough in f64 while points are added and removed).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Moments {
    origin: [f64; 3],
    /// Number of points.
    pub n: usize,
    s: [f64; 3],
    ss: [f64; 6],
}

impl Moments {
    /// Empty moments around `origin`.
    pub fn new(origin: [f64; 3]) -> Self {
        Moments {
            origin,
            n: 0,
            s: [0.0; 3],
            ss: [0.0; 6],
        }
    }

    fn update(&mut self, p: &[f64; 3], w: f64) {
        let x = p[0] - self.origin[0];
        let y = p[1] - self.origin[1];
        let z = p[2] - self.origin[2];
        self.s[0] += w * x;
        self.s[1] += w * y;
        self.s[2] += w * z;
        self.ss[0] += w * x * x;
        self.ss[1] += w * x * y;
        self.ss[2] += w * x * z;
        self.ss[3] += w * y * y;
        self.ss[4] += w * y * z;
        self.ss[5] += w * z * z;
    }

    /// Adds a point.
    #[inline]
    pub fn add(&mut self, p: &[f64; 3]) {
        self.update(p, 1.0);
        self.n += 1;
    }

    /// Removes a point that was added before.
    #[inline]
    pub fn remove(&mut self, p: &[f64; 3]) {
        self.update(p, -1.0);
        self.n = self.n.saturating_sub(1);
    }

    /// Centroid and covariance eigen-decomposition: (centroid, eigenvalues ascending, the
    /// matching eigenvectors). `None` with fewer than 3 points.
    pub fn eigen(&self) -> Option<Eigen> {
        if self.n < 3 {
            return None;
        }
        let inv = 1.0 / self.n as f64;
        let m = [self.s[0] * inv, self.s[1] * inv, self.s[2] * inv];
        let c = |a: usize, b: usize| {
            let k = match (a.min(b), a.max(b)) {
                (0, 0) => 0,
                (0, 1) => 1,
                (0, 2) => 2,
                (1, 1) => 3,
                (1, 2) => 4,
                _ => 5,
            };
            self.ss[k] * inv - m[a] * m[b]
        };
        let cov: [[f64; 3]; 3] = std::array::from_fn(|a| std::array::from_fn(|b| c(a, b)));
        let (vals, vecs) = crate::geom::sym3_eigen(cov);
        let vals = vals.map(|v| v.max(0.0));
        let centroid = [
            m[0] + self.origin[0],
            m[1] + self.origin[1],
            m[2] + self.origin[2],
        ];
        Some((centroid, vals, vecs))
    }

    /// Variance of the points along coordinate axis `a` (0 x, 1 y, 2 z); None without points.
    pub fn variance(&self, a: usize) -> Option<f64> {
        if self.n == 0 {
            return None;
        }
        let inv = 1.0 / self.n as f64;
        let k = [0, 3, 5][a];
        Some((self.ss[k] * inv - (self.s[a] * inv).powi(2)).max(0.0))
    }

    /// Mean squared distance of the points to `plane`; None without points.
    pub fn mean_sq_distance(&self, plane: &Plane) -> Option<f64> {
        if self.n == 0 {
            return None;
        }
        let inv = 1.0 / self.n as f64;
        let m = self.s.map(|v| v * inv);
        let n = plane.n;
        // The plane in coordinates relative to `origin`: n·q = d0.
        let d0 = plane.d - (0..3).map(|k| n[k] * self.origin[k]).sum::<f64>();
        let off = (0..3).map(|k| n[k] * m[k]).sum::<f64>() - d0;
        const K: [[usize; 3]; 3] = [[0, 1, 2], [1, 3, 4], [2, 4, 5]];
        let mut var = 0.0;
        for a in 0..3 {
            for b in 0..3 {
                var += n[a] * n[b] * (self.ss[K[a][b]] * inv - m[a] * m[b]);
            }
        }
        Some(var.max(0.0) + off * off)
    }

    /// Least-squares plane (smallest eigenvector through the centroid) and the RMS of the
    /// orthogonal residuals.
    pub fn plane(&self) -> Option<(Plane, f64)> {
        let (c, vals, vecs) = self.eigen()?;
        let n = orient(vecs[0]);
        let d = n[0] * c[0] + n[1] * c[1] + n[2] * c[2];
        Some((Plane { n, d }, vals[0].sqrt()))
    }
}

/// Least-squares plane of the points `idx`.
pub fn fit_plane(pts: &[[f64; 3]], idx: impl IntoIterator<Item = u32>) -> Option<(Plane, f64)> {
    let mut it = idx.into_iter().peekable();
    let first = *it.peek()?;
    let mut m = Moments::new(pts[first as usize]);
    for i in it {
        m.add(&pts[i as usize]);
    }
    m.plane()
}

/// Local normal and surface variation `λ0 / (λ0 + λ1 + λ2)` (Rabbani's "curvature") of every
/// point over itself and its neighbours within `r`. Points with fewer than 3 such points get a
/// zero normal and curvature `+∞`.
pub fn normals(pts: &[[f64; 3]], nb: &Neighbours, r: f64) -> Vec<([f32; 3], f32)> {
    let r2 = (r * r) as f32;
    (0..pts.len())
        .into_par_iter()
        .map(|i| {
            let mut m = Moments::new(pts[i]);
            m.add(&pts[i]);
            for &j in nb.within(i, r2) {
                m.add(&pts[j as usize]);
            }
            match m.eigen() {
                Some((_, vals, vecs)) => {
                    let s = vals[0] + vals[1] + vals[2];
                    let curv = if s > 0.0 { vals[0] / s } else { 0.0 };
                    let n = orient(vecs[0]);
                    ([n[0] as f32, n[1] as f32, n[2] as f32], curv as f32)
                }
                None => ([0.0; 3], f32::INFINITY),
            }
        })
        .collect()
}

/// True when 16-bit colour fields hold 8-bit values (every channel of every point ≤ 255), as
/// many writers do instead of scaling by 256 as LAS asks.
pub fn rgb_is_8bit(rgb: &[[u16; 3]]) -> bool {
    rgb.iter()
        .all(|c| c[0] <= 255 && c[1] <= 255 && c[2] <= 255)
}

/// Which RGB → CIELab conversion to use.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize, Default)]
#[serde(rename_all = "snake_case")]
pub enum LabFormula {
    /// sRGB (IEC 61966-2-1) with its gamma removed, sRGB→XYZ matrix, D65 white point, and the
    /// CIE 1976 L*a*b* formulas with the linear segment near black.
    #[default]
    Srgb,
    /// Thesis eqs. 2.6–2.7 (Skarbek & Koschan): linear RGB straight into the given XYZ matrix,
    /// white = the matrix applied to full-scale RGB, cube roots without the linear segment.
    Thesis,
}

fn lab_f(t: f64) -> f64 {
    const D: f64 = 6.0 / 29.0;
    if t > D * D * D {
        t.cbrt()
    } else {
        t / (3.0 * D * D) + 4.0 / 29.0
    }
}

/// sRGB's transfer function removed: a channel in [0, 1] (clamped) to linear light.
fn srgb_linear(c: f64) -> f64 {
    let c = c.clamp(0.0, 1.0);
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// CIELab of linear sRGB (sRGB→XYZ matrix, D65 white).
fn lab_of_linear(lin: [f64; 3]) -> [f64; 3] {
    let x = 0.4124564 * lin[0] + 0.3575761 * lin[1] + 0.1804375 * lin[2];
    let y = 0.2126729 * lin[0] + 0.7151522 * lin[1] + 0.0721750 * lin[2];
    let z = 0.0193339 * lin[0] + 0.1191920 * lin[1] + 0.9503041 * lin[2];
    // D65 reference white.
    let (fx, fy, fz) = (lab_f(x / 0.95047), lab_f(y), lab_f(z / 1.08883));
    [116.0 * fy - 16.0, 500.0 * (fx - fy), 200.0 * (fy - fz)]
}

/// [`rgb_to_lab`] with [`LabFormula::Srgb`] of a stored 16-bit colour whose full scale is
/// 255 (`eight_bit`, see [`rgb_is_8bit`]) or 65535: the same values, the transfer function
/// read from a table per scale (built once per process) instead of three `powf` a point.
pub fn rgb16_to_lab(c: [u16; 3], eight_bit: bool) -> [f64; 3] {
    use std::sync::OnceLock;
    static T8: OnceLock<Vec<f64>> = OnceLock::new();
    static T16: OnceLock<Vec<f64>> = OnceLock::new();
    let table = if eight_bit {
        T8.get_or_init(|| {
            (0..=255u16)
                .map(|v| srgb_linear(v as f64 / 255.0))
                .collect()
        })
    } else {
        T16.get_or_init(|| {
            (0..=u16::MAX)
                .map(|v| srgb_linear(v as f64 / 65535.0))
                .collect()
        })
    };
    // Above the table (not 8-bit data after all): full scale, as the clamp would give.
    let lin = c.map(|v| table.get(v as usize).copied().unwrap_or(1.0));
    lab_of_linear(lin)
}

/// Converts RGB scaled to [0, 1] into CIELab (L in 0–100). See [`LabFormula`].
pub fn rgb_to_lab(rgb: [f64; 3], formula: LabFormula) -> [f64; 3] {
    match formula {
        LabFormula::Srgb => lab_of_linear(rgb.map(srgb_linear)),
        LabFormula::Thesis => {
            let c = rgb.map(|v| v.clamp(0.0, 1.0));
            const M: [[f64; 3]; 3] = [
                [0.607, 0.174, 0.200],
                [0.299, 0.587, 0.114],
                [0.000, 0.066, 1.116],
            ];
            let xyz = M.map(|r| r[0] * c[0] + r[1] * c[1] + r[2] * c[2]);
            let white = M.map(|r| r[0] + r[1] + r[2]);
            let f = |i: usize| (xyz[i] / white[i]).cbrt();
            [
                116.0 * f(1) - 16.0,
                500.0 * (f(0) - f(1)),
                200.0 * (f(1) - f(2)),
            ]
        }
    }
}

/// Vector median filter over each point and its first `k - 1` neighbours (thesis §3.4, eq.
/// 3.1 with the L1 norm): every point takes the colour, among those `k`, whose summed L1
/// distance to the others is smallest. Ties go to the earlier (closer) candidate.
pub fn vector_median(rgb: &[[f32; 3]], nb: &Neighbours, k: usize) -> Vec<[f32; 3]> {
    (0..rgb.len())
        .into_par_iter()
        .map(|i| {
            let list = nb.of(i);
            let take = list.len().min(k.saturating_sub(1));
            let win = std::iter::once(i as u32).chain(list[..take].iter().copied());
            let cand: Vec<[f32; 3]> = win.map(|j| rgb[j as usize]).collect();
            let mut best = (f32::INFINITY, rgb[i]);
            for a in &cand {
                let s: f32 = cand
                    .iter()
                    .map(|b| (a[0] - b[0]).abs() + (a[1] - b[1]).abs() + (a[2] - b[2]).abs())
                    .sum();
                if s < best.0 {
                    best = (s, *a);
                }
            }
            best.1
        })
        .collect()
}

/// Euclidean colour distance (thesis eq. 2.8 / 2.10).
#[inline]
pub fn cdist(a: &[f32; 3], b: &[f64; 3]) -> f64 {
    let d0 = a[0] as f64 - b[0];
    let d1 = a[1] as f64 - b[1];
    let d2 = a[2] as f64 - b[2];
    (d0 * d0 + d1 * d1 + d2 * d2).sqrt()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lab_reference_values() {
        // sRGB white → L 100, a b 0; pure red → (53.24, 80.09, 67.20) (standard tables).
        let w = rgb_to_lab([1.0, 1.0, 1.0], LabFormula::Srgb);
        assert!((w[0] - 100.0).abs() < 0.01 && w[1].abs() < 0.01 && w[2].abs() < 0.01);
        let r = rgb_to_lab([1.0, 0.0, 0.0], LabFormula::Srgb);
        assert!((r[0] - 53.24).abs() < 0.05, "{r:?}");
        assert!((r[1] - 80.09).abs() < 0.1, "{r:?}");
        assert!((r[2] - 67.20).abs() < 0.1, "{r:?}");
        let k = rgb_to_lab([0.0, 0.0, 0.0], LabFormula::Srgb);
        assert!(k[0].abs() < 1e-9);
        let t = rgb_to_lab([1.0, 1.0, 1.0], LabFormula::Thesis);
        assert!((t[0] - 100.0).abs() < 1e-9 && t[1].abs() < 1e-9 && t[2].abs() < 1e-9);
    }

    #[test]
    fn table_lookup_gives_the_computed_values_bit_for_bit() {
        for v in (0..=u16::MAX)
            .step_by(97)
            .chain([0, 1, 10, 11, 254, 255, 256, 65534, 65535])
        {
            let c = [v, v.wrapping_mul(7), 65535 - v];
            let want = rgb_to_lab(c.map(|x| x as f64 / 65535.0), LabFormula::Srgb);
            assert_eq!(rgb16_to_lab(c, false), want, "{c:?}");
            let c8 = c.map(|x| x % 256);
            let want = rgb_to_lab(c8.map(|x| x as f64 / 255.0), LabFormula::Srgb);
            assert_eq!(rgb16_to_lab(c8, true), want, "{c8:?}");
        }
        // Not 8-bit after all: clamped to full scale as the division would be.
        let over = rgb_to_lab([1.0, 300.0 / 255.0, 0.0], LabFormula::Srgb);
        assert_eq!(rgb16_to_lab([255, 300, 0], true), over);
    }

    #[test]
    fn eight_bit_detection() {
        assert!(rgb_is_8bit(&[[0, 255, 17], [3, 4, 5]]));
        assert!(!rgb_is_8bit(&[[0, 256, 17]]));
        assert!(!rgb_is_8bit(&[[65535, 0, 0], [3, 4, 5]]));
    }

    #[test]
    fn plane_fit_recovers_tilted_plane() {
        let n = [0.0, -0.6, 0.8];
        let mut pts = Vec::new();
        for i in 0..20 {
            for j in 0..20 {
                let (u, v) = (i as f64 * 0.1, j as f64 * 0.1);
                // u along x, v along (0, 0.8, 0.6), offset 2 along n, far from the origin.
                pts.push([
                    1e5 + u,
                    2e5 + 0.8 * v + 2.0 * n[1],
                    10.0 + 0.6 * v + 2.0 * n[2],
                ]);
            }
        }
        let (p, rms) = fit_plane(&pts, 0..pts.len() as u32).unwrap();
        let dot = p.n[0] * n[0] + p.n[1] * n[1] + p.n[2] * n[2];
        assert!(dot.abs() > 1.0 - 1e-9, "{p:?}");
        assert!(rms < 1e-6);
        assert!(p.dist(&pts[37]) < 1e-6);
    }

    #[test]
    fn vector_median_removes_outlier() {
        let pts: Vec<[f64; 3]> = (0..5).map(|i| [i as f64, 0.0, 0.0]).collect();
        let nb = super::super::neighbours::knn_kdtree(&pts, 4, 10.0);
        let mut rgb = vec![[0.5f32, 0.5, 0.5]; 5];
        rgb[2] = [1.0, 0.0, 0.0];
        let f = vector_median(&rgb, &nb, 5);
        assert_eq!(f[2], [0.5, 0.5, 0.5]);
    }
}
