#!/usr/bin/env bash
# The demo on bundled data: bake the bunny scene (samples/medium.toml at R = 8 so it takes
# seconds) through the stages that exist so far — sample, row-transform, transpose,
# column-transform, quantize — relights the result under two environment maps with its
# errors, inspects and verifies every container and writes preview images. Prints where
# outputs are.
set -euo pipefail
BUILD=${1:-build}
cd "$(dirname "$0")/.."
OUT=out/demo
LTBAKE=$BUILD/ltbake
mkdir -p "$OUT"

echo "== sample: ray-cast the transport matrix of samples/medium.toml (bunny on a plane)"
"$LTBAKE" sample samples/medium.toml -o "$OUT/raw.ltm" --cube-res 8 --spp 4 --overwrite

echo "== row-transform: Haar wavelets over each row's six cube faces"
"$LTBAKE" row-transform "$OUT/raw.ltm" -o "$OUT/rows.ltm" --filter haar --overwrite

echo "== transpose: column blocks (each light's image contiguous), within 256 MiB"
"$LTBAKE" transpose "$OUT/rows.ltm" -o "$OUT/cols.ltm" --mem-limit 256MiB --overwrite

echo "== column-transform: each light's image to its optimal depth (LeGall 5/3), 5% of its terms"
"$LTBAKE" column-transform "$OUT/cols.ltm" -o "$OUT/cols4d.ltm" --keep 0.05 --overwrite

echo "== quantize: 9 bits, level scaling, dithered"
"$LTBAKE" quantize "$OUT/cols4d.ltm" -o "$OUT/final.ltm" --bits 9 --overwrite

echo "== relight: final.ltm under two of Blender's CC0 environment maps (blender-data), 100 lighting terms"
ENVS=$(bash scripts/find_envmaps.sh)
for env in sunset forest; do
  "$LTBAKE" relight "$OUT/final.ltm" --env "$ENVS/$env.exr" --clamp --terms 100 --reference "$OUT/raw.ltm" \
    -o "$OUT/relit-$env.png"
  "$LTBAKE" relight "$OUT/final.ltm" --env "$ENVS/$env.exr" --clamp --terms 100 -o "$OUT/relit-$env.exr" -q
done

echo "== inspect"
"$LTBAKE" inspect "$OUT/raw.ltm"
"$LTBAKE" inspect --json "$OUT/cols.ltm" > "$OUT/cols.inspect.json"
"$LTBAKE" inspect "$OUT/final.ltm"

echo "== verify"
"$LTBAKE" verify "$OUT/raw.ltm" "$OUT/rows.ltm" "$OUT/cols.ltm" "$OUT/cols4d.ltm" "$OUT/final.ltm"

echo "== previews"
"$LTBAKE" convert "$OUT/raw.ltm" "$OUT/raw.npy" -q
"$LTBAKE" convert "$OUT/final.ltm" "$OUT/final-pixels.npy" --basis pixels -q
/usr/bin/python3 - "$OUT" <<'PY'
import json, sys
import numpy as np
import matplotlib
matplotlib.use("Agg")
import matplotlib.pyplot as plt
d = sys.argv[1]
T = np.load(f"{d}/raw.npy")
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
print(f"final.ltm against raw.ltm: relative RMS error {rel:.4f} over the matrix, {rel_sky:.4f} on the uniform-sky image")
PY

echo
echo "demo outputs in $(pwd)/$OUT:"
echo "  raw.ltm    sampled transport matrix: 65536 pixels x 384 lights (+ mask, position, normal tables)"
echo "  rows.ltm   after row-transform (Haar, per cube face)"
echo "  cols.ltm   after transpose (one chunk per light: its 256x256 image); cols.inspect.json"
echo "  cols4d.ltm after column-transform (adaptive depth per light image, 5% of terms)"
echo "  final.ltm  after quantize (9 bits): what relighting reads"
echo "  relit-sunset.png/.exr, relit-forest.png/.exr   relit images (errors against raw.ltm printed above)"
echo "  preview-sky.png, preview-zenith-texel.png, preview-sky-compressed.png"
