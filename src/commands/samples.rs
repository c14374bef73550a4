//! `tessera samples`: training samples for the labelling stage, from classified points or from
//! GeoJSON polygons over point files.

use tessera::cli::SamplesArgs;
use tessera::label::samples;
use tessera::Error;

/// Builds and saves the sample set.
pub fn samples(a: SamplesArgs) -> anyhow::Result<()> {
    let is_json = a
        .from
        .extension()
        .and_then(|e| e.to_str())
        .is_some_and(|e| e.eq_ignore_ascii_case("geojson") || e.eq_ignore_ascii_case("json"));
    let set = if is_json {
        if a.input.is_empty() {
            return Err(Error::Config(
                "samples from polygons need the point files (--input)".into(),
            )
            .into());
        }
        let polys = samples::read_polygons(&a.from)?;
        let inputs = tessera::io::input::expand_paths(&a.input)?;
        samples::from_polygons(&polys, &inputs, &a.point_classes, a.min_points)?
    } else {
        let mut set = samples::from_classified_points(&a.from, &a.field, a.block_m, a.min_points)?;
        if !a.classes.is_empty() {
            set.samples.retain(|s| a.classes.contains(&s.class));
        }
        set
    };
    set.save(&a.out)?;
    let mut per: std::collections::BTreeMap<u8, usize> = Default::default();
    for s in &set.samples {
        *per.entry(s.class).or_default() += 1;
    }
    tracing::info!(
        "{} samples (per class: {per:?}) written to {}",
        set.samples.len(),
        a.out.display()
    );
    Ok(())
}
