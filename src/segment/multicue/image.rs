//! The panoramic range image of one scan (paper §2.2): rows are laser rings (elevation θ),
//! columns firing directions (azimuth φ), each pixel the point measured there.
//!
//! Organised clouds (a spinning sensor's PointCloud2 of `height` rings × `width` columns)
//! already are this image: pixel `(r, c)` is point `r * width + c`. Unorganised scans
//! (SemanticKITTI frames) are projected: azimuth gives the column, and the rows are the rings
//! found as clusters of the points' elevation angles (a 64-beam sensor fires at 64 fixed
//! elevations; the gaps between them are far wider than the spread within one).

use std::f64::consts::PI;

/// Why a scan cannot be made into a range image.
#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum ImageError {
    /// Zero rows or columns, or a layout that does not match the number of points.
    #[error("scan layout {rows} × {cols} does not fit its {points} points")]
    Layout {
        /// Rows given.
        rows: usize,
        /// Columns given.
        cols: usize,
        /// Points given.
        points: usize,
    },
    /// No point with a finite, positive range.
    #[error("scan has no valid returns ({points} points, all NaN or at the origin)")]
    NoReturns {
        /// Points given.
        points: usize,
    },
    /// More elevation clusters than the image may have rows.
    #[error("{rings} elevation rings found (at most {max} allowed; set a wider ring gap)")]
    TooManyRings {
        /// Rings found.
        rings: usize,
        /// The limit.
        max: usize,
    },
    /// More pixels than an image may have ([`MAX_PIXELS`]).
    #[error("scan image of {rows} × {cols} pixels is too large (at most {max} pixels)")]
    TooLarge {
        /// Rows.
        rows: usize,
        /// Columns.
        cols: usize,
        /// The limit.
        max: usize,
    },
    /// Colour given for a different number of points.
    #[error("{colours} colours for {points} points")]
    Colour {
        /// Colours given.
        colours: usize,
        /// Points given.
        points: usize,
    },
}

/// No point in a pixel.
pub const NONE: u32 = u32::MAX;

/// Most pixels an image may have: 2²⁸ (a 128-ring sensor's scan of 2 M columns), so that a
/// pixel's index packs into 28 bits ([`super::cues::Links`]).
pub const MAX_PIXELS: usize = 1 << 28;

/// `rows × cols`, or [`ImageError::TooLarge`].
fn pixels(rows: usize, cols: usize) -> Result<usize, ImageError> {
    rows.checked_mul(cols)
        .filter(|&n| n <= MAX_PIXELS)
        .ok_or(ImageError::TooLarge {
            rows,
            cols,
            max: MAX_PIXELS,
        })
}

/// A range image: `rows × cols` pixels, row-major.
#[derive(Debug, Clone)]
pub struct RangeImage {
    /// Rings.
    pub rows: usize,
    /// Columns (firing directions).
    pub cols: usize,
    /// Sensor-frame coordinates per pixel (meaningful where `range > 0`).
    pub xyz: Vec<[f32; 3]>,
    /// Range per pixel, metres; 0 where there is no return.
    pub range: Vec<f32>,
    /// CIELab colour per pixel, when the scan has colour.
    pub lab: Option<Vec<[f32; 3]>>,
    /// Index of the input point each pixel holds ([`NONE`] where empty).
    pub point: Vec<u32>,
    /// Angular step between columns, radians.
    pub col_step: f32,
    /// Angular step between rows, radians (mean over the rings).
    pub row_step: f32,
    /// Whether the columns close a full turn (column `cols - 1` neighbours column 0).
    pub wraps: bool,
}

impl RangeImage {
    /// Pixels.
    pub fn len(&self) -> usize {
        self.range.len()
    }
    /// True for an image without pixels.
    pub fn is_empty(&self) -> bool {
        self.range.is_empty()
    }
    /// Whether pixel `i` holds a return.
    #[inline]
    pub fn valid(&self, i: usize) -> bool {
        self.range[i] > 0.0
    }
    /// Angle between the beams of two pixels `dr` rows and `dc` columns apart, radians.
    #[inline]
    pub fn step(&self, dr: isize, dc: isize) -> f32 {
        let (a, b) = (dr as f32 * self.row_step, dc as f32 * self.col_step);
        (a * a + b * b).sqrt()
    }
    /// Per-pixel values (`pixel[i]` for pixel `i`) as per-point values of the scan's `n`
    /// points; 0 for points in no pixel (no return, or the farther of two in one pixel).
    pub fn to_points(&self, pixel: &[u32], n: usize) -> Vec<u32> {
        let mut out = vec![0u32; n];
        for (&p, &v) in self.point.iter().zip(pixel) {
            if p != NONE && (p as usize) < n {
                out[p as usize] = v;
            }
        }
        out
    }
    /// Pixels with a return.
    pub fn valid_count(&self) -> usize {
        self.range.iter().filter(|&&r| r > 0.0).count()
    }
    /// The pixel `dc` columns and `dr` rows from `(r, c)`, wrapping around in columns when
    /// the image closes a turn; None outside the image.
    #[inline]
    pub fn offset(&self, r: usize, c: usize, dr: isize, dc: isize) -> Option<usize> {
        let rr = r as isize + dr;
        if rr < 0 || rr >= self.rows as isize {
            return None;
        }
        let mut cc = c as isize + dc;
        let n = self.cols as isize;
        if cc < 0 || cc >= n {
            if !self.wraps {
                return None;
            }
            cc = cc.rem_euclid(n);
        }
        Some(rr as usize * self.cols + cc as usize)
    }

    /// The neighbour of `(r, c)` in direction `(dr, dc)`: the nearest pixel with a return, across
    /// at most `gap` pixels without one (glass and dark paint return few echoes, and such
    /// dropouts would otherwise cut a surface into pieces), with how many steps away it lies
    /// (`k`: `k · dr` rows and `k · dc` columns, for the surface test); None when there is
    /// none that near or the image ends.
    #[inline]
    pub fn across(
        &self,
        r: usize,
        c: usize,
        dr: isize,
        dc: isize,
        gap: usize,
    ) -> Option<(usize, isize)> {
        for k in 1..=gap as isize + 1 {
            let j = self.offset(r, c, k * dr, k * dc)?;
            if self.valid(j) {
                return Some((j, k));
            }
        }
        None
    }

    /// The image of an organised scan: `rows × cols` points in `order`, in the sensor frame;
    /// `lab` optional CIELab colours, one per point. Points with a non-finite coordinate or
    /// at the origin are empty pixels. Columns are taken to span a full turn (spinning
    /// sensors), rows the elevation range of the valid points.
    pub fn organised(
        rows: usize,
        cols: usize,
        xyz: &[[f32; 3]],
        lab: Option<&[[f32; 3]]>,
        order: Order,
    ) -> Result<Self, ImageError> {
        if rows == 0 || cols == 0 || pixels(rows, cols)? != xyz.len() {
            return Err(ImageError::Layout {
                rows,
                cols,
                points: xyz.len(),
            });
        }
        check_colour(xyz.len(), lab)?;
        // Point index of each pixel.
        let src: Vec<usize> = match order {
            Order::RowMajor => (0..xyz.len()).collect(),
            Order::ColumnMajor => (0..xyz.len())
                .map(|px| (px % cols) * rows + px / cols)
                .collect(),
        };
        let xyz: Vec<[f32; 3]> = src.iter().map(|&i| xyz[i]).collect();
        let range: Vec<f32> = xyz.iter().map(range_of).collect();
        let point = src
            .iter()
            .zip(&range)
            .map(|(&i, &r)| if r > 0.0 { i as u32 } else { NONE })
            .collect();
        let mut img = RangeImage {
            rows,
            cols,
            xyz,
            range,
            lab: lab.map(|l| src.iter().map(|&i| l[i]).collect()),
            point,
            col_step: (2.0 * PI / cols as f64) as f32,
            row_step: 0.0,
            wraps: true,
        };
        img.row_step = img.measured_row_step();
        if img.valid_count() == 0 {
            return Err(ImageError::NoReturns {
                points: rows * cols,
            });
        }
        Ok(img)
    }

    /// The image of an unorganised scan by spherical projection: `cols` columns over a full
    /// turn of azimuth, rows from the elevation angles as `rings` says, highest first. Where
    /// two points fall in one pixel the nearer is kept (the farther is occluded at this
    /// resolution) and counted in the second value returned.
    pub fn spherical(
        xyz: &[[f32; 3]],
        lab: Option<&[[f32; 3]]>,
        cols: usize,
        rings: Rings,
    ) -> Result<(Self, usize), ImageError> {
        if cols == 0 {
            return Err(ImageError::Layout {
                rows: 0,
                cols,
                points: xyz.len(),
            });
        }
        check_colour(xyz.len(), lab)?;
        let valid: Vec<usize> = (0..xyz.len())
            .filter(|&i| range_of(&xyz[i]) > 0.0)
            .collect();
        if valid.is_empty() {
            return Err(ImageError::NoReturns { points: xyz.len() });
        }
        let elev = |p: &[f32; 3]| {
            let h = (p[0] as f64).hypot(p[1] as f64);
            (p[2] as f64).atan2(h)
        };
        let mut e: Vec<f64> = valid.iter().map(|&i| elev(&xyz[i])).collect();
        e.sort_by(f64::total_cmp);
        let mut cuts = Vec::new(); // elevation boundaries between rows, ascending
        match rings {
            Rings::Gaps { gap_deg, max_rows } => {
                // Sorted elevations cut where consecutive ones are more than the gap apart.
                let gap = gap_deg.to_radians();
                for w in e.windows(2) {
                    if w[1] - w[0] > gap {
                        cuts.push(0.5 * (w[0] + w[1]));
                    }
                }
                if cuts.len() + 1 > max_rows {
                    return Err(ImageError::TooManyRings {
                        rings: cuts.len() + 1,
                        max: max_rows,
                    });
                }
            }
            Rings::Uniform(rows) => {
                let (lo, hi) = (e[0], e[e.len() - 1]);
                let step = (hi - lo) / rows.max(1) as f64;
                cuts.extend((1..rows).map(|k| lo + k as f64 * step));
            }
        }
        let rows = cuts.len() + 1;
        let n = pixels(rows, cols)?;
        let mut img = RangeImage {
            rows,
            cols,
            xyz: vec![[0.0; 3]; n],
            range: vec![0.0; n],
            lab: lab.map(|_| vec![[0.0; 3]; n]),
            point: vec![NONE; n],
            col_step: (2.0 * PI / cols as f64) as f32,
            row_step: 0.0,
            wraps: true,
        };
        let mut collisions = 0;
        for &i in &valid {
            let p = &xyz[i];
            // Ring index counted from the top (row 0 = highest elevation), as organised
            // sensors lay out their rings.
            let ring = cuts.partition_point(|&c| c < elev(p));
            let r = rows - 1 - ring;
            let az = (p[1] as f64).atan2(p[0] as f64); // (-π, π]
            let c = (((PI - az) / (2.0 * PI)) * cols as f64) as usize % cols;
            let px = r * cols + c;
            let rho = range_of(p);
            if img.point[px] != NONE {
                collisions += 1;
                if img.range[px] <= rho {
                    continue;
                }
            }
            img.xyz[px] = *p;
            img.range[px] = rho;
            img.point[px] = i as u32;
            if let (Some(dst), Some(src)) = (img.lab.as_mut(), lab) {
                dst[px] = src[i];
            }
        }
        img.row_step = img.measured_row_step();
        Ok((img, collisions))
    }

    /// Mean elevation step between consecutive rings, from the median elevations of the first
    /// and the last row with returns; falls back to the column step when fewer than two rows
    /// hold returns.
    fn measured_row_step(&self) -> f32 {
        let median = |r: usize| -> Option<f32> {
            let mut e: Vec<f32> = (0..self.cols)
                .map(|c| r * self.cols + c)
                .filter(|&i| self.valid(i))
                .map(|i| {
                    let p = self.xyz[i];
                    p[2].atan2(p[0].hypot(p[1]))
                })
                .collect();
            if e.is_empty() {
                return None;
            }
            let m = e.len() / 2;
            e.select_nth_unstable_by(m, f32::total_cmp);
            Some(e[m])
        };
        // Only these two rows count (the rows between were measured once and never used).
        let first = (0..self.rows).find_map(|r| median(r).map(|e| (r, e)));
        let last = (0..self.rows).rev().find_map(|r| median(r).map(|e| (r, e)));
        match (first, last) {
            (Some((r0, e0)), Some((r1, e1))) if r1 > r0 => (e0 - e1).abs() / (r1 - r0) as f32,
            _ => self.col_step,
        }
    }
}

/// How an organised cloud lays out its `rows × cols` points.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Order {
    /// Ring by ring (`sensor_msgs/PointCloud2` as documented: point `r * width + c`).
    RowMajor,
    /// Column by column, the rings of one firing consecutive (what early Ouster ROS drivers
    /// wrote while declaring `height` rings × `width` columns: point `c * height + r`).
    ColumnMajor,
}

impl Order {
    /// The order a per-point ring number reveals: row-major when point `i` is on ring
    /// `i / cols`, column-major when on ring `i % rows` (for at least 99 % of the points);
    /// None when neither holds (then the ring field does not describe the layout).
    pub fn from_rings(ring: &[u32], rows: usize, cols: usize) -> Option<Order> {
        if rows == 0 || cols == 0 || ring.len() != rows * cols {
            return None;
        }
        let n = ring.len();
        let row = ring
            .iter()
            .enumerate()
            .filter(|&(i, &r)| r as usize == i / cols)
            .count();
        let col = ring
            .iter()
            .enumerate()
            .filter(|&(i, &r)| r as usize == i % rows)
            .count();
        if row * 100 >= n * 99 {
            Some(Order::RowMajor)
        } else if col * 100 >= n * 99 {
            Some(Order::ColumnMajor)
        } else {
            None
        }
    }
}

/// How [`RangeImage::spherical`] finds the rows of an unorganised scan.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Rings {
    /// The sensor's rings, as clusters of elevation angles separated by more than `gap_deg`
    /// (at most `max_rows` of them). Needs a sensor whose beams share one origin; where each
    /// laser sits apart (the HDL-64E of KITTI) the clusters smear into each other.
    Gaps {
        /// Smallest gap between rings, degrees.
        gap_deg: f64,
        /// Most rings accepted.
        max_rows: usize,
    },
    /// `n` rows of equal elevation span between the lowest and highest return (the projection
    /// RangeNet++ uses for SemanticKITTI, with 64 rows).
    Uniform(usize),
}

fn check_colour(points: usize, lab: Option<&[[f32; 3]]>) -> Result<(), ImageError> {
    match lab {
        Some(l) if l.len() != points => Err(ImageError::Colour {
            colours: l.len(),
            points,
        }),
        _ => Ok(()),
    }
}

/// Range of a point from the sensor; 0 for a non-finite point or one at the origin.
#[inline]
fn range_of(p: &[f32; 3]) -> f32 {
    let r = (p[0] * p[0] + p[1] * p[1] + p[2] * p[2]).sqrt();
    if r.is_finite() && r > 1e-6 {
        r
    } else {
        0.0
    }
}

#[cfg(test)]
pub(crate) mod tests {
    use super::*;

    /// The surface test of the unit tests: tan θ = 0.1 and the paper's 4-neighbours (no gap
    /// bridging).
    pub(crate) const STRICT: crate::segment::multicue::cues::Jump =
        crate::segment::multicue::cues::Jump {
            tan_theta: 0.1,
            max_gap_px: 0,
        };

    /// A flat `rows × cols` image for the mean-shift and integration tests: every pixel at
    /// range 10 (so every pixel covers the same), no wrap, beams 0.001 rad apart.
    pub(crate) fn flat_image(rows: usize, cols: usize) -> RangeImage {
        let xyz: Vec<[f32; 3]> = (0..rows * cols)
            .map(|i| [10.0, (i % cols) as f32 * 0.01, (i / cols) as f32 * 0.01])
            .collect();
        let mut img = RangeImage::organised(rows, cols, &xyz, None, Order::RowMajor).unwrap();
        img.wraps = false;
        (img.row_step, img.col_step) = (0.001, 0.001);
        img.range.iter_mut().for_each(|r| *r = 10.0);
        img
    }

    /// A scan of `rows` rings 1° apart from +3° down and `cols` columns of the plane z = -2
    /// and a wall x = 5 (whichever is hit first along each ray, up to 80 m), in sensor frame.
    pub(crate) fn plane_and_wall(rows: usize, cols: usize) -> Vec<[f32; 3]> {
        let mut v = Vec::with_capacity(rows * cols);
        for r in 0..rows {
            let el = (3.0 - r as f64).to_radians();
            for c in 0..cols {
                let az = PI - 2.0 * PI * (c as f64 + 0.5) / cols as f64;
                let d = [el.cos() * az.cos(), el.cos() * az.sin(), el.sin()];
                let mut t = f64::INFINITY;
                if d[2] < -1e-9 {
                    t = t.min(-2.0 / d[2]);
                }
                if d[0] > 1e-9 {
                    t = t.min(5.0 / d[0]);
                }
                if t.is_finite() && t < 80.0 {
                    v.push([(t * d[0]) as f32, (t * d[1]) as f32, (t * d[2]) as f32]);
                } else {
                    v.push([f32::NAN; 3]);
                }
            }
        }
        v
    }

    #[test]
    fn organised_layout_is_checked() {
        let pts = plane_and_wall(8, 90);
        let img = RangeImage::organised(8, 90, &pts, None, Order::RowMajor).unwrap();
        assert_eq!((img.rows, img.cols), (8, 90));
        assert!(img.valid_count() > 8 * 30 && img.valid_count() < 8 * 90);
        assert!(
            (img.row_step.to_degrees() - 1.0).abs() < 0.05,
            "{}",
            img.row_step
        );
        assert_eq!(img.offset(0, 0, 0, -1), Some(89));
        assert_eq!(img.offset(0, 0, -1, 0), None);
        assert!(matches!(
            RangeImage::organised(8, 91, &pts, None, Order::RowMajor),
            Err(ImageError::Layout { .. })
        ));
        assert!(matches!(
            RangeImage::organised(0, 0, &[], None, Order::RowMajor),
            Err(ImageError::Layout { .. })
        ));
        // Too many pixels (or rows × columns beyond usize): an error, before any allocation.
        for (rows, cols) in [(1 << 14, (1 << 14) + 1), (usize::MAX, 2)] {
            assert!(matches!(
                RangeImage::organised(rows, cols, &pts, None, Order::RowMajor),
                Err(ImageError::TooLarge { .. })
            ));
        }
        assert!(
            RangeImage::organised(1 << 14, 1 << 14, &pts, None, Order::RowMajor)
                .is_err_and(|e| matches!(e, ImageError::Layout { .. }))
        );
        assert!(matches!(
            RangeImage::spherical(&pts, None, 1 << 20, Rings::Uniform(1 << 9)),
            Err(ImageError::TooLarge { .. })
        ));
        let nan = vec![[f32::NAN; 3]; 6];
        assert!(matches!(
            RangeImage::organised(2, 3, &nan, None, Order::RowMajor),
            Err(ImageError::NoReturns { points: 6 })
        ));
        assert!(matches!(
            RangeImage::organised(8, 90, &pts, Some(&[[0.0; 3]; 3]), Order::RowMajor),
            Err(ImageError::Colour { .. })
        ));
    }

    #[test]
    fn column_major_clouds_give_the_same_image() {
        let (rows, cols) = (8, 90);
        let pts = plane_and_wall(rows, cols);
        let a = RangeImage::organised(rows, cols, &pts, None, Order::RowMajor).unwrap();
        // The same scan written column by column.
        let cm: Vec<[f32; 3]> = (0..rows * cols)
            .map(|i| pts[(i % rows) * cols + i / rows])
            .collect();
        let b = RangeImage::organised(rows, cols, &cm, None, Order::ColumnMajor).unwrap();
        assert_eq!(a.range, b.range);
        let ring_rm: Vec<u32> = (0..rows * cols).map(|i| (i / cols) as u32).collect();
        let ring_cm: Vec<u32> = (0..rows * cols).map(|i| (i % rows) as u32).collect();
        assert_eq!(
            Order::from_rings(&ring_rm, rows, cols),
            Some(Order::RowMajor)
        );
        assert_eq!(
            Order::from_rings(&ring_cm, rows, cols),
            Some(Order::ColumnMajor)
        );
        assert_eq!(Order::from_rings(&vec![3; rows * cols], rows, cols), None);
        // Each pixel names its point in the input order.
        for px in 0..rows * cols {
            if b.point[px] != NONE {
                assert_eq!(cm[b.point[px] as usize], a.xyz[px]);
            }
        }
    }

    #[test]
    fn spherical_projection_recovers_the_organised_image() {
        let (rows, cols) = (8, 90);
        let pts = plane_and_wall(rows, cols);
        let org = RangeImage::organised(rows, cols, &pts, None, Order::RowMajor).unwrap();
        // Shuffle the points (a projection must not depend on their order).
        let mut order: Vec<usize> = (0..pts.len()).collect();
        order.reverse();
        order.rotate_left(37);
        let shuffled: Vec<[f32; 3]> = order.iter().map(|&i| pts[i]).collect();
        let (img, collisions) = RangeImage::spherical(
            &shuffled,
            None,
            cols,
            Rings::Gaps {
                gap_deg: 0.3,
                max_rows: 256,
            },
        )
        .unwrap();
        assert_eq!(collisions, 0);
        // Rings without any return are not found; the rings that are keep their order.
        let full_rows: Vec<usize> = (0..rows)
            .filter(|&r| (0..cols).any(|c| org.valid(r * cols + c)))
            .collect();
        assert_eq!(img.rows, full_rows.len());
        for (ir, &r) in full_rows.iter().enumerate() {
            for c in 0..cols {
                let a = org.range[r * cols + c];
                let b = img.range[ir * cols + c];
                assert!((a - b).abs() < 1e-5, "ring {r} col {c}: {a} vs {b}");
                if b > 0.0 {
                    assert_eq!(order[img.point[ir * cols + c] as usize], r * cols + c);
                }
            }
        }
        assert!(matches!(
            RangeImage::spherical(
                &shuffled,
                None,
                cols,
                Rings::Gaps {
                    gap_deg: 0.001,
                    max_rows: 4
                }
            ),
            Err(ImageError::TooManyRings { .. })
        ));
        // Uniform rows: as many as asked, every point in one.
        let (u, uc) = RangeImage::spherical(&shuffled, None, cols, Rings::Uniform(5)).unwrap();
        assert_eq!(u.rows, 5);
        assert!(uc > 0);
        assert_eq!(u.valid_count() + uc, org.valid_count());
    }
}
