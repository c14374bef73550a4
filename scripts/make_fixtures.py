#!/usr/bin/env python3
"""Write LAS/LAZ fixtures with laspy (an implementation independent of tessera) for the
point formats the shared data does not cover: 6 and 7 (LAS 1.4), with every attribute set
to random values and extra-bytes attributes.

Usage: make_fixtures.py OUTDIR [N]
"""
import os
import sys

import laspy
import numpy as np

out = sys.argv[1]
n = int(sys.argv[2]) if len(sys.argv) > 2 else 20000
os.makedirs(out, exist_ok=True)
rng = np.random.default_rng(7)

for fmt in (6, 7):
    h = laspy.LasHeader(point_format=fmt, version="1.4")
    h.offsets = np.array([431000.0, 5390000.0, 100.0])
    h.scales = np.array([0.001, 0.001, 0.001])
    h.add_extra_dim(laspy.ExtraBytesParams(name="height", type=np.float64))
    h.add_extra_dim(laspy.ExtraBytesParams(name="label", type=np.uint16))
    las = laspy.LasData(h)
    las.x = 431000.0 + rng.uniform(0, 120, n)
    las.y = 5390000.0 + rng.uniform(0, 80, n)
    las.z = 100.0 + rng.uniform(-5, 30, n)
    las.intensity = rng.integers(0, 65535, n, dtype=np.uint16)
    rn = rng.integers(1, 16, n)
    las.return_number = rn
    las.number_of_returns = np.minimum(15, rn + rng.integers(0, 3, n))
    las.synthetic = rng.integers(0, 2, n).astype(bool)
    las.key_point = rng.integers(0, 2, n).astype(bool)
    las.withheld = rng.integers(0, 2, n).astype(bool)
    las.overlap = rng.integers(0, 2, n).astype(bool)
    las.scanner_channel = rng.integers(0, 4, n)
    las.scan_direction_flag = rng.integers(0, 2, n).astype(bool)
    las.edge_of_flight_line = rng.integers(0, 2, n).astype(bool)
    las.classification = rng.integers(0, 256, n, dtype=np.uint8)
    las.user_data = rng.integers(0, 256, n, dtype=np.uint8)
    las.scan_angle = rng.integers(-30000, 30000, n, dtype=np.int16)
    las.point_source_id = rng.integers(0, 65535, n, dtype=np.uint16)
    las.gps_time = rng.uniform(0, 1e6, n)
    if fmt == 7:
        las.red = rng.integers(0, 65535, n, dtype=np.uint16)
        las.green = rng.integers(0, 65535, n, dtype=np.uint16)
        las.blue = rng.integers(0, 65535, n, dtype=np.uint16)
    las.height = rng.normal(0, 10, n)
    las.label = rng.integers(0, 1000, n, dtype=np.uint16)
    las.write(os.path.join(out, f"pf{fmt}.laz"))
    las.write(os.path.join(out, f"pf{fmt}.las"))
print("ok")
