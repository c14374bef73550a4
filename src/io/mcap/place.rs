//! Placing one cloud in the world: decode, bind to the file's layout, drop invalid and near
//! points, find each point's time and pose (de-skew), transform. Runs on worker threads; reads
//! only shared, immutable state (transform tree, layout, settings) plus its own caches.

use super::fields::{unpack_rgb, CloudSchema};
use super::pointcloud2::{self, datatype, Accessor};
use super::tf::{normalise, Chain, Iso, Limits, TfTree};
use super::wire::{Encoding, Stamp};
use super::McapParams;
use nalgebra::Point3;
use std::collections::HashMap;

/// Unix time minus this is LAS "adjusted standard GPS time" (GPS seconds − 1e9): the GPS
/// epoch is 1980-01-06 (Unix 315 964 800) and GPS time is ahead of UTC by the 18 leap seconds
/// inserted since (the count valid since 2017-01-01; earlier drives are off by a second or
/// two, which only shifts all times equally).
pub const UNIX_TO_ADJUSTED_GPS_S: i128 = 315_964_800 - 18 + 1_000_000_000;

/// A cloud in world coordinates, ready to be encoded (buffers are reused between clouds).
#[derive(Debug, Default)]
pub struct Placed {
    /// World coordinates (+ world offset) of the kept points.
    pub xyz: Vec<[f64; 3]>,
    /// Adjusted GPS time, LAS intensity and 16-bit RGB of the kept points.
    pub attrs: Vec<(f64, u16, [u16; 3])>,
    /// Extra bytes of the kept points, back to back.
    pub extras: Vec<u8>,
    /// Header stamp.
    pub stamp: Stamp,
    /// Points in the cloud (`width × height`).
    pub points_in: u64,
    /// Non-finite points dropped.
    pub nan: u64,
    /// Points nearer than `min_range_m` dropped.
    pub near: u64,
    /// Whether per-point poses were used.
    pub deskewed: bool,
    /// Extra fields of the layout this cloud lacks (written as 0).
    pub missing: Vec<String>,
    /// Segments found in the scan (when scans are segmented).
    pub scan_segments: u32,
    /// Why the scan could not be segmented (its points carry segment 0), when it could not.
    pub scan_unsegmented: Option<String>,
}

impl Placed {
    fn clear(&mut self) {
        self.xyz.clear();
        self.attrs.clear();
        self.extras.clear();
        self.missing.clear();
        self.points_in = 0;
        self.nan = 0;
        self.near = 0;
        self.deskewed = false;
        self.scan_segments = 0;
        self.scan_unsegmented = None;
    }
}

/// Why a cloud could not be used: a kind (for the counts), a message, and its stamp when the
/// message could be decoded that far.
#[derive(Debug, Clone)]
pub struct Unusable {
    /// Short kind: "undecodable", "missing pose", ...
    pub kind: &'static str,
    /// What went wrong.
    pub why: String,
    /// The cloud's header stamp, if known.
    pub stamp: Option<Stamp>,
}

/// How a cloud's per-point time values map to absolute nanoseconds.
#[derive(Debug, Clone, Copy)]
struct TimeMap {
    unit_s: f64,
    absolute: bool,
}

impl TimeMap {
    /// Decides from the cloud's first finite time value: values past 1e6 s are absolute
    /// epoch times, smaller ones offsets from the header stamp. With an automatic unit, a
    /// float field holding more than 1e14 units is taken as nanoseconds (Livox style).
    fn detect(a: &Accessor, unit_s: f64, auto_unit: bool, v: f64) -> TimeMap {
        let mut unit = unit_s;
        if auto_unit && !datatype::is_integer(a.datatype) && v.abs() > 1e14 {
            unit = 1e-9;
        }
        TimeMap {
            unit_s: unit,
            absolute: (v * unit).abs() > 1e6,
        }
    }

    #[inline]
    fn to_ns(self, v: f64, stamp_ns: i128) -> i128 {
        let ns = if self.unit_s == 1e-9 {
            v.round() as i128
        } else {
            (v * self.unit_s * 1e9).round() as i128
        };
        if self.absolute {
            ns
        } else {
            stamp_ns + ns
        }
    }
}

/// One worker's placer.
pub struct Placer<'a> {
    tf: &'a TfTree,
    lim: Limits,
    p: &'a McapParams,
    schema: &'a CloudSchema,
    chains: HashMap<String, Result<Chain, String>>,
    pose_cache: HashMap<i128, Iso>,
}

impl<'a> Placer<'a> {
    /// A placer for clouds of the layout `schema`.
    pub fn new(tf: &'a TfTree, lim: Limits, p: &'a McapParams, schema: &'a CloudSchema) -> Self {
        Placer {
            tf,
            lim,
            p,
            schema,
            chains: HashMap::new(),
            pose_cache: HashMap::new(),
        }
    }

    /// Places the serialised cloud `data` (of `encoding`, `None` if unsupported) into `out`.
    pub fn place(
        &mut self,
        data: &[u8],
        encoding: Option<Encoding>,
        encoding_note: &str,
        out: &mut Placed,
    ) -> Result<(), Unusable> {
        out.clear();
        let unusable =
            |kind: &'static str, why: String, stamp: Option<Stamp>| Unusable { kind, why, stamp };
        let Some(enc) = encoding else {
            return Err(unusable(
                "unsupported encoding",
                format!(
                    "{encoding_note} is not supported; tessera reads \"ros1\" and \"cdr\" (ROS 2)"
                ),
                None,
            ));
        };
        let cloud = pointcloud2::decode(data, enc).map_err(|e| {
            unusable(
                "undecodable",
                format!("cannot decode PointCloud2: {e}"),
                None,
            )
        })?;
        let stamp = cloud.stamp;
        out.stamp = stamp;
        out.points_in = cloud.len() as u64;
        let p = self.p;
        let b = self
            .schema
            .bind(&cloud, p.time_unit_s)
            .map_err(|e| unusable("layout", e, Some(stamp)))?;
        out.missing.clone_from(&b.missing);
        let frame = normalise(cloud.frame_id).to_string();
        let tf = self.tf;
        let chain = self
            .chains
            .entry(frame.clone())
            .or_insert_with(|| tf.chain(&p.target_frame, &frame).map_err(|e| e.to_string()))
            .clone()
            .map_err(|e| unusable("no transform chain", e, Some(stamp)))?;
        let stamp_ns = stamp.as_nanos();
        let cloud_pose: Iso = tf
            .eval(&chain, stamp_ns, &self.lim)
            .map_err(|e| unusable("missing pose", e.to_string(), Some(stamp)))?;
        let deskew = p.deskew && b.time.is_some() && !chain.is_static;
        out.deskewed = deskew;
        let min_r2 = p.min_range_m * p.min_range_m;
        let [ax, ay, az] = b.xyz;
        let mut time_map: Option<TimeMap> = None;
        self.pose_cache.clear();
        let mut last_t = i128::MIN;
        let mut pose = cloud_pose;
        let off = p.world_offset;
        let eb = self.schema.extra_bytes();
        // The scan is segmented in its own (sensor) frame, before any point is dropped, so the
        // image keeps the cloud's layout.
        let scan_labels = match (&p.scan_segments, self.schema.scan_segment) {
            (Some(seg), true) => Some(segment_cloud(&cloud, &b, seg.as_ref(), out)),
            _ => None,
        };
        for i in 0..cloud.len() {
            let pt = cloud.point(i);
            let (x, y, z) = (ax.get(pt), ay.get(pt), az.get(pt));
            if !(x.is_finite() && y.is_finite() && z.is_finite()) {
                out.nan += 1;
                continue;
            }
            if x * x + y * y + z * z < min_r2 {
                out.near += 1;
                continue;
            }
            let t_ns = match &b.time {
                Some((a, unit)) => {
                    let v = a.get(pt);
                    let tm = *time_map
                        .get_or_insert_with(|| TimeMap::detect(a, *unit, p.time_unit_s == 0.0, v));
                    if v.is_finite() {
                        tm.to_ns(v, stamp_ns)
                    } else {
                        stamp_ns
                    }
                }
                None => stamp_ns,
            };
            if deskew && t_ns != last_t {
                // Organised clouds repeat each firing time once per ring: evaluate the chain
                // once per distinct time.
                pose = match self.pose_cache.get(&t_ns) {
                    Some(q) => *q,
                    None => {
                        let q = tf.eval(&chain, t_ns, &self.lim).map_err(|e| {
                            unusable(
                                "missing pose",
                                format!("point {i} (per-point time): {e}"),
                                Some(stamp),
                            )
                        })?;
                        if self.pose_cache.len() < 1 << 16 {
                            self.pose_cache.insert(t_ns, q);
                        }
                        q
                    }
                };
                last_t = t_ns;
            }
            let w = pose * Point3::new(x, y, z);
            out.xyz.push([w.x + off[0], w.y + off[1], w.z + off[2]]);
            let inten = b
                .intensity
                .map(|a| a.get(pt).round().clamp(0.0, 65535.0) as u16)
                .unwrap_or(0);
            let rgb = b.rgb.map(|a| unpack_rgb(a.bits32(pt))).unwrap_or([0; 3]);
            let gps = (t_ns - UNIX_TO_ADJUSTED_GPS_S * 1_000_000_000) as f64 * 1e-9;
            out.attrs.push((gps, inten, rgb));
            let before = out.extras.len();
            for (e, spec) in b.extras.iter().zip(&self.schema.extras) {
                match e {
                    Some(a) => a.push_le(pt, &mut out.extras),
                    None => out.extras.extend(std::iter::repeat_n(0u8, spec.size)),
                }
            }
            if let Some(l) = &scan_labels {
                out.extras.extend(u64::from(l[i]).to_le_bytes());
            }
            debug_assert_eq!(out.extras.len() - before, eb);
        }
        Ok(())
    }
}

/// The per-point segments of `cloud` by the run's [`super::ScanSegmenter`], all 0
/// when the scan cannot be segmented (the reason goes to `out`).
fn segment_cloud(
    cloud: &pointcloud2::PointCloud2,
    b: &super::fields::Bound,
    seg: &dyn super::ScanSegmenter,
    out: &mut Placed,
) -> Vec<u32> {
    use crate::model::ScanPoints;
    let n = cloud.len();
    let [ax, ay, az] = b.xyz;
    let mut xyz = Vec::with_capacity(n);
    let mut rgb = b.rgb.map(|_| Vec::with_capacity(n));
    let ring_acc = cloud
        .field("ring")
        .filter(|f| f.count == 1 && datatype::size(f.datatype).is_some())
        .map(|f| cloud.accessor(f));
    let mut ring = ring_acc.map(|_| Vec::with_capacity(n));
    for i in 0..n {
        let pt = cloud.point(i);
        xyz.push([ax.get(pt) as f32, ay.get(pt) as f32, az.get(pt) as f32]);
        if let (Some(a), Some(v)) = (&b.rgb, rgb.as_mut()) {
            v.push(unpack_rgb(a.bits32(pt)));
        }
        if let (Some(a), Some(v)) = (&ring_acc, ring.as_mut()) {
            let r = a.get(pt);
            v.push(if r.is_finite() && r >= 0.0 {
                r as u32
            } else {
                u32::MAX
            });
        }
    }
    let scan = ScanPoints {
        rows: cloud.height as usize,
        cols: cloud.width as usize,
        xyz: &xyz,
        rgb: rgb.as_deref(),
        ring: ring.as_deref(),
    };
    match seg.segment(scan) {
        Ok((labels, k)) if k < 1 << super::fields::SCAN_SEGMENT_BITS => {
            out.scan_segments = k;
            labels
        }
        Ok((_, k)) => {
            out.scan_unsegmented = Some(format!("{k} segments, more than a scan may have"));
            vec![0; n]
        }
        Err(e) => {
            out.scan_unsegmented = Some(e.to_string());
            vec![0; n]
        }
    }
}
