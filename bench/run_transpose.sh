#!/usr/bin/env bash
# `ltbake transpose` at the papers' scale against the dd I/O floor and an h5py baseline.
#
#   bash bench/run_transpose.sh BUILD_DIR [REPS=3]
#
# Input: a 65536 x 24576 f32 row-block container (6.44 GB payload, R = 64; random data
# from `ltb_transpose_bench make`, ~8 MiB row blocks), made once (not timed).
# Each repetition, in an order that rotates by one step per repetition:
#   transpose   ltbake transpose in.ltm -o out.ltm --mem-limit 1GiB --progress never
#               (wall time; peak RSS, user and sys time from /usr/bin/time); the output
#               is written with O_DIRECT (the default since 2026-11-25)
#   transpose_buffered   the same with --no-direct-io (output through the page cache, as
#               before 2026-11-25)
#   dd copy     dd if=in.ltm of=copy bs=8M conv=fdatasync      (read + write once: the floor)
#   dd read     dd if=in.ltm of=/dev/null bs=8M
#   dd write    dd if=/dev/zero of=z bs=8M count=N conv=fdatasync   (N x 8 MiB = in.ltm's size)
# Once: transpose --no-verify-input (exactly 1 read + 1 write); dd with
# iflag=direct oflag=direct (the disk without the page cache, for reference only); the
# transposes again under bench/io_timeline.py (where the time goes; not in the medians).
# The first transpose's output is checked (`ltb_transpose_bench check`: 8 columns, every
# element against the generator) and `ltbake verify`ed, outside the clock.
# h5py baseline (bench/h5py_transpose.py): the same matrix converted to HDF5 (not timed;
# row-block chunks 64 x 24576), then timed transposes with a 1 GiB chunk cache
# (rdcc_nbytes) on each file, bands of 2048 input rows (192 MiB), output dataset
# (24576, 65536) in 1024 x 1024 chunks, fsync of the output in the clock:
#   h5py          the band transposed with np.ascontiguousarray(band.T)  (what
#                 `out[:, r0:r1] = band.T` does inside h5py)       LTB_BENCH_H5PY_REPS times
#   h5py_sliced   the band transposed in slices of 64 rows (--slice 64; ~3x faster numpy
#                 transposition here)                               LTB_BENCH_H5PY_REPS times
#   h5py_sliced_cache256m  the same with a 256 MiB cache, whose peak RSS is close to
#                 ltbake's budget (once; LTB_BENCH_H5PY_SMALL_CACHE=0 skips it)
# Each variant's first output is checked against the input with numpy (8 columns).
#
# Before every timed command every file it reads is evicted from the page cache
# (`ltm_io_bench evict`: fdatasync + posix_fadvise DONTNEED, no root; mincore must then
# show 0 bytes resident) and the script waits (up to 30 s) for the machine to be < 15%
# busy, recording how busy it was. Outputs are deleted right after they are measured.
# Every timed writer syncs: ltbake's Finish() fdatasyncs, dd uses conv=fdatasync,
# h5py_transpose.py fsyncs its output.
#
# Environment: LTB_BENCH_DIR (default bench/out/), LTB_BENCH_ROWS / LTB_BENCH_COLS (a
# smaller matrix for a quick trial), LTB_BENCH_H5PY_REPS (0 skips h5py),
# LTB_BENCH_TIMELINE=0 skips the io_timeline runs.
# Disk: at most 2 copies of the matrix at once (in.ltm + out.ltm or dd's copy; later
# in.h5 + out.h5), 12.9 GB at full size; 3 copies + 1 GiB free is checked first.
# Everything is deleted on exit. Took 11.5 minutes with REPS=5 here (~9 with 3).
# Raw results: bench/results/transpose.jsonl; summary: bench/results/transpose.md.
set -euo pipefail

BUILD=${1:?usage: run_transpose.sh BUILD_DIR [REPS=3]}
REPS=${2:-3}
ROWS=${LTB_BENCH_ROWS:-65536}
COLS=${LTB_BENCH_COLS:-24576}
H5REPS=${LTB_BENCH_H5PY_REPS:-2}
H5SMALL=${LTB_BENCH_H5PY_SMALL_CACHE:-1}
TIMELINE=${LTB_BENCH_TIMELINE:-1}
HERE=$(cd "$(dirname "$0")" && pwd)
BUILD_ABS=$(cd "$BUILD" && pwd)
OUT=${LTB_BENCH_DIR:-$HERE/out}/transpose
RESULTS=$HERE/results
PY=/usr/bin/python3
[[ -x $PY ]] || { echo "needs /usr/bin/python3 (with numpy and h5py for the baseline)" >&2; exit 1; }
[[ -x /usr/bin/time ]] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 1; }
for b in ltbake bench/ltm_io_bench bench/ltb_transpose_bench; do
  [[ -x $BUILD_ABS/$b ]] || { echo "no $BUILD_ABS/$b: build first (cmake --build $BUILD)" >&2; exit 1; }
done
mkdir -p "$OUT" "$RESULTS"
# Private copies, so a rebuild of BUILD_DIR during the run cannot swap the binaries.
cp "$BUILD_ABS/ltbake" "$BUILD_ABS/bench/ltm_io_bench" "$BUILD_ABS/bench/ltb_transpose_bench" "$OUT/"
LTBAKE=$OUT/ltbake
IOB=$OUT/ltm_io_bench
TB=$OUT/ltb_transpose_bench

IN=$OUT/in.ltm
TOUT=$OUT/out.ltm
COPY=$OUT/copy.bin
ZERO=$OUT/zero.bin
H5IN=$OUT/in.h5
H5OUT=$OUT/out.h5
TIMEF=$OUT/time.txt
JSONL=$RESULTS/transpose.jsonl
cleanup() { rm -f "$IN" "$TOUT" "$COPY" "$ZERO" "$H5IN" "$H5OUT" "$TIMEF" "$LTBAKE" "$IOB" "$TB"; rmdir "$OUT" 2>/dev/null || true; }
trap cleanup EXIT

PAYLOAD=$((ROWS * COLS * 4))
need_kib=$((3 * PAYLOAD / 1024 + 1024 * 1024))
avail_kib=$(df -Pk "$OUT" | awk 'NR==2{print $4}')
if ((avail_kib < need_kib)); then
  echo "need $((need_kib / 1024 / 1024)) GiB free in $OUT, have $((avail_kib / 1024 / 1024)) GiB" >&2
  exit 1
fi

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.6f", b - a }'; }
busy_1s() {  # whole-machine CPU busy % over one second (iowait counts as idle)
  local u n s i w q sq st b1 i1 b2 i2
  read -r _ u n s i w q sq st _ </proc/stat
  b1=$((u + n + s + q + sq + st)) i1=$((i + w))
  sleep 1
  read -r _ u n s i w q sq st _ </proc/stat
  b2=$((u + n + s + q + sq + st)) i2=$((i + w))
  echo $((100 * (b2 - b1) / ((b2 - b1) + (i2 - i1) + 1)))
}
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
evict() {  # evict FILE...: drop the files from the page cache; fail if any page is left
  local f left
  for f in "$@"; do
    "$IOB" evict "$f" >/dev/null
    left=$("$IOB" resident "$f" | "$PY" -c 'import json,sys; print(json.load(sys.stdin)["resident_bytes"])')
    if [[ $left != 0 ]]; then echo "eviction left $left bytes of $f in the page cache" >&2; return 1; fi
  done
}
# record KIND REP WALL_SECONDS PAYLOAD_BYTES [TIME_FILE] [TOOL_STDOUT]: one JSON line in $JSONL.
record() {
  "$PY" - "$JSONL" "$BUSY" "$@" <<'EOF'
import json, re, sys
path, busy = sys.argv[1], int(sys.argv[2])
kind, rep, secs, size = sys.argv[3], int(sys.argv[4]), float(sys.argv[5]), int(sys.argv[6])
d = {"kind": kind, "rep": rep, "wall_seconds": secs, "payload_bytes": size, "gb_per_s": size / secs / 1e9,
     "busy_before_pct": busy, "loadavg": open("/proc/loadavg").read().split()[0]}
if len(sys.argv) > 7 and sys.argv[7]:
    e, m, u, s = open(sys.argv[7]).read().split()[-4:]
    d.update(time_elapsed=float(e), peak_rss_kib=int(m), user_seconds=float(u), sys_seconds=float(s))
if len(sys.argv) > 8 and sys.argv[8]:
    out = sys.argv[8]
    m = re.search(r"(\d+) panel\(s\) of up to (\d+) columns.*read (\d+) \+ verified (\d+) bytes, wrote (\d+)", out)
    if m:
        d.update(panels=int(m[1]), panel_cols=int(m[2]), bytes_read=int(m[3]), bytes_verified=int(m[4]),
                 bytes_written=int(m[5]))
        md = re.search(r"\((\d+) with O_DIRECT\)", out)
        d["bytes_direct"] = int(md[1]) if md else 0
    else:
        try:
            d["tool"] = json.loads(out.strip().splitlines()[-1])
        except (ValueError, IndexError):
            d["stdout"] = out
with open(path, "a") as f:
    f.write(json.dumps(d) + "\n")
rss = d.get("peak_rss_kib")
print(f"  rep {rep} {kind:<28} {secs:8.2f} s {d['gb_per_s']:6.3f} GB/s  (busy before {busy:2d}%)" +
      (f"  peak RSS {rss / 1024:.0f} MiB, user {d['user_seconds']:.1f} s, sys {d['sys_seconds']:.1f} s" if rss else ""))
EOF
}
note() { "$PY" -c 'import json,sys; print(json.dumps(json.loads(sys.argv[1])))' "$1" >>"$JSONL"; }

transpose() {  # KIND REP [extra ltbake flags]
  local kind=$1 rep=$2 t0 t1 out
  shift 2
  rm -f "$TOUT"
  evict "$IN"; settle
  t0=$(now)
  out=$(/usr/bin/time -f '%e %M %U %S' -o "$TIMEF" "$LTBAKE" transpose "$IN" -o "$TOUT" --mem-limit 1GiB --progress never "$@")
  t1=$(now)
  record "$kind" "$rep" "$(elapsed "$t0" "$t1")" "$PAYLOAD" "$TIMEF" "$out"
  if [[ $rep == 1 && $kind == transpose ]]; then
    local c
    c=$("$TB" check "$TOUT" --samples 6) || { echo "transpose output is wrong: $c" >&2; exit 1; }
    note "{\"kind\": \"check_ltbake_output\", \"result\": $c}"
    "$LTBAKE" verify "$TOUT" --progress never >/dev/null || { echo "ltbake verify failed on $TOUT" >&2; exit 1; }
    echo "  (output checked: 8 columns element by element, and ltbake verify)"
  fi
  rm -f "$TOUT"
}
dd_copy() {
  local t0 t1
  evict "$IN"; settle
  t0=$(now); dd if="$IN" of="$COPY" bs=8M conv=fdatasync status=none; t1=$(now)
  record dd_copy "$1" "$(elapsed "$t0" "$t1")" "$PAYLOAD"
  rm -f "$COPY"
}
dd_read_write() {
  local t0 t1 count
  evict "$IN"; settle
  t0=$(now); dd if="$IN" of=/dev/null bs=8M status=none; t1=$(now)
  record dd_read "$1" "$(elapsed "$t0" "$t1")" "$PAYLOAD"
  count=$((($(stat -c %s "$IN") + 8388607) / 8388608))
  settle
  t0=$(now); dd if=/dev/zero of="$ZERO" bs=8M count="$count" conv=fdatasync status=none; t1=$(now)
  record dd_write "$1" "$(elapsed "$t0" "$t1")" "$PAYLOAD"
  rm -f "$ZERO"
}

: >"$JSONL"
note "{\"kind\": \"setup\", \"rows\": $ROWS, \"cols\": $COLS, \"payload_bytes\": $PAYLOAD, \"reps\": $REPS, \"h5py_reps\": $H5REPS, \"date\": \"$(date -Iseconds)\", \"cpu\": \"$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //')\", \"nproc\": $(nproc), \"mem_kib\": $(awk '/MemTotal/{print $2}' /proc/meminfo), \"kernel\": \"$(uname -r)\"}"
echo "transpose benchmark: $ROWS x $COLS f32 ($PAYLOAD bytes), $REPS repetitions, files in $OUT"
settle
j=$("$TB" make "$IN" --rows "$ROWS" --cols "$COLS")
note "{\"kind\": \"make_input\", \"file_bytes\": $(stat -c %s "$IN"), \"tool\": $j}"
echo "  input made: $(stat -c %s "$IN") bytes"

step_transpose() { transpose transpose "$1"; }
step_transpose_buffered() { transpose transpose_buffered "$1" --no-direct-io; }
STEPS=(step_transpose dd_copy dd_read_write step_transpose_buffered)
for ((rep = 1; rep <= REPS; rep++)); do
  for ((i = 0; i < ${#STEPS[@]}; i++)); do "${STEPS[(i + rep - 1) % ${#STEPS[@]}]}" "$rep"; done
done
transpose transpose_no_verify 1 --no-verify-input

# For reference: the disk without the page cache (not the floor: ltbake and dd above
# both go through it).
evict "$IN"; settle
t0=$(now); dd if="$IN" of="$COPY" bs=8M iflag=direct oflag=direct status=none; sync "$COPY"; t1=$(now)
record dd_copy_direct 1 "$(elapsed "$t0" "$t1")" "$PAYLOAD"
rm -f "$COPY"

if [[ $TIMELINE == 1 ]]; then
  for flags in "" "--no-verify-input"; do
    kind=timeline_transpose${flags:+_no_verify}
    rm -f "$TOUT"; evict "$IN"; settle
    j=$("$PY" "$HERE/io_timeline.py" --out "$RESULTS/$kind.tsv" -- "$LTBAKE" transpose "$IN" -o "$TOUT" --mem-limit 1GiB --progress never $flags 2>/dev/null)
    note "{\"kind\": \"$kind\", \"busy_before_pct\": $BUSY, \"tool\": $j}"
    echo "  $kind: $(echo "$j" | "$PY" -c 'import json,sys; d=json.load(sys.stdin); print("%.2f s, CPU s of the busiest threads %s" % (d["wall_seconds"], d["thread_cpu_max_seconds"]))') -> results/$kind.tsv"
    rm -f "$TOUT"
  done
fi
rm -f "$IN"

if ((H5REPS > 0)); then
  settle
  t0=$(now)
  j=$("$TB" raw --rows "$ROWS" --cols "$COLS" | "$PY" "$HERE/h5py_transpose.py" convert "$H5IN" --rows "$ROWS" --cols "$COLS" --chunks 64x"$COLS")
  t1=$(now)
  note "{\"kind\": \"h5py_convert\", \"seconds\": $(elapsed "$t0" "$t1"), \"tool\": $j}"
  echo "  HDF5 input made: $(stat -c %s "$H5IN") bytes in $(elapsed "$t0" "$t1") s"
  h5run() {  # KIND REP CACHE SLICE
    local t0 t1 out
    rm -f "$H5OUT"
    evict "$H5IN"; settle
    t0=$(now)
    out=$(/usr/bin/time -f '%e %M %U %S' -o "$TIMEF" "$PY" "$HERE/h5py_transpose.py" transpose "$H5IN" "$H5OUT" \
      --order rows --out-chunks 1024x1024 --band-bytes 256MiB --cache "$3" --slice "$4")
    t1=$(now)
    record "$1" "$2" "$(elapsed "$t0" "$t1")" "$PAYLOAD" "$TIMEF" "$out"
    if [[ $2 == 1 ]]; then
      local c
      c=$("$PY" "$HERE/h5py_transpose.py" check "$H5IN" "$H5OUT") || { echo "h5py output is wrong: $c" >&2; exit 1; }
      note "{\"kind\": \"check_$1\", \"result\": $c}"
    fi
    rm -f "$H5OUT"
  }
  for ((rep = 1; rep <= H5REPS; rep++)); do
    h5run h5py "$rep" 1GiB 0
    h5run h5py_sliced "$rep" 1GiB 64
  done
  if [[ $H5SMALL == 1 ]]; then h5run h5py_sliced_cache256m 1 256MiB 64; fi
  rm -f "$H5IN"
fi

"$PY" "$HERE/summarize_transpose.py" "$JSONL" "$RESULTS/transpose.md" "bash bench/run_transpose.sh $BUILD $REPS"
echo "wrote $RESULTS/transpose.md"
