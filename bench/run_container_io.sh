#!/usr/bin/env bash
# Container (.ltm) write/read throughput against dd on the same disk.
#
#   bash bench/run_container_io.sh BUILD_DIR [SIZE_GIB=4] [REPS=3]
#
# Each repetition writes, then reads, three files of SIZE_GIB on the same filesystem:
#   dd write (zeros)   dd if=/dev/zero of=Z bs=8M count=N conv=fdatasync; rm Z
#   dd write (random)  ltm_io_bench gen | dd of=F bs=8M iflag=fullblock conv=fdatasync
#   container write    ltm_io_bench write C --bytes SIZE   (random f32, raw encoding,
#                      a producer thread checksums chunks, Finish() fdatasyncs)
# then, each after evicting the file from the page cache:
#   dd read            dd if=F of=/dev/null bs=8M         (the random dd file)
#   container read     ltm_io_bench read C                (1 thread, checksums verified)
#   ... prefetch       ltm_io_bench read C --prefetch 4   (caller-side readahead)
#   ... no checksum    ltm_io_bench read C --no-verify
#   dd read of C       dd if=C of=/dev/null bs=8M         (dd over the container's blocks)
# The order of the writes and of the reads rotates between repetitions, since on a
# shared VM the position in the sequence matters (REPS = 15 balances both exactly).
# Before each timed command the script waits (up to 30 s) for the machine to be idle
# and records how busy it was.
#
# Eviction: `ltm_io_bench evict` = fdatasync + posix_fadvise(DONTNEED) on the file; it
# needs no root and leaves other users' caches alone. LTB_BENCH_DROP_CACHES=1 adds
# `echo 3 > /proc/sys/vm/drop_caches`. Either way mincore must show 0 bytes of the file
# resident before each timed read, or the script stops.
# Afterwards a 1 GiB container is written and read, for the reader's peak RSS at a
# second size.
#
# Time = wall time of the whole process (date +%s.%N around it); GB/s = file size /
# time (1 GB = 1e9 bytes). Raw results: bench/results/container_io.jsonl; medians and
# ratios: bench/results/container_io.md (bench/summarize_container_io.py). Files go to
# $LTB_BENCH_DIR (default bench/out/, the repository's filesystem) and are deleted at
# the end of each repetition: at most 2 * SIZE_GIB (+ 1 GiB) on disk at a time.
set -euo pipefail

BUILD=${1:?usage: run_container_io.sh BUILD_DIR [SIZE_GIB=4] [REPS=3]}
SIZE_GIB=${2:-4}
REPS=${3:-3}
HERE=$(cd "$(dirname "$0")" && pwd)
SRC_BIN=$(cd "$BUILD" && pwd)/bench/ltm_io_bench
[[ -x $SRC_BIN ]] || { echo "no $SRC_BIN: build first (make build)" >&2; exit 1; }
OUT=${LTB_BENCH_DIR:-$HERE/out}
RESULTS=$HERE/results
mkdir -p "$OUT" "$RESULTS"
PY=/usr/bin/python3
[[ -x $PY ]] || PY=python3
# A private copy, so a rebuild of BUILD_DIR during the run cannot swap the binary.
BIN=$OUT/ltm_io_bench
cp "$SRC_BIN" "$BIN"

BYTES=$((SIZE_GIB * 1024 * 1024 * 1024))
BS=$((8 * 1024 * 1024))
COUNT=$((BYTES / BS))
ZERO=$OUT/dd-zero.bin
DDF=$OUT/dd-random.bin
LTM=$OUT/bench.ltm
SMALL=$OUT/small.ltm
JSONL=$RESULTS/container_io.jsonl
cleanup() { rm -f "$ZERO" "$DDF" "$LTM" "$SMALL" "$BIN" "$OUT/time.txt"; }
trap cleanup EXIT

need_gib=$((2 * SIZE_GIB + 1))
avail_kib=$(df -Pk "$OUT" | awk 'NR==2{print $4}')
if ((avail_kib < need_gib * 1024 * 1024)); then
  echo "need ${need_gib} GiB free in $OUT, have $((avail_kib / 1024 / 1024)) GiB" >&2
  exit 1
fi

DROP=no
if [[ ${LTB_BENCH_DROP_CACHES:-0} == 1 ]]; then
  if [[ -w /proc/sys/vm/drop_caches ]] && (sync && echo 3 >/proc/sys/vm/drop_caches) 2>/dev/null; then
    DROP=yes
  else
    echo "LTB_BENCH_DROP_CACHES=1 but /proc/sys/vm/drop_caches is not writable; using posix_fadvise only" >&2
  fi
fi

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.6f", b - a }'; }
# CPU busy % of the whole machine over one second (all CPUs; iowait counts as idle).
busy_1s() {
  local u n s i w q sq st b1 i1 b2 i2
  read -r _ u n s i w q sq st _ </proc/stat
  b1=$((u + n + s + q + sq + st)) i1=$((i + w))
  sleep 1
  read -r _ u n s i w q sq st _ </proc/stat
  b2=$((u + n + s + q + sq + st)) i2=$((i + w))
  echo $((100 * (b2 - b1) / ((b2 - b1) + (i2 - i1) + 1)))
}
# Waits up to 30 s for the machine to be < 15% busy; leaves the last sample in BUSY.
BUSY=0
settle() {
  sync
  local t
  for ((t = 0; t < 30; t++)); do
    BUSY=$(busy_1s)
    ((BUSY < 15)) && return 0
  done
  echo "  (machine still ${BUSY}% busy after 30 s; measuring anyway)"
}
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
  "$PY" - "$JSONL" "$BUSY" "$@" <<'EOF'
import json, sys
path, busy = sys.argv[1], int(sys.argv[2])
kind, rep, secs, size = sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6])
d = {"kind": kind, "rep": rep, "wall_seconds": secs, "file_bytes": size, "gb_per_s": size / secs / 1e9,
     "busy_before_pct": busy, "loadavg": open("/proc/loadavg").read().split()[0]}
if len(sys.argv) > 7 and sys.argv[7]:
    d["tool"] = json.loads(sys.argv[7])
with open(path, "a") as f:
    f.write(json.dumps(d) + "\n")
rss = d.get("tool", {}).get("peak_rss_kib")
print(f"  rep {rep} {kind:<20} {secs:7.3f} s {d['gb_per_s']:7.3f} GB/s  (busy before {busy:2d}%)" +
      (f"  peak RSS {rss / 1024:.1f} MiB" if rss else ""))
EOF
}

write_dd_zero() {
  local rep=$1 t0 t1
  settle
  t0=$(now); dd if=/dev/zero of="$ZERO" bs=$BS count=$COUNT conv=fdatasync status=none; t1=$(now)
  record dd_write "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$ZERO")"
  rm -f "$ZERO"
}
write_dd_random() {
  local rep=$1 t0 t1
  settle
  t0=$(now); "$BIN" gen --bytes "$BYTES" | dd of="$DDF" bs=$BS iflag=fullblock conv=fdatasync status=none; t1=$(now)
  record dd_write_random "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$DDF")"
}
write_ltm() {
  local rep=$1 t0 t1 j
  settle
  t0=$(now); j=$("$BIN" write "$LTM" --bytes "$BYTES"); t1=$(now)
  record ltm_write "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$LTM")" "$j"
}
read_dd() {  # KIND REP FILE
  local t0 t1
  evict "$3"; settle
  t0=$(now); dd if="$3" of=/dev/null bs=$BS status=none; t1=$(now)
  record "$1" "$2" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$3")"
}
read_ltm() {  # KIND REP FILE [flags...]
  local kind=$1 rep=$2 file=$3 t0 t1 j
  shift 3
  evict "$file"; settle
  t0=$(now); j=$("$BIN" read "$file" "$@"); t1=$(now)
  record "$kind" "$rep" "$(elapsed "$t0" "$t1")" "$(stat -c %s "$file")" "$j"
}

: >"$JSONL"
echo "ltm_io_bench: ${SIZE_GIB} GiB, $REPS repetitions, files in $OUT (drop_caches: $DROP)"
# One step each; every repetition runs them rotated by one, so over REPS = 3 (writes)
# or 5 (reads) repetitions each step takes each position once.
WRITES=(write_dd_zero write_dd_random write_ltm)
r_dd() { read_dd dd_read "$1" "$DDF"; }
r_ltm() { read_ltm ltm_read "$1" "$LTM"; }
r_prefetch() { read_ltm ltm_read_prefetch4 "$1" "$LTM" --prefetch 4; }
r_noverify() { read_ltm ltm_read_noverify "$1" "$LTM" --no-verify; }
r_dd_container() { read_dd dd_read_container "$1" "$LTM"; }
READS=(r_dd r_ltm r_prefetch r_noverify r_dd_container)
for ((rep = 1; rep <= REPS; rep++)); do
  rm -f "$ZERO" "$DDF" "$LTM"
  for ((i = 0; i < ${#WRITES[@]}; i++)); do "${WRITES[(i + rep - 1) % ${#WRITES[@]}]}" "$rep"; done
  for ((i = 0; i < ${#READS[@]}; i++)); do "${READS[(i + rep - 1) % ${#READS[@]}]}" "$rep"; done
  rm -f "$DDF" "$LTM"
done

# Peak RSS of the reader at 1 GiB (the full-size runs above report theirs), measured by
# the reader itself and, at both sizes, by /usr/bin/time when it is installed.
settle
j=$("$BIN" write "$SMALL" --bytes $((1024 * 1024 * 1024)))
record ltm_write_1gib 1 "$(echo "$j" | "$PY" -c 'import json,sys; print(json.load(sys.stdin)["seconds"])')" "$(stat -c %s "$SMALL")" "$j"
read_ltm ltm_read_1gib 1 "$SMALL"
if [[ -x /usr/bin/time ]]; then
  evict "$SMALL"
  /usr/bin/time -f %M -o "$OUT/time.txt" "$BIN" read "$SMALL" >/dev/null
  echo "{\"kind\": \"time_maxrss_1gib\", \"maxrss_kib\": $(cat "$OUT/time.txt")}" >>"$JSONL"
  rm -f "$SMALL"
  settle
  "$BIN" write "$LTM" --bytes "$BYTES" >/dev/null
  evict "$LTM"
  /usr/bin/time -f %M -o "$OUT/time.txt" "$BIN" read "$LTM" >/dev/null
  echo "{\"kind\": \"time_maxrss_full\", \"maxrss_kib\": $(cat "$OUT/time.txt")}" >>"$JSONL"
  rm -f "$LTM"
fi
rm -f "$SMALL"

CMD="bash bench/run_container_io.sh $BUILD $SIZE_GIB $REPS"
[[ $DROP == yes ]] && CMD="LTB_BENCH_DROP_CACHES=1 $CMD"
"$PY" "$HERE/summarize_container_io.py" "$JSONL" "$RESULTS/container_io.md" "$SIZE_GIB" "$REPS" "$DROP" "$OUT" "$CMD"
echo "wrote $RESULTS/container_io.md"
