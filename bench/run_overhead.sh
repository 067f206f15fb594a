#!/usr/bin/env bash
# What `ltbake run` costs over typing the stage commands by hand: the same bake of
# samples/medium.toml (R = 8 by default) to final.ltm, (a) as the four stage commands a
# user would run (fused sample + row-transform, transpose, column-transform, quantize) and
# (b) as `ltbake run` of an equivalent recipe, each into a fresh directory, interleaved,
# REPS times. Then (c) a rerun of the finished recipe (everything skipped). Prints medians,
# the ratio and the parts of run's overhead it records (reading outputs back for their
# content_hash), and writes bench/results/run_overhead_rR.md.
#
# usage: bash bench/run_overhead.sh [BUILD=build] [REPS=3] [CUBE_RES=8]
set -euo pipefail
BUILD=${1:-build}
REPS=${2:-3}
R=${3:-8}
cd "$(dirname "$0")/.."
WORK=$(mktemp -d)
trap 'rm -rf "$WORK"' EXIT
cp "$BUILD/ltbake" "$WORK/ltbake"  # a snapshot: a rebuild during the run cannot mix binaries
LT="$WORK/ltbake"
cat > "$WORK/bake.toml" <<EOF
name = "overhead"
scene = "$(pwd)/samples/medium.toml"
targets = ["quantize"]
[sample]
cube_res = $R
[column-transform]
keep = 0.05   # as typed by hand below (the recipe default is budget = "5%")
EOF

now() { date +%s.%N; }
secs() { printf '%.3f' "$(echo "$2 - $1" | bc)"; }
manual=() run=() rerun=() hashing=()
for rep in $(seq 1 "$REPS"); do
  d="$WORK/manual$rep"; mkdir -p "$d"
  t0=$(now)
  "$LT" sample samples/medium.toml -o "$d/rows.ltm" --cube-res "$R" --row-transform haar -q
  "$LT" transpose "$d/rows.ltm" -o "$d/cols.ltm" -q
  "$LT" column-transform "$d/cols.ltm" -o "$d/cols4d.ltm" --keep 0.05 -q
  "$LT" quantize "$d/cols4d.ltm" -o "$d/final.ltm" -q
  t1=$(now)
  manual+=("$(secs "$t0" "$t1")")
  m_hash=$("$LT" inspect --json "$d/final.ltm" | /usr/bin/python3 -c 'import json,sys; print(json.load(sys.stdin)["content_hash"])')
  rm -rf "$d"

  w="$WORK/run$rep"
  t0=$(now)
  "$LT" run "$WORK/bake.toml" --workdir "$w" -q
  t1=$(now)
  run+=("$(secs "$t0" "$t1")")
  t0=$(now)
  "$LT" run "$WORK/bake.toml" --workdir "$w" -q
  t1=$(now)
  rerun+=("$(secs "$t0" "$t1")")
  read -r r_hash h <<<"$(/usr/bin/python3 - "$w/run.json" <<'PY'
import json, sys
j = json.load(open(sys.argv[1]))
final = [s for s in j["stages"] if s["node"] == "quantize"][0]["output"]["content_hash"]
print(final, "%.3f" % sum(s["output"].get("hash_seconds", 0) for s in j["stages"]))
PY
)"
  hashing+=("$h")
  [ "$m_hash" = "$r_hash" ] || { echo "final.ltm differs: manual $m_hash, run $r_hash" >&2; exit 1; }
  rm -rf "$w"
  echo "rep $rep: manual ${manual[-1]} s, run ${run[-1]} s (hashing outputs ${h} s), rerun ${rerun[-1]} s"
done

median() { printf '%s\n' "$@" | sort -g | awk '{a[NR]=$1} END {print (NR % 2) ? a[(NR+1)/2] : (a[NR/2] + a[NR/2+1]) / 2}'; }
M=$(median "${manual[@]}"); RN=$(median "${run[@]}"); RR=$(median "${rerun[@]}"); H=$(median "${hashing[@]}")
RATIO=$(printf '%.2f' "$(echo "scale=4; $RN / $M" | bc)")
CPU=$(grep -m1 "model name" /proc/cpuinfo | cut -d: -f2 | sed 's/^ *//')
OUT=bench/results/run_overhead_r$R.md
cat > "$OUT" <<EOF
# \`ltbake run\` against the same stages typed by hand

Machine: $(nproc) × $CPU, $(awk '/MemTotal/ {printf "%.1f GiB", $2/1048576}' /proc/meminfo), $(date +%F).
Bake: samples/medium.toml (256×256 pixels) at R = $R to final.ltm (fused sample + row-transform,
transpose, column-transform --keep 0.05, quantize), each run into a fresh directory; the
two ways interleaved, $REPS repetitions; both end with the same final.ltm content_hash.
Reproduce: \`bash bench/run_overhead.sh BUILD $REPS $R\`.

| | median wall (s) | all runs (s) |
|---|---|---|
| stage commands by hand | $M | ${manual[*]} |
| \`ltbake run\` | $RN | ${run[*]} |
| \`ltbake run\` again (all skipped) | $RR | ${rerun[*]} |

\`ltbake run\` / by hand = **$RATIO**. Of run's extra time, reading each output back for its
content_hash took a median $H s (run.json \`hash_seconds\`, summed over the stages); the
rest is planning, the report and process start-up.
EOF
cat "$OUT"
