#!/usr/bin/env bash
# The demo on bundled data: `ltbake run samples/medium-bake.toml` bakes the bunny scene
# (sample + row-transform fused, transpose, column-transform, quantize) and relights the
# result under two of Blender's CC0 environment maps with its error against the
# uncompressed matrix; then inspects and verifies the containers and writes preview images.
# Prints the run's summary table and where the outputs and run.json are.
set -euo pipefail
BUILD=${1:-build}
cd "$(dirname "$0")/.."
LTBAKE=$BUILD/ltbake
OUT=out/medium-bake
export LTBAKE_ENVMAPS=${LTBAKE_ENVMAPS:-$(bash scripts/find_envmaps.sh)}

echo "== ltbake run samples/medium-bake.toml (a rerun skips what is up to date; Ctrl-C, then rerun, resumes)"
mkdir -p "$OUT"
"$LTBAKE" run samples/medium-bake.toml | tee "$OUT/run.out"

echo
echo "== inspect"
"$LTBAKE" inspect "$OUT/rows.ltm"
"$LTBAKE" inspect --json "$OUT/cols.ltm" > "$OUT/cols.inspect.json"
"$LTBAKE" inspect "$OUT/final.ltm"

echo "== verify"
"$LTBAKE" verify "$OUT/rows.ltm" "$OUT/cols.ltm" "$OUT/cols4d.ltm" "$OUT/final.ltm"

echo "== previews"
"$LTBAKE" convert "$OUT/rows.ltm" "$OUT/rows-pixels.npy" --basis pixels -q
"$LTBAKE" convert "$OUT/final.ltm" "$OUT/final-pixels.npy" --basis pixels -q
/usr/bin/python3 - "$OUT" <<'PY'
import json, sys
import numpy as np
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
d = sys.argv[1]
T = np.load(f"{d}/rows-pixels.npy")
R = 8
W = H = 256
sky = T.sum(axis=1).reshape(H, W)                       # uniform white sky
top = T[:, 4 * R * R + (R // 2) * R + R // 2].reshape(H, W)  # one texel near the zenith
plt.imsave(f"{d}/preview-sky.png", sky, cmap="gray", vmin=0, vmax=sky.max())
plt.imsave(f"{d}/preview-zenith-texel.png", top, cmap="gray", vmin=0, vmax=top.max())
F = np.load(f"{d}/final-pixels.npy")
sky_c = F.sum(axis=1).reshape(H, W)
plt.imsave(f"{d}/preview-sky-compressed.png", sky_c, cmap="gray", vmin=0, vmax=sky.max())
rel = np.sqrt(((F.astype(np.float64) - T) ** 2).sum() / (T.astype(np.float64) ** 2).sum())
rel_sky = np.sqrt(((sky_c - sky) ** 2).sum() / (sky ** 2).sum())
print(f"preview images: {d}/preview-sky.png (uniform sky), {d}/preview-zenith-texel.png (one light overhead), "
      f"{d}/preview-sky-compressed.png (uniform sky from final.ltm)")
print(f"final.ltm against the uncompressed matrix: relative RMS error {rel:.4f} over the matrix, "
      f"{rel_sky:.4f} on the uniform-sky image")
PY
rm -f "$OUT/rows-pixels.npy" "$OUT/final-pixels.npy"

echo
echo "== the bake's summary (from ltbake run)"
sed -n '/^stage  /,/^run report/p' "$OUT/run.out"
echo
echo "demo outputs in $(pwd)/$OUT:"
echo "  run.json   the run report: every stage's command, log, wall time, peak RSS, sizes, content_hash"
echo "  logs/      each stage's log"
echo "  rows.ltm   sampled and row-transformed in one pass (Haar per cube face): 65536 pixels x 384 lights"
echo "  cols.ltm   after transpose (one chunk per light: its 256x256 image); cols.inspect.json"
echo "  cols4d.ltm after column-transform (adaptive depth per light image, 5% of terms)"
echo "  final.ltm  after quantize (one quantizer step for the matrix, at most 10% more RMS error): what relighting reads"
echo "  relit-sunset.png, relit-forest.png   relit images (errors against rows.ltm printed above, and in run.json)"
echo "  preview-sky.png, preview-zenith-texel.png, preview-sky-compressed.png"
echo
bin=$(cd "$BUILD" && pwd)
echo "ltbake is $bin/ltbake (not on PATH): export PATH=\"$bin:\$PATH\" to run the commands above as"
echo "'ltbake ...', or install it with its stage executables and the Python module: make install PREFIX=\$HOME/.local"
