#!/usr/bin/env bash
# Real-data evaluations through the product path (tessera run + tessera eval), called by CI when
# ../shared/data exists. Fails when the ISPRS gate is missed (mean total error > 5.0 % or mean
# kappa < 84 %, each sample filtered on its own with config/airborne.toml).
# Also reports the original ISPRS protocol (filter the whole site file, score the sample points
# found in it by coordinates) for information.
set -euo pipefail
cd "$(dirname "$0")/.."
DATA=${TESSERA_DATA:-../shared/data}
ISPRS="$DATA/isprs-filtertest"
W=$(mktemp -d); trap 'rm -rf "$W"' EXIT
cargo build --release -q
BIN="${CARGO_TARGET_DIR:-target}/release/tessera"

if [ ! -d "$ISPRS" ]; then
  # Under CI the gate must run: missing data fails it.
  if [ "${CI:-}" = "true" ]; then echo "FAIL: $ISPRS not found (CI=true requires it)"; exit 1; fi
  echo "SKIP: $ISPRS not found"; exit 0
fi
echo "== ISPRS filter test: each sample filtered alone, config/airborne.toml (one parameter set)"
: > "$W/samples.jsonl"
for s in 11 12 21 22 23 24 31 41 42 51 52 53 54 61 71; do
  f="$ISPRS/samp$s-utm.laz"
  $BIN -q run "$f" --out "$W/s$s" --config config/airborne.toml
  $BIN eval ground --reference "$f" --result "$W/s$s" --json | sed "s/^{/{\"sample\":\"samp$s\",/" >> "$W/samples.jsonl"
done
echo "== ISPRS original protocol: whole site filtered, sample points scored (information)"
: > "$W/sites.jsonl"
for pair in "21 CSite2_orig" "22 CSite2_orig" "23 CSite2_orig" "24 CSite2_orig" "31 CSite3_orig" \
            "41 CSite4_orig" "42 CSite4_orig" "51 FSite5_orig" "52 FSite5_orig" "53 FSite5_orig" \
            "54 FSite5_orig" "61 FSite6_orig" "71 FSite7_orig"; do
  set -- $pair
  site="$ISPRS/$2-utm.laz"
  [ -d "$W/$2" ] || $BIN -q run "$site" --out "$W/$2" --config config/airborne.toml
  $BIN eval ground --reference "$ISPRS/samp$1-utm.laz" --result "$W/$2" --allow-unmatched --match-precision-m 0.01 --json \
    | sed "s/^{/{\"sample\":\"samp$1\",\"site\":\"$2\",/" >> "$W/sites.jsonl"
done
python3 - "$W/samples.jsonl" "$W/sites.jsonl" <<'PY'
import json, sys
def table(path, title):
    rows = [json.loads(l) for l in open(path)]
    print(f"\n{title}")
    print(f"{'sample':<8} {'scored':>7} {'TypeI%':>7} {'TypeII%':>8} {'total%':>7} {'kappa%':>7}")
    for r in rows:
        print(f"{r['sample']:<8} {r['scored_points']:>7} {r['type1_pct']:>7.2f} {r['type2_pct']:>8.2f} {r['total_pct']:>7.2f} {r['kappa_pct']:>7.2f}")
    mt = sum(r['total_pct'] for r in rows) / len(rows)
    mk = sum(r['kappa_pct'] for r in rows) / len(rows)
    print(f"{'mean':<8} {'':>7} {'':>7} {'':>8} {mt:>7.2f} {mk:>7.2f}")
    return mt, mk
mt, mk = table(sys.argv[1], "ISPRS samples (each filtered alone; gate: mean total <= 5.0 %, mean kappa >= 84 %; PDAL smrf defaults 5.14 / 83.3)")
table(sys.argv[2], "ISPRS original protocol (site filtered, samples matched at 1 cm; samp11/12 need the missing CSite1_orig)")
if mt > 5.0 or mk < 84.0:
    print(f"FAIL: ISPRS gate missed (mean total {mt:.2f} %, mean kappa {mk:.2f} %)")
    sys.exit(1)
print(f"\nISPRS gate passed: mean total {mt:.2f} %, mean kappa {mk:.2f} %")
PY
