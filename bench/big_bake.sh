#!/usr/bin/env bash
# The whole bake at the papers' scale on a small machine (issue 23, part 3), measured the way a
# new user would run it: `ltbake run` of bench/big_bake.toml (samples/medium.toml at R = 64,
# 256x256 pixels, spp 1: a 65536 x 24576 matrix, 6.4 GB logical; fused sample + row-transform
# (Haar), transpose, column-transform (adaptive LeGall 5/3, keep 0.02), quantize, one relight)
# inside a memory cgroup of MEM (default 2 GiB) that counts the page cache, with the I/O floor
# (dd writing and reading the same number of bytes) measured in the same cgroup first.
#
# While the bake runs, a sampler records every 0.5 s: the cgroup's memory (rss, page cache),
# the machine's busy CPUs and the disk's read/write bytes. Afterwards the per-stage table
# (wall, CPU, disk bytes, peak RSS, output bytes; from run.json) and a timeline plot are
# written to bench/results/big_bake_rR.{md,tsv,png}.
#
# usage: bash bench/big_bake.sh [BUILD=build] [R=64] [MEM=2G] [WORK=/tmp/ltb-big-bake]
# Needs root for the cgroup (v1 or v2); without it the bake runs unconfined and says so.
set -euo pipefail
BUILD=${1:-build}
R=${2:-64}
MEM=${3:-2G}
WORK=${4:-/tmp/ltb-big-bake}
cd "$(dirname "$0")/.."
ROOT=$(pwd)
rm -rf "$WORK"
mkdir -p "$WORK"
cp "$BUILD/ltbake" "$WORK/ltbake"  # a snapshot: a rebuild during the run cannot mix binaries
LT="$WORK/ltbake"
ENVMAPS=${LTBAKE_ENVMAPS:-$(scripts/find_envmaps.sh)}
MEM_BYTES=$(numfmt --from=iec "$MEM")
# Each stage gets 3/4 of the cgroup: the rest is the page cache of the files it streams.
STAGE_MEM=$((MEM_BYTES * 3 / 4))

cat > "$WORK/big_bake.toml" <<EOF
name = "big-bake"
scene = "$ROOT/samples/medium.toml"
targets = ["quantize", "relight"]

[sample]
cube_res = $R
spp = 1

[row-transform]
filter = "haar"

[column-transform]
filter = "legall53"
depth = "adaptive"
keep = 0.02

[relight]
matrix = "final"
envs = ["$ENVMAPS/sunset.exr"]
terms = 100
clamp = true
format = "png"
EOF

# The cgroup: v2 (memory.max) or v1 (memory.limit_in_bytes), as a child of ours.
CG=""
if [ -w /sys/fs/cgroup/cgroup.subtree_control ] 2>/dev/null && [ -f /sys/fs/cgroup/cgroup.controllers ]; then
  CG=/sys/fs/cgroup/ltb-big-bake-$$
  mkdir "$CG" && echo "$MEM_BYTES" > "$CG/memory.max" && echo 0 > "$CG/memory.swap.max" 2>/dev/null || true
  MEMFILE=memory.current
elif [ -d /sys/fs/cgroup/memory ]; then
  parent=/sys/fs/cgroup/memory$(awk -F: '$2 == "memory" {print $3}' /proc/self/cgroup)
  CG=$parent/ltb-big-bake-$$
  if mkdir "$CG" 2>/dev/null; then
    echo "$MEM_BYTES" > "$CG/memory.limit_in_bytes"
    MEMFILE=memory.usage_in_bytes
  else
    CG=""
  fi
fi
# The bake's own CPU time (the machine may be shared): v2 cpu.stat, or a v1 cpuacct group.
CPUACCT=""
if [ -n "$CG" ] && [ -f "$CG/cpu.stat" ]; then
  CPUACCT=v2
elif [ -n "$CG" ] && [ -d /sys/fs/cgroup/cpuacct ]; then
  CPUACCT=/sys/fs/cgroup/cpuacct/ltb-big-bake-$$
  mkdir "$CPUACCT" 2>/dev/null || CPUACCT=""
fi
cpu_ns() {
  if [ "$CPUACCT" = v2 ]; then awk '$1 == "usage_usec" {printf "%.0f\n", $2 * 1000}' "$CG/cpu.stat"
  elif [ -n "$CPUACCT" ]; then cat "$CPUACCT/cpuacct.usage"
  else awk '{printf "%.0f\n", ($2 + $3 + $4 + $7 + $8 + $9) * 1e7}' <(head -1 /proc/stat)  # the machine's
  fi
}
cleanup() {
  [ -n "${SAMPLER:-}" ] && kill "$SAMPLER" 2>/dev/null || true
  if [ -n "$CPUACCT" ] && [ "$CPUACCT" != v2 ]; then
    echo $$ > /sys/fs/cgroup/cpuacct/cgroup.procs
    rmdir "$CPUACCT" 2>/dev/null || true
  fi
  if [ -n "$CG" ]; then
    # Move ourselves out again before removing the group.
    if [ -f "$CG/memory.limit_in_bytes" ]; then echo $$ > "$(dirname "$CG")/cgroup.procs"; else echo $$ > /sys/fs/cgroup/cgroup.procs; fi
    rmdir "$CG" 2>/dev/null || true
  fi
}
trap cleanup EXIT
if [ -n "$CPUACCT" ] && [ "$CPUACCT" != v2 ]; then echo $$ > "$CPUACCT/cgroup.procs"; fi
if [ -n "$CG" ]; then
  echo $$ > "$CG/cgroup.procs"
  echo "memory cgroup $CG: limit $MEM ($MEM_BYTES bytes), page cache included"
else
  echo "WARNING: no memory cgroup (not root?): the bake runs without the $MEM limit" >&2
fi
OOM_BEFORE=$(grep -s '^oom_kill ' "${CG:-/nonexistent}/memory.events" "${CG:-/nonexistent}/memory.oom_control" | awk '{print $2}' | head -1 || true)

# The I/O floor: the matrix's logical size written (with fdatasync) and read back by dd.
LOGICAL=$((65536 * 6 * R * R * 4))
COUNT=$((LOGICAL / (8 << 20)))
t0=$(date +%s.%N)
dd if=/dev/zero of="$WORK/dd.bin" bs=8M count="$COUNT" conv=fdatasync status=none
t1=$(date +%s.%N)
dd if="$WORK/dd.bin" of=/dev/null bs=8M status=none
t2=$(date +%s.%N)
rm -f "$WORK/dd.bin"
DD_WRITE=$(echo "$t1 - $t0" | bc)
DD_READ=$(echo "$t2 - $t1" | bc)

# The sampler: time, cgroup memory, its page cache, CPUs busy with the bake (its cgroup's
# CPU time), disk bytes read/written per second (the whole disk).
DISK=$(lsblk -no pkname "$(df --output=source "$WORK" | tail -1)" 2>/dev/null || true)
[ -n "$DISK" ] || DISK=$(basename "$(df --output=source "$WORK" | tail -1)")
TSV="$WORK/timeline.tsv"
(
  echo -e "t\tmem_bytes\tcache_bytes\tbusy_cpus\tread_bytes\twrite_bytes"
  prev=""
  start=$(date +%s.%N)
  while :; do
    now=$(date +%s.%N)
    mem=0 cache=0
    if [ -n "$CG" ]; then
      mem=$(cat "$CG/$MEMFILE")
      cache=$(awk '$1 == "cache" || $1 == "file" {print $2; exit}' "$CG/memory.stat")
    fi
    busy=$(cpu_ns)
    read -r rd wr < <(awk -v d="$DISK" '$3 == d {printf "%.0f %.0f\n", $6 * 512, $10 * 512}' /proc/diskstats)
    if [ -n "$prev" ]; then
      read -r pt pbusy prd pwr <<<"$prev"
      dt=$(echo "$now - $pt" | bc)
      cpus=$(echo "scale=3; ($busy - $pbusy) / ($dt * 1000000000)" | bc)
      echo -e "$(echo "$now - $start" | bc)\t$mem\t$cache\t$cpus\t$(echo "($rd - $prd) / $dt" | bc)\t$(echo "($wr - $pwr) / $dt" | bc)"
    fi
    prev="$now $busy $rd $wr"
    sleep 0.5
  done
) > "$TSV" &
SAMPLER=$!

/usr/bin/time -f "%e %U %S %M" -o "$WORK/time.txt" "$LT" run "$WORK/big_bake.toml" --workdir "$WORK/w" \
  --mem-limit "$STAGE_MEM" --jobs "$(nproc)" -q
kill "$SAMPLER" 2>/dev/null || true
SAMPLER=""
OOM_AFTER=$(grep -s '^oom_kill ' "${CG:-/nonexistent}/memory.events" "${CG:-/nonexistent}/memory.oom_control" | awk '{print $2}' | head -1 || true)
MAXMEM=$(cat "$CG/memory.max_usage_in_bytes" 2>/dev/null || cat "$CG/memory.peak" 2>/dev/null || echo 0)

mkdir -p bench/results
cp "$TSV" "bench/results/big_bake_r$R.tsv"
cp "$WORK/w/run.json" "bench/results/big_bake_r$R.run.json"
/usr/bin/python3 bench/big_bake_report.py "$WORK/w/run.json" "bench/results/big_bake_r$R.tsv" "$WORK/time.txt" \
  --r "$R" --mem "$MEM" --dd-write "$DD_WRITE" --dd-read "$DD_READ" --logical "$LOGICAL" \
  --oom "${OOM_BEFORE:-0}:${OOM_AFTER:-0}" --max-mem "${MAXMEM:-0}" --cgroup "${CG:-none}" \
  --out "bench/results/big_bake_r$R"
