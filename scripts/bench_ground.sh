#!/usr/bin/env bash
# Ground filtering: tessera (config/airborne.toml) vs CSF (csf_ground.py --res 1 --rigid 2
# --slope-smooth) and PCL's approximate progressive morphological filter, on the 1 M-point
# synthetic tile of ../shared/peers/make_synth.py, runs alternated in the same session.
# Whole-process wall time (median of RUNS) and Cohen's kappa from the peers' own scorer.
# Needs: python3 with laspy, lazrs, numpy, cloth-simulation-filter; pcl-tools (optional).
# Usage: scripts/bench_ground.sh [RUNS=3]
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-3}
PEERS=$(readlink -f "${PEERS:-../shared/peers}")
W=${BENCH_DIR:-/tmp/tessera-bench-ground}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN=$(readlink -f "${CARGO_TARGET_DIR:-target}/release/tessera")
python3 "$PEERS/make_synth.py" "$W/ref.las" --n 1000000 --tool-input "$W/in.las" > /dev/null
HAVE_PCL=0; command -v pcl_progressive_morphological_filter > /dev/null && HAVE_PCL=1
[ $HAVE_PCL = 1 ] && python3 "$PEERS/pcdio.py" las2pcd "$W/in.las" "$W/all.pcd" > /dev/null
t() { /usr/bin/time -f "%e" -o "$W/t" "$@" > "$W/log" 2>&1; cat "$W/t"; }
score() { python3 "$PEERS/score_ground.py" "$W/ref.las" "$1" | tail -1; }
kappa() { echo "$1" | grep -o 'kappa[^%]*%' | head -1; }
declare -a TT TC TP
for i in $(seq "$RUNS"); do
  rm -rf "$W/tess"
  TT+=("$(t "$BIN" -q run "$W/in.las" --out "$W/tess" --config config/airborne.toml --set 'stages.run=["ground"]' --set output.format=las)")
  TC+=("$(t python3 "$PEERS/csf_ground.py" "$W/in.las" "$W/csf.las" --res 1.0 --rigid 2 --slope-smooth)")
  if [ $HAVE_PCL = 1 ]; then
    TP+=("$(t pcl_progressive_morphological_filter "$W/all.pcd" "$W/pmf.pcd" -max_window_size 33 -slope 0.5 \
        -max_distnace 2.0 -initial_distance 0.3 -cell_size 1.0 -base 2 -exponential 1 -approximate 1)")
  fi
  echo "run $i: tessera ${TT[-1]} s, CSF ${TC[-1]} s${TP:+, PCL PMF ${TP[-1]} s}"
done
# Merge tessera's tiles into one file for the peers' scorer (not timed).
python3 - "$W" <<'PY'
import glob, sys, laspy, numpy as np
w = sys.argv[1]
tiles = sorted(glob.glob(f"{w}/tess/*.las"))
first = laspy.read(tiles[0]); pts = [laspy.read(t).points for t in tiles]
out = laspy.LasData(first.header); out.points = laspy.ScaleAwarePointRecord(
    np.concatenate([p.array for p in pts]), first.header.point_format, first.header.scales, first.header.offsets)
out.write(f"{w}/tess.las")
PY
ST=$(score "$W/tess.las"); SC=$(score "$W/csf.las")
if [ $HAVE_PCL = 1 ]; then
  pcl_convert_pcd_ascii_binary "$W/pmf.pcd" "$W/pmf_b.pcd" 1 > /dev/null 2>&1
  python3 "$PEERS/pcdio.py" subset2las "$W/ref.las" "$W/all.pcd" "$W/pmf_b.pcd" "$W/pmf.las" > /dev/null
  SP=$(score "$W/pmf.las")
fi
med() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END{print (NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2}'; }
mt=$(med "${TT[@]}"); mc=$(med "${TC[@]}")
echo "tessera ground (airborne set): median $mt s; $ST"
echo "CSF res 1 rigid 2 slope smooth: median $mc s; $SC"
[ $HAVE_PCL = 1 ] && echo "PCL PMF approximate:          median $(med "${TP[@]}") s; $SP"
python3 -c "print(f'speed ratio CSF/tessera: {float($mc)/float($mt):.2f} (>1: tessera faster)')"
