#!/usr/bin/env bash
# What COPC output costs against plain LAZ: one synthetic street (LENGTH_M, default 300),
# `tessera run` with output.format = "laz" and = "copc", alternating, N runs each (default 3),
# same binary, same session. Prints per run and the medians: total and write seconds (the
# write phase holds the octree building and the compression), peak RSS and output size.
# Usage: scripts/bench_copc.sh [N] [LENGTH_M]   (BIN=path to a release tessera)
set -euo pipefail
N=${1:-3}
LEN=${2:-300}
BIN=${BIN:-$(dirname "$0")/../target/release/tessera}
W=$(mktemp -d /tmp/tessera-bench-copc.XXXXXX)
trap 'rm -rf "$W"' EXIT
"$BIN" -q synth --length-m "$LEN" --out "$W/scene" > /dev/null
rows=()
for i in $(seq 1 "$N"); do
  for fmt in laz copc; do
    rm -rf "$W/out"
    "$BIN" -q run "$W/scene" --out "$W/out" --set "output.format=\"$fmt\"" > /dev/null
    row=$(python3 -c "
import json, os, glob
s = json.load(open('$W/out/summary.json'))
size = sum(os.path.getsize(p) for p in glob.glob('$W/out/*.laz'))
print('$fmt', s['seconds']['total'], s['seconds']['write'], s.get('peak_rss_mb', 0), size / 2**20, s['points_out'])")
    rows+=("$row")
    echo "run $i: $row" | awk '{printf "%s %s %s: total %.2f s, write %.2f s, peak RSS %.0f MiB, %.1f MiB of tiles, %d points\n", $1, $2, $3, $4, $5, $6, $7, $8}'
  done
done
printf '%s\n' "${rows[@]}" | python3 -c '
import sys, statistics as st
rows = [l.split() for l in sys.stdin if l.strip()]
m = {}
for f in ("laz", "copc"):
    r = [x for x in rows if x[0] == f]
    m[f] = [st.median(float(x[k]) for x in r) for k in (1, 2, 3, 4)]
    print(f"median {f}: total {m[f][0]:.2f} s, write {m[f][1]:.2f} s, peak RSS {m[f][2]:.0f} MiB, {m[f][3]:.1f} MiB")
c, l = m["copc"], m["laz"]
print(f"copc / laz: total {c[0] / l[0]:.3f}, write {c[1] / l[1]:.3f}, size {c[3] / l[3]:.3f}")
'
