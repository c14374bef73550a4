#!/usr/bin/env bash
# Segmentation benchmark (issue 4).
# 1. The 1 M-point synthetic tile of ../shared/peers/make_synth.py, non-ground points only (the
#    reference classes, as the peers get them): tessera's segment stage (config/airborne.toml,
#    the thesis ALS set) vs PCL RegionGrowingRGB (peers' pcl_rg driver, run_peers.sh settings)
#    and CloudCompare RANSAC planes, runs alternated in the same session. Whole-process wall
#    time (median of RUNS) and roof-facet ARI from the peers' own scorer
#    (score_objects.py --ref-field user_data).
# 2. Segment-stage throughput on a synthetic street scene of >= 20 M points (SCENE_M metres of
#    drive): points segmented per second of stage time, whole-run wall time and peak RSS.
# Needs: python3 with laspy, lazrs, numpy; PCL_RG (compiled ../shared/peers/pcl_rg.cpp) and
# CloudCompare optional (../shared/peers/setup_peers.sh installs both).
# Usage: scripts/bench_segment.sh [RUNS=3]   env: PCL_RG, SCENE_M (default 1000), SKIP_BIG=1
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-3}
PEERS=$(readlink -f "${PEERS:-../shared/peers}")
PCL_RG=${PCL_RG:-$(command -v pcl_rg || true)}
W=${BENCH_DIR:-/tmp/tessera-bench-segment}
rm -rf "$W"; mkdir -p "$W"
cargo build --release -q
BIN=$(readlink -f "${CARGO_TARGET_DIR:-target}/release/tessera")
python3 "$PEERS/make_synth.py" "$W/ref.las" --n 1000000 --tool-input "$W/in.las" > /dev/null
python3 "$PEERS/pcdio.py" las2pcd "$W/ref.las" "$W/ng.pcd" --drop-class 2,7 > /dev/null
python3 - "$W" <<'PY'
import sys, numpy as np, laspy
w = sys.argv[1]; r = laspy.read(f"{w}/ref.las"); m = r.header.mins
a = np.column_stack([np.asarray(r.x)-m[0], np.asarray(r.y)-m[1], np.asarray(r.z),
                     np.asarray(r.red)>>8, np.asarray(r.green)>>8, np.asarray(r.blue)>>8, np.arange(len(r.points))])
ng = ~np.isin(np.asarray(r.classification), [2, 7])
np.savetxt(f"{w}/ng_idx.txt", a[ng], fmt="%.3f %.3f %.3f %d %d %d %d")
PY
HAVE_CC=0; command -v CloudCompare > /dev/null && HAVE_CC=1
t() { /usr/bin/time -f "%e" -o "$W/t" "$@" > "$W/log" 2>&1; cat "$W/t"; }
declare -a TT TP TC
for i in $(seq "$RUNS"); do
  rm -rf "$W/tess"
  # One tile holds the whole 200 m site (the peers run untiled too); 2 GiB so it is not split.
  TT+=("$(t "$BIN" -q run "$W/ref.las" --out "$W/tess" --config config/airborne.toml \
      --set 'stages.run=["segment"]' --set tiling.tile_size_m=1000 --memory-budget 2048 --set output.format=las)")
  [ -n "$PCL_RG" ] && TP+=("$(t "$PCL_RG" rgb "$W/ng.pcd" "$W/rg_rgb.txt" 1.0 35 25 50 1 10 30)")
  if [ $HAVE_CC = 1 ]; then
    rm -rf "$W/ccr"; mkdir -p "$W/ccr"; cp "$W/ng_idx.txt" "$W/ccr/ng.txt"
    TC+=("$(cd "$W/ccr" && QT_QPA_PLATFORM=offscreen t CloudCompare -SILENT -NO_TIMESTAMP -AUTO_SAVE OFF \
        -C_EXPORT_FMT ASC -O ng.txt -RANSAC EPSILON_ABSOLUTE 0.15 BITMAP_EPSILON_ABSOLUTE 0.5 SUPPORT_POINTS 200 \
        MAX_NORMAL_DEV 20 PROBABILITY 0.01 ENABLE_PRIMITIVE PLANE OUT_CLOUD_DIR . OUTPUT_INDIVIDUAL_SUBCLOUDS)")
  fi
  echo "run $i: tessera ${TT[-1]} s${TP:+, PCL RG-RGB ${TP[-1]} s}${TC:+, CloudCompare RANSAC ${TC[-1]} s}"
done
# tessera's segment_id back to the reference order (matched by coordinates; not timed).
python3 - "$W" <<'PY'
import glob, sys, numpy as np, laspy
w = sys.argv[1]; r = laspy.read(f"{w}/ref.las")
key = lambda f: np.round(np.column_stack([f.x, f.y, f.z]) * 1000).astype(np.int64)
rk = key(r); lut = {}
for t in sorted(glob.glob(f"{w}/tess/*.las")):
    f = laspy.read(t); ids = np.asarray(f.segment_id).astype(np.int64)
    for k, s in zip(map(tuple, key(f)), ids): lut[k] = s
lab = np.array([lut[tuple(k)] for k in rk], np.int64)
lab = np.where(lab > 0, lab, -1)
lab[np.isin(np.asarray(r.classification), [2, 7])] = -2
np.save(f"{w}/tess.npy", lab)
PY
score() { python3 "$PEERS/score_objects.py" "$W/ref.las" "$1" --ref-field user_data | tail -1; }
med() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END{print (NR%2)?a[(NR+1)/2]:(a[NR/2]+a[NR/2+1])/2}'; }
mt=$(med "${TT[@]}")
echo "tessera segment (airborne set), non-ground: median $mt s; facets: $(score "$W/tess.npy")"
if [ -n "$PCL_RG" ]; then
  python3 "$PEERS/labels_txt_to_npy.py" "$W/ref.las" "$W/rg_rgb.txt" "$W/rg_rgb.npy" --drop-class 2,7
  mp=$(med "${TP[@]}")
  echo "PCL RegionGrowingRGB, non-ground:          median $mp s; facets: $(score "$W/rg_rgb.npy")"
  python3 -c "print(f'speed ratio PCL RG-RGB / tessera: {float($mp)/float($mt):.2f} (target >= 5)')"
fi
if [ $HAVE_CC = 1 ]; then
  N=$(python3 -c "import laspy,sys; print(laspy.open(sys.argv[1]).header.point_count)" "$W/ref.las")
  ls "$W"/ccr/*PLANE*.asc | tr '\n' '\0' | xargs -0 python3 "$PEERS/idx_files_to_labels.py" labels "$N" "$W/cc.npy" --col 6 > /dev/null
  python3 - "$W" <<'PY'
import sys, numpy as np, laspy
w = sys.argv[1]; r = laspy.read(f"{w}/ref.las"); l = np.load(f"{w}/cc.npy")
l[np.isin(np.asarray(r.classification), [2, 7])] = -2; np.save(f"{w}/cc.npy", l)
PY
  echo "CloudCompare RANSAC planes, non-ground:    median $(med "${TC[@]}") s; facets: $(score "$W/cc.npy")"
fi

[ "${SKIP_BIG:-0}" = 1 ] && exit 0
# ---- throughput on a >= 20 M point street scene ----
SCENE_M=${SCENE_M:-1000}
"$BIN" -q synth --out "$W/street" --length-m "$SCENE_M" > /dev/null
rm -rf "$W/big"
/usr/bin/time -v "$BIN" -q run "$W/street" --out "$W/big" --set 'stages.run=["ground","segment","stats"]' 2> "$W/big.time"
python3 - "$W" <<'PY'
import json, re, sys
w = sys.argv[1]; s = json.load(open(f"{w}/big/summary.json"))
seg = sum(t["stats"]["segment"]["points_considered"] for t in s["tile_list"])
sec = s["seconds"]
wall = re.search(r"Elapsed \(wall clock\) time \(h:mm:ss or m:ss\): (\S+)", open(f"{w}/big.time").read()).group(1)
rss = int(re.search(r"Maximum resident set size \(kbytes\): (\d+)", open(f"{w}/big.time").read()).group(1)) / 1024
print(f"street scene: {s['points_in']:,} points, {s['tiles']} tiles; segment stage {sec['stage_segment']:.1f} s "
      f"(summed over workers) for {seg:,} points considered (core + {5} m strip, non-ground): "
      f"{seg / sec['stage_segment'] / 1e6:.2f} M points/s per worker, "
      f"{s['points_in'] / sec['stage_segment'] / 1e6:.2f} M input points/s per worker; "
      f"ground stage {sec['stage_ground']:.1f} s; whole run wall {wall}, peak RSS {rss:.0f} MiB")
PY
