#!/usr/bin/env bash
# Peak RSS against the number of tiles (issue 63): flat synthetic regions of SIDE x SIDE metres
# at DENSITY points/m2 (uniform random x/y, so the points arrive in no spatial order; 2 m boxes
# 2 m high every 25 m), one LAS file each, 10 m tiles with a 5 m buffer, --memory-budget 256.
# Per region: `tessera run` pass-through and ground + segment, then `plan --tasks 2` + both
# tasks + `tessera stitch` (ground + segment). Prints tiles, wall seconds, peak RSS (MiB) per
# command, and each RSS against the smallest region's. Every run must stay under the budget
# (tessera itself exits 4 when one does not).
# Usage: scripts/bench_cells.sh ["500 1000 2000"] [DENSITY=1]
#   500 m -> 2,505 cells, 1000 m -> 10,011, 2000 m -> 40,018 (~2, ~4, ~15 minutes at density 1).
set -euo pipefail
cd "$(dirname "$0")/.."
SIDES=${1:-"500 1000 2000"}; DENSITY=${2:-1}
W=${BENCH_DIR:-/tmp/tessera-bench-cells}
cargo build --release -q
BIN="$(pwd)/${CARGO_TARGET_DIR:-target}/release/tessera"
rm -rf "$W"; mkdir -p "$W"
python3 -c "import laspy, numpy" 2>/dev/null || python3 -m pip install -q laspy numpy
SET=(--set pipeline.memory_budget_mb=256 --set tiling.tile_size_m=10 --set tiling.buffer_m=5)
GS='stages.run=["ground","segment"]'

# measure NAME CMD...: runs CMD under /usr/bin/time, prints "NAME wall rss".
measure() {
  local name=$1; shift
  local t
  /usr/bin/time -o "$W/time" -f "%e %M" "$@" >/dev/null 2>"$W/err" \
    || { echo "$name failed:" >&2; tail -3 "$W/err" >&2; exit 1; }
  t=$(tail -1 "$W/time")
  echo "$name ${t% *} $(( ${t#* } / 1024 ))"
}

results="$W/results"; : > "$results"
for side in $SIDES; do
  python3 - "$side" "$DENSITY" "$W/r.las" <<'PY'
import sys, numpy as np, laspy
side, dens, path = float(sys.argv[1]), float(sys.argv[2]), sys.argv[3]
rng = np.random.default_rng(3)
n = int(side * side * dens)
x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
z = rng.normal(0, 0.02, n) + 2.0 * (((x % 25) < 2) & ((y % 25) < 2))
h = laspy.LasHeader(point_format=1, version="1.2"); h.scales = [0.01] * 3; h.offsets = [0, 0, 0]
las = laspy.LasData(h); las.x, las.y, las.z = x, y, z
las.write(path)
PY
  rm -rf "$W/o"; measure "$side pass" "$BIN" -q run "$W/r.las" --out "$W/o" "${SET[@]}" --set 'stages.run=["stats"]' >> "$results"
  tiles=$(python3 -c "import json;print(json.load(open('$W/o/summary.json'))['tiles'])")
  rm -rf "$W/o"; measure "$side g+s" "$BIN" -q run "$W/r.las" --out "$W/o" "${SET[@]}" --set "$GS" >> "$results"
  rm -rf "$W/o" "$W/plan"
  "$BIN" -q plan "$W/r.las" --out "$W/plan" --tasks 2 "${SET[@]}" --set "$GS" >/dev/null
  measure "$side task0" "$BIN" -q run --plan "$W/plan" --task 0 >> "$results"
  measure "$side task1" "$BIN" -q run --plan "$W/plan" --task 1 >> "$results"
  measure "$side stitch" "$BIN" -q stitch "$W/plan" >> "$results"
  echo "$side $tiles" >> "$W/tiles"
  rm -rf "$W/plan" "$W/r.las"
done
python3 - "$results" "$W/tiles" <<'PY'
import sys, collections
rows = [l.split() for l in open(sys.argv[1])]
tiles = dict(l.split() for l in open(sys.argv[2]))
by = collections.defaultdict(dict)
for side, cmd, wall, rss in rows:
    by[cmd][side] = (float(wall), int(rss))
sides = list(tiles)
print(f"{'command':8} " + " ".join(f"{tiles[s] + ' tiles':>22}" for s in sides))
for cmd, v in by.items():
    base = v[sides[0]][1]
    cells = [f"{v[s][0]:7.1f} s {v[s][1]:4d} MiB {v[s][1] / base:4.2f}x" for s in sides]
    print(f"{cmd:8} " + " ".join(f"{c:>22}" for c in cells))
PY
