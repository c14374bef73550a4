#!/usr/bin/env bash
# Issue 22: where the 5 M points/s per core target stands against the mean-shift filters the
# multi-cue method is built on, and against the method the target comes from. On the benchmark
# drive of `cargo bench --bench multicue` (seed 7, 60 m, 77 scans of 32 x 1024, 2.01 M returns),
# runs alternated RUNS times, one core each:
#   tessera    the multi-cue bench (MULTICUE_ONLY=1): all three cues, integration included; the
#              colour cue alone; the colour cue alone with the exact filter (basin_px = 0)
#   OpenCV     cv2.pyrMeanShiftFiltering on the colour images (8-bit CIELab, 3 x 3 window as
#              tessera's hs_px = 1, colour bandwidth 8, at most 5 moves as max_iter): one cue,
#              the filter only
#   EDISON     Comaniciu & Meer's reference code (msImageProcessor::Filter: filter, then pixels
#              of one mode connected into regions), sigma_s 2 (its window test is d^2 < sigma_s^2,
#              so 2 is the same 3 x 3 window), sigma_r 8, each of its three speed-up levels:
#              one cue
#   single-pass  Bogoslavskyi & Stachniss's range-image labelling (theta 10 deg), where the
#              issue's target comes from (written here from the paper; no ground removal)
# Needs: g++, python3 with numpy, mcap, rosbags (.ci/run installs them); installs
# opencv-python-headless with pip, and downloads the EDISON sources (the pymeanshift 0.2.2
# source archive from PyPI: its C++ only, the Python wrapper predates numpy 2).
# Usage: scripts/bench_meanshift_peers.sh [RUNS=5]   env: BENCH_DIR
set -euo pipefail
cd "$(dirname "$0")/.."
RUNS=${1:-5}
W=${BENCH_DIR:-/tmp/tessera-bench-meanshift}
# Only a directory this script made (it holds the marker) is ever removed.
if [ -e "$W" ] && [ ! -e "$W/.tessera-bench-meanshift" ]; then
  echo "$W exists and was not made by this script; set BENCH_DIR to a new directory"; exit 1
fi
rm -rf "$W"; mkdir -p "$W/src" "$W/out"; touch "$W/.tessera-bench-meanshift"
python3 -c 'import numpy, mcap, rosbags' \
  || { echo "needs: pip install numpy mcap mcap-ros1-support mcap-ros2-support rosbags"; exit 1; }
python3 -c 'import cv2' 2> /dev/null \
  || python3 -m pip install -q --disable-pip-version-check opencv-python-headless
python3 - "$W/src" <<'PY'
# The archive's address from PyPI's simple index; its digest pinned.
import hashlib, io, re, sys, tarfile, urllib.request
sha = "fe2b3dac59d2f2c6b264ed2b331320622580ca0fd36e2b4cbf73453ec41b7fe2"
index = urllib.request.urlopen("https://pypi.org/simple/pymeanshift/", timeout=60).read().decode()
url = next(u for u in re.findall(r'href="([^"#]+)', index) if u.endswith("pymeanshift-0.2.2.tar.gz"))
data = urllib.request.urlopen(url, timeout=120).read()
if hashlib.sha256(data).hexdigest() != sha:
    sys.exit(f"{url}: sha256 differs from the pinned {sha}")
tarfile.open(fileobj=io.BytesIO(data)).extractall(sys.argv[1])
PY
E="$W/src/pymeanshift-0.2.2"
g++ -O3 -w -I"$E" -o "$W/edison_filter" scripts/meanshift_peers/edison_filter.cpp \
  "$E/ms.cpp" "$E/msImageProcessor.cpp" "$E/rlist.cpp" "$E/RAList.cpp"
g++ -O3 -Wall -o "$W/single_pass" scripts/meanshift_peers/single_pass.cpp
cargo build --release -q
BIN=$(readlink -f "${CARGO_TARGET_DIR:-target}/release/tessera")
"$BIN" -q synth --mcap --seed 7 --length-m 60 --out "$W/drive"
python3 scripts/mcap_dump_clouds.py "$W/drive/drive.mcap" "$W/dump" > /dev/null
python3 scripts/meanshift_peers/images.py "$W/dump" "$W/img"
cargo bench -q --bench multicue --no-run 2> /dev/null
tess() {  # NAME [MULTICUE toml]
  MULTICUE="${2:-}" MULTICUE_ONLY=1 TESSERA_DATA=/nonexistent \
    cargo bench -q --bench multicue -- "$W/drive/drive.mcap" 2> /dev/null \
    | tr '\n' ' ' >> "$W/out/$1"
  echo >> "$W/out/$1"
}
for i in $(seq "$RUNS"); do
  echo "round $i of $RUNS" >&2
  tess tessera_3cues
  tess tessera_colour 'cues = ["colour"]'
  tess tessera_colour_exact $'cues = ["colour"]\nbasin_px = 0'
  python3 scripts/meanshift_peers/opencv_filter.py "$W/img/rgb.raw" 1 8 5 1 1 >> "$W/out/opencv"
  for s in 0 1 2; do "$W/edison_filter" "$W/img/rgb.raw" 2 8 "$s" 1 >> "$W/out/edison_$s"; done
  "$W/single_pass" "$W/img/range.raw" 10 1 >> "$W/out/single_pass"
done
python3 - "$W/out" <<'PY'
import os, re, statistics as st, sys
out = sys.argv[1]
def lines(n): return [l for l in open(os.path.join(out, n)).read().splitlines() if l.strip()]
rows = []
for n, what in [("tessera_3cues", "tessera multicue, 3 cues + integration"),
                ("tessera_colour", "tessera, colour cue alone"),
                ("tessera_colour_exact", "tessera, colour cue alone, exact filter")]:
    L = lines(n)
    rate = st.median(float(re.search(r"multicue ([0-9.]+) M", l).group(1)) for l in L)
    secs = [[float(x) for x in re.search(r"cues ([0-9.]+), mean shift ([0-9.]+), integration ([0-9.]+)", l).groups()] for l in L]
    ms = st.median(s[1] for s in secs); tot = st.median(sum(s) for s in secs)
    ck = sorted(set(re.search(r"checksum ([0-9a-f]+)", l).group(1) for l in L))
    rows.append((what, rate, tot, f"mean shift (filter + grouping) {ms:.2f} s; checksum {','.join(ck)}"))
for n, what in [("opencv", "OpenCV pyrMeanShiftFiltering, colour, filter only"),
                ("edison_0", "EDISON Filter, colour, no speed-up"),
                ("edison_1", "EDISON Filter, colour, medium speed-up"),
                ("edison_2", "EDISON Filter, colour, high speed-up"),
                ("single_pass", "single-pass labelling (Bogoslavskyi & Stachniss)")]:
    L = lines(n)
    rate = st.median(float(re.search(r"median ([0-9.]+) M", l).group(1)) for l in L)
    tot = st.median(float(re.search(r"returns, ([0-9.]+) s", l).group(1)) for l in L)
    rows.append((what, rate, tot, ""))
base = rows[0][1]
print(f"{'method':52s} {'M returns/s':>11s} {'x tessera':>9s} {'seconds':>8s}  (medians of {len(lines('opencv'))} alternated runs; per-scan medians)")
for what, rate, tot, extra in rows:
    print(f"{what:52s} {rate:11.2f} {rate / base:9.2f} {tot:8.3f}  {extra}")
PY
