#!/usr/bin/env bash
# Stitching at fixed memory (issue 6): a long synthetic drive processed with ground +
# segment + stitching at 25 m tiles, for growing numbers of tiles in a row. The stitcher's
# frontier (tiles whose border summaries are held, records, bytes, union-find nodes, closed
# tiles waiting for a component) and the process's peak RSS (/usr/bin/time) must stay flat.
# The scene is two rows of tiles wide (the drive runs along a tile border in y), so N tiles in
# a row are ~2N tiles. Segmentation radii are scaled to the point spacing (thesis §5.4:
# r_seed = 2.5 s, r_grow = 3 s, never below the defaults) so lower densities keep segments.
# Usage: scripts/bench_stitch.sh ["50 200" tiles in a row]   env: DENSITY (points/m² at 5 m,
#        default 100), BUDGET (MiB, default 512), TILE_M (default 25)
set -euo pipefail
cd "$(dirname "$0")/.."
ROWS=${1:-"50 200"}
DENSITY=${DENSITY:-100}; BUDGET=${BUDGET:-512}; TILE_M=${TILE_M:-25}
W=${BENCH_DIR:-/tmp/tessera-bench-stitch}
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"
read -r RS RG < <(python3 -c "s=$DENSITY**-0.5;print(max(0.15,round(2.5*s,3)),max(0.2,round(3*s,3)))")
echo "density $DENSITY pts/m² at 5 m, tiles $TILE_M m, budget $BUDGET MiB, r_seed $RS m, r_grow $RG m"
printf "%-7s %-10s %-6s %-8s %-9s %-9s %-10s %-9s %-8s %-8s %-8s\n" \
  "in row" "points" "tiles" "wall s" "RSS MiB" "frontier" "records" "KiB" "nodes" "waiting" "merges"
mkdir -p "$W"
for n in $ROWS; do
  len=$(python3 -c "print($n * $TILE_M)")
  rm -rf "$W/scene" "$W/out"
  $BIN -q synth --out "$W/scene" --length-m "$len" --points-per-m2 "$DENSITY" --seed 5
  s=$( { /usr/bin/time -f "%e %M" $BIN -q run "$W/scene" --out "$W/out" --memory-budget "$BUDGET" \
        --set 'stages.run=["ground","segment","stats"]' --set "tiling.tile_size_m=$TILE_M" \
        --set "segment.params.r_seed_m=$RS" --set "segment.params.r_grow_m=$RG" >/dev/null; } 2>&1 | tail -1)
  python3 - "$W/out/summary.json" "$n" "$s" <<'PY'
import json, sys
s = json.load(open(sys.argv[1])); st = s["stitch"]; wall, kb = sys.argv[3].split()
print(f"{sys.argv[2]:<7} {s['points_out']:<10} {s['tiles']:<6} {float(wall):<8.1f} {int(kb)/1024:<9.1f} "
      f"{st['frontier_tiles_max']:<9} {st['frontier_records_max']:<10} {st['frontier_bytes_max']/1024:<9.0f} "
      f"{st['open_nodes_max']:<8} {st['waiting_tiles_max']:<8} {st['merges']:<8}")
PY
done
rm -rf "$W"
