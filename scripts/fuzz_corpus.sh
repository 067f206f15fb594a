#!/usr/bin/env bash
# Seeds a fuzzing corpus with small valid containers (raw, zstd, zero chunks, both layouts,
# sealed and unsealed). usage: fuzz_corpus.sh BUILD_DIR CORPUS_DIR
set -euo pipefail
BUILD=$1; CORPUS=$2
cd "$(dirname "$0")/.."
mkdir -p "$CORPUS"
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
/usr/bin/python3 - "$tmp" <<'PY'
import sys, numpy as np
d = sys.argv[1]
m = np.load("samples/tiny-transport.npy")
np.save(f"{d}/a.npy", m)
z = m.copy(); z[:8] = 0
np.save(f"{d}/z.npy", z)
PY
"$BUILD/ltbake" convert "$tmp/a.npy" "$CORPUS/rows.ltm" --chunk-size 256 -q --overwrite
"$BUILD/ltbake" convert "$tmp/z.npy" "$CORPUS/cols-zstd.ltm" --chunk-size 256 --layout cols --zstd -q --overwrite
"$BUILD/ltbake" convert "$tmp/a.npy" "$CORPUS/one-chunk.ltm" -q --overwrite
head -c 1200 "$CORPUS/rows.ltm" > "$CORPUS/partial.ltm"
