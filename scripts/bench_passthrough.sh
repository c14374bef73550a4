#!/usr/bin/env bash
# Pass-through throughput: read LAZ -> tile -> write LAZ with tessera, against laspy + lazrs
# (parallel read + parallel write, ../shared/peers/laspy_io_bench.py) on the same file, runs
# alternated in the same session. Prints medians and the ratio (>1 means tessera is faster).
# Usage: scripts/bench_passthrough.sh [LENGTH_M=200] [RUNS=5]
set -euo pipefail
cd "$(dirname "$0")/.."
LEN=${1:-200}; RUNS=${2:-5}
PEERS=${PEERS:-../shared/peers}
W=${BENCH_DIR:-/tmp/tessera-bench-pt}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"
$BIN -q synth --out "$W/scene" --length-m "$LEN" --file-length-m "$LEN"
python3 - "$W" <<'PY'
import sys, laspy
w = sys.argv[1]
d = laspy.read(f"{w}/scene/scene_00000.laz")
d.write(f"{w}/in.las")
print(f"input: {len(d.points)} points, point format {d.header.point_format.id}")
PY
tess=(); peer=()
# `sync` before each timed run: each tool writes its outputs (laspy ~230 MB of LAS + LAZ per
# run), and without it the kernel's writeback of one tool's files lands in the other's timing.
for i in $(seq "$RUNS"); do
  sync
  python3 "$PEERS/laspy_io_bench.py" "$W/in.las" "$W/lb" > "$W/lb.txt"
  p=$(awk '/read LAZ \(lazrs parallel\)/{r=$(NF-1)} /write LAZ \(lazrs parallel\)/{w=$(NF-1)} END{printf "%.3f", r+w}' "$W/lb.txt")
  peer+=("$p")
  rm -rf "$W/out"
  sync
  s=$( { /usr/bin/time -f "%e %M" $BIN -q run "$W/lb/io_bench.laz" --out "$W/out" --set 'stages.run=["stats"]' >/dev/null; } 2>&1 | tail -1)
  tess+=("$(echo "$s" | cut -d' ' -f1)")
  echo "run $i: laspy read+write ${p} s, tessera ${s% *} s (max RSS $(( ${s#* } / 1024 )) MiB)"
done
N=$(python3 -c "import laspy;print(laspy.open('$W/in.las').header.point_count)")
python3 - "$N" "${tess[*]}" "${peer[*]}" <<'PY'
import sys, statistics as st
n = int(sys.argv[1]); t = [float(x) for x in sys.argv[2].split()]; p = [float(x) for x in sys.argv[3].split()]
mt, mp = st.median(t), st.median(p)
print(f"points: {n}")
print(f"tessera run (whole process, read LAZ -> tile -> write LAZ): median {mt:.2f} s = {n/mt/1e6:.2f} M points/s")
print(f"laspy+lazrs parallel read LAZ + write LAZ (in-process, no tiling): median {mp:.2f} s = {n/mp/1e6:.2f} M points/s")
print(f"ratio (laspy time / tessera time): {mp/mt:.2f}")
PY
