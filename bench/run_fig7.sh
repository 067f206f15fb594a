#!/usr/bin/env bash
# Figure 7 of Cheslack-Postava et al. 2007 for ltbake's compressor: relative RMS error
# against nonzeros for 2D (`--depth none`, Ng et al. 2003), naive full 4D (`--depth full`),
# adaptive 4D (`--depth adaptive`), all with `--terms N` per column, and the global
# rate-distortion budget (`--depth adaptive --budget K`, K = the nonzeros of the adaptive
# --terms runs). Results in bench/results/column_transform_fig7*.md.
#
#   bash bench/run_fig7.sh [BUILD_DIR=build]
#
# Pipeline (once): ltbake sample samples/medium.toml --cube-res R (256x256 image) -> raw.ltm;
# row-transform --filter db2 -> rows.ltm; transpose -> cols.ltm; convert rows.ltm rows.npy
# (the reference T, in the row-transformed basis). The default is R = 16: the issue's
# sweep at the scene's own R = 32 takes more than its ~25-minute limit on this 2-vCPU VM.
# Each run: column-transform cols.ltm -o c4.ltm --filter legall53 --depth D --terms N|--budget K
# --json (wall time and peak RSS from /usr/bin/time; the machine's busy % just before is
# recorded), quantize --bits 9 --json, convert final.ltm final.npy (decodes to the
# row-transformed basis), and `bench/fig7.py error` computes ||T - T'||_F / ||T||_F in row
# bands of the memory-mapped .npy files (float64 sums). final.npy is deleted after each run.
# Once, at adaptive N = 256 (if in the list), the unquantized output is decoded too and its
# NumPy error is compared with column-transform's reported relative_rms_error.
# Extras (LTB_FIG7_EXTRAS=1, the default): the budgets K with `--depth none` and `--depth
# full` too (a global threshold: the fair 2D baseline, since --terms spends the same N on
# every column whatever its energy), the 2D --terms curve extended to larger N
# (LTB_FIG7_NONE_EXTRA_TERMS) and the 2D budget curve to budgets given as fractions of the
# matrix (LTB_FIG7_NONE_EXTRA_FRACTIONS), so that the 2D curves reach the 4D curves' errors.
#
# Environment: LTB_FIG7_CUBE_RES (16), LTB_FIG7_TERMS ("16 32 64 128 256 512 1024 2048"),
# LTB_FIG7_EXTRAS (1), LTB_FIG7_NONE_EXTRA_TERMS ("4096 8192 16384 32768"),
# LTB_FIG7_NONE_EXTRA_FRACTIONS ("0.01 0.02 0.05 0.1 0.2 0.4"), LTB_FIG7_DIR
# (bench/out/fig7_rR), LTB_FIG7_NAME (column_transform_fig7 at R = 16, else
# column_transform_fig7_rR), LTB_FIG7_KEEP=1 keeps the big intermediates at the end.
# A run whose results are in $DIR/runs/KEY/ is skipped, so an interrupted sweep resumes and
# a rerun only rewrites the report (delete $DIR to start over).
# Outputs: bench/results/NAME.{csv,png,md} (`bench/fig7.py report`; the hand-written
# observations bench/fig7_notesSUFFIX.md are appended when present).
# Time here (2 vCPUs, busy with another engineer's jobs): R = 16, all 58 runs: 16 min.
# R = 32 with LTB_FIG7_TERMS="64 512 2048" LTB_FIG7_NONE_EXTRA_TERMS="8192 32768"
# LTB_FIG7_NONE_EXTRA_FRACTIONS="0.02 0.05 0.1 0.2" (24 runs): 19 min.
# Disk at R = 32: ~1.2 GB each for raw/rows/cols.ltm, 1.6 GB for rows.npy and for each
# decoded final.npy (one at a time): ~7 GB peak (R = 16: a quarter). Deleted at the end;
# the per-run JSON files, machine.txt and stages.tsv stay in $DIR.
set -euo pipefail

BUILD=${1:-build}
HERE=$(cd "$(dirname "$0")" && pwd)
ROOT=$(cd "$HERE/.." && pwd)
BUILD_ABS=$(cd "$BUILD" 2>/dev/null && pwd) || { echo "no build dir $BUILD" >&2; exit 1; }
R=${LTB_FIG7_CUBE_RES:-16}
OUT=${LTB_FIG7_DIR:-$HERE/out/fig7_r$R}
RESULTS=$HERE/results
TERMS=${LTB_FIG7_TERMS:-16 32 64 128 256 512 1024 2048}
EXTRAS=${LTB_FIG7_EXTRAS:-1}
KEEP=${LTB_FIG7_KEEP:-0}
if [[ $R == 16 ]]; then NAME=${LTB_FIG7_NAME:-column_transform_fig7}; else NAME=${LTB_FIG7_NAME:-column_transform_fig7_r$R}; fi
NONE_EXTRA_TERMS=${LTB_FIG7_NONE_EXTRA_TERMS:-4096 8192 16384 32768}
NONE_EXTRA_FRACTIONS=${LTB_FIG7_NONE_EXTRA_FRACTIONS:-0.01 0.02 0.05 0.1 0.2 0.4}
CHECK_TERMS=256
PY=/usr/bin/python3
[[ -x $PY ]] || { echo "needs /usr/bin/python3 with numpy and matplotlib" >&2; exit 1; }
[[ -x /usr/bin/time ]] || { echo "needs /usr/bin/time (apt-get install time)" >&2; exit 1; }
[[ -x $BUILD_ABS/ltbake ]] || { echo "no $BUILD_ABS/ltbake: build first (cmake --build $BUILD)" >&2; exit 1; }
if ! ls "$ROOT"/data/meshes/bunny.* >/dev/null 2>&1; then
  echo "data/meshes/bunny.* missing: make samples" >&2
  make -C "$ROOT" samples
fi
mkdir -p "$OUT/runs" "$RESULTS"
avail_kib=$(df -Pk "$OUT" | awk 'NR==2{print $4}')
need_kib=$((8 * 1024 * 1024 * R * R / 1024))  # ~8 GB at R = 32
if ((avail_kib < need_kib)); then
  echo "need $((need_kib / 1024 / 1024)) GiB free in $OUT, have $((avail_kib / 1024 / 1024)) GiB" >&2
  exit 1
fi

# A private copy of the binary, so a rebuild of BUILD_DIR during the sweep cannot swap it.
LTBAKE=$OUT/ltbake
cp "$BUILD_ABS/ltbake" "$LTBAKE"

now() { date +%s.%N; }
elapsed() { awk -v a="$1" -v b="$2" 'BEGIN { printf "%.3f", b - a }'; }
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
settle() {  # wait up to 5 s for the machine to be < 25% busy; record how busy it was
  local t
  for ((t = 0; t < 5; t++)); do
    BUSY=$(busy_1s)
    ((BUSY < 25)) && return 0
  done
  return 0
}

T_START=$(now)
cd "$OUT"
BIN_SHA=$(sha256sum "$LTBAKE" | cut -d' ' -f1)

# ---- machine and provenance (written by the invocation that bakes) ------------------
write_machine() {
  {
    echo "date: $(date -u '+%Y-%m-%d %H:%M:%S UTC')"
    echo "git: $(git -C "$ROOT" rev-parse HEAD 2>/dev/null || echo '?')"
    echo "git_dirty: $(git -C "$ROOT" status --short 2>/dev/null | tr '\n' ';')"
    echo "binary_sha256: $BIN_SHA"
    echo "cube_res: $R"
    echo "terms: $TERMS"
    echo "extras: $EXTRAS"
    echo "--- lscpu | head -20"
    lscpu | head -20
    echo "--- nproc"
    nproc
    echo "--- free -g"
    free -g
    echo "--- uname -r"
    uname -r
  } >machine.txt
}

# ---- bake (once; only when some run still needs the matrix) --------------------------
stage() {  # stage NAME OUTPUT CMD...: run once, record wall seconds in stages.tsv
  local name=$1 out=$2
  shift 2
  if [[ -f $out.done ]]; then return 0; fi
  echo "== $name"
  local t0 t1
  t0=$(now)
  "$@"
  t1=$(now)
  printf '%s\t%s\n' "$name" "$(elapsed "$t0" "$t1")" >>stages.tsv
  touch "$out.done"
}
BAKED=0
bake() {
  ((BAKED)) && return 0
  if [[ ! -f raw.ltm.done ]]; then
    : >stages.tsv
    write_machine
  fi
  stage sample raw.ltm "$LTBAKE" sample "$ROOT/samples/medium.toml" -o raw.ltm --cube-res "$R" --overwrite --progress never
  stage row-transform rows.ltm "$LTBAKE" row-transform raw.ltm -o rows.ltm --filter db2 --overwrite --progress never
  stage transpose cols.ltm "$LTBAKE" transpose rows.ltm -o cols.ltm --overwrite --progress never
  stage convert-reference rows.npy "$LTBAKE" convert rows.ltm rows.npy --overwrite --progress never
  "$LTBAKE" inspect cols.ltm --json --no-content >cols.inspect.json
  BAKED=1
}

# ---- one run ------------------------------------------------------------------------
# run MODE DEPTH KIND VALUE [EXTRA=0]: KIND is terms or budget; EXTRA=1 marks points
# beyond the issue's sweep.
SWEPT=0
run() {
  local mode=$1 depth=$2 kind=$3 value=$4 extra=${5:-0}
  local key=${mode}_${value} dir=runs/${mode}_${value}
  if [[ -f $dir/done ]]; then return 0; fi
  bake
  SWEPT=1
  rm -rf "$dir"
  mkdir -p "$dir"
  rm -f c4.ltm final.ltm final.npy c4.npy
  settle
  local t0 t1
  t0=$(now)
  /usr/bin/time -f '%e %M %U %S' -o "$dir/ct.time" \
    "$LTBAKE" column-transform cols.ltm -o c4.ltm --filter legall53 --depth "$depth" --"$kind" "$value" \
    --json --overwrite --progress never >"$dir/ct.json"
  t1=$(now)
  printf '{"mode": "%s", "depth": "%s", "kind": "%s", "value": %s, "extra": %s, "wall_seconds": %s, "busy_before_pct": %s, "loadavg": "%s", "binary_sha256": "%s"}\n' \
    "$mode" "$depth" "$kind" "$value" "$([[ $extra == 1 ]] && echo true || echo false)" "$(elapsed "$t0" "$t1")" \
    "$BUSY" "$(cut -d' ' -f1-3 /proc/loadavg)" "$BIN_SHA" >"$dir/run.json"
  "$LTBAKE" quantize c4.ltm -o final.ltm --bits 9 --json --overwrite --progress never >"$dir/q.json"
  "$LTBAKE" convert final.ltm final.npy --overwrite --progress never >/dev/null
  local tests=(final.npy)
  if [[ $mode == adaptive && $value == "$CHECK_TERMS" ]]; then  # once: the unquantized output through NumPy
    "$LTBAKE" convert c4.ltm c4.npy --overwrite --progress never >/dev/null
    tests+=(c4.npy)
  fi
  "$PY" "$HERE/fig7.py" error rows.npy "${tests[@]}" >"$dir/err.json"
  rm -f final.npy c4.npy
  touch "$dir/done"
  "$PY" "$HERE/fig7.py" line "$dir"
}

echo "== sweep in $OUT (R = $R; terms: $TERMS; extras: $EXTRAS)"
for n in $TERMS; do run adaptive adaptive terms "$n"; done
for n in $TERMS; do run none none terms "$n"; done
for n in $TERMS; do run full full terms "$n"; done
# Budgets: the nonzeros the adaptive --terms runs kept (before quantization).
BUDGETS=$(for n in $TERMS; do "$PY" -c 'import json,sys; print(json.load(open(sys.argv[1]))["nonzeros"])' "runs/adaptive_$n/ct.json"; done)
for k in $BUDGETS; do run adaptive_budget adaptive budget "$k"; done
if [[ $EXTRAS == 1 ]]; then
  for k in $BUDGETS; do run none_budget none budget "$k"; done
  for k in $BUDGETS; do run full_budget full budget "$k"; done
  # The 2D curves never get near the 4D errors within the sweep above; extend them (cheap).
  for n in $NONE_EXTRA_TERMS; do run none none terms "$n" 1; done
  ELEMS=$("$PY" -c 'import json,sys; d=json.load(open(sys.argv[1])); print(d["rows"]*d["cols"])' "runs/adaptive_${TERMS%% *}/ct.json")
  for f in $NONE_EXTRA_FRACTIONS; do
    run none_budget none budget "$("$PY" -c 'import sys; print(round(float(sys.argv[1]) * int(sys.argv[2])))' "$f" "$ELEMS")" 1
  done
fi
if ((SWEPT)); then
  printf '%s\t%s\n' "sweep-invocation" "$(elapsed "$T_START" "$(now)")" >>stages.tsv
else
  echo "every run was done already; only the report is rewritten"
fi

# ---- report -------------------------------------------------------------------------
"$PY" "$HERE/fig7.py" report --dir "$OUT" --results "$RESULTS" --name "$NAME" --notes "$HERE/fig7_notes${NAME#column_transform_fig7}.md"

if [[ $KEEP != 1 ]]; then
  rm -f raw.ltm rows.ltm cols.ltm rows.npy c4.ltm final.ltm c4.npy final.npy "$LTBAKE"
  rm -f ./*.done
  echo "big intermediates deleted (the per-run JSON in $OUT/runs stays)"
fi
