//! Training samples for labelling: a tessera sample set (JSON) and GeoJSON polygons.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let p = common::file_with(data, "json");
    let _ = tessera::label::samples::SampleSet::load(&p, 1.0, 10);
    let g = common::file_with(data, "geojson");
    let _ = tessera::label::samples::read_polygons(&g);
});
