#!/usr/bin/env bash
# Peak RSS of the pass-through pipeline at growing input sizes with the same settings:
# memory must be flat (largest / smallest <= 1.15). Sizes in millions of points (default
# "5 20 100"); a synthetic drive of ~2.15 M points per 100 m (default density) is generated for each.
# Usage: scripts/bench_memory.sh [BUDGET_MB=256] ["5 20 100"]
set -euo pipefail
cd "$(dirname "$0")/.."
BUDGET=${1:-256}; SIZES=${2:-"5 20 100"}
# Stages to run (default: pass-through); e.g. STAGES='["ground"]'
STAGES=${STAGES:-'["stats"]'}
W=${BENCH_DIR:-/tmp/tessera-bench-mem}
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"
mkdir -p "$W"
printf "%-10s %-12s %-10s %-10s %-8s %-8s\n" "M points" "points" "wall s" "RSS MiB" "tiles" "split"
for m in $SIZES; do
  len=$(python3 -c "print(round($m * 1e6 / 2.15e6 * 100))")
  rm -rf "$W/scene" "$W/out"
  $BIN -q synth --out "$W/scene" --length-m "$len" --seed 5
  s=$( { /usr/bin/time -f "%e %M" $BIN -q run "$W/scene" --out "$W/out" --memory-budget "$BUDGET" --set "stages.run=$STAGES" >/dev/null; } 2>&1 | tail -1)
  read -r pts tiles split < <(python3 -c "import json;s=json.load(open('$W/out/summary.json'));print(s['points_out'],s['tiles'],s['tiles_split'])")
  printf "%-10s %-12s %-10s %-10s %-8s %-8s\n" "$m" "$pts" "${s% *}" "$(( ${s#* } / 1024 ))" "$tiles" "$split"
done
rm -rf "$W"
