#!/usr/bin/env bash
# The demo job on bundled data: build a light transport matrix (closed form, see
# scripts/make_demo_matrix.py), write it to an .ltm container, inspect and verify it,
# convert it back and check the round trip. Prints where the outputs are.
set -euo pipefail
BUILD=${1:-build}
cd "$(dirname "$0")/.."
OUT=out/demo
LTBAKE=$BUILD/ltbake
mkdir -p "$OUT"

echo "== building the demo matrix"
/usr/bin/python3 scripts/make_demo_matrix.py "$OUT/transport.npy" --width 64 --cube-res 8

echo "== writing it to a container"
rm -f "$OUT/transport.ltm"
"$LTBAKE" convert "$OUT/transport.npy" "$OUT/transport.ltm" --zstd --chunk-size 256KiB

echo "== inspect"
"$LTBAKE" inspect "$OUT/transport.ltm"
"$LTBAKE" inspect --json "$OUT/transport.ltm" > "$OUT/transport.inspect.json"

echo "== verify"
"$LTBAKE" verify "$OUT/transport.ltm"

echo "== round trip back to .npy"
"$LTBAKE" convert "$OUT/transport.ltm" "$OUT/transport-roundtrip.npy"
/usr/bin/python3 - "$OUT" <<'PY'
import sys, numpy as np
d = sys.argv[1]
a, b = np.load(f"{d}/transport.npy"), np.load(f"{d}/transport-roundtrip.npy")
assert a.tobytes() == b.tobytes(), "round trip differs"
print(f"round trip bit-exact: {a.shape[0]} x {a.shape[1]} float32")
PY

echo
echo "demo outputs in $(pwd)/$OUT:"
echo "  transport.npy              the matrix (4096 pixels x 384 cubemap texels)"
echo "  transport.ltm              the container (zstd chunks; all-zero chunks stored free)"
echo "  transport.inspect.json     ltbake inspect --json of it"
echo "  transport-roundtrip.npy    converted back, bit-exact"
