//! ROS 1 and CDR (ROS 2) PointCloud2 messages: decoding and reading every field of every
//! point.
#![no_main]
use libfuzzer_sys::fuzz_target;
use tessera::io::mcap::pointcloud2::decode;
use tessera::io::mcap::wire::Encoding;

fuzz_target!(|data: &[u8]| {
    for enc in [Encoding::Ros1, Encoding::Cdr] {
        if let Ok(c) = decode(data, enc) {
            let acc: Vec<_> = c.fields.iter().map(|f| c.accessor(f)).collect();
            for i in 0..c.len().min(1 << 16) {
                let p = c.point(i);
                for a in &acc {
                    let _ = a.get(p);
                }
            }
        }
    }
});
