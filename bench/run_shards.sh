#!/usr/bin/env bash
# What sharding costs on one machine: the bake of samples/medium.toml (R = 16 by default) to
# final.ltm by `ltbake run` unsharded and with --shards 2, 4 and 8 through the local engine
# (--jobs 2 in all cases), each into a fresh directory, interleaved, REPS times. Prints the
# median wall time per shard count, its ratio to unsharded, the time run.json records for
# committing the manifests, and checks every final.ltm has the unsharded content_hash.
# Writes bench/results/run_shards_rR.md.
#
# usage: bash bench/run_shards.sh [BUILD=build] [REPS=3] [CUBE_RES=16]
set -euo pipefail
BUILD=${1:-build}
REPS=${2:-3}
R=${3:-16}
cd "$(dirname "$0")/.."
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
cp "$BUILD/ltbake" "$WORK/ltbake"
LT="$WORK/ltbake"
printf 'name = "shards"\nscene = "%s"\ntargets = ["quantize"]\n[sample]\ncube_res = %s\n' \
  "$(pwd)/samples/medium.toml" "$R" >"$WORK/bake.toml"
now() { date +%s.%N; }
hash_of() { "$LT" inspect --json "$1" | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)["content_hash"])'; }
COUNTS=(1 2 4 8)
declare -A T C
ref=""
for rep in $(seq 1 "$REPS"); do
  for n in "${COUNTS[@]}"; do
    d="$WORK/n$n-$rep"
    t0=$(now)
    "$LT" run "$WORK/bake.toml" --workdir "$d" --shards "$n" --jobs 2 -q
    t1=$(now)
    T[$n]+="$(echo "$t1 - $t0" | bc) "
    C[$n]+="$(/usr/bin/python3 -c 'import json,sys; print(sum(s.get("commit_seconds", 0) for s in json.load(open(sys.argv[1]))["stages"]))' "$d/run.json") "
    h=$(hash_of "$d/final.ltm")
    [ -z "$ref" ] && ref=$h
    [ "$h" = "$ref" ] || { echo "final.ltm content_hash $h with $n shards, expected $ref" >&2; exit 1; }
    rm -rf "$d"
  done
done
median() { printf '%s\n' $1 | sort -g | awk '{a[NR]=$1} END {print a[int((NR+1)/2)]}'; }
base=$(median "${T[1]}")
out="bench/results/run_shards_r$R.md"
{
  echo "# \`ltbake run --shards N\` on one machine (local engine), samples/medium.toml, R = $R"
  echo
  echo "Machine: $(nproc) vCPU, $(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2 | sed 's/^ //'), $(free -g | awk '/Mem:/ {print $2}') GiB RAM."
  echo "Date: $(date -u +%Y-%m-%d). $REPS interleaved repetitions; medians. Every final.ltm: content_hash $ref."
  echo
  echo "| shards | wall (median) | vs unsharded | commit time (median, all stages) | runs (s) |"
  echo "|---|---|---|---|---|"
  for n in "${COUNTS[@]}"; do
    m=$(median "${T[$n]}")
    printf '| %s | %.2f s | %.2f× | %.3f s | %s|\n' "$n" "$m" "$(echo "$m / $base" | bc -l)" "$(median "${C[$n]}")" "${T[$n]}"
  done
} | tee "$out"
