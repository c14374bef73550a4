#!/usr/bin/env python3
"""Baseline for scripts/bench_mcap.sh: MCAP -> points with the Python `mcap` reader and the
`mcap-ros2-support` / `mcap-ros1-support` decoders, then numpy for the point blob (x, y, z of
every point, counting those with finite coordinates) — the same work `tessera info` does on
every PointCloud2 (decompress, deserialise, read x/y/z of every point, count the valid ones).

Usage: mcap_decode_bench.py FILE.mcap   (prints "clouds points valid seconds")
"""
import sys
import time

import numpy as np
from mcap.reader import make_reader
from mcap_ros1.decoder import DecoderFactory as Ros1Decoders
from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

DT = {1: "i1", 2: "u1", 3: "i2", 4: "u2", 5: "i4", 6: "u4", 7: "f4", 8: "f8"}


def main():
    t0 = time.perf_counter()
    clouds = points = valid = 0
    with open(sys.argv[1], "rb") as f:
        reader = make_reader(f, decoder_factories=[Ros2Decoders(), Ros1Decoders()])
        for schema, _channel, _msg, m in reader.iter_decoded_messages():
            if schema is None or schema.name.replace("/msg/", "/") != "sensor_msgs/PointCloud2":
                continue
            order = ">" if m.is_bigendian else "<"
            xyz = [fl for fl in m.fields if fl.name in ("x", "y", "z")]
            dtype = np.dtype({
                "names": [fl.name for fl in xyz],
                "formats": [order + DT[fl.datatype] for fl in xyz],
                "offsets": [fl.offset for fl in xyz],
                "itemsize": m.point_step,
            })
            blob = bytes(m.data)
            for r in range(m.height):
                a = np.frombuffer(blob, dtype=dtype, count=m.width, offset=r * m.row_step)
                ok = np.isfinite(a["x"]) & np.isfinite(a["y"]) & np.isfinite(a["z"])
                valid += int(ok.sum())
            clouds += 1
            points += m.width * m.height
    print(clouds, points, valid, f"{time.perf_counter() - t0:.3f}")


if __name__ == "__main__":
    main()
