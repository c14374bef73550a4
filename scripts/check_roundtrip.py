#!/usr/bin/env python3
"""Independent round-trip check with laspy: the multiset of points over all output tiles
must equal the multiset of input points, on every dimension of the input (extra bytes too).

Usage: check_roundtrip.py OUTDIR INPUT [INPUT ...]
Exit 0 when equal, 1 with a message naming the first differing dimension otherwise.
"""
import glob
import os
import sys

import laspy
import numpy as np

outdir, inputs = sys.argv[1], sys.argv[2:]


def load(paths):
    parts = [laspy.read(p) for p in paths]
    dims = list(parts[0].point_format.dimension_names)
    cols = {d: np.concatenate([np.asarray(p[d]) for p in parts]) for d in dims}
    return dims, cols


dims_in, a = load(inputs)
tiles = sorted(glob.glob(os.path.join(outdir, "*.laz")) + glob.glob(os.path.join(outdir, "*.las")))
if not tiles:
    print(f"no output tiles in {outdir}")
    sys.exit(1)
dims_out, b = load(tiles)
missing = [d for d in dims_in if d not in dims_out]
if missing:
    print(f"output lacks dimensions {missing}")
    sys.exit(1)
n_in, n_out = len(a[dims_in[0]]), len(b[dims_in[0]])
if n_in != n_out:
    print(f"point count differs: {n_in} in, {n_out} out")
    sys.exit(1)
keys_a = [a[d].astype(np.float64) for d in reversed(dims_in)]
keys_b = [b[d].astype(np.float64) for d in reversed(dims_in)]
ia, ib = np.lexsort(keys_a), np.lexsort(keys_b)
for d in dims_in:
    if not np.array_equal(a[d][ia], b[d][ib]):
        k = int(np.argmax(a[d][ia] != b[d][ib]))
        print(f"dimension {d} differs (first at sorted row {k}: {a[d][ia][k]} vs {b[d][ib][k]})")
        sys.exit(1)
print(f"ok: {n_in} points, {len(dims_in)} dimensions equal across {len(tiles)} tiles")
