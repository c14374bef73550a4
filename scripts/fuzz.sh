#!/usr/bin/env bash
# Runs every cargo-fuzz target of scripts/fuzz for SECONDS each (default 60), with seed corpora
# from small files in $TESSERA_DATA and the generator, at a 2 GB RSS limit.
#   scripts/fuzz.sh [SECONDS] [TARGET...]
# Needs the nightly toolchain and cargo-fuzz (`cargo install cargo-fuzz`). Crashes land in
# scripts/fuzz/artifacts/TARGET/; each becomes a regression input of `cargo test`
# (tests/bad_input.rs). Prints executions and findings per target; exit 1 on any finding.
set -euo pipefail
cd "$(dirname "$0")/.."
SECONDS_EACH=${1:-60}
shift || true
DATA=${TESSERA_DATA:-../shared/data}
FUZZ=scripts/fuzz
CORPUS=${FUZZ_CORPUS:-/tmp/tessera-fuzz-corpus}
TARGETS=("$@")
[ ${#TARGETS[@]} -gt 0 ] || TARGETS=(las_file mcap_file pointcloud2 pcd config trajectory samples)
command -v cargo-fuzz >/dev/null || { echo "cargo-fuzz missing: cargo install cargo-fuzz" >&2; exit 2; }

seed() { # target file...
  mkdir -p "$CORPUS/$1"; local t=$1; shift
  for f in "$@"; do [ -f "$f" ] && cp -f "$f" "$CORPUS/$t/" || true; done
}
if [ ! -d "$CORPUS/las_file" ]; then
  BIN=target/release/tessera
  [ -x "$BIN" ] || cargo build --release
  tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
  "$BIN" synth --length-m 4 --file-length-m 2 --out "$tmp/scene" -q
  "$BIN" synth --mcap --length-m 3 --rings 4 --columns 64 --out "$tmp/drive" -q
  # Small seeds keep executions fast: 300-point LAS/LAZ files in formats 1, 3, 6, 7 and 8
  # (LAZ through lazrs, an independent writer), plus one real file.
  python3 - "$tmp" <<'PY' || true
import sys, numpy as np, laspy
for fmt, ver in [(1, "1.2"), (3, "1.2"), (6, "1.4"), (7, "1.4"), (8, "1.4")]:
    las = laspy.create(point_format=fmt, file_version=ver)
    n = 300
    las.x = np.linspace(0, 30, n); las.y = np.linspace(0, 5, n); las.z = np.sin(np.arange(n))
    las.classification = np.arange(n) % 10
    las.gps_time = np.arange(n) * 0.001
    for ext in ("las", "laz"):
        las.write(f"{sys.argv[1]}/seed_{fmt}.{ext}")
PY
  seed las_file "$DATA/isprs-filtertest/samp24-utm.laz" "$tmp"/seed_*.la?
  seed mcap_file "$tmp/drive/drive.mcap"
  python3 - "$tmp/drive/drive.mcap" "$CORPUS/pointcloud2" <<'PY' || true
import sys, os
from mcap.reader import make_reader
os.makedirs(sys.argv[2], exist_ok=True)
with open(sys.argv[1], "rb") as f:
    for k, (schema, channel, msg) in enumerate(make_reader(f).iter_messages()):
        if schema and schema.name.endswith("PointCloud2") and k < 50:
            open(os.path.join(sys.argv[2], f"msg{k}"), "wb").write(msg.data)
PY
  head -c 65536 "$DATA/pcl-tutorials/min_cut_segmentation_tutorial.pcd" > "$tmp/head.pcd"
  seed pcd "$tmp/head.pcd"
  seed config config/default.toml config/airborne.toml
  printf 'time,x,y,z,qx,qy,qz,qw\n1700000000.0,1,2,3,0,0,0,1\n1700000000.1,1.1,2,3,0,0,0,1\n' > "$tmp/t.csv"
  seed trajectory "$tmp/t.csv"
fi
if [ ! -d "$CORPUS/samples" ]; then
  mkdir -p "$CORPUS/samples"
  cat > "$CORPUS/samples/set.json" <<'JSON'
{"samples":[{"class":11,"name":"road 1","points":812,"mean":[41.5,-0.8,2.1],"std":[6.2,1.1,1.9]},
 {"class":2,"name":"grass","points":95,"mean":[48.0,-19.5,27.0],"std":[3.0,2.5,4.0]}]}
JSON
  cat > "$CORPUS/samples/polygons.geojson" <<'JSON'
{"type":"FeatureCollection","features":[
 {"type":"Feature","properties":{"class":11,"name":"road"},"geometry":{"type":"Polygon",
  "coordinates":[[[0,0],[10,0],[10,4],[0,4],[0,0]],[[2,1],[3,1],[3,2],[2,1]]]}},
 {"type":"Feature","properties":{"class":2},"geometry":{"type":"MultiPolygon",
  "coordinates":[[[[20,0],[25,0],[25,5],[20,0]]]]}}]}
JSON
fi
status=0
for t in "${TARGETS[@]}"; do
  mkdir -p "$CORPUS/$t"
  log=$(mktemp)
  # -O: optimised without overflow checks, as tessera ships (release profile): LASzip's
  # arithmetic wraps on purpose (laz's GPS-time deltas overflow under debug assertions).
  if ! cargo +nightly fuzz run -O --fuzz-dir "$FUZZ" "$t" "$CORPUS/$t" -- \
      -max_total_time="$SECONDS_EACH" -rss_limit_mb=2048 -timeout=20 -max_len=1048576 -print_final_stats=1 \
      >"$log" 2>&1; then
    status=1
    echo "== $t: FINDING"; grep -E "ERROR|panicked|SUMMARY|Test unit written" "$log" | head -8
  fi
  execs=$(grep -oE "stat::number_of_executed_units: *[0-9]+" "$log" | grep -oE "[0-9]+$" | tail -1)
  echo "== $t: ${execs:-?} executions in ${SECONDS_EACH} s"
  rm -f "$log"
done
exit $status
