//! MCAP: records, chunks, summary, then the whole conversion (transforms, PointCloud2
//! decoding, placing, LAS parts) as `tessera run` does it.
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let p = common::file_with(data, "mcap");
    let work = p.with_extension("work");
    let _ = std::fs::remove_dir_all(&work);
    let mut params = tessera::Config::defaults().expect("defaults").mcap;
    params.on_error = tessera::io::mcap::OnError::Skip;
    params.target_frame = "os1_lidar".into();
    let _ = tessera::io::mcap::convert_file_with(&p, &work, &params, 1);
    let _ = tessera::io::mcap::info(&p);
    let _ = std::fs::remove_dir_all(&work);
});
