#!/usr/bin/env bash
# Runs the libFuzzer targets one after another, each for SECONDS in one process on one core
# (no -jobs/-workers/-fork unless asked), and prints
# per target: seconds, runs, edges covered (libFuzzer's `cov:` replaying the final corpus), corpus size and
# findings (crash-, leak-, timeout-, oom- files). docs/FUZZING.md.
#
# usage: fuzz_run.sh FUZZ_BUILD CORPUS SECONDS [TARGET...]   (default: every target)
# env:   FUZZ_KEEP_GOING=1  fork mode (-fork=1 -ignore_crashes/ooms/timeouts): a finding is
#                           saved and fuzzing goes on, instead of stopping the target
#        FUZZ_ARGS          extra libFuzzer flags
# Findings go to FUZZ_BUILD/findings/<target>/, logs to FUZZ_BUILD/logs/<target>.log, and a
# row per target is appended to FUZZ_BUILD/fuzz-results.tsv. Exit status 1 when anything
# was found.
set -uo pipefail
FUZZ_BUILD=$(realpath "$1"); CORPUS=$(realpath "$2"); SECONDS_EACH=$3; shift 3
HERE=$(cd "$(dirname "$0")/.." && pwd)
ALL=(ltm_reader_fuzzer npy_fuzzer hdr_fuzzer exr_fuzzer scene_fuzzer recipe_fuzzer
     off_fuzzer ply_fuzzer obj_fuzzer stl_fuzzer drc_fuzzer)
TARGETS=("$@")
[[ ${#TARGETS[@]} -gt 0 ]] || TARGETS=("${ALL[@]}")

# Largest input per target: the readers' seeds plus room to grow. The direct-I/O container
# seed (a 72 KiB chunk behind a padding frame) needs the larger bound.
max_len() {
  case $1 in
    ltm_reader_fuzzer) echo 131072 ;;
    scene_fuzzer|recipe_fuzzer) echo 16384 ;;
    *) echo 65536 ;;
  esac
}

mkdir -p "$FUZZ_BUILD/logs" "$FUZZ_BUILD/findings"
RESULTS=$FUZZ_BUILD/fuzz-results.tsv
[[ -f $RESULTS ]] || printf 'date\ttarget\tseconds\truns\tedges\tfeatures\tcorpus\tfindings\tmode\n' > "$RESULTS"
found_any=0
printf '%-18s %8s %10s %7s %8s %8s  %s\n' target seconds runs edges corpus findings artifacts
for t in "${TARGETS[@]}"; do
  bin=$FUZZ_BUILD/tests/fuzz/$t
  if [[ ! -x $bin ]]; then echo "fuzz_run.sh: $bin is missing" >&2; found_any=1; continue; fi
  corpus=$CORPUS/$t
  mkdir -p "$corpus"
  out=$FUZZ_BUILD/findings/$t
  mkdir -p "$out"
  before=$(ls "$out" | grep -cE '^(crash|leak|timeout|oom)-' || true)
  args=(-max_total_time="$SECONDS_EACH" -max_len="$(max_len "$t")" -rss_limit_mb=1024 -malloc_limit_mb=1024
        -timeout=10 -close_fd_mask=3 -print_final_stats=1 -artifact_prefix="$out/")
  dict=$HERE/tests/fuzz/dict/${t%_fuzzer}.dict
  [[ -f $dict ]] && args+=(-dict="$dict")
  mode=stop-at-first
  if [[ ${FUZZ_KEEP_GOING:-0} == 1 ]]; then
    args+=(-fork=1 -ignore_crashes=1 -ignore_ooms=1 -ignore_timeouts=1)
    mode=keep-going
  fi
  # The targets' temporary files: a process that dies of a finding leaves its own behind.
  export LTB_FUZZ_TMP
  LTB_FUZZ_TMP=$(mktemp -d "$( [[ -d /dev/shm ]] && echo /dev/shm || echo "${TMPDIR:-/tmp}")/ltb-fuzz-run-XXXXXX")
  log=$FUZZ_BUILD/logs/$t.log
  start=$(date +%s)
  # shellcheck disable=SC2086
  LTB_FUZZ_AUX=$CORPUS/aux/ltm ASAN_OPTIONS=detect_leaks=1:allocator_may_return_null=0 \
    UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 \
    "$bin" "${args[@]}" ${FUZZ_ARGS:-} "$corpus" > "$log" 2>&1
  rc=$?
  took=$(( $(date +%s) - start ))
  # The last status line: "#RUNS<tab>DONE cov: EDGES ft: FEATURES corp: N/SIZE ..." (fork
  # mode: "#RUNS: cov: ..."); the final stats give the run count when there is one.
  status=$(grep -E '^#[0-9]+.*cov: ' "$log" | tail -1)
  runs=$(grep -oE '^stat::number_of_executed_units: [0-9]+' "$log" | tail -1 | awk '{print $2}')
  [[ -n $runs ]] || runs=$(sed -E 's/^#([0-9]+).*/\1/' <<<"$status")
  edges=$(grep -oE 'cov: [0-9]+' <<<"$status" | awk '{print $2}')
  ft=$(grep -oE 'ft: [0-9]+' <<<"$status" | awk '{print $2}')
  # Fork mode counts coverage its own way; replaying the final corpus once (-runs=0) gives
  # the same measure in both modes: the edges the corpus covers ("INITED cov: N").
  replay=$(LTB_FUZZ_AUX=$CORPUS/aux/ltm timeout -s KILL 600 "$bin" -runs=0 -max_len="$(max_len "$t")" \
           -rss_limit_mb=1024 -malloc_limit_mb=1024 -timeout=10 -close_fd_mask=3 "$corpus" 2>&1 |
           grep -oE 'INITED cov: [0-9]+' | tail -1 | awk '{print $3}')
  [[ -n $replay ]] && edges=$replay
  rm -rf "$LTB_FUZZ_TMP"
  corp=$(ls "$corpus" | wc -l)
  after=$(ls "$out" | grep -cE '^(crash|leak|timeout|oom)-' || true)
  findings=$((after - before))
  if [[ $findings -eq 0 && $rc -ne 0 && $mode == stop-at-first ]]; then
    findings="rc=$rc"  # stopped without an artifact (e.g. a fatal error in the harness)
  fi
  arts=$(ls -t "$out" | grep -E '^(crash|leak|timeout|oom)-' | head -"${after:-0}" | head -3 | tr '\n' ' ')
  [[ $findings == 0 ]] || found_any=1
  printf '%-18s %8s %10s %7s %8s %8s  %s\n' "$t" "$took" "${runs:-?}" "${edges:-?}" "$corp" "$findings" \
    "$([[ $findings == 0 ]] || echo "$arts")"
  printf '%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\t%s\n' "$(date -u +%FT%TZ)" "$t" "$took" "${runs:-}" "${edges:-}" "${ft:-}" \
    "$corp" "$findings" "$mode" >> "$RESULTS"
done
echo "logs: $FUZZ_BUILD/logs/  findings: $FUZZ_BUILD/findings/  table: $RESULTS"
exit $found_any
