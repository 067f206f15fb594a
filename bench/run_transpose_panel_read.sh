#!/usr/bin/env bash
# Diagnostic for `ltbake transpose`: how long its panel passes take to read the input
# when it is NOT in the page cache (the out-of-core case: input larger than free RAM),
# as the stage reads it and with a prefetch.
#
#   bash bench/run_transpose_panel_read.sh BUILD_DIR [PANEL_COLS=2043]
#
# Makes the same 65536 x 24576 input as run_transpose.sh (LTB_BENCH_ROWS/COLS to change),
# then for every panel k (columns [k*PANEL_COLS, ...), 2043 = what the stage uses at 65536
# rows and --mem-limit 1GiB) evicts the file and runs `ltb_transpose_bench panel-read`:
#   plain      2 threads, one pread per row of the panel's column range (the stage's pattern)
#   prefetch   the same plus posix_fadvise(WILLNEED) of the next 85 rows' ranges
#   jobs8      8 threads, no prefetch
# Evicting before each panel stands for a page cache too small to keep the input between
# panels. Raw lines: bench/results/transpose_panel_read.jsonl; sums printed at the end.
set -euo pipefail
BUILD=${1:?usage: run_transpose_panel_read.sh BUILD_DIR [PANEL_COLS=2043]}
PC=${2:-2043}
ROWS=${LTB_BENCH_ROWS:-65536}
COLS=${LTB_BENCH_COLS:-24576}
HERE=$(cd "$(dirname "$0")" && pwd)
BUILD_ABS=$(cd "$BUILD" && pwd)
OUT=${LTB_BENCH_DIR:-$HERE/out}/panel_read
mkdir -p "$OUT" "$HERE/results"
cp "$BUILD_ABS/bench/ltm_io_bench" "$BUILD_ABS/bench/ltb_transpose_bench" "$OUT/"
IN=$OUT/in.ltm
JSONL=$HERE/results/transpose_panel_read.jsonl
trap 'rm -f "$IN" "$OUT/ltm_io_bench" "$OUT/ltb_transpose_bench"; rmdir "$OUT" 2>/dev/null || true' EXIT
avail_kib=$(df -Pk "$OUT" | awk 'NR==2{print $4}')
((avail_kib > ROWS * COLS * 4 / 1024 + 1048576)) || { echo "not enough free disk in $OUT" >&2; exit 1; }

"$OUT/ltb_transpose_bench" make "$IN" --rows "$ROWS" --cols "$COLS" >/dev/null
: >"$JSONL"
for ((c0 = 0; c0 < COLS; c0 += PC)); do
  n=$((COLS - c0 < PC ? COLS - c0 : PC))
  for v in plain prefetch jobs8; do
    case $v in
      plain) flags=() ;;
      prefetch) flags=(--prefetch-rows 85) ;;
      jobs8) flags=(--jobs 8) ;;
    esac
    "$OUT/ltm_io_bench" evict "$IN" >/dev/null
    sync
    j=$("$OUT/ltb_transpose_bench" panel-read "$IN" --col0 "$c0" --panel-cols "$n" "${flags[@]}")
    echo "{\"variant\": \"$v\", \"result\": $j}" >>"$JSONL"
  done
done
/usr/bin/python3 - "$JSONL" <<'EOF'
import json, sys
rows = [json.loads(l) for l in open(sys.argv[1])]
for v in ("plain", "prefetch", "jobs8"):
    r = [x["result"] for x in rows if x["variant"] == v]
    s = sum(x["seconds"] for x in r)
    b = sum(x["bytes"] for x in r)
    print(f"{v:<9} {len(r)} panels, {s:6.2f} s in total, {b / s / 1e9:.3f} GB/s useful, "
          f"per panel {min(x['seconds'] for x in r):.2f}-{max(x['seconds'] for x in r):.2f} s")
EOF
