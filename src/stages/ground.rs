//! The ground stage: progressive TIN densification on each tile's core + buffer points;
//! writes ASPRS class 2 (ground), 7 (low noise, if enabled) and the configured class for the
//! rest.

use super::stage::{parse_section, Attribute, Stage, StageSpec, TileReport};
use crate::error::{Error, Result};
use crate::ground::{classify_ground, GroundClass};
use crate::model::{RecordLayout, Tile};
use crate::tiling::FarCells;

/// ASPRS class codes written by the ground stage.
pub mod class {
    /// Ground.
    pub const GROUND: u8 = 2;
    /// Low point (noise).
    pub const LOW_NOISE: u8 = 7;
}

/// `[ground]` configuration section.
#[derive(Debug, Clone, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct GroundSection {
    /// Class for non-ground points (-1 = keep the input class).
    pub nonground_class: i64,
    /// Filter parameters.
    pub params: crate::ground::GroundParams,
}

impl GroundSection {
    /// Checks the section.
    pub fn validate(&self) -> Result<()> {
        if !(-1..=255).contains(&self.nonground_class) {
            return Err(Error::Config(format!(
                "ground.nonground_class must be -1 (keep) or 0..=255, got {}",
                self.nonground_class
            )));
        }
        self.params
            .validate()
            .map_err(|e| Error::Config(format!("ground.params: {e}")))
    }
}

/// Registry entry.
pub const SPEC: StageSpec = StageSpec {
    name: NAME,
    reads: &[],
    writes: WRITES,
    has_section: true,
    validate: |raw| parse_section::<GroundSection>(NAME, raw)?.validate(),
    build: |raw| Ok(Box::new(GroundStage::new(parse_section(NAME, raw)?)?)),
};

/// What the stage writes.
const WRITES: &[Attribute] = &[Attribute::GroundClasses];

/// The stage's name and the name of its section.
pub const NAME: &str = "ground";

/// Ground filtering stage.
#[derive(Debug, Clone)]
pub struct GroundStage {
    section: GroundSection,
}

impl GroundStage {
    /// Builds the stage from its configuration section.
    pub fn new(section: GroundSection) -> Result<Self> {
        section.validate()?;
        Ok(GroundStage { section })
    }
}

impl Stage for GroundStage {
    fn name(&self) -> &'static str {
        NAME
    }
    fn writes(&self) -> &'static [Attribute] {
        WRITES
    }
    fn bytes_per_point(&self) -> usize {
        self.section.params.bytes_per_point()
    }
    fn far_cells(&self) -> Option<FarCells> {
        // Only one representative low point per `densify_cell_m` cell seeds and densifies the
        // TIN; the rest are judged by the final pass, which only matters for written points.
        let p = &self.section.params;
        (p.densify_cell_m > 0.0).then_some(FarCells {
            cell_m: p.densify_cell_m,
            window_m: p.offset_m,
        })
    }
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()> {
        let classes =
            classify_in_clusters(&tile.xyz, &self.section.params).map_err(|e| Error::Stage {
                tile: tile.name.to_string(),
                stage: "ground",
                source: Box::new(e),
            })?;
        let keep = self.section.nonground_class < 0;
        let other = self.section.nonground_class.clamp(0, 255) as u8;
        if !keep && other > layout.max_classification() {
            return Err(Error::Config(format!(
                "ground.nonground_class {other} does not fit point format {} (max {}); set output.point_format to 6 or higher",
                layout.format.to_u8().unwrap_or(255),
                layout.max_classification()
            )));
        }
        let (mut n_ground, mut n_low) = (0u64, 0u64);
        let rl = layout.record_len;
        for (i, (rec, c)) in tile.records.chunks_exact_mut(rl).zip(&classes).enumerate() {
            let code = match c {
                GroundClass::Ground => Some(class::GROUND),
                GroundClass::LowNoise => Some(class::LOW_NOISE),
                GroundClass::NonGround => (!keep).then_some(other),
            };
            if let Some(code) = code {
                layout.set_classification(rec, code);
            }
            if i < tile.n_core {
                match c {
                    GroundClass::Ground => n_ground += 1,
                    GroundClass::LowNoise => n_low += 1,
                    GroundClass::NonGround => {}
                }
            }
        }
        report.stats.insert(
            "ground".into(),
            serde_json::json!({ "ground_points": n_ground, "low_noise_points": n_low }),
        );
        Ok(())
    }
}

/// [`classify_ground`] on a tile's points; a tile whose points are too far-flung for the
/// filter's seed grid (a few points spread over kilometres: sparse inputs get large tiles)
/// is filtered cluster by cluster instead. A cluster is a connected group of occupied
/// cells four seed cells wide: its points are more than three seed cells from any other
/// cluster's, farther than a TIN triangle between them could mean terrain. Tiles the filter
/// takes whole are filtered whole, so dense data is classified as before.
fn classify_in_clusters(
    xyz: &[[f64; 3]],
    params: &crate::ground::GroundParams,
) -> std::result::Result<Vec<GroundClass>, crate::ground::GroundError> {
    match classify_ground(xyz, params) {
        Err(crate::ground::GroundError::GridTooLarge { .. }) => {}
        other => return other,
    }
    let cell = 4.0 * params.seed_cell_m;
    let key = |p: &[f64; 3]| ((p[0] / cell).floor() as i64, (p[1] / cell).floor() as i64);
    // Union-find over the occupied cells, joined to their 8 neighbours.
    let mut index: std::collections::HashMap<(i64, i64), usize> = Default::default();
    for p in xyz {
        let n = index.len();
        index.entry(key(p)).or_insert(n);
    }
    let mut parent: Vec<usize> = (0..index.len()).collect();
    fn root(parent: &mut [usize], mut i: usize) -> usize {
        while parent[i] != i {
            parent[i] = parent[parent[i]];
            i = parent[i];
        }
        i
    }
    for (&(x, y), &i) in &index {
        for (dx, dy) in [(1, -1), (1, 0), (1, 1), (0, 1)] {
            if let Some(&j) = index.get(&(x + dx, y + dy)) {
                let (a, b) = (root(&mut parent, i), root(&mut parent, j));
                parent[a.max(b)] = a.min(b);
            }
        }
    }
    let mut members: std::collections::BTreeMap<usize, Vec<usize>> = Default::default();
    for (k, p) in xyz.iter().enumerate() {
        let c = root(&mut parent, index[&key(p)]);
        members.entry(c).or_default().push(k);
    }
    let mut out = vec![GroundClass::Ground; xyz.len()];
    for idx in members.values() {
        let pts: Vec<[f64; 3]> = idx.iter().map(|&k| xyz[k]).collect();
        for (&k, c) in idx.iter().zip(classify_ground(&pts, params)?) {
            out[k] = c;
        }
    }
    Ok(out)
}
