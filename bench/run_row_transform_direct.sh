#!/usr/bin/env bash
# The row-transform stage end to end, output with O_DIRECT (default) against --no-direct-io,
# alternated in the same run: 32768 x 6144 f32 (805 MB, R = 32, random normal values),
# haar, --jobs 2, input warm in the page cache, output deleted and `sync` before each run.
#
#   bash bench/run_row_transform_direct.sh BUILD_DIR [REPS=3]
#
# Prints one line per run (wall, user, sys from /usr/bin/time). Needs /usr/bin/python3 with
# numpy and ~1.7 GB free in LTB_BENCH_DIR (default bench/out/); everything is deleted after.
set -euo pipefail
BUILD=$(cd "${1:?usage: run_row_transform_direct.sh BUILD_DIR [REPS=3]}" && pwd)
REPS=${2:-3}
HERE=$(cd "$(dirname "$0")" && pwd)
D=${LTB_BENCH_DIR:-$HERE/out}/row_transform_direct
mkdir -p "$D"
trap 'rm -rf "$D"' EXIT
cd "$D"
L=$BUILD/ltbake
/usr/bin/python3 -c "
import numpy as np
m = np.lib.format.open_memmap('in.npy', mode='w+', dtype=np.float32, shape=(32768, 6144))
rng = np.random.default_rng(1)
for i in range(0, 32768, 4096): m[i:i+4096] = rng.standard_normal((4096, 6144), dtype=np.float32)
m.flush()"
"$L" convert in.npy in.ltm --cube-res 32 -q
rm in.npy
echo "$(grep -m1 'model name' /proc/cpuinfo | cut -d: -f2), $(nproc) vCPUs, kernel $(uname -r)"
for ((rep = 1; rep <= REPS; rep++)); do
  for v in direct buffered; do
    rm -f out.ltm; sync; sleep 2
    flag=()
    [[ $v == buffered ]] && flag=(--no-direct-io)
    /usr/bin/time -f "$v rep $rep: %e s wall, user %U, sys %S" "$L" row-transform in.ltm -o out.ltm --filter haar \
      --progress never -q "${flag[@]}"
  done
done
