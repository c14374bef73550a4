#!/usr/bin/env python3
"""Point-level agreement of two tessera output directories (e.g. main vs a change).

Usage: scripts/agreement.py OLD_DIR NEW_DIR

Points are matched by their integer coordinates and GPS time (tile names may differ when
splitting changes). Prints the share of points with the same classification and the share with
the same segmentation: a point agrees when its (old segment, new segment) pair is the largest
overlap of both its old and its new segment (ids themselves may differ). Points unsegmented
(id 0) in both agree. Exit 1 when the point sets differ.
"""
import glob, sys
import numpy as np
import laspy


def load(d):
    xs, cls, seg = [], [], []
    for f in sorted(glob.glob(f"{d}/*.laz") + glob.glob(f"{d}/*.las")):
        p = laspy.read(f)
        key = np.stack([p.X.astype(np.int64), p.Y.astype(np.int64), p.Z.astype(np.int64),
                        np.round(np.asarray(p.gps_time) * 1e6).astype(np.int64)], 1)
        xs.append(key)
        cls.append(np.asarray(p.classification))
        names = p.point_format.dimension_names
        seg.append(np.asarray(p["segment_id"]).astype(np.int64) if "segment_id" in names
                   else np.zeros(len(p), np.int64))
    k = np.concatenate(xs)
    order = np.lexsort(k.T[::-1])
    return k[order], np.concatenate(cls)[order], np.concatenate(seg)[order]


def main():
    ka, ca, sa = load(sys.argv[1])
    kb, cb, sb = load(sys.argv[2])
    if len(ka) != len(kb) or not np.array_equal(ka, kb):
        print(f"point sets differ: {len(ka)} vs {len(kb)} points")
        return 1
    n = len(ka)
    same_class = (ca == cb).mean()
    # Segment agreement by mutual best overlap.
    pair = sa * (sb.max() + 1) + sb
    up, inv, cnt = np.unique(pair, return_inverse=True, return_counts=True)
    pa, pb = up // (sb.max() + 1), up % (sb.max() + 1)
    best_a, best_b = {}, {}
    for i in np.argsort(-cnt, kind="stable"):
        best_a.setdefault(pa[i], i)
        best_b.setdefault(pb[i], i)
    mutual = np.zeros(len(up), bool)
    for a, i in best_a.items():
        if best_b.get(pb[i]) == i:
            mutual[i] = True
    both_zero = (pa == 0) & (pb == 0)
    agree = (mutual | both_zero)[inv]
    print(f"points: {n}")
    print(f"same classification: {100 * same_class:.3f} %")
    print(f"same segmentation (mutual best overlap): {100 * agree.mean():.3f} %")
    changed = ca != cb
    if changed.any():
        pairs, c = np.unique(np.stack([ca[changed], cb[changed]], 1), axis=0, return_counts=True)
        top = np.argsort(-c)[:8]
        print("class changes (old -> new: points): " +
              ", ".join(f"{pairs[i][0]}->{pairs[i][1]}: {c[i]}" for i in top))
    return 0


if __name__ == "__main__":
    sys.exit(main())
