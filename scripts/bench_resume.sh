#!/usr/bin/env bash
# Resume cost (issue 20): a fresh `tessera run` of a synthetic street (default stages) is
# timed; then the same run is killed (SIGKILL) at HALF of that time and the same command is
# run again: its time to finish is compared with the fresh run's (target ≤ 55 %: the finished
# cells are not recomputed, but every input is read and tiled again). Repeated RUNS times;
# medians printed. The resumed outputs are checked byte-identical to the fresh run's.
#
# Usage: scripts/bench_resume.sh [LENGTH_M=300] [RUNS=3]
set -euo pipefail
cd "$(dirname "$0")/.."
LENGTH=${1:-300}
RUNS=${2:-3}
W=${BENCH_DIR:-/tmp/tessera-bench-resume}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN=$(realpath "${CARGO_TARGET_DIR:-target}/release/tessera")
"$BIN" -q synth --length-m "$LENGTH" --out "$W/scene"
INPUTS=$(ls "$W"/scene/*.laz)
now() { date +%s.%N; }
: > "$W/results"
for r in $(seq 1 "$RUNS"); do
  rm -rf "$W/fresh" "$W/out"
  t0=$(now); "$BIN" -q run --out "$W/fresh" $INPUTS; t1=$(now)
  fresh=$(echo "$t1 - $t0" | bc -l)
  half=$(echo "$fresh / 2" | bc -l)
  "$BIN" -q run --out "$W/out" $INPUTS & pid=$!
  sleep "$half"; kill -9 "$pid"; wait "$pid" 2>/dev/null || true
  cells=$(wc -l < "$W/out/.tessera-resume/log")
  t0=$(now); "$BIN" -q run --out "$W/out" $INPUTS; t1=$(now)
  resumed=$(echo "$t1 - $t0" | bc -l)
  reused=$(python3 -c "import json; s=json.load(open('$W/out/summary.json')); print(s['tiles_reused'], s['tiles'])")
  for f in "$W"/fresh/*.laz "$W"/fresh/*.tsv; do cmp -s "$f" "$W/out/$(basename "$f")" || { echo "DIFF $f"; exit 1; }; done
  echo "$fresh $resumed $cells $reused" | tee -a "$W/results"
done
python3 - "$W/results" <<'PY'
import statistics, sys
rows = [list(map(float, l.split())) for l in open(sys.argv[1])]
fresh = statistics.median(r[0] for r in rows)
resumed = statistics.median(r[1] for r in rows)
ratio = statistics.median(r[1] / r[0] for r in rows)
print(f"fresh run median {fresh:.1f} s; resumed after a kill at 50 %: median {resumed:.1f} s = {100 * ratio:.0f} % of a fresh run (target ≤ 55 %)")
for r in rows:
    print(f"  fresh {r[0]:.1f} s, resumed {r[1]:.1f} s ({100 * r[1] / r[0]:.0f} %), journal lines at the kill {int(r[2])}, tiles reused {int(r[3])}/{int(r[4])}")
PY
