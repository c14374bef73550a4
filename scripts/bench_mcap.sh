#!/usr/bin/env bash
# MCAP benchmarks (issue 7), both in one session on the same files:
# 1. Decode throughput, MCAP -> points: `tessera info` (decompress, deserialise every
#    PointCloud2, read x/y/z of every point, count the valid ones) against Python `mcap` +
#    `mcap-ros2-support` + numpy doing the same (scripts/mcap_decode_bench.py); runs alternated,
#    median of RUNS each, ratio printed (> 1 means tessera is faster). Files: a simulated ROS 2
#    drive and the real Ouster ROS 1 recording when ../shared/data is present.
# 2. A whole simulated drive (>= 10^7 points) processed end to end by `tessera run` (decode,
#    georeference with /tf and de-skew, tile, the default stages ground + segment + label with
#    cross-tile stitching, write LAZ) at the default 1 GiB budget: points/s and peak RSS
#    (/usr/bin/time -v), one run.
# Usage: scripts/bench_mcap.sh [RUNS=5] [DRIVE_LENGTH_M=310]
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-5}; LEN=${2:-310}
W=${BENCH_DIR:-/tmp/tessera-bench-mcap}
DATA=${TESSERA_DATA:-../shared/data}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"
python3 -c "import mcap, mcap_ros2, mcap_ros1, numpy" \
  || { echo "needs: pip install mcap mcap-ros2-support mcap-ros1-support numpy"; exit 1; }

median() { python3 -c "import statistics,sys; print(f'{statistics.median(float(x) for x in sys.argv[1:]):.3f}')" "$@"; }

decode_bench() {
  local f=$1 name=$2 tess=() peer=() n="" t p
  for i in $(seq "$RUNS"); do
    p=$(python3 scripts/mcap_decode_bench.py "$f")
    peer+=("$(echo "$p" | awk '{print $4}')")
    n=$(echo "$p" | awk '{print $2" points ("$3" valid) in "$1" clouds"}')
    t=$( { /usr/bin/time -f "%e %M" "$BIN" info "$f" >/dev/null; } 2>&1 | tail -1)
    tess+=("$(echo "$t" | cut -d' ' -f1)")
    echo "  run $i: python ${peer[-1]} s, tessera ${tess[-1]} s (max RSS $(( ${t#* } / 1024 )) MiB)"
  done
  local mt mp pts
  mt=$(median "${tess[@]}"); mp=$(median "${peer[@]}")
  pts=$(echo "$p" | awk '{print $2}')
  python3 - "$name" "$n" "$pts" "$mt" "$mp" <<'PY'
import sys
name, desc, pts, mt, mp = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), float(sys.argv[5])
print(f"{name}: {desc}")
print(f"  tessera info:            median {mt:.3f} s = {pts / mt / 1e6:.2f} M points/s")
print(f"  python mcap+ros2/ros1:   median {mp:.3f} s = {pts / mp / 1e6:.2f} M points/s")
print(f"  ratio (python time / tessera time): {mp / mt:.2f}")
PY
}

echo "== synthesising drives"
"$BIN" -q synth --mcap --out "$W/small" --length-m 60
"$BIN" -q synth --mcap --out "$W/drive" --length-m "$LEN" --rings 32 --columns 1024
ls -l "$W/small/drive.mcap" "$W/drive/drive.mcap" | awk '{print "  "$5" bytes "$9}'

echo "== 1. decode throughput (median of $RUNS)"
decode_bench "$W/small/drive.mcap" "simulated ROS 2 drive (60 m, 32 x 1024, zstd)"
if [ -f "$DATA/mcap-ouster-ros1/ouster_os1_ros1profile.mcap" ]; then
  decode_bench "$DATA/mcap-ouster-ros1/ouster_os1_ros1profile.mcap" "Ouster OS1-64 ROS 1 recording"
fi

echo "== 2. whole drive end to end (one run)"
/usr/bin/time -v "$BIN" -q run "$W/drive/drive.mcap" --out "$W/out" 2> "$W/time.txt"
python3 - "$W" <<'PY'
import json, re, sys
w = sys.argv[1]
s = json.load(open(f"{w}/out/summary.json"))
t = open(f"{w}/time.txt").read()
wall = t.split("Elapsed (wall clock) time (h:mm:ss or m:ss):")[1].split()[0]
parts = [float(x) for x in wall.split(":")]
sec = sum(p * 60 ** i for i, p in enumerate(reversed(parts)))
rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", t).group(1)) / 1024
m = s["mcap"][0]
n = s["points_out"]
print(f"drive: {m['clouds']} clouds, {m['points_in_clouds']} beams, {n} points written "
      f"({m['points_nan']} no-returns dropped), {s['tiles']} tiles, stages {list(k for k in s['seconds'] if k.startswith('stage_'))}")
print(f"  MCAP decode + georeference + LAS parts: {m['seconds']:.2f} s = {n / m['seconds'] / 1e6:.2f} M points/s")
print(f"  whole run: {sec:.2f} s wall = {n / sec / 1e6:.2f} M points/s; peak RSS {rss:.0f} MiB "
      f"(summary {s['peak_rss_mb']:.0f} MiB, budget {s['memory_budget_mb']} MiB)")
PY
