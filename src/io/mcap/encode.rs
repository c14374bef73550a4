//! ROS 2 CDR (little-endian) serialisation of the messages tessera writes — the simulated
//! drive of `tessera synth --mcap` — and their `ros2msg` schema texts.

use super::pointcloud2::PointField;
use super::tf::TransformStamped;
use super::wire::Stamp;

/// `ros2msg` definition of `sensor_msgs/msg/PointCloud2` with its dependencies.
pub const POINTCLOUD2_SCHEMA: &str = "std_msgs/Header header
uint32 height
uint32 width
sensor_msgs/PointField[] fields
bool is_bigendian
uint32 point_step
uint32 row_step
uint8[] data
bool is_dense
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: sensor_msgs/PointField
uint8 INT8=1
uint8 UINT8=2
uint8 INT16=3
uint8 UINT16=4
uint8 INT32=5
uint8 UINT32=6
uint8 FLOAT32=7
uint8 FLOAT64=8
string name
uint32 offset
uint8 datatype
uint32 count
";

/// `ros2msg` definition of `tf2_msgs/msg/TFMessage` with its dependencies.
pub const TFMESSAGE_SCHEMA: &str = "geometry_msgs/TransformStamped[] transforms
================================================================================
MSG: geometry_msgs/TransformStamped
std_msgs/Header header
string child_frame_id
geometry_msgs/Transform transform
================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: geometry_msgs/Transform
geometry_msgs/Vector3 translation
geometry_msgs/Quaternion rotation
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
================================================================================
MSG: geometry_msgs/Quaternion
float64 x
float64 y
float64 z
float64 w
";

/// A little-endian CDR message under construction.
#[derive(Debug, Clone)]
pub struct CdrWriter {
    buf: Vec<u8>,
}

impl Default for CdrWriter {
    fn default() -> Self {
        CdrWriter::with_capacity(64)
    }
}

impl CdrWriter {
    /// A message with room for `n` bytes, starting with the CDR_LE encapsulation header.
    pub fn with_capacity(n: usize) -> Self {
        let mut buf = Vec::with_capacity(n + 4);
        buf.extend([0, 1, 0, 0]);
        CdrWriter { buf }
    }
    fn align(&mut self, n: usize) {
        while !(self.buf.len() - 4).is_multiple_of(n) {
            self.buf.push(0);
        }
    }
    /// A `uint8` / `bool`.
    pub fn u8(&mut self, v: u8) {
        self.buf.push(v);
    }
    /// A `uint32`.
    pub fn u32(&mut self, v: u32) {
        self.align(4);
        self.buf.extend(v.to_le_bytes());
    }
    /// An `int32`.
    pub fn i32(&mut self, v: i32) {
        self.align(4);
        self.buf.extend(v.to_le_bytes());
    }
    /// A `float64`.
    pub fn f64(&mut self, v: f64) {
        self.align(8);
        self.buf.extend(v.to_le_bytes());
    }
    /// A `string` (length with the NUL terminator, bytes, NUL).
    pub fn string(&mut self, s: &str) {
        self.u32(s.len() as u32 + 1);
        self.buf.extend(s.as_bytes());
        self.buf.push(0);
    }
    /// A `uint8[]`.
    pub fn bytes(&mut self, b: &[u8]) {
        self.u32(b.len() as u32);
        self.buf.extend_from_slice(b);
    }
    /// A `std_msgs/Header`.
    pub fn header(&mut self, stamp: Stamp, frame: &str) {
        self.i32(stamp.sec as i32);
        self.u32(stamp.nsec);
        self.string(frame);
    }
    /// The finished message.
    pub fn finish(self) -> Vec<u8> {
        self.buf
    }
}

/// Serialises a little-endian, dense-or-not `PointCloud2`.
#[allow(clippy::too_many_arguments)]
pub fn pointcloud2(
    stamp: Stamp,
    frame: &str,
    height: u32,
    width: u32,
    fields: &[PointField],
    point_step: u32,
    data: &[u8],
    is_dense: bool,
) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(data.len() + 64 + 32 * fields.len());
    w.header(stamp, frame);
    w.u32(height);
    w.u32(width);
    w.u32(fields.len() as u32);
    for f in fields {
        w.string(&f.name);
        w.u32(f.offset);
        w.u8(f.datatype);
        w.u32(f.count);
    }
    w.u8(0); // is_bigendian
    w.u32(point_step);
    w.u32(point_step * width);
    w.bytes(data);
    w.u8(is_dense as u8);
    w.finish()
}

/// Serialises a `tf2_msgs/TFMessage`.
pub fn tf_message(transforms: &[TransformStamped]) -> Vec<u8> {
    let mut w = CdrWriter::with_capacity(128 * transforms.len());
    w.u32(transforms.len() as u32);
    for t in transforms {
        w.header(t.stamp, &t.parent);
        w.string(&t.child);
        let v = t.iso.translation.vector;
        let q = t.iso.rotation.quaternion();
        for x in [v.x, v.y, v.z, q.i, q.j, q.k, q.w] {
            w.f64(x);
        }
    }
    w.finish()
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::io::mcap::pointcloud2::{datatype, decode};
    use crate::io::mcap::tf::{decode_tf_message, iso_from};
    use crate::io::mcap::wire::Encoding;

    #[test]
    fn encoded_messages_decode_back() {
        let fields = vec![
            PointField {
                name: "x".into(),
                offset: 0,
                datatype: datatype::FLOAT32,
                count: 1,
            },
            PointField {
                name: "ring".into(),
                offset: 4,
                datatype: datatype::UINT16,
                count: 1,
            },
        ];
        let mut data = Vec::new();
        data.extend(1.25f32.to_le_bytes());
        data.extend(9u16.to_le_bytes());
        data.extend([0, 0]);
        let s = Stamp { sec: 5, nsec: 7 };
        let m = pointcloud2(s, "lidar", 1, 1, &fields, 8, &data, false);
        let c = decode(&m, Encoding::Cdr).unwrap();
        assert_eq!(c.stamp, s);
        assert_eq!(c.fields, fields);
        assert_eq!(c.accessor(&c.fields[0]).get(c.point(0)), 1.25);
        assert!(!c.is_dense);
        let t = TransformStamped {
            stamp: s,
            parent: "map".into(),
            child: "base_link".into(),
            iso: iso_from([1.0, 2.0, 3.0], [0.0, 0.0, 0.6, 0.8]).unwrap(),
        };
        let back = decode_tf_message(&tf_message(&[t.clone(), t.clone()]), Encoding::Cdr).unwrap();
        assert_eq!(back.len(), 2);
        assert_eq!(back[1].child, "base_link");
        assert!((back[1].iso.translation.vector - t.iso.translation.vector).norm() < 1e-15);
        assert!(back[1].iso.rotation.angle_to(&t.iso.rotation) < 1e-12);
    }
}
