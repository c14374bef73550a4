#!/usr/bin/env bash
# Labelling throughput (issue 5).
# 1. The demo (`tessera demo`, 150 m synthetic street, ground + segment + label): whole pipeline
#    points/s (input points over the pipeline's wall seconds, synthesis excluded), whole
#    command wall time and peak RSS (/usr/bin/time).
# 2. A >= 20 M point synthetic street (SCENE_M metres, default 1000), ground + segment + label
#    with training samples from its first 50 m: labelling-stage points/s per worker (points
#    the stage labels — ground and non-ground within the core + label.context_m zone — over the
#    stage's seconds summed over workers), whole-run points/s, wall time and peak RSS.
# Usage: scripts/bench_label.sh     env: SCENE_M (default 1000), SKIP_BIG=1 (demo only)
set -euo pipefail
cd "$(dirname "$0")/.."
W=${BENCH_DIR:-/tmp/tessera-bench-label}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"

report() { # summary.json, /usr/bin/time -v output, title
python3 - "$1" "$2" "$3" <<'PY'
import json, re, sys
s = json.load(open(sys.argv[1])); t = open(sys.argv[2]).read(); title = sys.argv[3]
sec = s["seconds"]
wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", t).group(1)
rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", t).group(1)) / 1024
def labelled(l):
    ng = l["nonground_points"]
    ng = sum(ng.values()) if isinstance(ng, dict) else ng
    return (l["ground"] or {}).get("points", 0) + ng
lab = sum(labelled(x["stats"]["label"]) for x in s["tile_list"] if "label" in x.get("stats", {}))
print(f"{title}: {s['points_in']:,} points, {s['tiles']} tiles; pipeline {sec['pipeline']:.1f} s wall = "
      f"{s['points_in'] / sec['pipeline'] / 1e6:.3f} M points/s (ground + segment + label); stage CPU-s: "
      f"ground {sec.get('stage_ground', 0):.1f}, segment {sec.get('stage_segment', 0):.1f}, "
      f"label {sec.get('stage_label', 0):.1f}; label stage {lab:,} points labelled = "
      f"{lab / max(sec.get('stage_label', 0), 1e-9) / 1e6:.3f} M points/s per worker; "
      f"command wall {wall}, peak RSS {rss:.0f} MiB")
PY
}

/usr/bin/time -v "$BIN" -q demo --out "$W/demo" > "$W/demo.txt" 2> "$W/demo.time"
report "$W/demo/tiles/summary.json" "$W/demo.time" "demo"

[ "${SKIP_BIG:-0}" = 1 ] && { rm -rf "$W"; exit 0; }
SCENE_M=${SCENE_M:-1000}
"$BIN" -q synth --out "$W/street" --length-m "$SCENE_M" > /dev/null
"$BIN" -q samples --from "$W/street/scene_00000.laz" --field gt_class --classes 11,64,65,67 \
  --out "$W/samples.json" > /dev/null
/usr/bin/time -v "$BIN" -q run "$W/street" --out "$W/big" \
  --set 'stages.run=["ground","segment","label","stats"]' --set "label.samples=\"$W/samples.json\"" \
  2> "$W/big.time"
report "$W/big/summary.json" "$W/big.time" "street ${SCENE_M} m"
rm -rf "$W"
