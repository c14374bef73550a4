#!/usr/bin/env python3
"""Range and colour images of a drive's organised scans, for the mean-shift peers.

Reads the output of scripts/mcap_dump_clouds.py (one .npy per PointCloud2, rows = rings) and
writes to OUTDIR, scan after scan:
  rgb.raw    int32 scans, then per scan int32 height, width, int32 returns, and height x width
             x 3 bytes R, G, B (0 where the pixel has no return)
  range.raw  int32 scans, then per scan int32 height, width, int32 returns, height float32
             ring elevations (radians, the median over the ring's returns), and height x width
             float32 ranges (0 where the pixel has no return)

Usage: images.py DUMPDIR OUTDIR
"""
import json
import os
import struct
import sys

import numpy as np


def main():
    dump, out = sys.argv[1], sys.argv[2]
    os.makedirs(out, exist_ok=True)
    clouds = json.load(open(os.path.join(dump, "clouds.json")))
    with open(os.path.join(out, "rgb.raw"), "wb") as fr, open(os.path.join(out, "range.raw"), "wb") as fd:
        fr.write(struct.pack("<i", len(clouds)))
        fd.write(struct.pack("<i", len(clouds)))
        for c in clouds:
            a = np.load(os.path.join(dump, c["npy"]))
            h, w, cols = c["height"], c["width"], c["columns"]
            xyz = a[:, :3]
            ok = np.isfinite(xyz).all(axis=1)
            n = int(ok.sum())
            rng = np.where(ok, np.sqrt(np.nansum(xyz * xyz, axis=1)), 0.0)
            ok &= rng > 0
            # The packed float `rgb` field: its bits hold 0x00RRGGBB.
            bits = a[:, cols.index("rgb")].astype(np.float32).view(np.uint32)
            px = np.stack([(bits >> 16) & 255, (bits >> 8) & 255, bits & 255], axis=1).astype(np.uint8)
            px[~ok] = 0
            fr.write(struct.pack("<iii", h, w, n))
            fr.write(px.tobytes())
            elev = np.zeros(h, dtype=np.float32)
            z = np.where(ok, xyz[:, 2], 0.0)
            e = np.where(ok, np.arcsin(np.clip(z / np.where(ok, rng, 1.0), -1, 1)), np.nan).reshape(h, w)
            for r in range(h):
                v = e[r][np.isfinite(e[r])]
                elev[r] = np.median(v) if len(v) else np.nan
            good = np.isfinite(elev)
            if good.any() and not good.all():  # a ring without returns: interpolate its angle
                elev[~good] = np.interp(np.flatnonzero(~good), np.flatnonzero(good), elev[good])
            fd.write(struct.pack("<iii", h, w, n))
            fd.write(elev.tobytes())
            fd.write(np.where(ok, rng, 0.0).astype(np.float32).tobytes())


if __name__ == "__main__":
    main()
