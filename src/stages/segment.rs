//! The segmentation stage: planar + colour region growing (Sapkota; [`crate::segment`]) on
//! each tile's core + buffer points, by default on the points the ground stage left as
//! non-ground. Results: a per-point segment id (written as the `segment_id` extra-bytes
//! attribute of the output tiles) and a per-tile table of segments.
//!
//! Segment ids are local to a tile (1..=N in the tile's canonical order) until cross-tile
//! stitching assigns global ids.

use super::stage::{parse_section, Attribute, Stage, StageSpec, TileReport};
use crate::error::{Error, Result};
use crate::model::{RecordLayout, SegmentRow, Tile};
use crate::segment::{segment_at, SegParams};
use serde::Deserialize;

/// Which points take part in the segmentation.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SegmentPoints {
    /// Everything except ground (2) and noise (7, 18): objects, facades, vegetation.
    Nonground,
    /// Ground points only (class 2).
    Ground,
    /// Every point except noise (7, 18).
    All,
}

/// `[segment]` configuration section.
#[derive(Debug, Clone, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct SegmentSection {
    /// Which points are segmented.
    pub points: SegmentPoints,
    /// Only points within this distance outside the tile's core are segmented (capped by the
    /// tile's own buffer). The tiling buffer is sized for the ground filter's seed cells
    /// (20 m by default), far more context than region growing needs; segmenting all of it
    /// cost 8× the time on 12.5 m quadtree tiles. This strip is also the overlap in which
    /// neighbouring tiles' segments are compared when they are stitched.
    #[serde(default = "default_seg_context")]
    pub context_m: f64,
    /// Region-growing parameters.
    pub params: SegParams,
}

fn default_seg_context() -> f64 {
    5.0
}

/// Segmentation stage.
#[derive(Debug, Clone)]
pub struct SegmentStage {
    section: SegmentSection,
}

impl SegmentSection {
    /// Checks the section.
    pub fn validate(&self) -> Result<()> {
        self.params
            .validate()
            .map_err(|e| Error::Config(format!("segment.params: {e}")))?;
        if !(self.context_m.is_finite() && self.context_m >= 0.0) {
            return Err(Error::Config(format!(
                "segment.context_m must be >= 0, got {}",
                self.context_m
            )));
        }
        Ok(())
    }
}

/// Registry entry.
pub const SPEC: StageSpec = StageSpec {
    name: NAME,
    // The points it segments are chosen by their classes: the ground stage's when it runs
    // first, else the input's own (a classified survey), so the classes are not required.
    reads: &[],
    writes: WRITES,
    has_section: true,
    validate: |raw| parse_section::<SegmentSection>(NAME, raw)?.validate(),
    build: |raw| Ok(Box::new(SegmentStage::new(parse_section(NAME, raw)?)?)),
};

/// What the stage writes.
const WRITES: &[Attribute] = &[Attribute::SegmentIds];

/// The stage's name and the name of its section.
pub const NAME: &str = "segment";

impl SegmentStage {
    /// Builds the stage from its configuration section.
    pub fn new(section: SegmentSection) -> Result<Self> {
        section.validate()?;
        Ok(SegmentStage { section })
    }
}

impl Stage for SegmentStage {
    fn name(&self) -> &'static str {
        NAME
    }
    fn writes(&self) -> &'static [Attribute] {
        WRITES
    }
    fn context_m(&self) -> Option<f64> {
        Some(self.section.context_m)
    }
    fn bytes_per_point(&self) -> usize {
        // Neighbour rows (u32 index + f32 distance², k of them, written in place), canonical
        // order, normals, colour in two forms, labels and the growing queues. Measured by
        // `tests/stage_memory.rs` (counting allocator, k = 20) and summary.json `stages.
        // segment.bytes_per_point_peak`: 145 B per tile point on the leaves of the 300 m
        // street at 256 MiB (243 B with per-point lists packed into a second copy), so 8 B
        // per neighbour plus 40 B (+25 % slack).
        8 * self.section.params.k + 40
    }
    fn bytes_per_tile_point(&self) -> usize {
        // The mask, colour and label arrays over every tile point (1 + 6 + 4 B, and the
        // output labels while the table is built): a big tile with few non-ground points
        // grew 10.4 MiB for 52 k context points of 564 k (simulated drive).
        16
    }
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()> {
        let rl = layout.record_len;
        let near = tile.context_mask(self.section.context_m);
        let mask: Vec<bool> = tile
            .records
            .chunks_exact(rl)
            .zip(near)
            .map(|(rec, near)| {
                let c = layout.classification(rec);
                let noise = c == 7 || c == 18;
                let wanted = match self.section.points {
                    SegmentPoints::Nonground => c != 2 && !noise,
                    SegmentPoints::Ground => c == 2,
                    SegmentPoints::All => !noise,
                };
                wanted && near
            })
            .collect();
        report.worked_on(self.name(), mask.iter().filter(|&&m| m).count());
        let rgb: Option<Vec<[u16; 3]>> = layout.rgb_offset().map(|o| {
            tile.records
                .chunks_exact(rl)
                .map(|rec| {
                    let v = |i: usize| u16::from_le_bytes([rec[o + 2 * i], rec[o + 2 * i + 1]]);
                    [v(0), v(1), v(2)]
                })
                .collect()
        });
        // One origin for every tile of the run (the run layout's offsets), so neighbouring
        // tiles compute the geometry of the points they share identically.
        let t = &layout.transforms;
        let origin = [t.x.offset, t.y.offset, t.z.offset];
        let out = segment_at(
            &tile.xyz,
            rgb.as_deref(),
            Some(&mask),
            &self.section.params,
            Some(origin),
        )
        .map_err(|e| Error::Stage {
            tile: tile.name.to_string(),
            stage: "segment",
            source: Box::new(e),
        })?;
        let mut core_n = vec![0usize; out.segments.len() + 1];
        for &l in &out.labels[..tile.n_core] {
            core_n[l as usize] += 1;
        }
        tile.segment_table = out
            .segments
            .iter()
            .filter(|s| core_n[s.id as usize] > 0)
            .map(|s| SegmentRow {
                info: s.clone(),
                core_points: core_n[s.id as usize],
            })
            .collect();
        let segmented = tile.n_core - core_n[0];
        report.stats.insert(
            "segment".into(),
            serde_json::json!({
                "segments_in_core": tile.segment_table.len(),
                "core_points_segmented": segmented,
                "points_considered": out.stats.points,
                "seeds_tried": out.stats.seeds_tried,
            }),
        );
        tile.segments = out.labels;
        Ok(())
    }
}
