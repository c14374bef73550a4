//! `tessera thin`: density reduction by minimum point spacing.

use std::path::Path;

/// Thins `input` into `output`.
pub fn thin(spacing: f64, input: &Path, output: &Path) -> anyhow::Result<()> {
    let s = tessera::thin::thin_file(input, output, spacing)?;
    tracing::info!(
        "kept {} of {} points ({:.1} %) at spacing {spacing} m: {}",
        s.kept,
        s.seen,
        100.0 * s.kept as f64 / s.seen.max(1) as f64,
        output.display()
    );
    Ok(())
}
