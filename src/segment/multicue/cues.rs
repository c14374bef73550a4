//! The cues segmented on the range image (paper §2.3): range, surface normals, colour.
//!
//! Normals come from differences between neighbouring pixels (eq. 3) of the range image after
//! an adaptive Gaussian smoothing whose window is a fixed physical size `D` translated into
//! pixels by the range: `d(ρ) ≈ D / (ρ Δ)` (eq. 4), separately along rows and columns (a
//! spinning sensor's rings are several times farther apart than its columns). Smoothing and
//! differences stay on one surface ([`same_surface`]).

use super::image::RangeImage;

/// Largest half-window of the smoothing, pixels (near the sensor `D / ρΔ` grows without
/// bound).
const MAX_HALF: usize = 6;

/// Whether two returns at ranges `a` and `b`, whose beams are `alpha` radians apart, lie on
/// one surface (Bogoslavskyi & Stachniss, IROS 2016): the angle β between the farther beam
/// and the line joining the two points, `tan β = d₂ sin α / (d₁ − d₂ cos α)`, is at least θ
/// (`tan_theta`). A range step reads as a break in proportion to the beams' spacing, so
/// the test holds at every range and for rings and columns of different spacing; surfaces
/// seen at a grazing angle below θ (far ground) break too.
#[inline]
pub fn same_surface(a: f32, b: f32, alpha: f32, tan_theta: f32) -> bool {
    let (d1, d2) = if a >= b { (a, b) } else { (b, a) };
    let den = d1 - d2 * alpha.cos();
    den <= 0.0 || d2 * alpha.sin() >= tan_theta * den
}

/// Unit normals per pixel (zero where none can be computed), oriented towards the sensor.
/// `window_m` is the paper's `D`; `tan_theta` the surface test of [`same_surface`].
pub fn normals(img: &RangeImage, window_m: f32, tan_theta: f32) -> Vec<[f32; 3]> {
    let smooth = smoothed(img, window_m, tan_theta);
    let mut out = vec![[0.0f32; 3]; img.len()];
    for r in 0..img.rows {
        for c in 0..img.cols {
            let i = r * img.cols + c;
            if !img.valid(i) {
                continue;
            }
            let diff = |dr: isize, dc: isize| -> Option<[f32; 3]> {
                let alpha = img.step(dr, dc);
                let along = |s: isize| {
                    img.offset(r, c, dr * s, dc * s).filter(|&j| {
                        img.valid(j) && same_surface(img.range[i], img.range[j], alpha, tan_theta)
                    })
                };
                // Central difference, else one-sided.
                let (a, b) = match (along(1), along(-1)) {
                    (Some(a), Some(b)) => (a, b),
                    (Some(a), None) => (a, i),
                    (None, Some(b)) => (i, b),
                    (None, None) => return None,
                };
                Some(sub(smooth[a], smooth[b]))
            };
            if let (Some(v1), Some(v2)) = (diff(0, 1), diff(1, 0)) {
                let n = cross(v1, v2);
                let len = dot(n, n).sqrt();
                if len > 1e-12 {
                    let p = img.xyz[i];
                    let s = if dot(n, p) > 0.0 { -1.0 } else { 1.0 };
                    out[i] = n.map(|v| s * v / len);
                }
            }
        }
    }
    out
}

/// The range image's points after the adaptive Gaussian smoothing (σ = half the window).
fn smoothed(img: &RangeImage, window_m: f32, tan_theta: f32) -> Vec<[f32; 3]> {
    let mut out = img.xyz.clone();
    if window_m <= 0.0 {
        return out;
    }
    let half = |rho: f32, step: f32| -> usize {
        let d = window_m / (rho * step).max(1e-9);
        ((d * 0.5) as usize).min(MAX_HALF)
    };
    for r in 0..img.rows {
        for c in 0..img.cols {
            let i = r * img.cols + c;
            if !img.valid(i) {
                continue;
            }
            let rho = img.range[i];
            let (hr, hc) = (half(rho, img.row_step), half(rho, img.col_step));
            if hr == 0 && hc == 0 {
                continue;
            }
            let (sr, sc) = ((hr as f32).max(0.5), (hc as f32).max(0.5));
            let (mut acc, mut wsum) = ([0.0f32; 3], 0.0f32);
            for dr in -(hr as isize)..=hr as isize {
                for dc in -(hc as isize)..=hc as isize {
                    let Some(j) = img.offset(r, c, dr, dc) else {
                        continue;
                    };
                    let alpha = img.step(dr, dc);
                    if !img.valid(j) || !same_surface(rho, img.range[j], alpha, tan_theta) {
                        continue;
                    }
                    let (fr, fc) = (dr as f32 / sr, dc as f32 / sc);
                    let w = (-0.5 * (fr * fr + fc * fc)).exp();
                    let p = img.xyz[j];
                    for k in 0..3 {
                        acc[k] += w * p[k];
                    }
                    wsum += w;
                }
            }
            out[i] = acc.map(|v| v / wsum);
        }
    }
    out
}

#[inline]
fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}
#[inline]
fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}
#[inline]
pub(crate) fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

#[cfg(test)]
mod tests {
    use super::super::image::tests::plane_and_wall;
    use super::*;

    #[test]
    fn plane_and_wall_normals() {
        let (rows, cols) = (16, 360);
        let pts = plane_and_wall(rows, cols);
        let img =
            RangeImage::organised(rows, cols, &pts, None, super::super::image::Order::RowMajor)
                .unwrap();
        let n = normals(&img, 0.3, 3f32.to_radians().tan());
        // [good, all] for ground and wall pixels; a pixel next to where the two surfaces
        // meet may average both. Ground seen at less than the 3° of the surface test (beyond
        // ~38 m from a sensor 2 m up) has no neighbouring ring on its surface.
        let (mut ground, mut wall) = ([0, 0], [0, 0]);
        for ((p, &rho), nrm) in img.xyz.iter().zip(&img.range).zip(&n) {
            if rho <= 0.0 {
                continue;
            }
            if (p[2] + 2.0).abs() < 1e-3 && rho < 35.0 {
                ground[0] += (nrm[2] > 0.999) as usize;
                ground[1] += 1;
            } else if (p[0] - 5.0).abs() < 1e-3 {
                wall[0] += (nrm[0] < -0.999) as usize;
                wall[1] += 1;
            }
        }
        assert!(ground[1] > 1000 && wall[1] > 100, "{ground:?} {wall:?}");
        assert!(ground[0] * 100 >= ground[1] * 98, "{ground:?}");
        assert!(wall[0] * 100 >= wall[1] * 95, "{wall:?}");
    }

    #[test]
    fn surfaces_are_separated_by_range_jumps() {
        let t = 10f32.to_radians().tan();
        let a = 0.5f32.to_radians();
        // A wall facing the sensor: equal ranges.
        assert!(same_surface(10.0, 10.0, a, t));
        // A pole 1 m in front of a wall 10 m away: β ≈ 5°.
        assert!(!same_surface(10.0, 9.0, a, t));
        // Ground at a 20° grazing angle: β ≈ 20° whatever the range.
        for d in [5.0f32, 40.0] {
            let next = d * 20f32.to_radians().sin() / (20f32 + 0.5).to_radians().sin();
            assert!(same_surface(d, next, a, t), "{d} {next}");
        }
    }
}
