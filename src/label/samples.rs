//! Training samples for the supervised labelling of ground regions (street-level document,
//! chapter 5 §9.2): each sample is summarised by the mean and standard deviation of L*, a*,
//! b*; a region takes the class of a sample whose μ ± kσ box contains the region's mean colour
//! on every component. Samples of one class are kept apart, never pooled (§9.2.2: pooled
//! statistics of differently lit or wet patches would be meaningless).
//!
//! Sources:
//! - a LAS/LAZ whose points carry class codes (e.g. points cut out of a run's input and
//!   classified by hand): each class's points are split into square blocks of `block_m`, one
//!   sample per block with at least `min_points` points;
//! - polygons (GeoJSON `Polygon`/`MultiPolygon` features with a numeric `class` property)
//!   selecting points of the inputs: one sample per polygon;
//! - a JSON file written by `tessera samples` (the summaries themselves).

use crate::error::{Error, Result};
use crate::segment::{rgb_is_8bit, rgb_to_lab, LabFormula};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;
use std::path::Path;

/// One training sample.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct Sample {
    /// Class code the sample stands for.
    pub class: u8,
    /// Where it came from (block or polygon), for the report.
    pub name: String,
    /// Points in the sample.
    pub points: u64,
    /// Mean L*, a*, b*.
    pub mean: [f64; 3],
    /// Standard deviation of L*, a*, b*.
    pub std: [f64; 3],
}

impl Sample {
    /// Largest standardised distance `|x − μ| / σ` over the three components; σ is floored at
    /// `min_std` so a perfectly uniform sample still accepts its own colour.
    pub fn z(&self, lab: &[f64; 3], min_std: f64) -> f64 {
        (0..3)
            .map(|c| (lab[c] - self.mean[c]).abs() / self.std[c].max(min_std))
            .fold(0.0, f64::max)
    }
}

/// The classifier: every sample, in a fixed order.
#[derive(Debug, Clone, Default, PartialEq, Serialize, Deserialize)]
pub struct SampleSet {
    /// Samples.
    pub samples: Vec<Sample>,
}

impl SampleSet {
    /// The class of the sample whose μ ± `k`σ box contains `lab` on all components; when
    /// several do, the one with the smallest standardised distance (ties: earlier sample).
    pub fn classify(&self, lab: &[f64; 3], k: f64, min_std: f64) -> Option<u8> {
        let mut best: Option<(f64, u8)> = None;
        for s in &self.samples {
            let z = s.z(lab, min_std);
            if z <= k && best.is_none_or(|b| z < b.0) {
                best = Some((z, s.class));
            }
        }
        best.map(|b| b.1)
    }

    /// Loads a set: `.json` (written by [`SampleSet::save`]), `.las`/`.laz` (classified
    /// points, see [`from_classified_points`], classes from the classification field).
    pub fn load(path: &Path, block_m: f64, min_points: u64) -> Result<SampleSet> {
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        match ext.as_deref() {
            Some("json") => {
                let text = crate::io::files::read_text_bounded(path, 256 << 20)?;
                let set: SampleSet = serde_json::from_str(&text).map_err(|e| {
                    Error::bad_input(path, format!("not a tessera sample set: {e}"))
                })?;
                set.check(path)?;
                Ok(set)
            }
            Some("las") | Some("laz") => {
                from_classified_points(path, "classification", block_m, min_points)
            }
            _ => Err(Error::Config(format!(
                "{}: training samples must be .json (tessera samples), .las or .laz",
                path.display()
            ))),
        }
    }

    fn check(&self, path: &Path) -> Result<()> {
        if self.samples.is_empty() {
            return Err(Error::bad_input(path, "no training samples"));
        }
        for s in &self.samples {
            if !(s.mean.iter().chain(&s.std).all(|v| v.is_finite()) && s.points > 0) {
                return Err(Error::bad_input(
                    path,
                    format!(
                        "sample {} (class {}) has invalid statistics",
                        s.name, s.class
                    ),
                ));
            }
        }
        Ok(())
    }

    /// Writes the set as JSON (atomically).
    pub fn save(&self, path: &Path) -> Result<()> {
        let text =
            serde_json::to_string_pretty(self).map_err(|e| Error::Internal(e.to_string()))?;
        crate::io::output::write_atomic(path, text.as_bytes())
    }
}

/// Running sums of L*a*b* (Welford would be overkill at these magnitudes: values < 200).
#[derive(Debug, Clone, Default)]
pub struct LabStats {
    n: u64,
    s: [f64; 3],
    s2: [f64; 3],
}

impl LabStats {
    /// Adds one colour.
    pub fn add(&mut self, lab: &[f64; 3]) {
        self.n += 1;
        for ((s, s2), v) in self.s.iter_mut().zip(&mut self.s2).zip(lab) {
            *s += v;
            *s2 += v * v;
        }
    }
    /// Points added.
    pub fn n(&self) -> u64 {
        self.n
    }
    /// (mean, population standard deviation).
    pub fn mean_std(&self) -> ([f64; 3], [f64; 3]) {
        let n = self.n.max(1) as f64;
        let mean = self.s.map(|v| v / n);
        let std = std::array::from_fn(|c| (self.s2[c] / n - mean[c] * mean[c]).max(0.0).sqrt());
        (mean, std)
    }
}

/// Classes that are never training classes: never classified (0), unclassified (1), ground
/// without subclass (2) and noise (7, 18).
pub fn is_sample_class(c: u8) -> bool {
    !matches!(c, 0 | 1 | 2 | 7 | 18)
}

/// Colour of a LAS point as CIELab, `eight_bit` telling how the 16-bit fields are scaled.
pub fn point_lab(c: las::Color, eight_bit: bool) -> [f64; 3] {
    let s = if eight_bit { 255.0 } else { 65535.0 };
    rgb_to_lab(
        [c.red as f64 / s, c.green as f64 / s, c.blue as f64 / s],
        LabFormula::Srgb,
    )
}

/// Samples from a classified LAS/LAZ: per class (read from attribute `field`:
/// `classification` or an extra-bytes name), one sample per `block_m` square block with at
/// least `min_points` points. Streams the file twice (colour scale, then statistics).
pub fn from_classified_points(
    path: &Path,
    field: &str,
    block_m: f64,
    min_points: u64,
) -> Result<SampleSet> {
    if !(block_m > 0.0 && block_m.is_finite()) {
        return Err(Error::Config(format!(
            "label.sample_block_m must be > 0, got {block_m}"
        )));
    }
    let mut eight_bit = true;
    let mut any = false;
    for_each_point(path, |p| {
        if let Some(c) = p.color {
            any = true;
            eight_bit &= rgb_is_8bit(&[[c.red, c.green, c.blue]]);
        }
        Ok(())
    })?;
    if !any {
        return Err(Error::bad_input(
            path,
            "training samples need colour (RGB), the file has none",
        ));
    }
    let src = {
        crate::io::guard::check_path(path)?;
        let r = las::Reader::from_path(path).map_err(|e| Error::las(path, e))?;
        crate::io::attributes::field_source(path, r.header(), field)?
    };
    let mut blocks: BTreeMap<(u8, i64, i64), LabStats> = BTreeMap::new();
    for_each_point(path, |p| {
        let v = crate::io::attributes::field_value(path, p, src)?;
        let Ok(class) = u8::try_from(v) else {
            return Err(Error::bad_input(
                path,
                format!("{field} value {v} is not a class code (0..=255)"),
            ));
        };
        if !is_sample_class(class) {
            return Ok(());
        }
        let Some(c) = p.color else { return Ok(()) };
        let key = (
            class,
            (p.x / block_m).floor() as i64,
            (p.y / block_m).floor() as i64,
        );
        blocks.entry(key).or_default().add(&point_lab(c, eight_bit));
        Ok(())
    })?;
    let samples: Vec<Sample> = blocks
        .into_iter()
        .filter(|(_, s)| s.n() >= min_points)
        .map(|((class, bx, by), s)| {
            let (mean, std) = s.mean_std();
            Sample {
                class,
                name: format!(
                    "block {:.0},{:.0}",
                    bx as f64 * block_m,
                    by as f64 * block_m
                ),
                points: s.n(),
                mean,
                std,
            }
        })
        .collect();
    let set = SampleSet { samples };
    set.check(path)?;
    Ok(set)
}

/// Calls `f` on every point of a LAS/LAZ file, in chunks.
pub fn for_each_point(path: &Path, mut f: impl FnMut(&las::Point) -> Result<()>) -> Result<()> {
    crate::io::guard::check_path(path)?;
    let mut r = las::Reader::from_path(path).map_err(|e| Error::las(path, e))?;
    let mut pd = las::PointDataBuilder::new().for_header(r.header()).build();
    while r
        .fill_points(1 << 18, &mut pd)
        .map_err(|e| Error::las(path, e))?
        > 0
    {
        for p in pd.points() {
            f(&p.map_err(|e| Error::las(path, e))?)?;
        }
    }
    Ok(())
}

/// A polygon ring set: outer ring first, then holes (xy).
#[derive(Debug, Clone)]
pub struct Polygon {
    /// Class code.
    pub class: u8,
    /// Name (feature `name` property or its index).
    pub name: String,
    /// Rings: outer first, then holes.
    pub rings: Vec<Vec<[f64; 2]>>,
}

impl Polygon {
    /// Even-odd point-in-polygon over all rings (holes excluded).
    pub fn contains(&self, x: f64, y: f64) -> bool {
        let mut inside = false;
        for ring in &self.rings {
            let n = ring.len();
            let mut j = n.wrapping_sub(1);
            for i in 0..n {
                let (a, b) = (ring[i], ring[j]);
                if (a[1] > y) != (b[1] > y) && x < (b[0] - a[0]) * (y - a[1]) / (b[1] - a[1]) + a[0]
                {
                    inside = !inside;
                }
                j = i;
            }
        }
        inside
    }
}

/// Reads training polygons from GeoJSON: a FeatureCollection of `Polygon`/`MultiPolygon`
/// features, each with a numeric `class` property (and optionally `name`). Coordinates are in
/// the point cloud's projected CRS.
pub fn read_polygons(path: &Path) -> Result<Vec<Polygon>> {
    let text = crate::io::files::read_text_bounded(path, 1 << 30)?;
    let v: serde_json::Value = serde_json::from_str(&text)
        .map_err(|e| Error::bad_input(path, format!("not JSON: {e}")))?;
    let bad = |m: String| Error::bad_input(path, m);
    let features = v
        .get("features")
        .and_then(|f| f.as_array())
        .ok_or_else(|| bad("expected a GeoJSON FeatureCollection with \"features\"".into()))?;
    let ring = |r: &serde_json::Value, i: usize| -> Result<Vec<[f64; 2]>> {
        r.as_array()
            .ok_or_else(|| bad(format!("feature {i}: ring is not an array")))?
            .iter()
            .map(|p| match p.as_array().map(|a| a.as_slice()) {
                Some([x, y, ..]) => match (x.as_f64(), y.as_f64()) {
                    (Some(x), Some(y)) if x.is_finite() && y.is_finite() => Ok([x, y]),
                    _ => Err(bad(format!("feature {i}: bad coordinate"))),
                },
                _ => Err(bad(format!("feature {i}: bad coordinate"))),
            })
            .collect()
    };
    let mut out = Vec::new();
    for (i, f) in features.iter().enumerate() {
        let props = f.get("properties");
        let class = props
            .and_then(|p| p.get("class"))
            .and_then(|c| c.as_u64())
            .filter(|&c| c <= 255 && is_sample_class(c as u8))
            .ok_or_else(|| {
                bad(format!(
                    "feature {i}: needs a numeric \"class\" property (a class code 3..=255, not 7 or 18)"
                ))
            })? as u8;
        let name = props
            .and_then(|p| p.get("name"))
            .and_then(|n| n.as_str())
            .map(str::to_string)
            .unwrap_or_else(|| format!("polygon {i}"));
        let geom = f
            .get("geometry")
            .ok_or_else(|| bad(format!("feature {i}: no geometry")))?;
        let coords = geom
            .get("coordinates")
            .ok_or_else(|| bad(format!("feature {i}: no coordinates")))?;
        let polys: Vec<&serde_json::Value> = match geom.get("type").and_then(|t| t.as_str()) {
            Some("Polygon") => vec![coords],
            Some("MultiPolygon") => coords
                .as_array()
                .ok_or_else(|| bad(format!("feature {i}: bad MultiPolygon")))?
                .iter()
                .collect(),
            t => {
                return Err(bad(format!(
                    "feature {i}: geometry {t:?} is not a Polygon or MultiPolygon"
                )))
            }
        };
        let mut rings = Vec::new();
        for p in polys {
            for r in p
                .as_array()
                .ok_or_else(|| bad(format!("feature {i}: bad polygon")))?
            {
                let r = ring(r, i)?;
                if r.len() < 3 {
                    return Err(bad(format!("feature {i}: ring with fewer than 3 vertices")));
                }
                rings.push(r);
            }
        }
        out.push(Polygon { class, name, rings });
    }
    if out.is_empty() {
        return Err(bad("no polygons".into()));
    }
    Ok(out)
}

/// Samples from polygons over the points of `inputs` (LAS/LAZ files): one sample per polygon,
/// from the points inside it whose class is in `point_classes` (empty: all points).
pub fn from_polygons(
    polygons: &[Polygon],
    inputs: &[std::path::PathBuf],
    point_classes: &[u8],
    min_points: u64,
) -> Result<SampleSet> {
    let mut eight_bit = true;
    for f in inputs {
        for_each_point(f, |p| {
            if let Some(c) = p.color {
                eight_bit &= rgb_is_8bit(&[[c.red, c.green, c.blue]]);
            }
            Ok(())
        })?;
    }
    let bbox: Vec<[f64; 4]> = polygons
        .iter()
        .map(|p| {
            let mut b = [
                f64::INFINITY,
                f64::INFINITY,
                f64::NEG_INFINITY,
                f64::NEG_INFINITY,
            ];
            for q in p.rings.iter().flatten() {
                b = [
                    b[0].min(q[0]),
                    b[1].min(q[1]),
                    b[2].max(q[0]),
                    b[3].max(q[1]),
                ];
            }
            b
        })
        .collect();
    let mut stats = vec![LabStats::default(); polygons.len()];
    for f in inputs {
        for_each_point(f, |p| {
            let Some(c) = p.color else { return Ok(()) };
            if !point_classes.is_empty() && !point_classes.contains(&u8::from(p.classification)) {
                return Ok(());
            }
            for (k, poly) in polygons.iter().enumerate() {
                let b = bbox[k];
                if p.x >= b[0]
                    && p.x <= b[2]
                    && p.y >= b[1]
                    && p.y <= b[3]
                    && poly.contains(p.x, p.y)
                {
                    stats[k].add(&point_lab(c, eight_bit));
                }
            }
            Ok(())
        })?;
    }
    let mut samples = Vec::new();
    for (poly, s) in polygons.iter().zip(stats) {
        if s.n() < min_points {
            tracing::warn!(
                "training polygon {} (class {}) holds only {} coloured points; skipped",
                poly.name,
                poly.class,
                s.n()
            );
            continue;
        }
        let (mean, std) = s.mean_std();
        samples.push(Sample {
            class: poly.class,
            name: poly.name.clone(),
            points: s.n(),
            mean,
            std,
        });
    }
    if samples.is_empty() {
        return Err(Error::Config(
            "no training polygon holds enough coloured points".into(),
        ));
    }
    Ok(SampleSet { samples })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn classify_uses_boxes_and_keeps_samples_apart() {
        let set = SampleSet {
            samples: vec![
                Sample {
                    class: 11,
                    name: "sun".into(),
                    points: 100,
                    mean: [50.0, 0.0, 2.0],
                    std: [2.0, 1.0, 1.0],
                },
                Sample {
                    class: 11,
                    name: "shadow".into(),
                    points: 100,
                    mean: [30.0, 0.0, -2.0],
                    std: [2.0, 1.0, 1.0],
                },
                Sample {
                    class: 64,
                    name: "red".into(),
                    points: 100,
                    mean: [45.0, 35.0, 25.0],
                    std: [3.0, 3.0, 3.0],
                },
            ],
        };
        assert_eq!(set.classify(&[51.0, 0.5, 2.5], 3.0, 0.5), Some(11));
        assert_eq!(set.classify(&[31.0, 0.5, -2.5], 3.0, 0.5), Some(11));
        // Between the two road samples: pooled statistics would accept it, separate ones do not.
        assert_eq!(set.classify(&[40.0, 0.0, 0.0], 3.0, 0.5), None);
        assert_eq!(set.classify(&[44.0, 33.0, 28.0], 3.0, 0.5), Some(64));
    }

    #[test]
    fn polygon_with_hole() {
        let p = Polygon {
            class: 65,
            name: "p".into(),
            rings: vec![
                vec![
                    [0.0, 0.0],
                    [10.0, 0.0],
                    [10.0, 10.0],
                    [0.0, 10.0],
                    [0.0, 0.0],
                ],
                vec![[4.0, 4.0], [6.0, 4.0], [6.0, 6.0], [4.0, 6.0], [4.0, 4.0]],
            ],
        };
        assert!(p.contains(1.0, 1.0));
        assert!(!p.contains(5.0, 5.0));
        assert!(!p.contains(11.0, 5.0));
    }

    #[test]
    fn lab_stats() {
        let mut s = LabStats::default();
        s.add(&[1.0, 2.0, 3.0]);
        s.add(&[3.0, 2.0, 5.0]);
        let (m, sd) = s.mean_std();
        assert_eq!(m, [2.0, 2.0, 4.0]);
        assert!((sd[0] - 1.0).abs() < 1e-12 && sd[1].abs() < 1e-12);
    }
}
