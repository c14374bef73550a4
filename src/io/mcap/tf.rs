//! Poses: `tf2_msgs/TFMessage` and `nav_msgs/Odometry` decoding, and a transform tree that
//! answers "where was frame S in frame T at time t" through chains of static and timed
//! transforms, interpolating each timed link linearly (translation) and by slerp (rotation).
//!
//! Conventions (tf2's): a transform stamped with `header.frame_id = P`, `child_frame_id = C`
//! is the pose of C in P, i.e. it maps coordinates in C to coordinates in P. Every frame has
//! at most one parent. Frame names are compared without a leading `/` (ROS 1 tf allowed one).

use super::wire::{DResult, DecodeError, Encoding, Stamp, WireReader};
use nalgebra::{Isometry3, Quaternion, Translation3, UnitQuaternion};
use std::collections::HashMap;
use std::fmt;

/// A rigid transform.
pub type Iso = Isometry3<f64>;

/// One `geometry_msgs/TransformStamped` (or an odometry pose, or a trajectory row).
#[derive(Debug, Clone, PartialEq)]
pub struct TransformStamped {
    /// Time of validity.
    pub stamp: Stamp,
    /// Parent frame (`header.frame_id`).
    pub parent: String,
    /// Child frame.
    pub child: String,
    /// Pose of the child in the parent.
    pub iso: Iso,
}

/// Builds an isometry from a translation and an (x, y, z, w) quaternion, which must be
/// finite and non-zero (it is normalised).
pub fn iso_from(t: [f64; 3], q: [f64; 4]) -> Result<Iso, String> {
    let n = (q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]).sqrt();
    if !(n.is_finite() && n > 1e-9) || t.iter().any(|v| !v.is_finite()) {
        return Err(format!(
            "invalid pose: translation {t:?}, quaternion (x, y, z, w) {q:?}"
        ));
    }
    let uq = UnitQuaternion::from_quaternion(Quaternion::new(q[3], q[0], q[1], q[2]));
    Ok(Isometry3::from_parts(
        Translation3::new(t[0], t[1], t[2]),
        uq,
    ))
}

fn read_pose(r: &mut WireReader) -> DResult<Iso> {
    let t = [r.f64()?, r.f64()?, r.f64()?];
    let q = [r.f64()?, r.f64()?, r.f64()?, r.f64()?];
    iso_from(t, q).map_err(DecodeError)
}

/// Decodes a `tf2_msgs/TFMessage`.
pub fn decode_tf_message(buf: &[u8], enc: Encoding) -> DResult<Vec<TransformStamped>> {
    let mut r = WireReader::new(buf, enc)?;
    // Header (≥ 12 bytes) + child string (≥ 4) + 7 f64.
    let n = r.seq_len(72)?;
    let mut out = Vec::with_capacity(n);
    for _ in 0..n {
        let (stamp, parent) = r.header()?;
        let child = r.string()?;
        let iso = read_pose(&mut r)?;
        out.push(TransformStamped {
            stamp,
            parent: normalise(parent).to_string(),
            child: normalise(child).to_string(),
            iso,
        });
    }
    Ok(out)
}

/// Decodes the pose part of a `nav_msgs/Odometry` (the pose of `child_frame_id` in
/// `header.frame_id`; covariance and twist are not needed).
pub fn decode_odometry(buf: &[u8], enc: Encoding) -> DResult<TransformStamped> {
    let mut r = WireReader::new(buf, enc)?;
    let (stamp, parent) = r.header()?;
    let child = r.string()?;
    let iso = read_pose(&mut r)?;
    Ok(TransformStamped {
        stamp,
        parent: normalise(parent).to_string(),
        child: normalise(child).to_string(),
        iso,
    })
}

/// A frame name without a leading `/`.
pub fn normalise(frame: &str) -> &str {
    frame.trim_start_matches('/')
}

/// Spherical linear interpolation along the shorter arc (normalised linear interpolation when
/// the rotations are nearly equal, where slerp's formula loses precision).
pub fn slerp(a: &UnitQuaternion<f64>, b: &UnitQuaternion<f64>, s: f64) -> UnitQuaternion<f64> {
    let qa = a.quaternion().coords;
    let mut qb = b.quaternion().coords;
    let mut d = qa.dot(&qb);
    if d < 0.0 {
        qb = -qb;
        d = -d;
    }
    let v = if d > 0.9995 {
        qa * (1.0 - s) + qb * s
    } else {
        let th = d.min(1.0).acos();
        let sin = th.sin();
        qa * (((1.0 - s) * th).sin() / sin) + qb * ((s * th).sin() / sin)
    };
    UnitQuaternion::from_quaternion(Quaternion::from(v))
}

/// Interpolates two poses: translation linearly, rotation by slerp.
pub fn interpolate(a: &Iso, b: &Iso, s: f64) -> Iso {
    let t = a.translation.vector * (1.0 - s) + b.translation.vector * s;
    Isometry3::from_parts(Translation3::from(t), slerp(&a.rotation, &b.rotation, s))
}

/// How far pose lookups may reach.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Limits {
    /// Largest gap between the two samples around a time that is still interpolated, ns.
    pub max_gap_ns: i128,
    /// How far before the first / after the last sample the end sample is still used, ns.
    pub extrapolate_ns: i128,
}

#[derive(Debug, Clone)]
struct Edge {
    parent: usize,
    child: usize,
    fixed: Option<Iso>,
    samples: Vec<(i128, Iso)>,
}

/// Why a pose could not be found.
#[derive(Debug, Clone, PartialEq)]
pub enum PoseError {
    /// No chain of transforms connects the frames.
    NoChain(String),
    /// A timed link has no usable samples around the requested time.
    Missing {
        /// Parent frame of the link.
        parent: String,
        /// Child frame of the link.
        child: String,
        /// Requested time.
        at: Stamp,
        /// What is known about the link.
        detail: String,
    },
}

impl fmt::Display for PoseError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            PoseError::NoChain(s) => f.write_str(s),
            PoseError::Missing {
                parent,
                child,
                at,
                detail,
            } => write!(f, "no transform {parent} → {child} at {at}: {detail}"),
        }
    }
}

/// A resolved chain between two frames: links walked upwards from the source (applied as they
/// are) then downwards to the target (applied inverted).
#[derive(Debug, Clone, PartialEq)]
pub struct Chain {
    up: Vec<usize>,
    down: Vec<usize>,
    /// True if every link is static (one evaluation serves all times).
    pub is_static: bool,
}

/// The transform tree of a recording.
#[derive(Debug, Clone, Default)]
pub struct TfTree {
    names: HashMap<String, usize>,
    frames: Vec<String>,
    /// Edge to the parent, per frame.
    up: Vec<Option<usize>>,
    edges: Vec<Edge>,
}

impl TfTree {
    fn frame(&mut self, name: &str) -> usize {
        if let Some(&i) = self.names.get(name) {
            return i;
        }
        let i = self.frames.len();
        self.names.insert(name.to_string(), i);
        self.frames.push(name.to_string());
        self.up.push(None);
        i
    }

    /// Adds a transform; `fixed` for `/tf_static` (valid at every time). A frame given two
    /// different parents is an error, as in tf2.
    pub fn add(&mut self, t: &TransformStamped, fixed: bool) -> Result<(), String> {
        let (p, c) = (normalise(&t.parent), normalise(&t.child));
        if p == c {
            return Err(format!("transform from frame \"{p}\" to itself"));
        }
        let (pi, ci) = (self.frame(p), self.frame(c));
        let e = match self.up[ci] {
            Some(e) => {
                if self.edges[e].parent != pi {
                    return Err(format!(
                        "frame \"{c}\" has two parents: \"{}\" and \"{p}\"",
                        self.frames[self.edges[e].parent]
                    ));
                }
                e
            }
            None => {
                self.edges.push(Edge {
                    parent: pi,
                    child: ci,
                    fixed: None,
                    samples: Vec::new(),
                });
                self.up[ci] = Some(self.edges.len() - 1);
                self.edges.len() - 1
            }
        };
        let edge = &mut self.edges[e];
        if fixed {
            edge.fixed = Some(t.iso);
        } else {
            edge.samples.push((t.stamp.as_nanos(), t.iso));
        }
        Ok(())
    }

    /// Sorts the timed samples (recordings are not always in stamp order); for equal stamps
    /// the last one received wins.
    pub fn finish(&mut self) {
        for e in &mut self.edges {
            e.samples.sort_by_key(|s| s.0);
            let mut out: Vec<(i128, Iso)> = Vec::with_capacity(e.samples.len());
            for s in e.samples.drain(..) {
                match out.last_mut() {
                    Some(l) if l.0 == s.0 => *l = s,
                    _ => out.push(s),
                }
            }
            e.samples = out;
        }
    }

    /// Number of frames known.
    pub fn frame_count(&self) -> usize {
        self.frames.len()
    }

    /// Number of timed samples over all links.
    pub fn sample_count(&self) -> usize {
        self.edges.iter().map(|e| e.samples.len()).sum()
    }

    fn path_to_root(&self, mut f: usize) -> Vec<usize> {
        let mut path = vec![f];
        while let Some(e) = self.up[f] {
            f = self.edges[e].parent;
            if path.contains(&f) {
                break; // a cycle: stop (the lookup then fails with no common frame)
            }
            path.push(f);
        }
        path
    }

    /// Resolves the chain that maps `source` coordinates to `target` coordinates.
    pub fn chain(&self, target: &str, source: &str) -> Result<Chain, PoseError> {
        let (target, source) = (normalise(target), normalise(source));
        if target == source {
            return Ok(Chain {
                up: Vec::new(),
                down: Vec::new(),
                is_static: true,
            });
        }
        let known = |n: &str| self.names.get(n).copied();
        let list = || {
            let mut f = self.frames.clone();
            f.sort();
            if f.is_empty() {
                "none (no /tf, /tf_static or pose messages)".to_string()
            } else {
                f.join(", ")
            }
        };
        let s = known(source).ok_or_else(|| {
            PoseError::NoChain(format!(
                "frame \"{source}\" is not in the transform tree (frames: {})",
                list()
            ))
        })?;
        let t = known(target).ok_or_else(|| {
            PoseError::NoChain(format!(
                "target frame \"{target}\" is not in the transform tree (frames: {})",
                list()
            ))
        })?;
        let ps = self.path_to_root(s);
        let pt = self.path_to_root(t);
        let common = ps.iter().position(|f| pt.contains(f)).ok_or_else(|| {
            PoseError::NoChain(format!(
                "frames \"{source}\" and \"{target}\" are not connected (roots \"{}\" and \"{}\")",
                self.frames[*ps.last().unwrap_or(&s)],
                self.frames[*pt.last().unwrap_or(&t)]
            ))
        })?;
        let ct = pt.iter().position(|f| *f == ps[common]).unwrap_or(0);
        let edge_of = |f: &usize| self.up[*f];
        let up: Vec<usize> = ps[..common].iter().filter_map(edge_of).collect();
        let down: Vec<usize> = pt[..ct].iter().filter_map(edge_of).collect();
        let is_static = up
            .iter()
            .chain(down.iter())
            .all(|&e| self.edges[e].samples.is_empty());
        Ok(Chain {
            up,
            down,
            is_static,
        })
    }

    fn edge_at(&self, e: usize, t: i128, lim: &Limits) -> Result<Iso, PoseError> {
        let edge = &self.edges[e];
        let s = &edge.samples;
        if s.is_empty() {
            return edge
                .fixed
                .ok_or_else(|| PoseError::NoChain("empty link".into()));
        }
        let missing = |detail: String| PoseError::Missing {
            parent: self.frames[edge.parent].clone(),
            child: self.frames[edge.child].clone(),
            at: Stamp::from_nanos(t),
            detail,
        };
        let (first, last) = (s[0].0, s[s.len() - 1].0);
        if t < first || t > last {
            let (end, dist) = if t < first {
                (&s[0], first - t)
            } else {
                (&s[s.len() - 1], t - last)
            };
            if dist <= lim.extrapolate_ns {
                return Ok(end.1);
            }
            return Err(missing(format!(
                "{} samples cover {} .. {}; the time is {:.3} s outside",
                s.len(),
                Stamp::from_nanos(first),
                Stamp::from_nanos(last),
                dist as f64 * 1e-9
            )));
        }
        let i = s.partition_point(|x| x.0 <= t);
        if i == s.len() {
            return Ok(s[i - 1].1); // t == last
        }
        let (a, b) = (&s[i - 1], &s[i]);
        if b.0 - a.0 > lim.max_gap_ns {
            return Err(missing(format!(
                "samples at {} and {} are {:.3} s apart (limit {:.3} s)",
                Stamp::from_nanos(a.0),
                Stamp::from_nanos(b.0),
                (b.0 - a.0) as f64 * 1e-9,
                lim.max_gap_ns as f64 * 1e-9
            )));
        }
        let f = (t - a.0) as f64 / (b.0 - a.0) as f64;
        Ok(interpolate(&a.1, &b.1, f))
    }

    /// The transform mapping source to target coordinates at time `t` (ns since the epoch).
    pub fn eval(&self, chain: &Chain, t: i128, lim: &Limits) -> Result<Iso, PoseError> {
        let mut up = Iso::identity();
        for &e in &chain.up {
            up = self.edge_at(e, t, lim)? * up;
        }
        let mut down = Iso::identity();
        for &e in &chain.down {
            down = self.edge_at(e, t, lim)? * down;
        }
        Ok(down.inverse() * up)
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point3, Vector3};

    fn ts(sec: i64, parent: &str, child: &str, t: [f64; 3], yaw: f64) -> TransformStamped {
        let q = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), yaw);
        TransformStamped {
            stamp: Stamp { sec, nsec: 0 },
            parent: parent.into(),
            child: child.into(),
            iso: Isometry3::from_parts(Translation3::new(t[0], t[1], t[2]), q),
        }
    }

    const LIM: Limits = Limits {
        max_gap_ns: 5_000_000_000,
        extrapolate_ns: 0,
    };

    #[test]
    fn chain_with_static_mount_and_interpolated_motion() {
        let mut tf = TfTree::default();
        tf.add(&ts(10, "map", "base_link", [0.0, 0.0, 0.0], 0.0), false)
            .unwrap();
        tf.add(
            &ts(
                12,
                "/map",
                "base_link",
                [2.0, 0.0, 0.0],
                std::f64::consts::FRAC_PI_2,
            ),
            false,
        )
        .unwrap();
        tf.add(&ts(0, "base_link", "lidar", [0.0, 0.0, 1.5], 0.0), true)
            .unwrap();
        tf.finish();
        let c = tf.chain("map", "lidar").unwrap();
        assert!(!c.is_static);
        // At t = 11 s: base at x = 1, yaw 45°; a lidar point 1 m ahead lands at
        // (1 + cos45, sin45, 1.5).
        let p = tf.eval(&c, 11_000_000_000, &LIM).unwrap() * Point3::new(1.0, 0.0, 0.0);
        let h = std::f64::consts::FRAC_1_SQRT_2;
        assert!((p - Point3::new(1.0 + h, h, 1.5)).norm() < 1e-12, "{p}");
        // The inverse chain maps it back.
        let back = tf.chain("lidar", "map").unwrap();
        let q = tf.eval(&back, 11_000_000_000, &LIM).unwrap() * p;
        assert!((q - Point3::new(1.0, 0.0, 0.0)).norm() < 1e-12);
        // Outside the samples: an error naming the link and the time.
        let e = tf.eval(&c, 13_000_000_000, &LIM).unwrap_err().to_string();
        assert!(
            e.contains("map → base_link") && e.contains("13.000000000"),
            "{e}"
        );
        let lim = Limits {
            extrapolate_ns: 2_000_000_000,
            ..LIM
        };
        assert!(tf.eval(&c, 13_000_000_000, &lim).is_ok());
        let gap = Limits {
            max_gap_ns: 1_000_000_000,
            ..LIM
        };
        assert!(tf.eval(&c, 11_000_000_000, &gap).is_err());
    }

    #[test]
    fn sibling_frames_meet_at_their_common_parent() {
        let mut tf = TfTree::default();
        tf.add(&ts(0, "base", "a", [1.0, 0.0, 0.0], 0.0), true)
            .unwrap();
        tf.add(&ts(0, "base", "b", [0.0, 2.0, 0.0], 0.0), true)
            .unwrap();
        tf.finish();
        let c = tf.chain("b", "a").unwrap();
        assert!(c.is_static);
        let p = tf.eval(&c, 0, &LIM).unwrap() * Point3::origin();
        assert!((p - Point3::new(1.0, -2.0, 0.0)).norm() < 1e-12);
        assert!(tf.chain("a", "nowhere").is_err());
        assert!(tf
            .add(&ts(0, "other", "a", [0.0; 3], 0.0), true)
            .unwrap_err()
            .contains("two parents"));
    }

    #[test]
    fn slerp_takes_the_short_way_and_hits_the_ends() {
        let a = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.1);
        let b = UnitQuaternion::from_axis_angle(&Vector3::z_axis(), 0.9);
        let m = slerp(&a, &b, 0.5);
        assert!((m.angle() - 0.5).abs() < 1e-12);
        // -b is the same rotation; the midpoint must not swing the long way round.
        let nb = UnitQuaternion::new_unchecked(-b.into_inner());
        assert!(slerp(&a, &nb, 0.5).angle_to(&m) < 1e-12);
        assert!(slerp(&a, &b, 0.0).angle_to(&a) < 1e-12);
        assert!(slerp(&a, &b, 1.0).angle_to(&b) < 1e-12);
    }

    #[test]
    fn tf_message_round_trip_in_ros1() {
        let mut b = Vec::new();
        b.extend(1u32.to_le_bytes()); // one transform
        b.extend(0u32.to_le_bytes()); // seq
        b.extend(7u32.to_le_bytes());
        b.extend(9u32.to_le_bytes());
        b.extend(4u32.to_le_bytes());
        b.extend(b"/map");
        b.extend(4u32.to_le_bytes());
        b.extend(b"base");
        for v in [1.0f64, 2.0, 3.0, 0.0, 0.0, 0.0, 2.0] {
            b.extend(v.to_le_bytes());
        }
        let t = decode_tf_message(&b, Encoding::Ros1).unwrap();
        assert_eq!(t.len(), 1);
        assert_eq!((t[0].parent.as_str(), t[0].child.as_str()), ("map", "base"));
        assert_eq!(t[0].stamp, Stamp { sec: 7, nsec: 9 });
        assert_eq!(t[0].iso.translation.vector, Vector3::new(1.0, 2.0, 3.0));
        assert!(t[0].iso.rotation.angle() < 1e-12); // (0,0,0,2) normalised to identity
        b.truncate(b.len() - 8);
        assert!(decode_tf_message(&b, Encoding::Ros1).is_err());
    }
}
