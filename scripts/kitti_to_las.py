#!/usr/bin/env python3
"""SemanticKITTI frames (.npy points + labels, as in ../shared/data/semantickitti-open3dml) to
LAS 1.4 point format 6 with the SemanticKITTI learning id (0-19) as the classification, for
`tessera run`, `tessera train` and `tessera eval labels --class-map config/semantickitti.toml`.

usage: kitti_to_las.py POINTS.npy LABELS.npy OUT.las [--x-range X0,X1]
"""
import sys

import laspy
import numpy as np


def main():
    args = sys.argv[1:]
    xr = None
    if "--x-range" in args:
        i = args.index("--x-range")
        xr = tuple(float(v) for v in args[i + 1].split(","))
        del args[i : i + 2]
    if len(args) != 3:
        sys.exit(__doc__)
    pts = np.load(args[0]).astype(np.float64)
    lab = np.load(args[1]).reshape(-1).astype(np.int64)
    if pts.ndim != 2 or pts.shape[1] < 3 or len(pts) != len(lab):
        sys.exit(f"{args[0]}: expected (N, 3) points and N labels")
    if xr is not None:
        keep = (pts[:, 0] >= xr[0]) & (pts[:, 0] < xr[1])
        pts, lab = pts[keep], lab[keep]
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.scales = np.array([0.001, 0.001, 0.001])
    h.offsets = np.floor(pts[:, :3].min(axis=0))
    las = laspy.LasData(h)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.classification = lab.astype(np.uint8)
    las.return_number = np.ones(len(pts), np.uint8)
    las.number_of_returns = np.ones(len(pts), np.uint8)
    las.write(args[2])
    print(f"{args[2]}: {len(pts)} points")


if __name__ == "__main__":
    main()
