#!/usr/bin/env bash
# Container (.ltm) write/read throughput against dd on the same disk.
#
#   bash bench/run_container_io.sh BUILD_DIR [SIZE_GIB=4] [REPS=3]
#
# Each repetition, in alternating order (dd first on odd reps, the container first on
# even ones):
#   dd:        dd if=/dev/zero of=F bs=8M count=N conv=fdatasync          (write)
#              evict F; dd if=F of=/dev/null bs=8M                          (read)
#              ltm_io_bench gen | dd of=F bs=8M iflag=fullblock conv=fdatasync
#                                                  (write of random data, reference)
#   container: ltm_io_bench write C --bytes SIZE   (random f32, raw, Finish() fdatasyncs)
#              evict C; ltm_io_bench read C                 (plain loop, checksums on)
#              evict C; ltm_io_bench read C --no-verify
#              evict C; ltm_io_bench read C --prefetch 4    (caller-side readahead)
#              evict C; dd if=C of=/dev/null bs=8M          (dd over the same blocks)
# "evict" = fdatasync + posix_fadvise(DONTNEED) on the file (ltm_io_bench evict), plus
# `echo 3 > /proc/sys/vm/drop_caches` when this user may write it; the script checks
# with mincore that no byte of the file is left in the page cache before each read.
# Then a SIZE_GIB=1 container is written and read once more, to show the reader's
# peak RSS does not grow with the file.
#
# Every time is the wall time of the whole process (date +%s.%N around it), GB/s is
# the file's size / that time (1 GB = 1e9 bytes). Medians over the repetitions and
# the container/dd ratios go to bench/results/container_io.md; raw JSON lines to
# bench/results/container_io.jsonl. Files go to $LTB_BENCH_DIR (default bench/out/,
# on the same disk as the repository) and are deleted as soon as they are measured:
# at most one SIZE_GIB file exists at a time.
set -euo pipefail

BUILD=${1:?usage: run_container_io.sh BUILD_DIR [SIZE_GIB=4] [REPS=3]}
SIZE_GIB=${2:-4}
REPS=${3:-3}
HERE=$(cd "$(dirname "$0")" && pwd)
BIN=$(cd "$BUILD" && pwd)/bench/ltm_io_bench
[[ -x $BIN ]] || { echo "no $BIN: build first (make build)" >&2; exit 1; }
OUT=${LTB_BENCH_DIR:-$HERE/out}
RESULTS=$HERE/results
mkdir -p "$OUT" "$RESULTS"
PY=/usr/bin/python3
[[ -x $PY ]] || PY=python3

BYTES=$((SIZE_GIB * 1024 * 1024 * 1024))
BS=$((8 * 1024 * 1024))
COUNT=$((BYTES / BS))
DDF=$OUT/dd.bin
LTM=$OUT/bench.ltm
JSONL=$RESULTS/container_io.jsonl
trap 'rm -f "$DDF" "$LTM" "$OUT"/small.ltm' EXIT

need_gib=$((SIZE_GIB + 1))
avail_kib=$(df -Pk "$OUT" | awk 'NR==2{print $4}')
if ((avail_kib < need_gib * 1024 * 1024)); then
  echo "need ${need_gib} GiB free in $OUT, have $((avail_kib / 1024 / 1024)) GiB" >&2
  exit 1
fi

DROP=no
if [[ -w /proc/sys/vm/drop_caches ]] && (sync && echo 3 >/proc/sys/vm/drop_caches) 2>/dev/null; then DROP=yes; fi

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.6f", b - a }'; }
# evict FILE: drop FILE's pages from the page cache; fails when any are left.
evict() {
  "$BIN" evict "$1" >/dev/null
  if [[ $DROP == yes ]]; then sync; echo 3 >/proc/sys/vm/drop_caches; fi
  local left
  left=$("$BIN" resident "$1" | "$PY" -c 'import json,sys; print(json.load(sys.stdin)["resident_bytes"])')
  if [[ $left != 0 ]]; then echo "eviction left $left bytes of $1 in the page cache" >&2; return 1; fi
}
# record KIND REP SECONDS FILE_BYTES [JSON from the tool]: appends to $JSONL, prints a line.
record() {
  "$PY" - "$JSONL" "$@" <<'EOF'
import json, sys
path, kind, rep, secs, size = sys.argv[1], sys.argv[2], int(sys.argv[3]), float(sys.argv[4]), int(sys.argv[5])
d = {"kind": kind, "rep": rep, "wall_seconds": secs, "file_bytes": size, "gb_per_s": size / secs / 1e9}
if len(sys.argv) > 6 and sys.argv[6]:
    d["tool"] = json.loads(sys.argv[6])
with open(path, "a") as f:
    f.write(json.dumps(d) + "\n")
rss = d.get("tool", {}).get("peak_rss_kib")
print(f"  rep {rep} {kind:<20} {secs:7.3f} s {d['gb_per_s']:7.3f} GB/s" + (f"  peak RSS {rss / 1024:.1f} MiB" if rss else ""))
EOF
}
settle() { sync; sleep 1; }

run_dd() {
  local rep=$1 t0 t1
  rm -f "$DDF"; settle
  t0=$(now); dd if=/dev/zero of="$DDF" bs=$BS count=$COUNT conv=fdatasync status=none; t1=$(now)
  record dd_write "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$DDF")"
  evict "$DDF"
  t0=$(now); dd if="$DDF" of=/dev/null bs=$BS status=none; t1=$(now)
  record dd_read "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$DDF")"
  rm -f "$DDF"; settle
  t0=$(now); "$BIN" gen --bytes "$BYTES" | dd of="$DDF" bs=$BS iflag=fullblock conv=fdatasync status=none; t1=$(now)
  record dd_write_random "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$DDF")"
  rm -f "$DDF"; settle
}

# read_ltm KIND REP FILE [flags...]
read_ltm() {
  local kind=$1 rep=$2 file=$3 t0 t1 j
  shift 3
  evict "$file"
  t0=$(now); j=$("$BIN" read "$file" "$@"); t1=$(now)
  record "$kind" "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$file")" "$j"
}

run_ltm() {
  local rep=$1 t0 t1 j
  rm -f "$LTM"; settle
  t0=$(now); j=$("$BIN" write "$LTM" --bytes "$BYTES"); t1=$(now)
  record ltm_write "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$LTM")" "$j"
  read_ltm ltm_read "$rep" "$LTM"
  read_ltm ltm_read_noverify "$rep" "$LTM" --no-verify
  read_ltm ltm_read_prefetch4 "$rep" "$LTM" --prefetch 4
  # dd over the container file itself: the same blocks on disk, read the plain way.
  evict "$LTM"
  t0=$(now); dd if="$LTM" of=/dev/null bs=$BS status=none; t1=$(now)
  record dd_read_container "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$LTM")"
  rm -f "$LTM"; settle
}

: >"$JSONL"
echo "ltm_io_bench: ${SIZE_GIB} GiB, $REPS repetitions, files in $OUT (drop_caches: $DROP)"
for ((rep = 1; rep <= REPS; rep++)); do
  if ((rep % 2 == 1)); then run_dd "$rep"; run_ltm "$rep"; else run_ltm "$rep"; run_dd "$rep"; fi
done

# Peak RSS of the reader at 1 GiB (the 4 GiB runs above report theirs), measured by the
# reader itself and by /usr/bin/time when present.
SMALL=$OUT/small.ltm
rm -f "$SMALL"; settle
j=$("$BIN" write "$SMALL" --bytes $((1024 * 1024 * 1024)))
record ltm_write_1gib 1 "$(echo "$j" | "$PY" -c 'import json,sys; print(json.load(sys.stdin)["seconds"])')" "$(stat -c %s "$SMALL")" "$j"
read_ltm ltm_read_1gib 1 "$SMALL"
if [[ -x /usr/bin/time ]]; then
  for f in "$SMALL"; do
    evict "$f"
    /usr/bin/time -f %M -o "$OUT/time.txt" "$BIN" read "$f" >/dev/null
    echo "{\"kind\": \"time_maxrss_1gib\", \"maxrss_kib\": $(cat "$OUT/time.txt")}" >>"$JSONL"
  done
fi
rm -f "$SMALL"
# The same external measurement at full size, with one more container.
if [[ -x /usr/bin/time ]]; then
  rm -f "$LTM"; settle
  "$BIN" write "$LTM" --bytes "$BYTES" >/dev/null
  evict "$LTM"
  /usr/bin/time -f %M -o "$OUT/time.txt" "$BIN" read "$LTM" >/dev/null
  echo "{\"kind\": \"time_maxrss_full\", \"maxrss_kib\": $(cat "$OUT/time.txt")}" >>"$JSONL"
  rm -f "$LTM" "$OUT/time.txt"
fi

CMD="bash bench/run_container_io.sh $BUILD $SIZE_GIB $REPS"
"$PY" "$HERE/summarize_container_io.py" "$JSONL" "$RESULTS/container_io.md" "$SIZE_GIB" "$REPS" "$DROP" "$OUT" "$CMD"
echo "wrote $RESULTS/container_io.md"
