#!/usr/bin/env python3
"""Genuine ROS 2 (CDR) MCAP fixtures written by independent writers, with expected values.

Writers: `mcap-ros2-support` (mcap_ros2.writer, CDR little-endian) and `rosbags`
(serialize_cdr with little_endian=False, i.e. CDR big-endian encapsulation) inside the Python
`mcap` container writer. Nothing here shares code with tessera; the expected world
coordinates are computed with numpy (own quaternion algebra, linear + slerp interpolation).

Files written to OUTDIR:
  drive_le.mcap      CDR_LE, zstd chunks (several): /points (unorganised 1 x 240, point_step
                     32 with padding, x/y/z/intensity FLOAT32, ring UINT16, time FLOAT32 offset
                     in s, rgb packed FLOAT32, is_dense false with NaN points), /tf (map ->
                     base_link moving and turning, 20 Hz, plus an unrelated odom -> wheel link in
                     the same messages), /tf_static (base_link -> lidar, rotated mount),
                     /odom (nav_msgs/Odometry with the same poses)
  trajectory.csv     the same poses, "time,x,y,z,qx,qy,qz,qw"
  organised_be.mcap  CDR_BE encapsulation and big-endian point blob: /cloud_be (organised
                     3 x 5, point_step 40, row_step 208 with row padding, x/y/z FLOAT64,
                     intensity UINT16, ring UINT8, flag INT8, t UINT32 ns, label INT16,
                     code INT32, frame "map"); plus /cloud_le_msg_be_blob (the same cloud in a
                     CDR_LE message, blob still big-endian) and /cloud_lz4 in an lz4 chunk file
  expected.json      per cloud: topic, stamp, frame, shape, column names, raw values file,
                     world-coordinate files (deskewed and at the cloud stamp) where poses apply

Usage: mcap_make_ros2_fixtures.py OUTDIR
"""
import json
import math
import os
import sys

import numpy as np
from mcap.writer import CompressionType, Writer as McapWriter
from mcap_ros2.writer import Writer as Ros2Writer
from rosbags.typesys import Stores, get_typestore

T0 = 1_700_000_000  # seconds; all stamps are T0 + something

HEADER = "builtin_interfaces/Time stamp\nstring frame_id\n"
SEP = "=" * 80 + "\n"
POINTCLOUD2 = (
    "std_msgs/Header header\nuint32 height\nuint32 width\nsensor_msgs/PointField[] fields\n"
    "bool is_bigendian\nuint32 point_step\nuint32 row_step\nuint8[] data\nbool is_dense\n"
    + SEP + "MSG: std_msgs/Header\n" + HEADER
    + SEP + "MSG: sensor_msgs/PointField\nuint8 INT8=1\nuint8 UINT8=2\nuint8 INT16=3\n"
    "uint8 UINT16=4\nuint8 INT32=5\nuint8 UINT32=6\nuint8 FLOAT32=7\nuint8 FLOAT64=8\n"
    "string name\nuint32 offset\nuint8 datatype\nuint32 count\n"
)
VEC3 = "float64 x\nfloat64 y\nfloat64 z\n"
QUAT = "float64 x\nfloat64 y\nfloat64 z\nfloat64 w\n"
TFMESSAGE = (
    "geometry_msgs/TransformStamped[] transforms\n"
    + SEP + "MSG: geometry_msgs/TransformStamped\nstd_msgs/Header header\nstring child_frame_id\n"
    "geometry_msgs/Transform transform\n"
    + SEP + "MSG: std_msgs/Header\n" + HEADER
    + SEP + "MSG: geometry_msgs/Transform\ngeometry_msgs/Vector3 translation\n"
    "geometry_msgs/Quaternion rotation\n"
    + SEP + "MSG: geometry_msgs/Vector3\n" + VEC3
    + SEP + "MSG: geometry_msgs/Quaternion\n" + QUAT
)
ODOMETRY = (
    "std_msgs/Header header\nstring child_frame_id\ngeometry_msgs/PoseWithCovariance pose\n"
    "geometry_msgs/TwistWithCovariance twist\n"
    + SEP + "MSG: std_msgs/Header\n" + HEADER
    + SEP + "MSG: geometry_msgs/PoseWithCovariance\ngeometry_msgs/Pose pose\nfloat64[36] covariance\n"
    + SEP + "MSG: geometry_msgs/Pose\ngeometry_msgs/Point position\ngeometry_msgs/Quaternion orientation\n"
    + SEP + "MSG: geometry_msgs/Point\n" + VEC3
    + SEP + "MSG: geometry_msgs/Quaternion\n" + QUAT
    + SEP + "MSG: geometry_msgs/TwistWithCovariance\ngeometry_msgs/Twist twist\nfloat64[36] covariance\n"
    + SEP + "MSG: geometry_msgs/Twist\ngeometry_msgs/Vector3 linear\ngeometry_msgs/Vector3 angular\n"
    + SEP + "MSG: geometry_msgs/Vector3\n" + VEC3
)


# --- quaternion algebra (x, y, z, w) ------------------------------------------------------
def q_from_euler(roll, pitch, yaw):
    cr, sr = math.cos(roll / 2), math.sin(roll / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    return np.array([
        sr * cp * cy - cr * sp * sy,
        cr * sp * cy + sr * cp * sy,
        cr * cp * sy - sr * sp * cy,
        cr * cp * cy + sr * sp * sy,
    ])


def q_mul(a, b):
    ax, ay, az, aw = a
    bx, by, bz, bw = b
    return np.array([
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
        aw * bw - ax * bx - ay * by - az * bz,
    ])


def q_rotate(q, v):
    """Rotate rows of v (N x 3) by unit quaternion q."""
    u, w = q[:3], q[3]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


def q_slerp(a, b, s):
    d = float(np.dot(a, b))
    if d < 0:
        b, d = -b, -d
    if d > 0.9995:
        r = a * (1 - s) + b * s
    else:
        th = math.acos(min(d, 1.0))
        r = (math.sin((1 - s) * th) * a + math.sin(s * th) * b) / math.sin(th)
    return r / np.linalg.norm(r)


# --- the drive ----------------------------------------------------------------------------
def base_pose(t):
    """Pose of base_link in map at t seconds after T0."""
    p = np.array([3.0 * t + 0.2 * t * t, 0.5 * math.sin(t), 0.1 * t])
    q = q_from_euler(0.0, 0.02 * math.sin(2 * t), 0.3 * t)
    return p, q / np.linalg.norm(q)


MOUNT_T = np.array([0.5, 0.1, 1.8])
MOUNT_Q = q_from_euler(0.05, -0.1, math.pi / 2)
MOUNT_Q = MOUNT_Q / np.linalg.norm(MOUNT_Q)
TF_TIMES_NS = [int(round(k * 0.05 * 1e9)) for k in range(0, 41)]  # 0 .. 2 s at 20 Hz


def pose_at_ns(t_ns):
    """map <- base_link at t_ns (ns after T0), interpolated like tf2 between 20 Hz samples."""
    i = max(j for j, s in enumerate(TF_TIMES_NS) if s <= t_ns)
    if TF_TIMES_NS[i] == t_ns or i == len(TF_TIMES_NS) - 1:
        return base_pose(TF_TIMES_NS[i] * 1e-9)
    a, b = TF_TIMES_NS[i], TF_TIMES_NS[i + 1]
    f = (t_ns - a) / (b - a)
    pa, qa = base_pose(a * 1e-9)
    pb, qb = base_pose(b * 1e-9)
    return pa * (1 - f) + pb * f, q_slerp(qa, qb, f)


def world(points, t_ns):
    """World coordinates of lidar-frame points observed at t_ns (one time per point)."""
    out = np.empty_like(points)
    for k, (pt, tn) in enumerate(zip(points, t_ns)):
        p, q = pose_at_ns(int(tn))
        in_base = q_rotate(MOUNT_Q, pt[None, :])[0] + MOUNT_T
        out[k] = q_rotate(q, in_base[None, :])[0] + p
    return out


def stamp(ns_after_t0):
    total = T0 * 1_000_000_000 + ns_after_t0
    return {"sec": total // 1_000_000_000, "nanosec": total % 1_000_000_000}


def header(ns_after_t0, frame):
    return {"stamp": stamp(ns_after_t0), "frame_id": frame}


def tf_msg(ns, parent, child, p, q):
    return {
        "header": header(ns, parent),
        "child_frame_id": child,
        "transform": {
            "translation": {"x": p[0], "y": p[1], "z": p[2]},
            "rotation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
        },
    }


def field(name, offset, datatype, count=1):
    return {"name": name, "offset": offset, "datatype": datatype, "count": count}


def write_drive(out, rng, expected):
    path = os.path.join(out, "drive_le.mcap")
    with open(path, "wb") as f:
        w = Ros2Writer(f, chunk_size=64 * 1024, compression=CompressionType.ZSTD)
        s_pc = w.register_msgdef("sensor_msgs/msg/PointCloud2", POINTCLOUD2)
        s_tf = w.register_msgdef("tf2_msgs/msg/TFMessage", TFMESSAGE)
        s_od = w.register_msgdef("nav_msgs/msg/Odometry", ODOMETRY)
        log0 = T0 * 1_000_000_000
        static = {"transforms": [tf_msg(0, "base_link", "lidar", MOUNT_T, MOUNT_Q)]}
        w.write_message("/tf_static", s_tf, static, log_time=log0, publish_time=log0)
        events = []
        for tn in TF_TIMES_NS:
            events.append((tn, "tf", None))
        cloud_times = [int(round((0.1 + 0.1 * k) * 1e9)) for k in range(17)]  # 0.1 .. 1.7 s
        for tn in cloud_times:
            events.append((tn + 90_000_000, "cloud", tn))  # logged when the sweep ends
        events.sort(key=lambda e: (e[0], e[1]))
        n = 240
        dtype = np.dtype({
            "names": ["x", "y", "z", "intensity", "ring", "time", "rgb"],
            "formats": ["<f4", "<f4", "<f4", "<f4", "<u2", "<f4", "<u4"],
            "offsets": [0, 4, 8, 16, 20, 24, 28],
            "itemsize": 32,
        })
        for log_ns, kind, cn in events:
            if kind == "tf":
                p, q = base_pose(log_ns * 1e-9)
                wheel = tf_msg(log_ns, "odom", "wheel", [0.0, 0.0, 0.3], q_from_euler(0, log_ns * 1e-9, 0))
                msg = {"transforms": [wheel, tf_msg(log_ns, "map", "base_link", p, q)]}
                w.write_message("/tf", s_tf, msg, log_time=log0 + log_ns, publish_time=log0 + log_ns)
                odom = {
                    "header": header(log_ns, "map"),
                    "child_frame_id": "base_link",
                    "pose": {
                        "pose": {
                            "position": {"x": p[0], "y": p[1], "z": p[2]},
                            "orientation": {"x": q[0], "y": q[1], "z": q[2], "w": q[3]},
                        },
                        "covariance": [0.0] * 36,
                    },
                    "twist": {
                        "twist": {"linear": {"x": 0.0, "y": 0.0, "z": 0.0}, "angular": {"x": 0.0, "y": 0.0, "z": 0.0}},
                        "covariance": [0.0] * 36,
                    },
                }
                w.write_message("/odom", s_od, odom, log_time=log0 + log_ns, publish_time=log0 + log_ns)
                continue
            az = rng.uniform(-math.pi, math.pi, n)
            el = rng.uniform(-0.4, 0.3, n)
            rr = rng.uniform(2.0, 40.0, n)
            pts = np.stack([rr * np.cos(el) * np.cos(az), rr * np.cos(el) * np.sin(az), rr * np.sin(el)], axis=1)
            a = np.zeros(n, dtype=dtype)
            a["x"], a["y"], a["z"] = pts[:, 0], pts[:, 1], pts[:, 2]
            a["intensity"] = rng.uniform(0, 3000, n).astype(np.float32)
            a["ring"] = rng.integers(0, 128, n)
            a["time"] = np.sort(rng.uniform(0, 0.09, n)).astype(np.float32)
            a["rgb"] = rng.integers(0, 1 << 24, n)
            bad = rng.random(n) < 0.05
            a["x"][bad] = np.nan
            blob = bytearray(a.tobytes())
            # Padding bytes (12..16 of every point) hold garbage, as real drivers leave them.
            for k in range(n):
                blob[k * 32 + 12: k * 32 + 16] = bytes(rng.integers(0, 256, 4, dtype=np.uint8))
            msg = {
                "header": header(cn, "lidar"),
                "height": 1,
                "width": n,
                "fields": [
                    field("x", 0, 7), field("y", 4, 7), field("z", 8, 7), field("intensity", 16, 7),
                    field("ring", 20, 4), field("time", 24, 7), field("rgb", 28, 7),
                ],
                "is_bigendian": False,
                "point_step": 32,
                "row_step": 32 * n,
                "data": bytes(blob),
                "is_dense": False,
            }
            w.write_message("/points", s_pc, msg, log_time=log0 + log_ns, publish_time=log0 + log_ns)
            k = len(expected)
            cols = ["x", "y", "z", "intensity", "ring", "time", "rgb"]
            raw = np.stack([a[c].astype(np.float64) for c in cols], axis=1)
            np.save(os.path.join(out, f"raw_{k:03d}.npy"), raw)
            ok = ~np.isnan(a["x"])
            xyz = np.stack([a["x"], a["y"], a["z"]], axis=1).astype(np.float64)[ok]
            t_pt = np.array([cn + math.floor(float(v) * 1e9 + 0.5) for v in a["time"][ok]], dtype=np.int64)
            np.save(os.path.join(out, f"world_deskew_{k:03d}.npy"), world(xyz, t_pt))
            np.save(os.path.join(out, f"world_stamp_{k:03d}.npy"), world(xyz, np.full(len(xyz), cn)))
            np.save(os.path.join(out, f"time_{k:03d}.npy"), (t_pt + T0 * 1_000_000_000).astype(np.int64))
            expected.append({
                "file": "drive_le.mcap", "topic": "/points", "stamp_ns": log0 + cn, "frame_id": "lidar",
                "height": 1, "width": n, "point_step": 32, "row_step": 32 * n, "is_bigendian": False,
                "is_dense": False, "columns": cols, "raw": f"raw_{k:03d}.npy",
                "world_deskew": f"world_deskew_{k:03d}.npy", "world_stamp": f"world_stamp_{k:03d}.npy",
                "time_ns": f"time_{k:03d}.npy",
            })
        w.finish()
    with open(os.path.join(out, "trajectory.csv"), "w") as f:
        f.write("time,x,y,z,qx,qy,qz,qw\n")
        for tn in TF_TIMES_NS:
            p, q = base_pose(tn * 1e-9)
            total = T0 * 1_000_000_000 + tn
            f.write(f"{total // 1_000_000_000}.{total % 1_000_000_000:09d},"
                    + ",".join(repr(float(v)) for v in list(p) + list(q)) + "\n")


def organised_cloud(rng):
    h, wd, step, row = 3, 5, 40, 208
    dtype = np.dtype({
        "names": ["x", "y", "z", "intensity", "ring", "flag", "t", "label", "code"],
        "formats": [">f8", ">f8", ">f8", ">u2", "u1", "i1", ">u4", ">i2", ">i4"],
        "offsets": [0, 8, 16, 24, 26, 27, 28, 32, 36],
        "itemsize": step,
    })
    a = np.zeros(h * wd, dtype=dtype)
    a["x"] = rng.uniform(-50, 50, h * wd)
    a["y"] = rng.uniform(-50, 50, h * wd)
    a["z"] = rng.uniform(-3, 10, h * wd)
    a["intensity"] = rng.integers(0, 65536, h * wd)
    a["ring"] = rng.integers(0, 256, h * wd)
    a["flag"] = rng.integers(-128, 128, h * wd)
    a["t"] = rng.integers(0, 100_000_000, h * wd)
    a["label"] = rng.integers(-32768, 32768, h * wd)
    a["code"] = rng.integers(-2**31, 2**31, h * wd)
    a["x"][4] = np.nan  # one invalid point in an organised cloud
    blob = bytearray()
    for r in range(h):
        blob += a[r * wd:(r + 1) * wd].tobytes()
        blob += bytes([0xEE] * (row - wd * step))
    fields = [
        ("x", 0, 8), ("y", 8, 8), ("z", 16, 8), ("intensity", 24, 4), ("ring", 26, 2),
        ("flag", 27, 1), ("t", 28, 6), ("label", 32, 3), ("code", 36, 5),
    ]
    cols = [f[0] for f in fields]
    raw = np.stack([a[c].astype(np.float64) for c in cols], axis=1)
    return h, wd, step, row, bytes(blob), fields, cols, raw


def write_organised(out, rng, expected):
    store = get_typestore(Stores.ROS2_HUMBLE)
    PC2 = store.types["sensor_msgs/msg/PointCloud2"]
    PF = store.types["sensor_msgs/msg/PointField"]
    Hdr = store.types["std_msgs/msg/Header"]
    Time = store.types["builtin_interfaces/msg/Time"]
    for fname, compression in (("organised_be.mcap", CompressionType.ZSTD), ("organised_lz4.mcap", CompressionType.LZ4)):
        path = os.path.join(out, fname)
        with open(path, "wb") as f:
            w = McapWriter(f, compression=compression)
            w.start(profile="ros2", library="tessera fixtures (rosbags serialize_cdr)")
            sid = w.register_schema("sensor_msgs/msg/PointCloud2", "ros2msg", POINTCLOUD2.encode())
            topics = [("/cloud_be", False)] if fname == "organised_be.mcap" else [("/cloud_lz4", True)]
            if fname == "organised_be.mcap":
                topics.append(("/cloud_le_msg_be_blob", True))
            chans = {t: w.register_channel(t, "cdr", sid) for t, _ in topics}
            for k in range(2):
                h, wd, step, row, blob, fields, cols, raw = organised_cloud(rng)
                ns = 500_000_000 + k * 100_000_000
                st = stamp(ns)
                msg = PC2(
                    header=Hdr(stamp=Time(sec=st["sec"], nanosec=st["nanosec"]), frame_id="map"),
                    height=h, width=wd,
                    fields=[PF(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
                    is_bigendian=True, point_step=step, row_step=row,
                    data=np.frombuffer(blob, dtype=np.uint8), is_dense=False,
                )
                for topic, little in topics:
                    data = bytes(store.serialize_cdr(msg, "sensor_msgs/msg/PointCloud2", little_endian=little))
                    assert data[1] == (1 if little else 0)
                    log = T0 * 1_000_000_000 + ns
                    w.add_message(chans[topic], log_time=log, publish_time=log, data=data, sequence=k)
                    e = len(expected)
                    np.save(os.path.join(out, f"raw_{e:03d}.npy"), raw)
                    expected.append({
                        "file": fname, "topic": topic, "stamp_ns": T0 * 1_000_000_000 + ns, "frame_id": "map",
                        "height": h, "width": wd, "point_step": step, "row_step": row, "is_bigendian": True,
                        "is_dense": False, "columns": cols, "raw": f"raw_{e:03d}.npy",
                    })
            w.finish()


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    rng = np.random.default_rng(20240607)
    expected = []
    write_drive(out, rng, expected)
    write_organised(out, rng, expected)
    with open(os.path.join(out, "expected.json"), "w") as f:
        json.dump({"t0": T0, "clouds": expected}, f, indent=1)
    print(f"{len(expected)} clouds written to {out}")


if __name__ == "__main__":
    main()
