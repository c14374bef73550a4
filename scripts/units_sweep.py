#!/usr/bin/env python3
"""Feet against metres on every ISPRS sample (issue 23): each sample is rewritten in US survey
feet (EPSG:2903 GeoTIFF key, coordinates at RESOLUTION ft), both are run through the ground
filter (airborne preset), and the points classified differently are counted. With --noise,
the metre file is also run with uniform noise of half the feet rounding on its coordinates:
the filter's own sensitivity to sub-millimetre changes, the floor any unit conversion meets.

    python3 scripts/units_sweep.py [--bin target/release/tessera] [--resolution 0.001] [--noise]
"""
import argparse
import glob
import os
import shutil
import struct
import subprocess
import sys
import tempfile

import laspy
import numpy as np

US_FOOT = 1200 / 3937
SAMPLES = ["samp11", "samp12", "samp21", "samp22", "samp23", "samp24", "samp31", "samp41",
           "samp42", "samp51", "samp52", "samp53", "samp54", "samp61", "samp71"]


def classes(d, unit):
    m = {}
    for t in sorted(glob.glob(os.path.join(d, "*.la[sz]"))):
        las = laspy.read(t)
        k = np.round(np.vstack([las.x, las.y, las.z]).T * unit * 100).astype(np.int64)
        m.update(zip(map(tuple, k), las.classification))
    return m


def rewrite(las, path, unit, resolution, epsg, noise=0.0, seed=1):
    h = laspy.LasHeader(point_format=las.header.point_format.id, version="1.2")
    h.scales = np.array([resolution] * 3)
    h.offsets = np.array([round(las.header.mins[0] / unit, -3),
                          round(las.header.mins[1] / unit, -3), 0.0])
    keys = [1, 1, 0, 2, 1024, 0, 1, 1, 3072, 0, 1, epsg]
    h.vlrs.append(laspy.VLR("LASF_Projection", 34735, "", struct.pack(f"<{len(keys)}H", *keys)))
    out = laspy.LasData(h)
    rng = np.random.default_rng(seed)
    for axis in "xyz":
        v = np.asarray(getattr(las, axis)) / unit
        setattr(out, axis, v + rng.uniform(-noise, noise, len(v)))
    out.classification = las.classification
    out.write(path)


def run(b, cfg, src, out):
    shutil.rmtree(out, ignore_errors=True)
    subprocess.run([b, "-q", "run", src, "--out", out, "--config", cfg], check=True)


def main():
    here = os.path.dirname(os.path.abspath(__file__))
    ap = argparse.ArgumentParser()
    ap.add_argument("--bin", default=os.path.join(here, "..", "target", "release", "tessera"))
    ap.add_argument("--data", default=os.environ.get("TESSERA_DATA",
                                                     os.path.join(here, "..", "..", "shared", "data")))
    ap.add_argument("--resolution", type=float, default=0.001, help="feet file scale, ft")
    ap.add_argument("--noise", action="store_true")
    a = ap.parse_args()
    cfg = os.path.join(here, "..", "config", "airborne.toml")
    total = [0, 0, 0]
    with tempfile.TemporaryDirectory() as d:
        print(f"{'sample':8} {'points':>7} {'feet':>12}" + (f" {'noise floor':>14}" if a.noise else ""))
        for s in SAMPLES:
            src = os.path.join(a.data, "isprs-filtertest", f"{s}-utm.laz")
            las = laspy.read(src)
            run(a.bin, cfg, src, f"{d}/m")
            ref = classes(f"{d}/m", 1.0)
            rewrite(las, f"{d}/ft.laz", US_FOOT, a.resolution, 2903)
            run(a.bin, cfg, f"{d}/ft.laz", f"{d}/ft")
            ft = classes(f"{d}/ft", US_FOOT)
            n = len(ref)
            diff = sum(1 for k, c in ref.items() if ft.get(k) != c)
            line = f"{s:8} {n:7} {diff:5} {100 * diff / n:5.2f} %"
            total[0] += n
            total[1] += diff
            if a.noise:
                half = a.resolution * US_FOOT / 2
                rewrite(las, f"{d}/mn.laz", 1.0, 0.0001, 32632, noise=half)
                run(a.bin, cfg, f"{d}/mn.laz", f"{d}/mn")
                mn = classes(f"{d}/mn", 1.0)
                nd = sum(1 for k, c in ref.items() if mn.get(k) != c)
                total[2] += nd
                line += f" {nd:6} {100 * nd / n:5.2f} %"
            print(line, flush=True)
    print(f"all {total[0]:7} {total[1]:5} {100 * total[1] / total[0]:5.2f} %"
          + (f" {total[2]:6} {100 * total[2] / total[0]:5.2f} %" if a.noise else ""))
    return 0


if __name__ == "__main__":
    sys.exit(main())
