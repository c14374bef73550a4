#!/usr/bin/env bash
# Behaviour check between two versions: builds an earlier commit (a git worktree with its own
# target directory) and the working tree, runs both binaries on the same inputs with fresh
# output directories, and compares every output tile and segment table byte for byte.
#
# Usage: scripts/compare_outputs.sh OLD_COMMIT [WORKDIR]
# Inputs: the demo street scene (default pipeline), a simulated MCAP drive (default pipeline),
# an ISPRS sample with config/airborne.toml and the CycloMedia tile (default pipeline) — the
# last two from $TESSERA_DATA (default ../shared/data), skipped when missing.
# Exit 0 when every output is identical, 1 otherwise.
#
# SPEED_RUNS=N (default 0) then also times the demo (`tessera demo`, default scene) N times per
# binary, old and new alternated, and prints the medians of the pipeline time (summary.json
# seconds.pipeline) and of the whole command's wall time, and their ratios new/old.
set -euo pipefail
cd "$(dirname "$0")/.."
OLD=${1:?usage: scripts/compare_outputs.sh OLD_COMMIT [WORKDIR]}
W=${2:-/tmp/tessera-compare}
DATA=${TESSERA_DATA:-../shared/data}
rm -rf "$W"; mkdir -p "$W"
git worktree add -f --detach "$W/old-src" "$OLD" > /dev/null
trap 'git worktree remove --force "$W/old-src" 2>/dev/null || true' EXIT
# A cold release build takes ~14 min here; SEED_TARGET=target copies the current release
# artefacts first so only the tessera crate itself is rebuilt for the old commit.
if [ -n "${SEED_TARGET:-}" ] && [ -d "$SEED_TARGET/release" ]; then
  mkdir -p "$W/old-target"; cp -r "$SEED_TARGET/release" "$W/old-target/"
fi
echo "== building $OLD and the working tree (release)"
cargo build --release -q --manifest-path "$W/old-src/Cargo.toml" --target-dir "$W/old-target"
cargo build --release -q
OLD_BIN="$W/old-target/release/tessera"
NEW_BIN="${CARGO_TARGET_DIR:-target}/release/tessera"

"$NEW_BIN" -q synth --out "$W/in/demo" --length-m 150 --seed 1
"$NEW_BIN" -q synth --mcap --out "$W/in/drive" --length-m 40
CASES=("demo|$W/in/demo|" "drive|$W/in/drive/drive.mcap|")
[ -f "$DATA/isprs-filtertest/samp11-utm.laz" ] && CASES+=("isprs-samp11|$DATA/isprs-filtertest/samp11-utm.laz|--config config/airborne.toml")
[ -f "$DATA/cyclomedia-amsterdam-sidewalk/sidewalk_run1_2386_9702.laz" ] && CASES+=("cyclomedia|$DATA/cyclomedia-amsterdam-sidewalk/sidewalk_run1_2386_9702.laz|")

status=0
for c in "${CASES[@]}"; do
  IFS='|' read -r name input opts <<< "$c"
  # shellcheck disable=SC2086
  "$OLD_BIN" -q run "$input" --out "$W/old/$name" $opts
  # shellcheck disable=SC2086
  "$NEW_BIN" -q run "$input" --out "$W/new/$name" $opts
  # (find, not a glob: a run without segmentation writes no *.segments.tsv, and a failed
  # glob must not end the script under pipefail.)
  list() { (cd "$1" && find . -maxdepth 1 -type f \( -name '*.la[sz]' -o -name '*.segments.tsv' \) -printf '%f\n' | sort); }
  files=$(list "$W/old/$name")
  newfiles=$(list "$W/new/$name")
  if [ "$files" != "$newfiles" ]; then
    echo "$name: DIFFERENT file sets"; status=1; continue
  fi
  same=0; diff=0
  for f in $files; do
    if cmp -s "$W/old/$name/$f" "$W/new/$name/$f"; then same=$((same + 1)); else diff=$((diff + 1)); echo "  differs: $name/$f"; fi
  done
  [ "$diff" -eq 0 ] || status=1
  echo "$name: $same files identical, $diff different"
done

if [ "${SPEED_RUNS:-0}" -gt 0 ]; then
  echo "== speed: tessera demo, $SPEED_RUNS runs per binary, alternated (old, new, old, ...)"
  for i in $(seq 1 "$SPEED_RUNS"); do
    for v in old new; do
      bin=$OLD_BIN; [ "$v" = new ] && bin=$NEW_BIN
      d="$W/speed/$v"; rm -rf "$d"; sync
      t0=$(date +%s.%N)
      "$bin" -q demo --out "$d" > /dev/null
      t1=$(date +%s.%N)
      p=$(python3 -c "import json,sys; print(json.load(open(sys.argv[1]))['seconds']['pipeline'])" "$d/tiles/summary.json")
      echo "$v $p $(python3 -c "print($t1 - $t0)")" | tee -a "$W/speed.txt"
    done
  done
  python3 - "$W/speed.txt" <<'PY'
import statistics, sys
rows = [l.split() for l in open(sys.argv[1]) if l.strip()]
med = {}
for v in ("old", "new"):
    pipe = [float(r[1]) for r in rows if r[0] == v]
    wall = [float(r[2]) for r in rows if r[0] == v]
    med[v] = (statistics.median(pipe), statistics.median(wall))
    print(f"{v}: pipeline median {med[v][0]:.2f} s (runs {', '.join(f'{x:.2f}' for x in pipe)}); "
          f"demo wall median {med[v][1]:.2f} s")
print(f"ratio new/old: pipeline {med['new'][0] / med['old'][0]:.3f}, wall {med['new'][1] / med['old'][1]:.3f}")
PY
fi
exit $status
