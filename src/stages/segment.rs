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
use crate::segment::multicue::{ties, MulticueParams};
use crate::segment::{segment_at, SegParams};
use serde::Deserialize;

/// The segmentation method.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum SegmentMethod {
    /// Planar + colour region growing on the tile's points (any input).
    #[default]
    RegionGrowing,
    /// Multi-cue segmentation of each scan while an MCAP drive is decoded, the scans'
    /// segments tied into world segments per tile ([`crate::segment::multicue`]).
    Multicue,
}

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
    /// The method.
    #[serde(default)]
    pub method: SegmentMethod,
    /// Multi-cue parameters (`method = "multicue"`).
    #[serde(default)]
    pub multicue: MulticueParams,
    /// How scan segments are tied into world segments (`method = "multicue"`).
    #[serde(default)]
    pub tie: ties::TieParams,
}

fn default_seg_context() -> f64 {
    3.0
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
        self.multicue.validate().map_err(Error::Config)?;
        self.tie.validate().map_err(Error::Config)?;
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

/// The scan segmenter the MCAP conversion runs when `stages.run` segments with
/// `method = "multicue"` (None otherwise).
pub fn scan_segmenter(
    run: &[String],
    sections: &toml::Table,
) -> Result<Option<std::sync::Arc<dyn crate::io::mcap::ScanSegmenter>>> {
    if !run.iter().any(|r| r == NAME) {
        return Ok(None);
    }
    let raw = sections
        .get(NAME)
        .cloned()
        .unwrap_or_else(|| toml::Value::Table(toml::Table::new()));
    let section: SegmentSection = parse_section(NAME, &raw)?;
    Ok(match section.method {
        SegmentMethod::Multicue => Some(std::sync::Arc::new(section.multicue)),
        SegmentMethod::RegionGrowing => None,
    })
}

/// Sets the tile's per-point segments and its table (the segments with core points); returns
/// the core points segmented.
fn set_table(tile: &mut Tile, labels: &[u32], segments: &[crate::model::SegmentInfo]) -> usize {
    let mut core_n = vec![0usize; segments.len() + 1];
    for &l in &labels[..tile.n_core] {
        core_n[l as usize] += 1;
    }
    tile.segment_table = segments
        .iter()
        .filter(|s| core_n[s.id as usize] > 0)
        .map(|s| SegmentRow {
            info: s.clone(),
            core_points: core_n[s.id as usize],
        })
        .collect();
    tile.n_core - core_n[0]
}

/// Plane, spread and mean colour of each segment `1..=k` of `labels` (coordinates relative to
/// `origin` while summed, the plane offset in input coordinates).
fn describe(
    xyz: &[[f64; 3]],
    labels: &[u32],
    k: usize,
    rgb: Option<(&[u8], usize, usize)>,
    origin: [f64; 3],
) -> Vec<crate::model::SegmentInfo> {
    use crate::segment::features::Moments;
    let mut mom: Vec<Moments> = vec![Moments::new(origin); k];
    let mut csum = vec![[0.0f64; 3]; k];
    let eight_bit = rgb.is_some_and(|(recs, rl, o)| {
        recs.chunks_exact(rl)
            .all(|r| (0..3).all(|c| r[o + 2 * c + 1] == 0))
    });
    for (i, &l) in labels.iter().enumerate() {
        if l == 0 {
            continue;
        }
        let s = l as usize - 1;
        mom[s].add(&xyz[i]);
        if let Some((recs, rl, o)) = rgb {
            let c = RecordLayout::rgb_at(&recs[i * rl..(i + 1) * rl], o);
            for (sum, v) in csum[s].iter_mut().zip(c) {
                let v = v as f64;
                *sum += if eight_bit { v } else { v * 255.0 / 65535.0 };
            }
        }
    }
    mom.iter()
        .zip(&csum)
        .enumerate()
        .map(|(s, (m, cs))| {
            let (plane, rms) = m.plane().unwrap_or((
                crate::segment::features::Plane {
                    n: [0.0, 0.0, 1.0],
                    d: 0.0,
                },
                0.0,
            ));
            let nrm = plane.n;
            crate::model::SegmentInfo {
                id: s as u32 + 1,
                n: m.n,
                normal: nrm,
                d: plane.d + nrm[0] * origin[0] + nrm[1] * origin[1] + nrm[2] * origin[2],
                mean_rgb: cs.map(|v| v / m.n.max(1) as f64),
                rms,
            }
        })
        .collect()
}

impl SegmentStage {
    /// `method = "multicue"`: the points' scan segments (segmented while the drive was
    /// decoded) tied into world segments ([`ties::tie`]) over the context points.
    fn tie_scans(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        member: &[bool],
        report: &mut TileReport,
    ) -> Result<()> {
        use crate::io::mcap::SCAN_SEGMENT;
        let rl = layout.record_len;
        let Some((off, _)) = layout
            .extra(SCAN_SEGMENT)
            .filter(|(_, f)| f.size == 8 && f.data_type == crate::io::extra::TYPE_U64)
        else {
            return Err(Error::Stage {
                tile: tile.name.to_string(),
                stage: NAME,
                source: Box::new(Error::Config(format!(
                    "segment.method = \"multicue\" needs points decoded from an MCAP drive (their \"{SCAN_SEGMENT}\" attribute); these inputs have none: use method = \"region_growing\""
                ))),
            });
        };
        let values: Vec<u64> = tile
            .records
            .chunks_exact(rl)
            .map(|r| u64::from_le_bytes(r[off..off + 8].try_into().unwrap_or([0; 8])))
            .collect();
        // Every point near the core tells what its scan saw; the noise points do not.
        let near = tile.context_mask(self.section.context_m);
        let observe: Vec<bool> = tile
            .records
            .chunks_exact(rl)
            .zip(&near)
            .map(|(r, &n)| n && !matches!(layout.classification(r), 7 | 18))
            .collect();
        let t = &layout.transforms;
        let origin = [t.x.offset, t.y.offset, t.z.offset];
        let tp = &self.section.tie;
        let colour_check = tp.plane_tolerance_m > 0.0 && tp.colour_tolerance > 0.0;
        let lab: Option<Vec<[f32; 3]>> = layout.rgb_offset().filter(|_| colour_check).map(|o| {
            let rgb: Vec<[u16; 3]> = tile
                .records
                .chunks_exact(rl)
                .map(|r| RecordLayout::rgb_at(r, o))
                .collect();
            let eight = crate::segment::rgb_is_8bit(&rgb);
            // Only segment members' colours are used (ground points are most of a tile).
            rgb.iter()
                .zip(member)
                .map(|(&c, &m)| match m {
                    true => crate::segment::features::rgb16_to_lab(c, eight).map(|v| v as f32),
                    false => [0.0; 3],
                })
                .collect()
        });
        let (labels, st) = ties::tie(
            &tile.xyz,
            &values,
            &observe,
            member,
            lab.as_deref(),
            origin,
            &self.section.tie,
        );
        drop(lab);
        let rgb = layout.rgb_offset().map(|o| (&tile.records[..], rl, o));
        let segments = describe(&tile.xyz, &labels, st.world_segments, rgb, origin);
        let segmented = set_table(tile, &labels, &segments);
        report.stats.insert(
            "segment".into(),
            serde_json::json!({
                "method": "multicue",
                "segments_in_core": tile.segment_table.len(),
                "core_points_segmented": segmented,
                "scans": st.scans,
                "scan_segments": st.scan_segments,
                "candidate_pairs": st.candidate_pairs,
                "ties": st.ties,
                "unconfirmed": st.unconfirmed,
                "apart": st.apart,
                "split_off": st.split_off,
                "stems": st.stems,
                "attached_points": st.attached,
                "leftover_segments": st.leftover_segments,
            }),
        );
        tile.segments = labels;
        Ok(())
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
        match self.section.method {
            SegmentMethod::RegionGrowing => 8 * self.section.params.k + 40,
            // Tying: the points' values (8 B), (voxel, scan, node) entries (16 B), node and
            // label per point (8 B), the CIELab colours when there is colour (12 B, and the
            // 6 B of RGB they are made from), the masks, and the segment sums and pair counts,
            // which grow with segments, not points; the refinement's point lists, voxel maps
            // and per-segment shapes. Estimated, with slack; not yet measured by
            // `tests/stage_memory.rs` (summary.json peak on the 32-ring 60 m drive: 62 B per
            // tile point without the refinement, 73 B with it).
            SegmentMethod::Multicue => 84,
        }
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
        if self.section.method == SegmentMethod::Multicue {
            return self.tie_scans(tile, layout, &mask, report);
        }
        let rgb: Option<Vec<[u16; 3]>> = layout.rgb_offset().map(|o| {
            tile.records
                .chunks_exact(rl)
                .map(|rec| RecordLayout::rgb_at(rec, o))
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
        let segmented = set_table(tile, &out.labels, &out.segments);
        report.stats.insert(
            "segment".into(),
            serde_json::json!({
                "segments_in_core": tile.segment_table.len(),
                "core_points_segmented": segmented,
                "points_considered": out.stats.points,
                "seeds_tried": out.stats.seeds_tried,
                "seconds": {
                    "order": out.stats.stage_s[0], "neighbours": out.stats.stage_s[1],
                    "normals": out.stats.stage_s[2], "colour": out.stats.stage_s[3],
                    "grow": out.stats.stage_s[4], "output": out.stats.stage_s[5],
                },
            }),
        );
        tile.segments = out.labels;
        Ok(())
    }
}
