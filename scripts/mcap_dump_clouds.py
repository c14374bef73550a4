#!/usr/bin/env python3
"""Independent PointCloud2 decoder (the oracle of tests/mcap_oracle.rs).

Reads an MCAP file with the Python `mcap` reader, deserialises every sensor_msgs/PointCloud2
with `rosbags` using the message definition stored in the file's own schema record (ROS 1
`ros1msg` or ROS 2 `ros2msg`/CDR), and unpacks the point blob with numpy structured dtypes
built from the message's field table (offsets, point_step padding, row_step, byte order).
No code is shared with tessera.

Writes to OUTDIR:
  clouds.json      one entry per cloud: topic, log time, stamp, frame, shape, steps, flags,
                   field table, and the .npy file holding its values
  cloud_NNNN.npy   float64 array, one row per point (row-major over height x width), one
                   column per scalar field in field-table order (every datatype is exact in
                   float64)

Usage: mcap_dump_clouds.py FILE.mcap OUTDIR
"""
import json
import os
import sys

import numpy as np
from mcap.reader import make_reader
from rosbags.typesys import Stores, get_typestore, get_types_from_msg

DT = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def full_name(name):
    return name if "/msg/" in name else name.replace("/", "/msg/", 1)


def main():
    path, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    store = get_typestore(Stores.EMPTY)
    registered = set()
    clouds = []
    with open(path, "rb") as f:
        reader = make_reader(f)
        for schema, channel, msg in reader.iter_messages():
            if schema is None or full_name(schema.name) != "sensor_msgs/msg/PointCloud2":
                continue
            if schema.id not in registered:
                types = get_types_from_msg(schema.data.decode(), full_name(schema.name))
                store.register(types)
                registered.add(schema.id)
            if channel.message_encoding == "ros1":
                m = store.deserialize_ros1(msg.data, "sensor_msgs/msg/PointCloud2")
            elif channel.message_encoding == "cdr":
                m = store.deserialize_cdr(msg.data, "sensor_msgs/msg/PointCloud2")
            else:
                raise SystemExit(f"{channel.topic}: unsupported encoding {channel.message_encoding}")
            order = ">" if m.is_bigendian else "<"
            scalar = [fl for fl in m.fields if fl.count == 1]
            dtype = np.dtype(
                {
                    "names": [fl.name for fl in scalar],
                    "formats": [order + DT[fl.datatype] for fl in scalar],
                    "offsets": [fl.offset for fl in scalar],
                    "itemsize": m.point_step,
                }
            )
            blob = np.asarray(m.data, dtype=np.uint8).tobytes()
            rows = []
            for r in range(m.height):
                start = r * m.row_step
                rows.append(np.frombuffer(blob, dtype=dtype, count=m.width, offset=start))
            pts = np.concatenate(rows) if rows else np.zeros(0, dtype=dtype)
            table = np.stack([pts[fl.name].astype(np.float64) for fl in scalar], axis=1)
            name = f"cloud_{len(clouds):04d}.npy"
            np.save(os.path.join(out, name), table)
            stamp = m.header.stamp
            clouds.append(
                {
                    "topic": channel.topic,
                    "log_time": msg.log_time,
                    "stamp_sec": int(stamp.sec),
                    "stamp_nsec": int(stamp.nanosec),
                    "frame_id": m.header.frame_id,
                    "height": int(m.height),
                    "width": int(m.width),
                    "point_step": int(m.point_step),
                    "row_step": int(m.row_step),
                    "is_bigendian": bool(m.is_bigendian),
                    "is_dense": bool(m.is_dense),
                    "fields": [[fl.name, int(fl.offset), int(fl.datatype), int(fl.count)] for fl in m.fields],
                    "columns": [fl.name for fl in scalar],
                    "npy": name,
                    "finite_xyz": int(np.isfinite(table[:, [c for c, fl in enumerate(scalar) if fl.name in ("x", "y", "z")]]).all(axis=1).sum()),
                }
            )
    with open(os.path.join(out, "clouds.json"), "w") as f:
        json.dump(clouds, f, indent=1)
    print(f"{len(clouds)} clouds, {sum(c['height'] * c['width'] for c in clouds)} points")


if __name__ == "__main__":
    main()
