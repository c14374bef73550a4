#!/usr/bin/env bash
# Scale of `tessera plan`: N_SIDE² synthetic LAS 1.2 files (headers and two points each, laid
# out on a square grid over EXTENT metres) planned on the default 50 m grid; prints the wall
# time and the maximum resident set size (/usr/bin/time -v) of the plan command.
#
# Usage: scripts/bench_plan.sh [N_SIDE=316] [EXTENT_M=50000] [TASKS=64]
#   defaults: 99,856 inputs over 50 km × 50 km = 1,000,000 tiles of 50 m (issue 20's
#   "10^5 inputs / 10^6 tiles").
# BENCH_DIR (default /tmp/tessera-bench-plan) holds the generated inputs (about 270 MB on a
# 4 KiB-block file system) and the plan; it is removed and recreated.
set -euo pipefail
cd "$(dirname "$0")/.."
N_SIDE=${1:-316}
EXTENT=${2:-50000}
TASKS=${3:-64}
W=${BENCH_DIR:-/tmp/tessera-bench-plan}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN=${CARGO_TARGET_DIR:-target}/release/tessera

echo "== generating $((N_SIDE * N_SIDE)) LAS headers over ${EXTENT} m"
python3 - "$W/in" "$N_SIDE" "$EXTENT" <<'PY'
import os, struct, sys
out, n_side, extent = sys.argv[1], int(sys.argv[2]), float(sys.argv[3])
os.makedirs(out)
step, scale = extent / n_side, 0.01

def header(minx, miny, maxx, maxy, npts):
    h = bytearray(227)
    h[0:4] = b"LASF"
    struct.pack_into("<BB", h, 24, 1, 2)  # LAS 1.2
    h[26:58] = b"tessera bench_plan".ljust(32, b"\0")
    struct.pack_into("<HHHI", h, 90, 1, 2026, 227, 227)  # day, year, header size, data offset
    struct.pack_into("<IBHI", h, 100, 0, 0, 20, npts)  # VLRs, format 0, record length, count
    struct.pack_into("<5I", h, 111, npts, 0, 0, 0, 0)
    struct.pack_into("<3d", h, 131, scale, scale, scale)
    struct.pack_into("<6d", h, 179, maxx, minx, maxy, miny, 1.0, 0.0)
    return h

def point(x, y, z):
    return struct.pack("<iiiHBBbBH", round(x / scale), round(y / scale), round(z / scale),
                       0, 0x11, 0, 0, 0, 0)

for i in range(n_side):
    for j in range(n_side):
        x0, y0 = i * step, j * step
        x1, y1 = x0 + step - scale, y0 + step - scale
        with open(f"{out}/f_{i:04d}_{j:04d}.las", "wb") as f:
            f.write(header(x0, y0, x1, y1, 2) + point(x0, y0, 0.0) + point(x1, y1, 1.0))
PY
sync
echo "== tessera plan --tasks $TASKS"
/usr/bin/time -v "$BIN" plan "$W/in" --out "$W/plan" --tasks "$TASKS" 2> "$W/time.txt" | head -1
grep -E "Elapsed|Maximum resident" "$W/time.txt"
echo "tiles.tsv: $(($(wc -l < "$W/plan/tiles.tsv") - 1)) tiles"
