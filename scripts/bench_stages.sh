#!/usr/bin/env bash
# Per-point cost of the stages (issue 21): on the demo street scene and on the simulated drive
# of scripts/bench_mcap.sh, each processed
#   a. as a pass-through (stages.run = ["stats"]: read LAZ -> tile -> write LAZ, the codec
#      floor), and
#   b. end to end with the default stages (ground + segment + label + stitching),
# alternated in the same session, RUNS times each; prints the medians, the throughput ratio
# end-to-end / pass-through, and per stage the CPU microseconds per input point and the points
# worked on per input point (summary.json `stages`). With OLD_BIN=path (e.g. a build of an
# earlier commit) that binary's end-to-end runs of both scenes are timed too, alternated, for
# before/after ratios and stage figures in the same session. With DRIVE_256=1, then the drive
# once at --memory-budget 256 with two workers (wall, peak RSS from /usr/bin/time -v and VmHWM).
# Also prints the CPU budget a ratio of 0.5 leaves the stages — twice the pass-through's wall
# time on the cores the end-to-end run keeps busy, less the pass-through's own CPU (the codec,
# which the end-to-end run does too) — next to what the stages' neighbour searches alone cost
# (per-tile phase seconds in summary.json; each tile runs on one worker thread).
# Usage: scripts/bench_stages.sh [RUNS=3] [DRIVE_LENGTH_M=310]
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-3}; LEN=${2:-310}
W=${BENCH_DIR:-/tmp/tessera-bench-stages}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"
OLD_BIN=${OLD_BIN:-}

echo "== inputs"
"$BIN" -q demo --out "$W/demo" > /dev/null
"$BIN" -q synth --mcap --out "$W/drive" --length-m "$LEN" --rings 32 --columns 1024
# The drive as LAZ (decoded and georeferenced once), so both runs read the same LAZ.
"$BIN" -q run "$W/drive/drive.mcap" --out "$W/drive_laz" --set 'stages.run=["stats"]' --set tiling.tile_size_m=1000
DEMO_SET=(--set "label.samples=\"$W/demo/samples.json\"")

# run NAME BIN OUT INPUT ARGS... -> appends "wall peak_rss_kib user_s sys_s" to $W/NAME.txt
run() {
  local name=$1 bin=$2 out=$3 input=$4; shift 4
  rm -rf "$out"; sync
  local t
  t=$( { /usr/bin/time -f "%e %M %U %S" "$bin" -q run "$input" --out "$out" "$@" > /dev/null; } 2>&1 | tail -1)
  echo "$t" >> "$W/$name.txt"
  local f; read -r -a f <<< "$t"
  echo "  $name: ${f[0]} s, max RSS $(( f[1] / 1024 )) MiB, CPU $(awk "BEGIN{print ${f[2]} + ${f[3]}}") s"
}

for i in $(seq "$RUNS"); do
  echo "== round $i"
  run demo_pt "$BIN" "$W/o_demo_pt" "$W/demo/scene" --set 'stages.run=["stats"]'
  run demo_e2e "$BIN" "$W/o_demo_e2e" "$W/demo/scene" "${DEMO_SET[@]}"
  if [ -n "$OLD_BIN" ]; then run demo_old "$OLD_BIN" "$W/o_demo_old" "$W/demo/scene" "${DEMO_SET[@]}"; fi
  run drive_pt "$BIN" "$W/o_drive_pt" "$W/drive_laz" --set 'stages.run=["stats"]'
  run drive_e2e "$BIN" "$W/o_drive_e2e" "$W/drive_laz"
  if [ -n "$OLD_BIN" ]; then run drive_old "$OLD_BIN" "$W/o_drive_old" "$W/drive_laz"; fi
done

if [ "${DRIVE_256:-0}" = 1 ]; then
  echo "== drive at --memory-budget 256, 2 workers"
  run drive_256 "$BIN" "$W/o_drive_256" "$W/drive_laz" --memory-budget 256 --threads 2
fi

python3 - "$W" "${OLD_BIN:+old}" <<'PY'
import json, os, statistics as st, sys
w, old = sys.argv[1], sys.argv[2] if len(sys.argv) > 2 else ""
def med(name):
    rows = [l.split() for l in open(f"{w}/{name}.txt")]
    return st.median(float(r[0]) for r in rows), max(int(r[1]) for r in rows) / 1024
def cpu(name):
    rows = [l.split() for l in open(f"{w}/{name}.txt")]
    return st.median(float(r[2]) + float(r[3]) for r in rows if len(r) >= 4)
def phase_seconds(s, stage, phase):
    return sum(t.get("stats", {}).get(stage, {}).get("seconds", {}).get(phase, 0.0) for t in s["tile_list"])
for scene in ("demo", "drive"):
    s = json.load(open(f"{w}/o_{scene}_e2e/summary.json"))
    n = s["points_in"]
    pt, pt_rss = med(f"{scene}_pt"); e2e, e2e_rss = med(f"{scene}_e2e")
    print(f"{scene}: {n} points")
    print(f"  pass-through: median {pt:.2f} s = {n / pt / 1e6:.2f} M points/s (max RSS {pt_rss:.0f} MiB)")
    print(f"  end to end:   median {e2e:.2f} s = {n / e2e / 1e6:.2f} M points/s (max RSS {e2e_rss:.0f} MiB)")
    print(f"  throughput ratio end-to-end / pass-through: {pt / e2e:.3f}")
    pt_cpu, e2e_cpu = cpu(f"{scene}_pt"), cpu(f"{scene}_e2e")
    busy = e2e_cpu / e2e
    budget = 2 * pt * busy - pt_cpu
    stage_cpu = sum(v["cpu_seconds"] for k, v in s["stages"].items())
    nbr = phase_seconds(s, "segment", "neighbours") + phase_seconds(s, "label", "neighbours")
    print(f"  CPU: pass-through {pt_cpu:.1f} s, end to end {e2e_cpu:.1f} s ({busy:.2f} cores busy); "
          f"stages {stage_cpu:.1f} s, of which neighbour searches {nbr:.1f} s (last run)")
    print(f"  CPU a ratio of 0.5 leaves beyond the codec: 2 x {pt:.2f} s x {busy:.2f} cores - {pt_cpu:.1f} s = {budget:.1f} s "
          f"(end to end spends {e2e_cpu - pt_cpu:.1f} s beyond it)")
    if old:
        o, o_rss = med(f"{scene}_old")
        print(f"  old binary end to end: median {o:.2f} s (max RSS {o_rss:.0f} MiB); ratio old/pass-through {pt / o:.3f}; speed-up {o / e2e:.2f}x")
    so = json.load(open(f"{w}/o_{scene}_old/summary.json")) if old else None
    for k, v in s["stages"].items():
        if k == "stats":
            continue
        was = ""
        if so and k in so.get("stages", {}):
            was = f" (old binary, last run: {so['stages'][k]['cpu_us_per_input_point']:.2f})"
        print(f"  stage {k:8s} {v['cpu_us_per_input_point']:6.2f} CPU-us per input point{was}, "
              f"{v['points_per_input_point']:.2f} points worked on per input point, "
              f"peak {v['bytes_per_point_peak']:.0f} B per tile point")
    print(f"  tiles {s['tiles']}, split grid tiles {s['tiles_split']}")
if not os.path.exists(f"{w}/o_drive_256/summary.json"):
    sys.exit(0)
s = json.load(open(f"{w}/o_drive_256/summary.json"))
t, rss = med("drive_256")
print(f"drive at 256 MiB, 2 workers: {t:.1f} s wall, max RSS {rss:.0f} MiB (VmHWM {s['peak_rss_mb']:.0f} MiB), "
      f"{s['tiles']} tiles, {s['tiles_split']} split")
PY
