//! What kind of data a file holds, from its header and a bounded sample of its first points:
//! airborne (a scanner looking down from far away) or mobile/terrestrial (a scanner among the
//! objects it measures).
//!
//! The deciding cue is how evenly the points cover the ground. An airborne scanner sweeps the
//! ground at a nearly constant range, so the points per ground cell vary little; a vehicle or
//! tripod scanner's density falls with the square of the range and piles up on the facades,
//! poles and cars beside it. The cell is sized to hold about [`POINTS_PER_CELL`] points on
//! average, so sparse and dense surveys are compared alike. Measured on the labelled data
//! tessera is tested with (coefficient of variation of the points per occupied cell):
//!
//! | data | CV | median local density, pts/m² |
//! |---|---|---|
//! | airborne: ISPRS samples, AHN, IGN LiDAR HD, lidR Topography, PDAL Autzen | 0.32–0.93 | 0.5–35 |
//! | vehicle scans: SemanticKITTI (HDL-64), nuScenes (HDL-32), ika (VLP-32) | 1.65–3.88 | 7–214 |
//! | street-level mobile mapping: CycloMedia | 1.51–1.58 | 1,500–2,600 |
//!
//! A cloud sampled evenly from surfaces (tessera's synthetic street) has a low CV but a local
//! density no airborne survey reaches, hence the second cue: [`MOBILE_DENSITY`].
//! Multiple returns and scan angles are reported as evidence, not used: converted vehicle scans
//! have neither, and airborne files often lack them too (the ISPRS samples).

use super::input::InputFile;
use crate::error::Result;
use std::collections::HashMap;

/// Points the first points of a file are sampled up to.
pub const SAMPLE_POINTS: u64 = 200_000;
/// Average points per cell the evenness is measured at.
pub const POINTS_PER_CELL: f64 = 16.0;
/// Coefficient of variation of the points per occupied cell at and above which the coverage
/// is uneven (a scanner among its objects).
pub const UNEVEN_CV: f64 = 1.2;
/// Median local density (points per m² in the 1 m cell of each point) at and above which the
/// data is mobile or terrestrial whatever its evenness.
pub const MOBILE_DENSITY: f64 = 100.0;

/// The kind of platform the points were measured from.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Platform {
    /// A scanner looking down from an aircraft.
    Airborne,
    /// A scanner on a vehicle, a backpack or a tripod, among the objects it measures.
    Mobile,
}

/// What a sample showed, and what follows.
#[derive(Debug, Clone, serde::Serialize)]
pub struct Detection {
    /// The decision.
    pub platform: Platform,
    /// Points sampled.
    pub sampled_points: u64,
    /// Cell size the evenness was measured at, metres.
    pub cell_m: f64,
    /// Coefficient of variation of the points per occupied cell.
    pub density_cv: f64,
    /// Median over the points of the points per m² in their 1 m cell.
    pub median_local_density: f64,
    /// Share of points that are one of several returns of their pulse.
    pub multiple_returns: f64,
    /// 95th percentile of the absolute scan angle, degrees.
    pub scan_angle_p95_deg: f64,
    /// The cue that decided, in words.
    pub reason: String,
}

/// The first points of one file: coordinates, returns per pulse and scan angles.
#[derive(Debug, Default)]
pub struct Sample {
    xy: Vec<[f64; 2]>,
    multiple: u64,
    angles: Vec<f32>,
}

impl Sample {
    /// Reads up to `max` points from the start of `file`.
    pub fn of_file(file: &InputFile, max: u64) -> Result<Sample> {
        let mut r = super::input::open_reader(&file.path, None)?;
        let n = max.min(file.points);
        let pts = r
            .read_points(n)
            .map_err(|e| crate::error::Error::las(&file.path, e))?;
        Ok(Sample {
            xy: pts.x().zip(pts.y()).map(|(x, y)| [x, y]).collect(),
            multiple: pts.number_of_returns().filter(|&n| n > 1).count() as u64,
            angles: pts.scan_angle_degrees().map(f32::abs).collect(),
        })
    }

    /// A sample of given coordinates (tests, and clouds read by other means).
    pub fn of_points(xy: Vec<[f64; 2]>) -> Sample {
        Sample {
            xy,
            ..Default::default()
        }
    }
}

/// Decides from a sample. `None` for fewer than 100 points (nothing to go on).
pub fn detect(s: &Sample) -> Option<Detection> {
    let n = s.xy.len();
    if n < 100 {
        return None;
    }
    let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
    for p in &s.xy {
        for k in 0..2 {
            lo[k] = lo[k].min(p[k]);
            hi[k] = hi[k].max(p[k]);
        }
    }
    let area = ((hi[0] - lo[0]) * (hi[1] - lo[1])).max(1.0);
    let cell_m = (POINTS_PER_CELL * area / n as f64).sqrt().clamp(0.5, 50.0);
    let counts = |cell: f64| {
        let mut m: HashMap<(i64, i64), u32> = HashMap::new();
        for p in &s.xy {
            let k = (
                ((p[0] - lo[0]) / cell).floor() as i64,
                ((p[1] - lo[1]) / cell).floor() as i64,
            );
            *m.entry(k).or_default() += 1;
        }
        m
    };
    let cells = counts(cell_m);
    let mean = n as f64 / cells.len() as f64;
    let var = cells
        .values()
        .map(|&c| (c as f64 - mean).powi(2))
        .sum::<f64>()
        / cells.len() as f64;
    let density_cv = var.sqrt() / mean;
    // The density each point sees: the count of its 1 m cell, weighted by the points in it.
    let mut local: Vec<u32> = counts(1.0).into_values().collect();
    local.sort_unstable();
    let mut seen = 0u64;
    let mut median_local_density = 0.0;
    for c in &local {
        seen += *c as u64;
        if 2 * seen >= n as u64 {
            median_local_density = *c as f64;
            break;
        }
    }
    let mut angles = s.angles.clone();
    angles.sort_unstable_by(f32::total_cmp);
    let scan_angle_p95_deg = angles
        .get((angles.len() as f64 * 0.95) as usize)
        .or(angles.last())
        .map_or(0.0, |&a| a as f64);
    let (platform, reason) = if density_cv >= UNEVEN_CV {
        (
            Platform::Mobile,
            format!("uneven coverage: density CV {density_cv:.2} ≥ {UNEVEN_CV} over {cell_m:.1} m cells"),
        )
    } else if median_local_density >= MOBILE_DENSITY {
        (
            Platform::Mobile,
            format!(
                "{median_local_density:.0} points/m² around the median point (≥ {MOBILE_DENSITY:.0}: no airborne survey is that dense)"
            ),
        )
    } else {
        (
            Platform::Airborne,
            format!(
                "even coverage: density CV {density_cv:.2} < {UNEVEN_CV} over {cell_m:.1} m cells, {median_local_density:.0} points/m² around the median point"
            ),
        )
    };
    Some(Detection {
        platform,
        sampled_points: n as u64,
        cell_m,
        density_cv,
        median_local_density,
        multiple_returns: s.multiple as f64 / n as f64,
        scan_angle_p95_deg,
        reason,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn rng(seed: &mut u64) -> f64 {
        *seed = seed
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        (*seed >> 11) as f64 / (1u64 << 53) as f64
    }

    #[test]
    fn an_even_survey_from_above_is_airborne() {
        let mut s = 1;
        let xy: Vec<[f64; 2]> = (0..40_000)
            .map(|_| [500.0 * rng(&mut s), 400.0 * rng(&mut s)])
            .collect();
        let d = detect(&Sample::of_points(xy)).unwrap();
        assert_eq!(d.platform, Platform::Airborne, "{d:?}");
        assert!(d.density_cv < 0.5, "{d:?}");
    }

    #[test]
    fn a_spinning_scanner_among_its_objects_is_mobile() {
        // 64 rings of 1,800 points around the sensor, at ranges growing with the beam angle.
        let mut xy = Vec::new();
        for ring in 0..64 {
            let r = 3.0 * 1.08f64.powi(ring);
            for k in 0..1800 {
                let a = k as f64 * std::f64::consts::TAU / 1800.0;
                xy.push([r * a.cos(), r * a.sin()]);
            }
        }
        let d = detect(&Sample::of_points(xy)).unwrap();
        assert_eq!(d.platform, Platform::Mobile, "{d:?}");
        assert!(d.density_cv >= UNEVEN_CV, "{d:?}");
    }

    #[test]
    fn evenly_sampled_dense_surfaces_are_mobile() {
        // 500 points/m² over a 20 m × 20 m street: even, but no airborne survey is that dense.
        let mut s = 2;
        let xy: Vec<[f64; 2]> = (0..200_000)
            .map(|_| [20.0 * rng(&mut s), 20.0 * rng(&mut s)])
            .collect();
        let d = detect(&Sample::of_points(xy)).unwrap();
        assert_eq!(d.platform, Platform::Mobile, "{d:?}");
    }

    #[test]
    fn too_few_points_decide_nothing() {
        assert!(detect(&Sample::of_points(vec![[0.0, 0.0]; 99])).is_none());
    }
}
