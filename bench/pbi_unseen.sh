#!/usr/bin/env bash
# bench/pbi_sequences.py on a scene and maps no bundled sample covers: the dragon at its finest
# resolution beside a pillar, 192x144 at R = 32 (bench/pbi_unseen_scene.toml), under two
# synthetic maps (bench/make_unseen_maps.py: a sun sky, three coloured windows).
#   bash bench/pbi_unseen.sh [BUILD_DIR=build]   -> bench/results/pbi_sequences_unseen.{md,csv,png}
set -euo pipefail
HERE=$(cd "$(dirname "$0")" && pwd)
BUILD=$(cd "${1:-$HERE/../build}" && pwd)
MAPS="$HERE/out/unseen_maps"
/usr/bin/python3 "$HERE/make_unseen_maps.py" "$MAPS"
"$BUILD/ltbake" run "$HERE/pbi_unseen_bake.toml" -q
LTB_PBI_MATRIX="$HERE/out/pbi_unseen/final.ltm" LTB_PBI_MAPS="$MAPS/sun_sky.hdr $MAPS/three_windows.hdr" \
  LTB_PBI_NAME=pbi_sequences_unseen LTB_PBI_DESC="unseen scene: dragon_res2 beside a pillar, 192x144, R = 32" \
  /usr/bin/python3 "$HERE/pbi_sequences.py" "$BUILD"
