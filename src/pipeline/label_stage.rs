//! The labelling stage ([`crate::label`]): ground subclasses for the ground points (region
//! growing on colour, small-region merging, training samples, smoothing) and non-ground
//! classes from segment and object geometry. Runs after `ground` and (for facades and roofs)
//! `segment`; writes the classification codes of the points of the core and a strip around it.

use super::segment_stage::rgb_offset;
use super::stage::{Stage, StageSpec, TileReport};
use crate::config::Config;
use crate::error::{Error, Result};
use crate::label::kerbs::{classify_by_kerbs, KerbRule};
use crate::label::{
    classify_objects, label_ground, GroundLabelParams, LabelCodes, ObjectInput, ObjectParams,
    SampleSet,
};
use crate::model::{RecordLayout, Tile};
use crate::segment::features::normals;
use crate::segment::neighbours::knn_surface;
use crate::segment::{rgb_is_8bit, rgb_to_lab, LabFormula};
use serde::Deserialize;
use std::path::PathBuf;
use std::sync::Arc;

/// `[label]` configuration section.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LabelSection {
    /// Training samples: a `.json` written by `tessera samples`, or a LAS/LAZ of classified
    /// points. Empty: unsupervised (ground regions stay `codes.unknown_ground`).
    #[serde(default)]
    pub samples: String,
    /// Block size splitting a classified LAS/LAZ into samples, metres.
    #[serde(default = "default_block")]
    pub sample_block_m: f64,
    /// Blocks/polygons with fewer coloured points are not samples.
    #[serde(default = "default_min_sample")]
    pub min_sample_points: u64,
    /// Points farther than this outside the core are context only (capped by the tile buffer).
    #[serde(default = "default_buffer")]
    pub buffer_m: f64,
    /// Ground subclass parameters.
    #[serde(default)]
    pub ground: GroundLabelParams,
    /// Non-ground rules.
    #[serde(default)]
    pub objects: ObjectParams,
    /// Class codes.
    #[serde(default)]
    pub codes: LabelCodes,
}

fn default_block() -> f64 {
    5.0
}
fn default_min_sample() -> u64 {
    30
}
fn default_buffer() -> f64 {
    5.0
}

impl Default for LabelSection {
    fn default() -> Self {
        LabelSection {
            samples: String::new(),
            sample_block_m: default_block(),
            min_sample_points: default_min_sample(),
            buffer_m: default_buffer(),
            ground: GroundLabelParams::default(),
            objects: ObjectParams::default(),
            codes: LabelCodes::default(),
        }
    }
}

/// Labelling stage.
#[derive(Debug, Clone)]
pub struct LabelStage {
    section: LabelSection,
    samples: Option<Arc<SampleSet>>,
}

impl LabelSection {
    /// Checks the section.
    pub fn validate(&self) -> Result<()> {
        let g = &self.ground;
        let positive = g.radius_m.is_finite() && g.radius_m > 0.0;
        let non_negative = self.buffer_m.is_finite() && self.buffer_m >= 0.0;
        if g.k < 3 || !positive || !non_negative {
            return Err(Error::Config(
                "label: ground.k must be >= 3, ground.radius_m > 0 and buffer_m >= 0".into(),
            ));
        }
        Ok(())
    }
}

/// Registry entry: ground subclasses need the ground filter's classes.
pub const SPEC: StageSpec = StageSpec {
    name: "label",
    requires: &["ground"],
    validate: |cfg: &Config| cfg.label.validate(),
    build: |cfg: &Config| Ok(Box::new(LabelStage::new(cfg.label.clone())?)),
};

impl LabelStage {
    /// Builds the stage, loading the training samples once.
    pub fn new(section: LabelSection) -> Result<Self> {
        section.validate()?;
        let samples = if section.samples.is_empty() {
            None
        } else {
            let set = SampleSet::load(
                &PathBuf::from(&section.samples),
                section.sample_block_m,
                section.min_sample_points,
            )?;
            tracing::info!(
                "label: {} training samples from {}",
                set.samples.len(),
                section.samples
            );
            Some(Arc::new(set))
        };
        Ok(LabelStage { section, samples })
    }
}

impl Stage for LabelStage {
    fn name(&self) -> &'static str {
        "label"
    }
    fn max_class_code(&self) -> u8 {
        let samples = self
            .samples
            .as_ref()
            .map_or(0, |s| s.samples.iter().map(|s| s.class).max().unwrap_or(0));
        let geometry = if self.samples.is_none() && self.section.ground.geometry {
            self.section
                .ground
                .geometry_codes
                .into_iter()
                .max()
                .unwrap_or(0)
        } else {
            0
        };
        self.section.codes.max().max(samples).max(geometry)
    }
    fn context_m(&self) -> Option<f64> {
        Some(self.section.buffer_m)
    }
    fn bytes_per_point(&self) -> usize {
        // Neighbour lists (index + distance, k of them), normals, colour, region and class
        // arrays, the object voxel maps. Measured by `tests/stage_memory.rs` (counting
        // allocator, k = 12): up to 348 B per context point including the per-tile arrays
        // below (synthetic street, 1.0 M of a tile's 1.27 M points in the context).
        8 * self.section.ground.k + 210
    }
    fn bytes_per_tile_point(&self) -> usize {
        // Flags, classes, heights above ground, voxel and object ids built for every tile
        // point (~25 B), with room for the ground height grid.
        48
    }
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()> {
        let max = layout.max_classification();
        let need = self.max_class_code();
        if need > max {
            return Err(Error::Config(format!(
                "label codes up to {need} do not fit point format {} (max {max}); set output.point_format = 6 or higher",
                layout.format.to_u8().unwrap_or(255)
            )));
        }
        let rl = layout.record_len;
        let zone = tile.core.expanded(self.section.buffer_m.min(tile.buffer_m));
        let n = tile.len();
        let classes: Vec<u8> = tile
            .records
            .chunks_exact(rl)
            .map(|r| layout.classification(r))
            .collect();
        let in_zone: Vec<bool> = tile.xyz.iter().map(|p| zone.contains(p[0], p[1])).collect();
        let is_ground: Vec<bool> = classes.iter().map(|&c| c == 2).collect();

        // Ground subclasses.
        let gidx: Vec<usize> = (0..n).filter(|&i| is_ground[i] && in_zone[i]).collect();
        let mut ground_report = serde_json::Value::Null;
        let mut new_class = classes.clone();
        // Seconds: neighbours, normals, colour, ground labelling, objects.
        let mut times = [0.0f64; 5];
        if !gidx.is_empty() {
            let o = tile.xyz[gidx[0]];
            let pts: Vec<[f64; 3]> = gidx
                .iter()
                .map(|&i| {
                    let p = tile.xyz[i];
                    [p[0] - o[0], p[1] - o[1], p[2] - o[2]]
                })
                .collect();
            let gp = &self.section.ground;
            let t = std::time::Instant::now();
            let nb = knn_surface(&pts, gp.k, gp.radius_m);
            times[0] = t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            let nrm = normals(&pts, &nb, gp.radius_m);
            times[1] = t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            let lab: Option<Vec<[f64; 3]>> = rgb_offset(layout).map(|off| {
                let rgb: Vec<[u16; 3]> = gidx
                    .iter()
                    .map(|&i| {
                        let rec = &tile.records[i * rl..(i + 1) * rl];
                        let v =
                            |c: usize| u16::from_le_bytes([rec[off + 2 * c], rec[off + 2 * c + 1]]);
                        [v(0), v(1), v(2)]
                    })
                    .collect();
                let s = if rgb_is_8bit(&rgb) { 255.0 } else { 65535.0 };
                rgb.iter()
                    .map(|c| rgb_to_lab(c.map(|v| v as f64 / s), LabFormula::Srgb))
                    .collect()
            });
            times[2] = t.elapsed().as_secs_f64();
            let t = std::time::Instant::now();
            let gl = label_ground(
                &nrm,
                lab.as_deref(),
                Some(&pts),
                &nb,
                self.samples.as_deref(),
                self.section.codes.unknown_ground,
                gp,
            );
            // Without samples, geometry mode names road / sidewalk / terrain by kerbs.
            let by_kerbs = (self.samples.is_none() && gp.geometry).then(|| {
                let rule = KerbRule::from_params(gp, self.section.codes.unknown_ground);
                let r2 = (gp.radius_m * gp.radius_m) as f32;
                let mut c = classify_by_kerbs(&pts, &nrm, &nb, r2, &gl.region, gl.regions, &rule);
                crate::label::ground::smooth_labels(&mut c, &nb, gp.smooth_k);
                c
            });
            times[3] = t.elapsed().as_secs_f64();
            let ground_class = by_kerbs.as_ref().unwrap_or(&gl.class);
            for (k, &i) in gidx.iter().enumerate() {
                new_class[i] = ground_class[k];
            }
            ground_report = serde_json::json!({
                "points": gidx.len(),
                "regions_grown": gl.regions_grown,
                "regions": gl.regions,
                "regions_unknown": gl.regions_unknown,
            });
        }

        // Non-ground.
        let todo: Vec<bool> = (0..n)
            .map(|i| in_zone[i] && !is_ground[i] && !matches!(classes[i], 7 | 18))
            .collect();
        let no_segments = vec![0u32; n];
        let segment = if tile.segments.len() == n {
            &tile.segments
        } else {
            &no_segments
        };
        let non_last: Vec<bool> = tile
            .records
            .chunks_exact(rl)
            .map(|r| {
                let (rn, nr) = layout.returns(r);
                rn < nr
            })
            .collect();
        let has_returns = tile
            .records
            .chunks_exact(rl)
            .any(|r| layout.returns(r).1 > 1);
        let t = std::time::Instant::now();
        let (obj, ostats) = classify_objects(
            &ObjectInput {
                xyz: &tile.xyz,
                is_ground: &is_ground,
                todo: &todo,
                segment,
                non_last_return: has_returns.then_some(&non_last[..]),
            },
            &self.section.objects,
        );
        times[4] = t.elapsed().as_secs_f64();
        for (i, c) in obj.iter().enumerate() {
            if let Some(c) = c {
                new_class[i] = self.section.codes.of(*c);
            }
        }
        for (rec, (&c, &z)) in tile
            .records
            .chunks_exact_mut(rl)
            .zip(new_class.iter().zip(&in_zone))
        {
            if z {
                layout.set_classification(rec, c);
            }
        }
        report.stats.insert(
            "label".into(),
            serde_json::json!({
                "ground": ground_report,
                "building_segments": ostats.building_segments,
                "objects": ostats.objects,
                "nonground_points": ostats.points,
                "seconds": {
                    "neighbours": times[0], "normals": times[1], "colour": times[2],
                    "ground_regions": times[3], "objects": times[4],
                },
            }),
        );
        Ok(())
    }
}
