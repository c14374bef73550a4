//! The pass-through stage: leaves points untouched and reports per-tile statistics.

use super::stage::{Stage, StageSpec, TileReport};
use crate::error::Result;
use crate::model::{RecordLayout, Tile};
use std::collections::BTreeMap;

/// Registry entry (no configuration section).
pub const SPEC: StageSpec = StageSpec {
    name: "stats",
    reads: &[],
    writes: &[],
    has_section: false,
    validate: |_| Ok(()),
    build: |_| Ok(Box::new(StatsStage)),
};

/// Pass-through stage: leaves points untouched and reports per-tile statistics.
#[derive(Debug, Default)]
pub struct StatsStage;

impl Stage for StatsStage {
    fn name(&self) -> &'static str {
        "stats"
    }
    fn bytes_per_point(&self) -> usize {
        0
    }
    fn needs_context(&self) -> bool {
        false
    }
    fn process(
        &self,
        tile: &mut Tile,
        layout: &RecordLayout,
        report: &mut TileReport,
    ) -> Result<()> {
        let core = &tile.xyz[..tile.n_core];
        let (mut zmin, mut zmax, mut zsum) = (f64::INFINITY, f64::NEG_INFINITY, 0.0);
        for p in core {
            zmin = zmin.min(p[2]);
            zmax = zmax.max(p[2]);
            zsum += p[2];
        }
        let mut counts = [0u64; 256];
        for rec in tile
            .records
            .chunks_exact(layout.record_len)
            .take(tile.n_core)
        {
            counts[layout.classification(rec) as usize] += 1;
        }
        let classes: BTreeMap<u8, u64> = (0..=255u8).zip(counts).filter(|&(_, n)| n > 0).collect();
        let n = core.len().max(1) as f64;
        report.stats.insert(
            "stats".into(),
            serde_json::json!({
                "core_points": tile.n_core,
                "buffer_points": tile.len() - tile.n_core,
                "z_min": zmin, "z_max": zmax, "z_mean": zsum / n,
                "density_per_m2": tile.n_core as f64 / (tile.core.width() * tile.core.width()),
                "classes": classes,
            }),
        );
        Ok(())
    }
}
