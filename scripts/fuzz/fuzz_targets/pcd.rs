//! PCD: header, ascii, binary and binary_compressed (LZF) data.
#![no_main]
use libfuzzer_sys::fuzz_target;

fuzz_target!(|data: &[u8]| {
    let _ = tessera::io::pcd::parse_pcd(data);
    if data.len() > 4 {
        let n = u16::from_le_bytes([data[0], data[1]]) as usize * 64;
        let _ = tessera::io::pcd::lzf::decompress(&data[2..], n);
    }
});
