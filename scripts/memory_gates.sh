#!/usr/bin/env bash
# The memory gates of issue 21, full size (too long for CI, which runs the first one in
# tests/memory_cap.rs): the default pipeline (ground + segment + label + stitching) on
#   1. the 300 m street of `tessera synth --seed 7` at --memory-budget 256 with 2 workers,
#   2. the same street at --memory-budget 160 with 1 worker,
#   3. the simulated drive of scripts/bench_mcap.sh at --memory-budget 256 with 2 workers.
# Each run is timed by /usr/bin/time -v; the script prints wall time, maximum resident set
# size, the run's own VmHWM (summary.json peak_rss_mb), tiles, the stitcher's frontier in
# memory and in its spill file, and exits 1 if any peak reaches its budget.
# Usage: scripts/memory_gates.sh [DRIVE_LENGTH_M=310]
set -euo pipefail
cd "$(dirname "$0")/.."
LEN=${1:-310}
W=${BENCH_DIR:-/tmp/tessera-memory-gates}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"

"$BIN" -q synth --seed 7 --length-m 300 --out "$W/street"
"$BIN" -q synth --mcap --out "$W/drive" --length-m "$LEN" --rings 32 --columns 1024

fail=0
# gate NAME BUDGET_MIB THREADS INPUT
gate() {
  local name=$1 mib=$2 threads=$3 input=$4
  local out="$W/o_$name"
  rm -rf "$out"; sync
  if ! /usr/bin/time -v "$BIN" -q run "$input" --out "$out" --memory-budget "$mib" --threads "$threads" \
      > /dev/null 2> "$W/$name.time"; then
    echo "$name: run failed"; tail -3 "$W/$name.time"; fail=1; return
  fi
  python3 - "$name" "$mib" "$W/$name.time" "$out/summary.json" <<'PY' || fail=1
import json, re, sys
name, mib, tfile, sfile = sys.argv[1], int(sys.argv[2]), sys.argv[3], sys.argv[4]
t = open(tfile).read()
rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", t).group(1)) / 1024
wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", t).group(1)
s = json.load(open(sfile))
st = s.get("stitch") or {}
ok = rss < mib and s["peak_rss_mb"] < mib and s["points_out"] == s["points_in"]
print(f"{name}: {s['points_in']} points, wall {wall}, max RSS {rss:.1f} MiB, VmHWM "
      f"{s['peak_rss_mb']:.1f} MiB (budget {mib}), tiles {s['tiles']}; frontier in memory "
      f"{st.get('frontier_bytes_max', 0) / 2**20:.1f} MiB (share "
      f"{s['budget']['stitch_bytes'] / 2**20:.1f}), spilled {st.get('spilled_summaries', 0)} "
      f"summaries, {st.get('spill_reads', 0)} read back, spill file peak "
      f"{st.get('spill_bytes_max', 0) / 2**20:.1f} MiB -> {'ok' if ok else 'OVER'}")
sys.exit(0 if ok else 1)
PY
}

gate street_256_2 256 2 "$W/street"
gate street_160_1 160 1 "$W/street"
gate drive_256_2 256 2 "$W/drive/drive.mcap"
exit $fail
