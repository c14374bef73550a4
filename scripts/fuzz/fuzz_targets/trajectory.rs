//! Trajectory CSV files (`mcap.pose_source = "trajectory"`).
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let p = common::file_with(data, "csv");
    let _ = tessera::io::mcap::trajectory::read_trajectory(&p, "map", "base_link");
});
