//! LAS/LAZ: header, VLRs, EVLRs, LASzip record, chunk table and chunk decoding, through the
//! reader the pipeline uses (scan, then every point in chunks).
#![no_main]
use libfuzzer_sys::fuzz_target;
mod common;

fuzz_target!(|data: &[u8]| {
    let laz = data.len() > 104 && data[104] & 0x80 != 0;
    let p = common::file_with(data, if laz { "laz" } else { "las" });
    let Ok(set) = tessera::io::input::scan_inputs(&[p], None) else {
        return;
    };
    for f in &set.files {
        let _ = tessera::io::input::read_file_chunks(f, &set.layout, 4096, || None, |_, _| Ok(()));
    }
});
