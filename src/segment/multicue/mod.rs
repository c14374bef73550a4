//! Multi-cue segmentation of organised scans — Barnea & Filin, *Segmentation of terrestrial
//! laser scanning data by integrating range and image content* (seed document 004, "the
//! paper" below).
//!
//! One scan at a time, in its panoramic range image ([`image`], §2.2):
//! 1. cues per pixel ([`cues`], §2.3): range; surface normals from neighbouring pixels after a
//!    range-adaptive Gaussian smoothing (eqs. 3–4); CIELab colour when the scan has colour;
//! 2. mean-shift segmentation of each cue in the joint spatial–range domain ([`meanshift`],
//!    §2.4);
//! 3. integration ([`integrate`], §2.5): the largest segment of all cues by 3-D coverage is
//!    accepted when its dispersion is acceptable, its pixels leave every cue, the cues'
//!    remainders are regrouped, and so on down to a minimum coverage.
//!
//! The paper gives the method but no parameter values; the defaults below are ours, in
//! physical units, and documented where they are set.

pub mod cues;
pub mod image;
pub mod integrate;
pub mod meanshift;
mod refine;
pub mod ties;

use std::borrow::Cow;
use std::time::Instant;

use serde::{Deserialize, Serialize};

pub use crate::model::ScanPoints;
use cues::Jump;
pub use image::{ImageError, Order, RangeImage, Rings};
use integrate::{CueSegments, Integrated, Rules};
use meanshift::Kernel;

/// Parameters of the multi-cue segmentation.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct MulticueParams {
    /// Mean-shift spatial half-window, pixels.
    pub hs_px: usize,
    /// Most mean-shift moves per pixel.
    pub max_iter: usize,
    /// Mean-shift basins of attraction ([`meanshift`]): a pixel up to this many columns after
    /// a window's start in its row (or either side in the rows below, `basin_rows`), passed by
    /// the window with a value within half the bandwidth, takes the window's end value instead
    /// of starting its own (0: every pixel starts a window, the exact filter).
    pub basin_px: usize,
    /// Basins also reach this many rows below a window's start (rows are filtered in bands of
    /// `1 + basin_rows`; 0: the window's own row only).
    pub basin_rows: usize,
    /// Basins: a pixel takes a window's end value only if its value lay within this share of
    /// the bandwidth of the window's where the window passed it, in `(0, 1]`. 1 is the rule of
    /// the high-speedup filter in Comaniciu & Meer's EDISON code: on the benchmark drive the
    /// segmentation runs ~15 % faster per scan, at one or two fewer correct world segments
    /// per drive (README, issue 22); the default ½ keeps those.
    pub basin_hr: f32,
    /// Grouping: filtered values within this share of the bandwidth join.
    pub merge: f32,
    /// Range cue bandwidth, metres.
    pub range_hr_m: f32,
    /// Normal cue bandwidth, degrees between normals.
    pub normal_hr_deg: f32,
    /// Colour cue bandwidth, CIELab units.
    pub colour_hr: f32,
    /// Physical window of the normals' adaptive smoothing (`D` of eq. 4), metres.
    pub smooth_window_m: f32,
    /// Neighbouring returns lie on one surface when the line joining them makes at least this
    /// angle with the farther beam, degrees (Bogoslavskyi & Stachniss 2016 use 10° on
    /// ground-free scans; ground seen at a grazing angle needs less).
    pub min_angle_deg: f32,
    /// Neighbouring returns connect across at most this many pixels without a return (0: the
    /// paper's 4-neighbours only). Glass and dark surfaces drop returns; without bridging a
    /// window's glass falls apart into pieces below `min_points`.
    pub max_gap_px: usize,
    /// Integration: largest acceptable RMS spread of a range segment, metres.
    pub range_max_dispersion_m: f32,
    /// Largest acceptable spread of a normal segment, degrees.
    pub normal_max_dispersion_deg: f32,
    /// Largest acceptable spread of a colour segment, CIELab units.
    pub colour_max_dispersion: f32,
    /// A segment of any cue is accepted only if its colours also spread no more than
    /// `colour_max_dispersion` (scans with colour). Our addition to the paper, which checks a
    /// segment in its own cue: there the normals' ground (road, footpath and grass in one)
    /// and whole façades with their windows were accepted first and the colour cue's finer
    /// segments lost their pixels; see `config/default.toml` for the measured effect.
    pub colour_veto: bool,
    /// Integration stops below this coverage (Σ range of the segment's pixels, metres).
    pub min_coverage_m: f32,
    /// Smaller segments are not accepted (their points stay unsegmented).
    pub min_points: usize,
    /// Which cues take part: any of "range", "normals", "colour" (colour only when the scan
    /// has it).
    pub cues: Vec<String>,
}

impl Default for MulticueParams {
    fn default() -> Self {
        MulticueParams {
            hs_px: 1,
            max_iter: 5,
            basin_px: 3,
            basin_rows: 1,
            basin_hr: 0.5,
            merge: 0.5,
            range_hr_m: 0.5,
            normal_hr_deg: 15.0,
            colour_hr: 8.0,
            smooth_window_m: 0.3,
            min_angle_deg: 3.0,
            max_gap_px: 1,
            range_max_dispersion_m: 0.5,
            normal_max_dispersion_deg: 12.0,
            colour_max_dispersion: 10.0,
            colour_veto: true,
            min_coverage_m: 50.0,
            min_points: 10,
            cues: vec!["range".into(), "normals".into(), "colour".into()],
        }
    }
}

impl MulticueParams {
    /// Checks the parameters.
    pub fn validate(&self) -> Result<(), String> {
        let pos = [
            self.range_hr_m,
            self.normal_hr_deg,
            self.colour_hr,
            self.merge,
            self.range_max_dispersion_m,
            self.normal_max_dispersion_deg,
            self.colour_max_dispersion,
        ];
        if pos.iter().any(|v| !(v.is_finite() && *v > 0.0)) {
            return Err("segment.multicue: bandwidths, merge and dispersions must be > 0".into());
        }
        let nonneg = [self.smooth_window_m, self.min_coverage_m];
        if nonneg.iter().any(|v| !(v.is_finite() && *v >= 0.0)) {
            return Err("segment.multicue: smooth_window_m and min_coverage_m must be >= 0".into());
        }
        if self.max_gap_px > 8 {
            return Err(format!(
                "segment.multicue: max_gap_px must be at most 8, got {}",
                self.max_gap_px
            ));
        }
        if !(self.min_angle_deg.is_finite() && (0.0..90.0).contains(&self.min_angle_deg)) {
            return Err("segment.multicue: min_angle_deg must be in [0, 90)".into());
        }
        if self.hs_px == 0 || self.hs_px > 32 || self.max_iter == 0 {
            return Err("segment.multicue: hs_px must be 1..=32 and max_iter >= 1".into());
        }
        if self.basin_px > 32 {
            return Err(format!(
                "segment.multicue: basin_px must be at most 32, got {}",
                self.basin_px
            ));
        }
        if !(self.basin_hr > 0.0 && self.basin_hr <= 1.0) {
            return Err(format!(
                "segment.multicue: basin_hr must be in (0, 1], got {}",
                self.basin_hr
            ));
        }
        if self.basin_rows > 8 {
            return Err(format!(
                "segment.multicue: basin_rows must be at most 8, got {}",
                self.basin_rows
            ));
        }
        if self.normal_hr_deg >= 180.0 || self.normal_max_dispersion_deg >= 180.0 {
            return Err("segment.multicue: normal angles must be below 180°".into());
        }
        for c in &self.cues {
            if Cue::parse(c).is_none() {
                return Err(format!(
                    "segment.multicue.cues: unknown cue \"{c}\" (range, normals, colour)"
                ));
            }
        }
        if self.cues.is_empty() {
            return Err("segment.multicue.cues must name at least one cue".into());
        }
        Ok(())
    }
    fn jump(&self) -> Jump {
        Jump {
            tan_theta: self.min_angle_deg.to_radians().tan(),
            max_gap_px: self.max_gap_px,
        }
    }
}

/// A cue.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Cue {
    /// Range.
    Range,
    /// Surface normals.
    Normals,
    /// CIELab colour.
    Colour,
}

impl Cue {
    /// The cue a name stands for.
    pub fn parse(s: &str) -> Option<Cue> {
        match s {
            "range" => Some(Cue::Range),
            "normals" => Some(Cue::Normals),
            "colour" | "color" => Some(Cue::Colour),
            _ => None,
        }
    }
}

/// Chord length between unit vectors `deg` degrees apart.
fn chord(deg: f32) -> f32 {
    2.0 * (0.5 * deg.to_radians()).sin()
}

/// The segmentation of one scan.
#[derive(Debug, Clone, Default)]
pub struct ScanSegmentation {
    /// Segment per pixel of the image (0 = none), 1.. in order of acceptance.
    pub pixel_labels: Vec<u32>,
    /// Segments.
    pub segments: u32,
    /// The cues used, in order, with each one's own segmentation per pixel.
    pub cue_labels: Vec<(Cue, Vec<u32>)>,
    /// Integration figures.
    pub integrated: Integrated,
    /// Seconds: cues (neighbour links, normals), mean shift (all cues), integration.
    pub seconds: [f64; 3],
}

impl ScanSegmentation {
    /// Segment per input point of the scan (`n` points; 0 for points not in the image).
    pub fn point_labels(&self, img: &RangeImage, n: usize) -> Vec<u32> {
        img.to_points(&self.pixel_labels, n)
    }
    /// Each cue's own segmentation per input point ([`single_cue_labels`] with `min_points`),
    /// in the order of [`ScanSegmentation::cue_labels`]: what a cue alone would give, for
    /// comparing the integration with it.
    pub fn cue_point_labels(&self, img: &RangeImage, n: usize, min_points: usize) -> Vec<Vec<u32>> {
        self.cue_labels
            .iter()
            .map(|(_, l)| img.to_points(&single_cue_labels(l, min_points), n))
            .collect()
    }
}

/// Per-scan scoring against reference segments: reference segments with fewer than
/// `min_points` returns in the scan set to 0 (unlabelled) — no method can find them there, as
/// no segment smaller than that is kept.
pub fn without_small_segments(truth: &mut [u32], min_points: usize) {
    let mut size = std::collections::HashMap::new();
    for &l in truth.iter() {
        *size.entry(l).or_insert(0usize) += 1;
    }
    for l in truth.iter_mut() {
        if size[l] < min_points {
            *l = 0;
        }
    }
}

/// One cue as the mean shift and the integration take it.
struct CueInput<'a> {
    cue: Cue,
    /// Values per pixel, `dim` each, flattened: the image's own where it has them.
    values: Cow<'a, [f32]>,
    dim: usize,
    usable: Cow<'a, [bool]>,
    kernel: Kernel,
    max_dispersion: f32,
    veto: bool,
}

/// Segments one scan's range image with the cues of `p` (colour skipped when the image has
/// none).
pub fn segment_scan(img: &RangeImage, p: &MulticueParams) -> ScanSegmentation {
    let n = img.len();
    let jump = p.jump();
    let t = Instant::now();
    let links = cues::Links::new(img, jump);
    let valid: Vec<bool> = (0..n).map(|i| img.valid(i)).collect();
    let wanted: Vec<Cue> = p.cues.iter().filter_map(|c| Cue::parse(c)).collect();
    let mut flat: Vec<CueInput> = Vec::new();
    let kernel = |hr: f32| Kernel {
        hs: p.hs_px,
        hr,
        max_iter: p.max_iter,
        merge: p.merge,
        basin: p.basin_px,
        basin_rows: p.basin_rows,
        basin_hr: p.basin_hr,
    };
    for cue in [Cue::Range, Cue::Normals, Cue::Colour] {
        if !wanted.contains(&cue) {
            continue;
        }
        match cue {
            Cue::Range => flat.push(CueInput {
                cue,
                values: Cow::Borrowed(&img.range),
                dim: 1,
                usable: Cow::Borrowed(&valid),
                kernel: kernel(p.range_hr_m),
                max_dispersion: p.range_max_dispersion_m,
                veto: false,
            }),
            Cue::Normals => {
                let nrm = cues::normals(img, p.smooth_window_m, &links);
                let usable = Cow::Owned(nrm.iter().map(|v| *v != [0.0; 3]).collect());
                flat.push(CueInput {
                    cue,
                    values: Cow::Owned(nrm.into_flattened()),
                    dim: 3,
                    usable,
                    kernel: kernel(chord(p.normal_hr_deg)),
                    max_dispersion: chord(p.normal_max_dispersion_deg),
                    veto: false,
                });
            }
            Cue::Colour => {
                if let Some(lab) = &img.lab {
                    flat.push(CueInput {
                        cue,
                        values: Cow::Borrowed(lab.as_flattened()),
                        dim: 3,
                        usable: Cow::Borrowed(&valid),
                        kernel: kernel(p.colour_hr),
                        max_dispersion: p.colour_max_dispersion,
                        veto: p.colour_veto,
                    });
                }
            }
        }
    }
    let t_cues = t.elapsed().as_secs_f64();
    let t = Instant::now();
    let labels: Vec<Vec<u32>> = flat
        .iter()
        .map(|c| match c.dim {
            1 => shift::<1>(img, &c.values, &c.usable, c.kernel, &links),
            _ => shift::<3>(img, &c.values, &c.usable, c.kernel, &links),
        })
        .collect();
    let t_shift = t.elapsed().as_secs_f64();
    let t = Instant::now();
    // The cues' labels go into the integration (which reads them) and come back out for
    // `cue_labels`, not copied.
    let segs: Vec<CueSegments> = flat
        .iter()
        .zip(labels)
        .map(|(c, l)| CueSegments {
            values: &c.values,
            dim: c.dim,
            labels: l,
            max_dispersion: c.max_dispersion,
            veto: c.veto,
        })
        .collect();
    let rules = Rules {
        min_coverage: p.min_coverage_m,
        min_pixels: p.min_points,
    };
    let mut integrated = integrate::integrate(img, &segs, rules, &links);
    let t_int = t.elapsed().as_secs_f64();
    let pixel_labels = std::mem::take(&mut integrated.labels);
    ScanSegmentation {
        segments: integrated.segments,
        pixel_labels,
        cue_labels: flat
            .iter()
            .map(|f| f.cue)
            .zip(segs.into_iter().map(|s| s.labels))
            .collect(),
        integrated,
        seconds: [t_cues, t_shift, t_int],
    }
}

/// One cue's mean shift: filtered, then grouped.
fn shift<const D: usize>(
    img: &RangeImage,
    flat: &[f32],
    usable: &[bool],
    k: Kernel,
    links: &cues::Links,
) -> Vec<u32> {
    // A view of the flat values as arrays, not a copy.
    let (v, rest) = flat.as_chunks::<D>();
    debug_assert!(rest.is_empty());
    let f = meanshift::filter(img, v, usable, k);
    meanshift::group(&f, usable, k, links).0
}

/// A single cue's segmentation as a result of its own: its segments with at least
/// `min_points` pixels, numbered 1.. (for comparing the integration with each cue).
pub fn single_cue_labels(labels: &[u32], min_points: usize) -> Vec<u32> {
    let max = labels.iter().copied().max().unwrap_or(0) as usize;
    let mut count = vec![0usize; max + 1];
    for &l in labels {
        count[l as usize] += 1;
    }
    let mut id = vec![0u32; max + 1];
    let mut next = 0;
    labels
        .iter()
        .map(|&l| {
            if l == 0 || count[l as usize] < min_points {
                return 0;
            }
            if id[l as usize] == 0 {
                next += 1;
                id[l as usize] = next;
            }
            id[l as usize]
        })
        .collect()
}

/// Columns of the spherical projection of an unorganised scan (the 0.18° azimuth step of
/// 64-beam sensors at 10 Hz).
pub const SPHERICAL_COLS: usize = 2048;

/// Segments one scan given as points: organised scans (`rows > 1`) in their own layout
/// (column-major when the ring numbers say so), unorganised ones by spherical projection with
/// rings found from gaps in elevation. Returns the segment per point (0 = none, 1..) and the
/// number of segments.
pub fn segment_points(s: ScanPoints, p: &MulticueParams) -> Result<(Vec<u32>, u32), ImageError> {
    let n = s.xyz.len();
    // sRGB's transfer function from a table (the same values as `rgb_to_lab` of the colour
    // over 65535, bit for bit; three `powf` a point were about as costly as the segmentation).
    let lab: Option<Vec<[f32; 3]>> = s.rgb.map(|c| {
        c.iter()
            .map(|&v| crate::segment::features::rgb16_to_lab(v, false).map(|x| x as f32))
            .collect()
    });
    let img = if s.rows > 1 {
        let order = s
            .ring
            .and_then(|r| Order::from_rings(r, s.rows, s.cols))
            .unwrap_or(Order::RowMajor);
        RangeImage::organised(s.rows, s.cols, s.xyz, lab.as_deref(), order)?
    } else {
        let rings = Rings::Gaps {
            gap_deg: 0.2,
            max_rows: 256,
        };
        RangeImage::spherical(s.xyz, lab.as_deref(), SPHERICAL_COLS, rings)?.0
    };
    let seg = segment_scan(&img, p);
    Ok((seg.point_labels(&img, n), seg.segments))
}

impl crate::io::mcap::ScanSegmenter for MulticueParams {
    fn segment(&self, scan: ScanPoints<'_>) -> Result<(Vec<u32>, u32), String> {
        segment_points(scan, self).map_err(|e| e.to_string())
    }
}

#[cfg(test)]
mod tests {
    use super::image::tests::plane_and_wall;
    use super::*;

    #[test]
    fn plane_and_wall_are_two_segments() {
        let (rows, cols) = (16, 720);
        let pts = plane_and_wall(rows, cols);
        let img = RangeImage::organised(rows, cols, &pts, None, image::Order::RowMajor).unwrap();
        let p = MulticueParams::default();
        let s = segment_scan(&img, &p);
        // The two largest segments are the ground and the wall, from the normals cue.
        let mut size = vec![0usize; s.segments as usize + 1];
        for &l in &s.pixel_labels {
            size[l as usize] += 1;
        }
        let on = |l: u32, f: &dyn Fn(&[f32; 3]) -> bool| {
            (0..img.len())
                .filter(|&i| s.pixel_labels[i] == l && img.valid(i))
                .filter(|&i| f(&img.xyz[i]))
                .count()
        };
        // Ground within 35 m: farther it is seen at less than the surface test's 3°.
        let ground = |p: &[f32; 3]| (p[2] + 2.0).abs() < 1e-3 && p[0].hypot(p[1]) < 35.0;
        let wall = |p: &[f32; 3]| (p[0] - 5.0).abs() < 1e-3;
        assert_eq!(on(1, &wall), 0);
        assert_eq!(on(2, &ground), 0);
        assert!(s.segments >= 2);
        let g_all = (0..img.len())
            .filter(|&i| img.valid(i) && ground(&img.xyz[i]))
            .count();
        let w_all = (0..img.len())
            .filter(|&i| img.valid(i) && wall(&img.xyz[i]))
            .count();
        assert!(
            on(1, &ground) * 100 >= g_all * 95,
            "{} of {g_all}",
            on(1, &ground)
        );
        assert!(
            on(2, &wall) * 100 >= w_all * 90,
            "{} of {w_all}",
            on(2, &wall)
        );
        assert!(s.integrated.from_cue[1] >= 2, "{:?}", s.integrated);
        assert_eq!(s.point_labels(&img, pts.len()).len(), pts.len());
    }

    #[test]
    fn thread_count_does_not_change_the_result() {
        let (rows, cols) = (16, 720);
        let pts = plane_and_wall(rows, cols);
        let img = RangeImage::organised(rows, cols, &pts, None, image::Order::RowMajor).unwrap();
        let p = MulticueParams::default();
        let run = |threads: usize| {
            rayon::ThreadPoolBuilder::new()
                .num_threads(threads)
                .build()
                .unwrap()
                .install(|| segment_scan(&img, &p))
        };
        let (a, b) = (run(1), run(3));
        assert_eq!(a.pixel_labels, b.pixel_labels);
        assert_eq!(a.cue_labels, b.cue_labels);
    }

    #[test]
    fn params_are_checked() {
        let mut p = MulticueParams::default();
        assert!(p.validate().is_ok());
        p.cues = vec!["depth".into()];
        assert!(p.validate().unwrap_err().contains("depth"));
        p = MulticueParams {
            range_hr_m: f32::NAN,
            ..Default::default()
        };
        assert!(p.validate().is_err());
        p = MulticueParams {
            hs_px: 0,
            ..Default::default()
        };
        assert!(p.validate().is_err());
        p = MulticueParams {
            basin_px: 33,
            ..Default::default()
        };
        assert!(p.validate().unwrap_err().contains("basin_px"));
        p = MulticueParams {
            basin_rows: 9,
            ..Default::default()
        };
        assert!(p.validate().unwrap_err().contains("basin_rows"));
        for bad in [0.0, 1.5, f32::NAN] {
            let p = MulticueParams {
                basin_hr: bad,
                ..Default::default()
            };
            assert!(p.validate().unwrap_err().contains("basin_hr"), "{bad}");
        }
        p = MulticueParams {
            max_gap_px: 9,
            ..Default::default()
        };
        assert!(p.validate().unwrap_err().contains("max_gap_px"));
    }

    #[test]
    fn single_cue_keeps_segments_of_min_points() {
        assert_eq!(
            single_cue_labels(&[3, 3, 0, 5, 3, 7, 7], 2),
            [1, 1, 0, 0, 1, 2, 2]
        );
    }
}
