#!/usr/bin/env bash
# Scale-out cost of distributed runs (issue 20): one synthetic region with the default stages,
# processed (a) by one `tessera run` and (b) by `tessera plan --tasks 4` + the 4 tasks (2 at a
# time: this machine has 2 cores) + `tessera stitch`. Prints, from /usr/bin/time -v:
#   CPU-seconds (user + sys) of the single run and of all tasks + stitch, and their ratio
#   (the distributed path's overhead: every task re-reads the inputs its buffers reach and
#   re-processes those buffers); stitch wall time; peak RSS per task against the budget;
# and checks that both outputs are byte-identical.
#
# Usage: scripts/bench_scaleout.sh [LENGTH_M=2450]   (2450 m of street ≈ 51 M points)
# BENCH_DIR (default /tmp/tessera-bench-scaleout) holds the scene and outputs (~1.5 GB); it is
# removed and recreated.
set -euo pipefail
cd "$(dirname "$0")/.."
LENGTH=${1:-2450}
W=${BENCH_DIR:-/tmp/tessera-bench-scaleout}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN=$(realpath "${CARGO_TARGET_DIR:-target}/release/tessera")

measure() { # NAME CMD... → appends "NAME wall user sys maxrss_kb" to $W/times
  local name=$1; shift
  /usr/bin/time -v -o "$W/$name.time" "$@"
  awk -v n="$name" -F': ' '
    /Elapsed \(wall clock\)/ { split($2, t, ":"); w = (length(t) == 3) ? t[1]*3600 + t[2]*60 + t[3] : t[1]*60 + t[2] }
    /User time/ { u = $2 } /System time/ { s = $2 } /Maximum resident/ { m = $2 }
    END { printf "%s %.2f %.2f %.2f %d\n", n, w, u, s, m }' "$W/$name.time" >> "$W/times"
}

echo "== synthesising $LENGTH m of street"
"$BIN" -q synth --length-m "$LENGTH" --out "$W/scene"
INPUTS=$(ls "$W"/scene/*.laz | xargs realpath)
echo "== single process"
measure single "$BIN" -q run --out "$W/single" $INPUTS
echo "== plan + 4 tasks (2 at a time) + stitch"
measure plan "$BIN" -q plan --tasks 4 --out "$W/plan" $INPUTS
export -f measure; export W BIN
printf '%s\n' 0 1 2 3 | xargs -P 2 -I{} bash -c 'measure task{} "$BIN" -q run --plan "$W/plan" --task {}'
measure stitch "$BIN" -q stitch "$W/plan"

python3 - "$W" <<'PY'
import json, sys
w = sys.argv[1]
t = {}
for line in open(f"{w}/times"):
    n, wall, u, s, rss = line.split()
    t[n] = dict(wall=float(wall), cpu=float(u) + float(s), rss_mb=int(rss) / 1024)
s = json.load(open(f"{w}/single/summary.json"))
budget = s["memory_budget_mb"]
single = t["single"]["cpu"]
dist = sum(v["cpu"] for k, v in t.items() if k != "single")
print(f"points: {s['points_in']:,}  tiles: {s['tiles']}")
print(f"single run: {t['single']['wall']:.1f} s wall, {single:.1f} CPU-s, peak RSS {t['single']['rss_mb']:.0f} MiB")
for k in sorted(t):
    if k.startswith("task"):
        v = t[k]
        print(f"  {k}: {v['wall']:.1f} s wall, {v['cpu']:.1f} CPU-s, peak RSS {v['rss_mb']:.0f} MiB (budget {budget} MiB)")
print(f"plan: {t['plan']['wall']:.2f} s; stitch: {t['stitch']['wall']:.1f} s wall, {t['stitch']['cpu']:.1f} CPU-s, peak RSS {t['stitch']['rss_mb']:.0f} MiB")
print(f"distributed CPU-s (plan + tasks + stitch): {dist:.1f} = {dist / single:.3f} × single ({100 * (dist / single - 1):+.1f} %)")
PY
echo "== outputs identical?"
diff <(cd "$W/single" && ls *.laz *.segments.tsv | sort) <(cd "$W/plan" && ls *.laz *.segments.tsv | sort)
n=0; for f in "$W"/single/*.laz "$W"/single/*.segments.tsv; do cmp -s "$f" "$W/plan/$(basename "$f")" || { echo "DIFF $(basename "$f")"; n=$((n+1)); }; done
echo "$n files differ"
[ "$n" -eq 0 ]
