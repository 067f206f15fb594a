#!/usr/bin/env bash
# Reruns every finding of the fuzz targets (FUZZ_BUILD/findings/<target>/crash-*, leak-*,
# oom-*, timeout-*) with the limits fuzz_run.sh uses and prints, per finding, what
# happened and the first frames outside libFuzzer, the sanitizers and libc, grouped so
# that findings with the same top frames are counted once. docs/FUZZING.md.
#
# usage: fuzz_triage.sh FUZZ_BUILD [TARGET...]
set -uo pipefail
FUZZ_BUILD=$(realpath "$1"); shift
TARGETS=("$@")
if [[ ${#TARGETS[@]} -eq 0 ]]; then
  for d in "$FUZZ_BUILD"/findings/*/; do TARGETS+=("$(basename "$d")"); done
fi
for t in "${TARGETS[@]}"; do
  bin=$FUZZ_BUILD/tests/fuzz/$t
  dir=$FUZZ_BUILD/findings/$t
  [[ -d $dir ]] || continue
  mapfile -t files < <(ls "$dir" | grep -E '^(crash|leak|timeout|oom)-')
  [[ ${#files[@]} -gt 0 ]] || continue
  echo "== $t: ${#files[@]} findings"
  for f in "${files[@]}"; do
    out=$(UBSAN_OPTIONS=print_stacktrace=1:halt_on_error=1 LTB_FUZZ_AUX=$FUZZ_BUILD/corpus/aux/ltm timeout -s KILL 120 "$bin" -rss_limit_mb=1024 -malloc_limit_mb=1024 \
          -timeout=10 -close_fd_mask=1 "$dir/$f" 2>&1)
    rc=$?
    what=$(grep -m1 -oE 'ERROR: [A-Za-z]+: [^(]*(\(malloc\([0-9]+\)\))?|runtime error: .*|Assertion .*|timeout after [0-9]+ seconds' <<<"$out")
    # Frames as "function file:line", without libFuzzer, the sanitizers, libc and the
    # standard library's own functions.
    frames=$(grep -E '^ +#[0-9]+ 0x[0-9a-f]+ in ' <<<"$out" | sed -E 's/^ +#[0-9]+ 0x[0-9a-f]+ in //; s/ \(.*BuildId.*\)//' |
             grep -vE '^(fuzzer::|__sanitizer|__asan|__ubsan|__interceptor|__libc|__pthread|__GI_|raise|abort|__assert|operator (new|delete)|std::|void std::|allocate |deallocate |_start|main |LLVMFuzzerTestOneInput|RunMallocHooks|malloc|calloc|realloc)' |
             grep -v 'include/c++/' | head -3 | sed -E 's/\(([^()]|\([^()]*\))*\)//g; s| /work/[^ ]*/\.\./| |' | cut -c1-120)
    what=$(sed -E 's/malloc\([0-9]+\)/malloc(N)/; s/load of value [0-9]+/load of value N/' <<<"$what")
    printf '%s\t%s\t%s\n' "${what:-exit $rc, no report (fixed?)}" "$(tr '\n' '|' <<<"$frames")" "$f"
  done | sort | awk -F'\t' '{k=$1"\t"$2; n[k]++; if(!(k in ex)) ex[k]=$3} END {for (k in n) printf "  %3d x %s\n        e.g. %s\n", n[k], k, ex[k]}'
done
