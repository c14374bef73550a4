#!/usr/bin/env bash
# What report.html costs (issue 24 gate: <= 5 % of the pipeline time on the demo): the demo
# with output.report = true and = false, alternating, N runs each (default 3), same binary,
# same session. The run with the report draws its rasters while the tiles are written (inside
# seconds.total) and then assembles the page (seconds.report); the cost is
#   median(total_on + report) / median(total_off) - 1.
# Usage: scripts/bench_report.sh [N] [LENGTH_M]   (BIN=path to a release tessera)
set -euo pipefail
N=${1:-3}
LEN=${2:-300}
BIN=${BIN:-$(dirname "$0")/../target/release/tessera}
W=$(mktemp -d /tmp/tessera-bench-report.XXXXXX)
trap 'rm -rf "$W"' EXIT
on=(); off=(); rep=()
for i in $(seq 1 "$N"); do
  for mode in true false; do
    rm -rf "$W/d"
    "$BIN" -q demo --out "$W/d" --length-m "$LEN" --set output.report=$mode > /dev/null
    read -r total report < <(python3 -c "import json,sys; s=json.load(open('$W/d/tiles/summary.json'))['seconds']; print(s['total'], s.get('report', 0))")
    if [ "$mode" = true ]; then
      on+=("$(python3 -c "print($total + $report)")"); rep+=("$report")
      [ -f "$W/d/tiles/report.html" ] || { echo "no report.html written"; exit 1; }
    else
      off+=("$total")
      [ ! -f "$W/d/tiles/report.html" ] || { echo "report.html written with output.report=false"; exit 1; }
    fi
    echo "run $i report=$mode: total $total s, report $report s"
  done
done
python3 - "${on[*]}" "${off[*]}" "${rep[*]}" <<'PY'
import sys, statistics as st
on, off, rep = ([float(x) for x in a.split()] for a in sys.argv[1:4])
m_on, m_off = st.median(on), st.median(off)
print(f"median with report {m_on:.2f} s (page assembly {st.median(rep):.2f} s), without {m_off:.2f} s: cost {100 * (m_on / m_off - 1):+.1f} %")
PY
