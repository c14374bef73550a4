//! Helpers of the MCAP integration tests: the Python oracle, tessera's decoder output in a
//! comparable form, and LAS part reading.
#![allow(dead_code)]

use std::path::{Path, PathBuf};
use tessera::io::mcap::pointcloud2::{self, datatype};
use tessera::io::mcap::reader::MessageRef;
use tessera::io::mcap::wire::Encoding;
use tessera::io::mcap::McapSource;

/// Whether python3 has the independent MCAP/ROS libraries.
pub fn have_py_mcap() -> bool {
    let ok = std::process::Command::new("python3")
        .args(["-c", "import mcap, mcap_ros2, rosbags, numpy"])
        .status()
        .map(|s| s.success())
        .unwrap_or(false);
    if !ok {
        eprintln!(
            "SKIP: python3 -c 'import mcap, mcap_ros2, rosbags, numpy' failed (pip install mcap mcap-ros2-support rosbags numpy)"
        );
    }
    ok
}

/// Runs `scripts/<name>` with `args`; panics with its output on failure.
pub fn run_script(name: &str, args: &[&Path]) {
    let script = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("scripts")
        .join(name);
    let out = std::process::Command::new("python3")
        .arg(&script)
        .args(args)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{name} failed: {}\n{}",
        String::from_utf8_lossy(&out.stdout),
        String::from_utf8_lossy(&out.stderr)
    );
}

/// One cloud as tessera decodes it.
#[derive(Debug, Clone)]
pub struct Decoded {
    pub topic: String,
    pub log_time: u64,
    pub stamp_ns: i128,
    pub frame_id: String,
    pub height: u32,
    pub width: u32,
    pub point_step: u32,
    pub row_step: u32,
    pub is_bigendian: bool,
    pub is_dense: bool,
    /// (name, offset, datatype, count)
    pub fields: Vec<(String, u32, u8, u32)>,
    /// Scalar field names in field-table order.
    pub columns: Vec<String>,
    /// values[point][column]
    pub values: Vec<Vec<f64>>,
}

/// Every PointCloud2 of `path`, decoded by tessera, in file order.
pub fn decode_clouds(path: &Path) -> Vec<Decoded> {
    let src = McapSource::open(path).unwrap();
    let mut out = Vec::new();
    let mut want =
        |c: &tessera::io::mcap::reader::ChannelInfo| c.message_type() == "sensor_msgs/PointCloud2";
    let mut on = |m: MessageRef| -> tessera::Result<()> {
        let enc = Encoding::from_channel(&m.channel.message_encoding).unwrap();
        let c = pointcloud2::decode(m.data, enc).unwrap();
        let scalar: Vec<_> = c.fields.iter().filter(|f| f.count == 1).collect();
        let acc: Vec<_> = scalar.iter().map(|f| c.accessor(f)).collect();
        let values = (0..c.len())
            .map(|i| acc.iter().map(|a| a.get(c.point(i))).collect())
            .collect();
        out.push(Decoded {
            topic: m.channel.topic.clone(),
            log_time: m.log_time,
            stamp_ns: c.stamp.as_nanos(),
            frame_id: c.frame_id.to_string(),
            height: c.height,
            width: c.width,
            point_step: c.point_step,
            row_step: c.row_step,
            is_bigendian: c.is_bigendian,
            is_dense: c.is_dense,
            fields: c
                .fields
                .iter()
                .map(|f| (f.name.clone(), f.offset, f.datatype, f.count))
                .collect(),
            columns: scalar.iter().map(|f| f.name.clone()).collect(),
            values,
        });
        Ok(())
    };
    let o = src.scan(&mut want, &mut on, true).unwrap();
    assert!(o.damage.is_empty(), "{:?}", o.damage);
    out
}

/// A float64 N×K .npy array as rows.
pub fn npy_rows(path: &Path) -> Vec<Vec<f64>> {
    let (descr, shape, data) = crate::common::read_npy(path).unwrap();
    assert_eq!(descr, "<f8", "{}", path.display());
    let k = if shape.len() == 2 { shape[1] } else { 1 };
    let vals: Vec<f64> = data
        .chunks_exact(8)
        .take(shape[0] * k)
        .map(|c| f64::from_le_bytes(c.try_into().unwrap()))
        .collect();
    vals.chunks(k.max(1)).map(|c| c.to_vec()).collect()
}

/// An int64 .npy vector.
pub fn npy_i64(path: &Path) -> Vec<i64> {
    let (descr, shape, data) = crate::common::read_npy(path).unwrap();
    assert_eq!(descr, "<i8", "{}", path.display());
    data.chunks_exact(8)
        .take(shape[0])
        .map(|c| i64::from_le_bytes(c.try_into().unwrap()))
        .collect()
}

/// Exact equality with NaN equal to NaN.
pub fn same(a: f64, b: f64) -> bool {
    a == b || (a.is_nan() && b.is_nan())
}

/// One point of a LAS part.
#[derive(Debug, Clone)]
pub struct LasPoint {
    pub xyz: [f64; 3],
    pub intensity: u16,
    pub gps_time: f64,
    pub rgb: Option<[u16; 3]>,
    pub point_source_id: u16,
    pub extra: Vec<u8>,
}

/// Points of LAS files, in order, and the extra-bytes attribute names with offsets.
pub fn read_parts(parts: &[PathBuf]) -> (Vec<LasPoint>, Vec<tessera::io::extra::ExtraField>) {
    let mut pts = Vec::new();
    let mut fields = Vec::new();
    for p in parts {
        let mut r = las::Reader::from_path(p).unwrap();
        if let Some(v) = r
            .header()
            .vlrs()
            .iter()
            .find(|v| v.user_id == "LASF_Spec" && v.record_id == 4)
        {
            fields = tessera::io::extra::fields(&v.data);
        }
        let data = r.read_all().unwrap();
        for q in data.points() {
            let q = q.unwrap();
            pts.push(LasPoint {
                xyz: [q.x, q.y, q.z],
                intensity: q.intensity,
                gps_time: q.gps_time.unwrap(),
                rgb: q.color.map(|c| [c.red, c.green, c.blue]),
                point_source_id: q.point_source_id,
                extra: q.extra_bytes,
            });
        }
    }
    (pts, fields)
}

/// The value of extra attribute `name` of a point (integer types only), as f64.
pub fn extra_value(p: &LasPoint, fields: &[tessera::io::extra::ExtraField], name: &str) -> f64 {
    let f = fields
        .iter()
        .find(|f| f.name == name)
        .unwrap_or_else(|| panic!("no extra attribute {name}"));
    let b = &p.extra[f.offset..f.offset + f.size];
    match f.data_type {
        1 => b[0] as f64,
        2 => b[0] as i8 as f64,
        3 => u16::from_le_bytes([b[0], b[1]]) as f64,
        4 => i16::from_le_bytes([b[0], b[1]]) as f64,
        5 => u32::from_le_bytes(b.try_into().unwrap()) as f64,
        6 => i32::from_le_bytes(b.try_into().unwrap()) as f64,
        9 => f32::from_le_bytes(b.try_into().unwrap()) as f64,
        10 => f64::from_le_bytes(b.try_into().unwrap()),
        t => panic!("extra type {t}"),
    }
}

/// Default `[mcap]` parameters with overrides.
pub fn params(sets: &[&str]) -> tessera::io::mcap::McapParams {
    let sets: Vec<String> = sets.iter().map(|s| s.to_string()).collect();
    tessera::Config::load(None, &sets).unwrap().mcap
}

/// LAS adjusted standard GPS time of a Unix time in ns.
pub fn gps_of(unix_ns: i128) -> f64 {
    (unix_ns - tessera::io::mcap::convert::UNIX_TO_ADJUSTED_GPS_S * 1_000_000_000) as f64 * 1e-9
}

/// Size of a PointField datatype (re-exported for tests).
pub fn dt_size(dt: u8) -> usize {
    datatype::size(dt).unwrap()
}
