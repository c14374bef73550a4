//! The labelling stage ([`crate::label`]): ground subclasses for the ground points (region
//! growing on colour, small-region merging, training samples, smoothing) and non-ground
//! classes from segment and object geometry. Runs after `ground` and (for facades and roofs)
//! `segment`; writes the classification codes of the points of the core and a strip around it.

use super::stage::{parse_section, Attribute, Stage, StageSpec, TileReport};
use crate::error::{Error, Result};
use crate::label::descriptors::{self, DescribeInput, Descriptors};
use crate::label::forest::ForestParams;
use crate::label::kerbs::{classify_by_kerbs, KerbRule};
use crate::label::model::{Collector, Model};
use crate::label::objects::{GroundGrid, ObjectStats};
use crate::label::{
    classify_objects, label_ground, GroundLabelParams, LabelCodes, ObjectClass, ObjectInput,
    ObjectParams, SampleSet,
};
use crate::model::{RecordLayout, Tile};
use crate::segment::features::normals;
use crate::segment::features::rgb16_to_lab;
use crate::segment::neighbours::knn_grid2d;
use crate::segment::rgb_is_8bit;
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
    /// Points farther than this outside the core are not labelled (capped by the tile buffer);
    /// the object labels use all of it, the ground subclasses `ground.context_m` of it.
    #[serde(default = "default_context")]
    pub context_m: f64,
    /// Ground subclass parameters.
    #[serde(default)]
    pub ground: GroundLabelParams,
    /// Non-ground rules.
    #[serde(default)]
    pub objects: ObjectParams,
    /// Class codes.
    #[serde(default)]
    pub codes: LabelCodes,
    /// A model written by `tessera train` (empty: the rules alone). Its classifier relabels
    /// the zone's points from multi-scale descriptors, with the rules' classes among them.
    #[serde(default)]
    pub model: String,
    /// Parameters of `tessera train`.
    #[serde(default)]
    pub train: ForestParams,
}

fn default_block() -> f64 {
    5.0
}
fn default_min_sample() -> u64 {
    30
}
fn default_context() -> f64 {
    3.0
}

impl Default for LabelSection {
    fn default() -> Self {
        LabelSection {
            samples: String::new(),
            sample_block_m: default_block(),
            min_sample_points: default_min_sample(),
            context_m: default_context(),
            ground: GroundLabelParams::default(),
            objects: ObjectParams::default(),
            codes: LabelCodes::default(),
            model: String::new(),
            train: ForestParams::default(),
        }
    }
}

/// Labelling stage.
#[derive(Debug, Clone)]
pub struct LabelStage {
    section: LabelSection,
    samples: Option<Arc<SampleSet>>,
    model: Option<Arc<Model>>,
    /// Training mode (`tessera train`): the zone's core points' descriptors go here.
    collector: Option<Arc<Collector>>,
}

impl LabelSection {
    /// Checks the section.
    pub fn validate(&self) -> Result<()> {
        let g = &self.ground;
        let positive = g.radius_m.is_finite() && g.radius_m > 0.0;
        let non_negative = [self.context_m, g.context_m]
            .iter()
            .all(|c| c.is_finite() && *c >= 0.0);
        if g.k < 3 || !positive || !non_negative {
            return Err(Error::Config(
                "label: ground.k must be >= 3, ground.radius_m > 0, context_m and ground.context_m >= 0"
                    .into(),
            ));
        }
        let t = &self.train;
        if t.trees == 0
            || t.trees > 10_000
            || t.max_depth > 64
            || !(1..=1_000_000).contains(&t.per_class)
            || !(1..=10_000_000).contains(&t.max_samples_per_class)
        {
            return Err(Error::Config(
                "label.train: trees 1..=10000, max_depth <= 64, per_class 1..=1000000, max_samples_per_class 1..=10000000".into(),
            ));
        }
        Ok(())
    }
}

/// Registry entry: ground subclasses need the ground filter's classes.
pub const SPEC: StageSpec = StageSpec {
    name: NAME,
    // Segment ids are used when present (facades, roofs), not required.
    reads: &[Attribute::GroundClasses],
    writes: WRITES,
    has_section: true,
    validate: |raw| parse_section::<LabelSection>(NAME, raw)?.validate(),
    build: |raw| Ok(Box::new(LabelStage::new(parse_section(NAME, raw)?)?)),
};

/// What the stage writes.
const WRITES: &[Attribute] = &[Attribute::Labels];

/// The stage's name and the name of its section.
pub const NAME: &str = "label";

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
        let model = if section.model.is_empty() {
            None
        } else {
            let m = Model::load(&PathBuf::from(&section.model))?;
            tracing::info!(
                "label: model {} ({} trees, classes {:?})",
                section.model,
                m.forest.trees.len(),
                m.classes
            );
            Some(Arc::new(m))
        };
        Ok(LabelStage {
            section,
            samples,
            model,
            collector: None,
        })
    }

    /// The stage in training mode: labels as configured (the rules, and the model if one is
    /// set) and hands the descriptors of its core points with a reference class to
    /// `collector`.
    pub fn for_training(section: LabelSection, collector: Arc<Collector>) -> Result<Self> {
        let mut s = LabelStage::new(section)?;
        s.collector = Some(collector);
        Ok(s)
    }
}

impl Stage for LabelStage {
    fn name(&self) -> &'static str {
        NAME
    }
    fn writes(&self) -> &'static [Attribute] {
        WRITES
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
        let model = self
            .model
            .as_ref()
            .map_or(0, |m| m.classes.iter().copied().max().unwrap_or(0));
        self.section
            .codes
            .max()
            .max(samples)
            .max(geometry)
            .max(model)
    }
    fn needs_intensity_scales(&self) -> bool {
        self.model.is_some() || self.collector.is_some()
    }
    fn context_m(&self) -> Option<f64> {
        // With a classifier the stage reads its descriptors' reach beyond the zone; declared
        // here, the tiler keeps those points at full density (beyond a stage's context it
        // thins the buffer, and a model's labels then depended on the tile layout: the
        // SemanticKITTI folds' building F1 moved 0.689 -> 0.650 when far thinning landed).
        Some(self.reach_m())
    }
    fn bytes_per_point(&self) -> usize {
        // Neighbour rows (index + distance², k of them, written in place and moved to point
        // order in place), normals, colour, region and class arrays, the object voxel maps.
        // Measured by `tests/stage_memory.rs` (counting allocator, k = 12): up to 148 B per
        // context point including the per-tile arrays below (synthetic street, 1.0 M of a
        // tile's 1.27 M points in the context; 218 B when the rows were packed into a second
        // copy, 348 B with the per-point lists of the kd-tree search).
        // The classifier's descriptors: the finest voxel of each point, a dual cell per point
        // (finest scale) or per finest voxel (coarser ones) and its 8 corner voxels (32 B per
        // dual cell), per-voxel block statistics (40 B per voxel, at most one voxel per point
        // and scale), a column cell per point and size, the copies of coordinates, heights and
        // flags of its points (~60 B), over the core and 8 m more. Measured by
        // `tests/stage_memory.rs` with a model (2026-11-28, world-anchored interpolated
        // descriptors): the simulated drive's worst tile grew 26.2 MiB against 70.6 MiB
        // charged, the street's 198.5 against 480.5 MiB.
        let classifier = if self.model.is_some() || self.collector.is_some() {
            160
        } else {
            0
        };
        8 * self.section.ground.k + 40 + classifier
    }
    fn bytes_per_tile_point(&self) -> usize {
        // Flags, classes, heights above ground, voxel and object ids built for every tile
        // point (~25 B), with room for the ground height grid.
        32
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
        let n = tile.len();
        let classes: Vec<u8> = tile
            .records
            .chunks_exact(rl)
            .map(|r| layout.classification(r))
            .collect();
        let in_zone = tile.context_mask(self.section.context_m);
        let ground_context = self.section.ground.context(self.section.context_m);
        let in_ground_zone = tile.context_mask(ground_context);
        let is_ground: Vec<bool> = classes.iter().map(|&c| c == 2).collect();
        let worked = (0..n)
            .filter(|&i| {
                if is_ground[i] {
                    in_ground_zone[i]
                } else {
                    in_zone[i]
                }
            })
            .count();
        report.worked_on(self.name(), worked);

        // Ground subclasses.
        let gidx: Vec<usize> = (0..n)
            .filter(|&i| is_ground[i] && in_ground_zone[i])
            .collect();
        let mut new_class = classes.clone();
        // Seconds: neighbours, normals, colour, ground labelling, objects.
        let mut times = [0.0f64; 7];
        let ground_report = if gidx.is_empty() {
            serde_json::Value::Null
        } else {
            self.ground_subclasses(tile, layout, &gidx, &mut new_class, &mut times)
        };

        // Non-ground.
        let todo: Vec<bool> = (0..n)
            .map(|i| in_zone[i] && !is_ground[i] && !matches!(classes[i], 7 | 18))
            .collect();
        let t = std::time::Instant::now();
        let (obj, ostats) = self.objects(tile, layout, &is_ground, &todo);
        times[4] = t.elapsed().as_secs_f64();
        for (i, c) in obj.iter().enumerate() {
            if let Some(c) = c {
                new_class[i] = self.section.codes.of(*c);
            }
        }
        let t = std::time::Instant::now();
        let (relabelled, descriptor_s) = if self.model.is_some() || self.collector.is_some() {
            self.classify_points(
                tile,
                layout,
                &classes,
                &is_ground,
                &ostats.object,
                &mut new_class,
            )
        } else {
            (0, 0.0)
        };
        times[5] = descriptor_s;
        times[6] = t.elapsed().as_secs_f64() - descriptor_s;
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
                "classifier_points": relabelled,
                "seconds": {
                    "neighbours": times[0], "normals": times[1], "colour": times[2],
                    "ground_regions": times[3], "objects": times[4], "descriptors": times[5],
                    "classifier": times[6],
                },
            }),
        );
        Ok(())
    }
}

impl LabelStage {
    /// Ground subclasses of the ground points `gidx` of the zone: region growing on normals
    /// and colour, samples or kerbs; writes them into `new_class`, times into `times[0..4]`.
    fn ground_subclasses(
        &self,
        tile: &Tile,
        layout: &RecordLayout,
        gidx: &[usize],
        new_class: &mut [u8],
        times: &mut [f64; 7],
    ) -> serde_json::Value {
        let rl = layout.record_len;
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
        let nb = knn_grid2d(&pts, gp.k, gp.radius_m);
        times[0] = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let nrm = normals(&pts, &nb, gp.radius_m);
        times[1] = t.elapsed().as_secs_f64();
        let t = std::time::Instant::now();
        let lab: Option<Vec<[f64; 3]>> = layout.rgb_offset().map(|off| {
            let rgb: Vec<[u16; 3]> = gidx
                .iter()
                .map(|&i| RecordLayout::rgb_at(&tile.records[i * rl..(i + 1) * rl], off))
                .collect();
            let eight = rgb_is_8bit(&rgb);
            rgb.iter().map(|&c| rgb16_to_lab(c, eight)).collect()
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
        serde_json::json!({
            "points": gidx.len(),
            "regions_grown": gl.regions_grown,
            "regions": gl.regions,
            "regions_unknown": gl.regions_unknown,
        })
    }

    /// The rule class of a point as an index into [`descriptors::RULES`].
    fn rule_index(&self, code: u8, ground: bool) -> u8 {
        let c = &self.section.codes;
        let g = &self.section.ground;
        let geometry = self.samples.is_none() && g.geometry;
        if ground {
            match code {
                _ if geometry && code == g.geometry_codes[0] => 6,
                _ if geometry && code == g.geometry_codes[1] => 7,
                _ if geometry && code == g.geometry_codes[2] => 8,
                _ => 0,
            }
        } else if code == c.building {
            1
        } else if code == c.high_vegetation {
            2
        } else if code == c.pole {
            3
        } else if code == c.vehicle {
            4
        } else {
            5
        }
    }

    /// How far beyond the core the stage reads points, metres: its zone (`context_m`), and
    /// with a classifier the descriptors' reach around the core points it classifies — a
    /// point reads each scale's statistics interpolated from the 8 voxels around it, each the
    /// statistics of a 3 × 3 × 3 block, so at the coarsest scale (3.2 m voxels) points up to
    /// 2.5 voxels (8 m) away count; the ground look-ups of [`crate::label::descriptors`]
    /// reach 5 m.
    fn reach_m(&self) -> f64 {
        let zone = self.section.context_m;
        if self.model.is_some() || self.collector.is_some() {
            let coarsest =
                crate::label::descriptors::SCALES[crate::label::descriptors::SCALES.len() - 1];
            zone.max(2.5 * coarsest).max(5.0)
        } else {
            zone
        }
    }

    /// The classifier: descriptors of the core points (not noise), over those and the points
    /// a few metres around them, then the model's class (ground points get a ground class,
    /// the others a non-ground class), or in training mode the descriptors of the core points
    /// with a reference class to the collector. Only core points: a buffer point's class is
    /// never written by this tile, and the classifier's class of one point feeds no other.
    /// Returns the points it classified and the seconds spent on descriptors before the
    /// per-point loop.
    fn classify_points(
        &self,
        tile: &Tile,
        layout: &RecordLayout,
        classes: &[u8],
        is_ground: &[bool],
        object: &[u32],
        new_class: &mut [u8],
    ) -> (usize, f64) {
        let t = std::time::Instant::now();
        let rl = layout.record_len;
        let around = tile.context_mask(self.reach_m());
        let sub: Vec<usize> = (0..tile.len()).filter(|&i| around[i]).collect();
        let xyz: Vec<[f64; 3]> = sub.iter().map(|&i| tile.xyz[i]).collect();
        let ground: Vec<bool> = sub.iter().map(|&i| is_ground[i]).collect();
        let grid = GroundGrid::new(&xyz, &ground, self.section.objects.ground_cell_m);
        let hag: Vec<f64> = xyz.iter().map(|p| grid.height(p)).collect();
        let segment: Vec<u32> = if tile.segments.len() == tile.len() {
            sub.iter().map(|&i| tile.segments[i]).collect()
        } else {
            vec![0; sub.len()]
        };
        let object: Vec<u32> = sub.iter().map(|&i| object[i]).collect();
        let rule: Vec<u8> = sub
            .iter()
            .map(|&i| self.rule_index(new_class[i], is_ground[i]))
            .collect();
        let rec = |i: usize| &tile.records[i * rl..(i + 1) * rl];
        let has_returns = sub.iter().any(|&i| layout.returns(rec(i)).1 > 1);
        let (non_last, returns): (Vec<bool>, Vec<u8>) = sub
            .iter()
            .map(|&i| {
                let (r, n) = layout.returns(rec(i));
                (r < n, n)
            })
            .unzip();
        // Intensity (bytes 12–13 of every format) scaled by the 99th percentile of its input
        // file (a property of the file, not of the tile); −1 (missing) for files without.
        let p99 = &layout.intensity_p99;
        let scale = |i: usize| {
            p99.get(crate::model::file_of(tile.ids[i]))
                .copied()
                .unwrap_or(0)
        };
        let intensity: Option<Vec<f32>> = sub.iter().any(|&i| scale(i) > 0).then(|| {
            sub.iter()
                .map(|&i| match scale(i) {
                    0 => -1.0,
                    s => (u16::from_le_bytes([rec(i)[12], rec(i)[13]]) as f32 / s as f32).min(2.0),
                })
                .collect()
        });
        let which: Vec<bool> = sub
            .iter()
            .map(|&i| i < tile.n_core && !matches!(classes[i], 7 | 18))
            .collect();
        let inp = DescribeInput {
            xyz: &xyz,
            hag: &hag,
            is_ground: &ground,
            segment: &segment,
            object: &object,
            rule: &rule,
            non_last: has_returns.then_some(&non_last[..]),
            returns: has_returns.then_some(&returns[..]),
            intensity: intensity.as_deref(),
        };
        let d = Descriptors::new(&inp, &which);
        let descriptor_s = t.elapsed().as_secs_f64();
        let mut row = vec![0.0f32; descriptors::feature_count()];
        let mut scratch = Vec::new();
        let allowed = self.model.as_ref().map(|m| m.allowed());
        let mut done = 0;
        for (k, &i) in sub.iter().enumerate() {
            if !which[k] {
                continue;
            }
            d.row(k, &mut row);
            if let Some(c) = &self.collector {
                let code = c.code_of(tile.ids[i]);
                if code != 0 {
                    c.add(code, tile.ids[i], is_ground[i], &row);
                }
            }
            if let (Some(m), Some(a)) = (&self.model, &allowed) {
                let a = &a[usize::from(!is_ground[i])];
                if a.iter().any(|&v| v) {
                    new_class[i] = m.classes[m.forest.predict(&row, a, &mut scratch)];
                    done += 1;
                }
            }
        }
        (done, descriptor_s)
    }

    /// Object classes of the points marked `todo` (non-ground, not noise, in the zone).
    fn objects(
        &self,
        tile: &Tile,
        layout: &RecordLayout,
        is_ground: &[bool],
        todo: &[bool],
    ) -> (Vec<Option<ObjectClass>>, ObjectStats) {
        let rl = layout.record_len;
        let n = tile.len();
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
        classify_objects(
            &ObjectInput {
                xyz: &tile.xyz,
                is_ground,
                todo,
                segment,
                non_last_return: has_returns.then_some(&non_last[..]),
            },
            &self.section.objects,
        )
    }
}
