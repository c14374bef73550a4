#!/usr/bin/env python3
"""Independent COPC check with laspy's CopcReader (lazrs backend).

Usage: check_copc.py LAZ_DIR COPC_DIR [QUERIES]

For every tile NAME.copc.laz in COPC_DIR and its plain counterpart NAME.laz (or .las) in
LAZ_DIR, written by the same run with output.format = "laz":
  - CopcReader.query() returns every point: the multiset of records equals the LAZ tile's on
    every dimension the LAZ tile has (extra bytes too), and the header counts agree;
  - the levels partition the points: the level queries together return each point once;
  - bounds queries (QUERIES random boxes per tile, default 12, plus boxes whose faces lie on
    the root's centre planes, where nodes meet) return exactly the LAZ points inside,
    computed with laspy's own rule (bounds rounded to the integer grid, inclusive).
Exit 0 when all hold; 1 with a message naming the tile and the first failure otherwise.
"""
import glob
import os
import sys

import laspy
import numpy as np
from laspy.copc import Bounds

laz_dir, copc_dir = sys.argv[1], sys.argv[2]
queries = int(sys.argv[3]) if len(sys.argv) > 3 else 12


def fail(msg):
    print(msg)
    sys.exit(1)


def columns(points, dims):
    return {d: np.asarray(points[d]) for d in dims}


def sorted_cols(cols, dims):
    if len(cols[dims[0]]) == 0:
        return cols
    order = np.lexsort([cols[d] for d in reversed(dims)])
    return {d: cols[d][order] for d in dims}


def same(a, b, dims, what):
    for d in dims:
        if len(a[d]) != len(b[d]):
            fail(f"{what}: {len(b[d])} points, expected {len(a[d])}")
        if not np.array_equal(a[d], b[d]):
            k = int(np.argmax(a[d] != b[d]))
            fail(f"{what}: dimension {d} differs at sorted row {k}: {b[d][k]} != {a[d][k]}")


tiles = sorted(glob.glob(os.path.join(copc_dir, "*.copc.laz")))
if not tiles:
    fail(f"no .copc.laz tiles in {copc_dir}")
rng = np.random.default_rng(24)
total = nodes = nq = inside = 0
for path in tiles:
    name = os.path.basename(path)[: -len(".copc.laz")]
    plain = [p for p in (os.path.join(laz_dir, name + e) for e in (".laz", ".las")) if os.path.exists(p)]
    if not plain:
        fail(f"{name}: no plain tile in {laz_dir}")
    ref = laspy.read(plain[0])
    with laspy.CopcReader.open(path) as r:
        hdr = r.header
        if hdr.point_format.id not in (6, 7, 8):
            fail(f"{name}: point format {hdr.point_format.id}")
        dims = [d for d in ref.point_format.dimension_names if d in set(hdr.point_format.dimension_names)]
        missing = set(ref.point_format.dimension_names) - set(dims)
        # Legacy formats name the scan angle differently; nothing else may be missing.
        if missing - {"scan_angle_rank"}:
            fail(f"{name}: COPC tile lacks {sorted(missing)}")
        want = sorted_cols(columns(ref.points, dims), dims)
        got_all = r.query()
        if hdr.point_count != len(ref.points) or len(got_all) != len(ref.points):
            fail(f"{name}: header {hdr.point_count}, query {len(got_all)}, LAZ {len(ref.points)}")
        same(want, sorted_cols(columns(got_all, dims), dims), dims, f"{name}: all points")
        entries = r.root_page.entries
        nodes += len(entries)
        depth = max(k.level for k in entries)
        by_level = [r.query(level=lv) for lv in range(depth + 1)]
        if sum(len(p) for p in by_level) != len(ref.points):
            fail(f"{name}: levels hold {sum(len(p) for p in by_level)} points, tile {len(ref.points)}")
        # Bounds queries.
        X, Y, Z = (np.asarray(ref.points[c]) for c in ("X", "Y", "Z"))
        mins, maxs = np.array(hdr.mins), np.array(hdr.maxs)
        c = np.array(r.copc_info.center)
        boxes = []
        for _ in range(queries):
            a = mins + rng.random(3) * (maxs - mins)
            b = a + rng.random(3) * (maxs - mins) * 0.6
            boxes.append((a, np.minimum(b, maxs + 1.0)))
        # Faces on the planes where the root's children meet (and a thin slab around them).
        boxes.append((np.array([mins[0], mins[1], mins[2]]), np.array([c[0], c[1], maxs[2]])))
        boxes.append((np.array([c[0], c[1], mins[2]]), np.array([maxs[0], maxs[1], c[2]])))
        boxes.append((np.array([c[0], mins[1], mins[2]]), np.array([c[0], maxs[1], maxs[2]])))
        for a, b in boxes:
            lo = np.round((a - hdr.offsets) / hdr.scales).astype(np.int64)
            hi = np.round((b - hdr.offsets) / hdr.scales).astype(np.int64)
            keep = (lo[0] <= X) & (X <= hi[0]) & (lo[1] <= Y) & (Y <= hi[1]) & (lo[2] <= Z) & (Z <= hi[2])
            got = r.query(bounds=Bounds(a, b))
            exp = sorted_cols({d: v[keep] for d, v in columns(ref.points, dims).items()}, dims)
            same(exp, sorted_cols(columns(got, dims), dims), dims, f"{name}: bounds query {a} .. {b}")
            nq += 1
            inside += int(keep.sum())
        total += len(ref.points)
print(
    f"{len(tiles)} COPC tiles, {total} points, {nodes} hierarchy nodes: every record equal to the LAZ tiles; "
    f"{nq} bounds queries returned exactly the {inside} points inside"
)
