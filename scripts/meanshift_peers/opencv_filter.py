#!/usr/bin/env python3
"""Times OpenCV's mean-shift filter (cv2.pyrMeanShiftFiltering, one level: the joint
spatial-range filter with a flat kernel over a (2 SP + 1)^2 window and colour distance <= SR)
on the colour images of images.py, converted to 8-bit CIELab outside the timed region, one
image after another on one OpenCV thread.

Usage: opencv_filter.py RGB.raw SP SR MAX_ITER EPS RUNS
Prints per run: total seconds, median returns/s per scan.
"""
import statistics
import struct
import sys
import time

import cv2
import numpy as np


def main():
    path, sp, sr, max_iter, eps, runs = sys.argv[1:7]
    sp, sr, max_iter, eps, runs = int(sp), float(sr), int(max_iter), float(eps), int(runs)
    cv2.setNumThreads(1)
    imgs = []
    with open(path, "rb") as f:
        (n,) = struct.unpack("<i", f.read(4))
        for _ in range(n):
            h, w, returns = struct.unpack("<iii", f.read(12))
            rgb = np.frombuffer(f.read(h * w * 3), dtype=np.uint8).reshape(h, w, 3)
            imgs.append((cv2.cvtColor(np.ascontiguousarray(rgb), cv2.COLOR_RGB2LAB), returns))
    crit = (cv2.TERM_CRITERIA_MAX_ITER | cv2.TERM_CRITERIA_EPS, max_iter, eps)
    for _ in range(runs):
        total, rates = 0.0, []
        for lab, returns in imgs:
            t = time.perf_counter()
            cv2.pyrMeanShiftFiltering(lab, sp, sr, maxLevel=0, termcrit=crit)
            s = time.perf_counter() - t
            total += s
            rates.append(returns / s)
        print(f"opencv {cv2.__version__} sp {sp} sr {sr} max_iter {max_iter} eps {eps}: {len(imgs)} scans, "
              f"{sum(r for _, r in imgs)} returns, {total:.3f} s, median {statistics.median(rates) / 1e6:.2f} M "
              f"returns/s per scan, threads {cv2.getNumThreads()}")


if __name__ == "__main__":
    main()
