#!/usr/bin/env bash
# ltbake cpca against scikit-learn KMeans + per-cluster PCA on the same rows, same K and S:
# relative RMS error, wall time (median of REPEATS) and peak RSS (/usr/bin/time -v), plus
# ltbake's peak RSS at twice the rows (memory bounded independent of N).
#
# usage: bench/cpca_vs_sklearn.sh ROWS.ltm K S [REPEATS] [OUTDIR]
#   e.g. bench/cpca_vs_sklearn.sh out/medium-bake/rows.ltm 64 8 3   (make demo: samples/medium-bake.toml, R = 8)
# writes OUTDIR/cpca_vs_sklearn.csv (one row per run); summarise with bench/cpca_summary.py
set -euo pipefail
ROOT=$(cd "$(dirname "$0")/.." && pwd)
LTBAKE=${LTBAKE:-$ROOT/build/ltbake}
ROWS=$1 K=$2 S=$3 REPEATS=${4:-3} OUT=${5:-$ROOT/bench/out/cpca}
mkdir -p "$OUT"
CSV=$OUT/cpca_vs_sklearn.csv
[ -f "$CSV" ] || echo "tool,rows,dims,K,S,repeat,wall_s,fit_s,peak_rss_kib,relative_rms_error,iterations" > "$CSV"
"$LTBAKE" convert "$ROWS" "$OUT/rows.npy" -q --overwrite 2>/dev/null || "$LTBAKE" convert "$ROWS" "$OUT/rows.npy" -q
read -r N D < <(/usr/bin/python3 -c "import numpy as np; a=np.load('$OUT/rows.npy', mmap_mode='r'); print(*a.shape)")
timed() {  # prints "wall_s peak_kib" of the command; its stdout goes to $OUT/last.out
  /usr/bin/time -f "%e %M" -o "$OUT/time.txt" "$@" > "$OUT/last.out"
  cat "$OUT/time.txt"
}
for r in $(seq 1 "$REPEATS"); do
  rm -f "$OUT/cpca.ltm" "$OUT/cpca.ltm.cpca-state"
  read -r wall kib < <(timed "$LTBAKE" cpca "$ROWS" -o "$OUT/cpca.ltm" -k "$K" -s "$S" --json --progress never)
  read -r err it < <(/usr/bin/python3 -c "import json; j=json.load(open('$OUT/last.out')); print(j['relative_rms_error'], j['iterations'])")
  echo "ltbake,$N,$D,$K,$S,$r,$wall,$wall,$kib,$err,$it" >> "$CSV"
  read -r wall kib < <(timed /usr/bin/python3 "$ROOT/bench/cpca_sklearn.py" "$OUT/rows.npy" "$K" "$S")
  read -r fit err it < <(/usr/bin/python3 -c "import json; j=json.load(open('$OUT/last.out')); print(j['fit_s'], j['relative_rms_error'], j['iterations'])")
  echo "sklearn,$N,$D,$K,$S,$r,$wall,$fit,$kib,$err,$it" >> "$CSV"
done
# Twice the rows (the matrix stacked on itself): ltbake's memory must not grow with N.
/usr/bin/python3 -c "import numpy as np; a=np.load('$OUT/rows.npy'); np.save('$OUT/rows2.npy', np.vstack([a, a]))"
"$LTBAKE" convert "$OUT/rows2.npy" "$OUT/rows2.ltm" -q --overwrite
rm -f "$OUT/cpca2.ltm" "$OUT/cpca2.ltm.cpca-state"
read -r wall kib < <(timed "$LTBAKE" cpca "$OUT/rows2.ltm" -o "$OUT/cpca2.ltm" -k "$K" -s "$S" --json --progress never)
read -r err it < <(/usr/bin/python3 -c "import json; j=json.load(open('$OUT/last.out')); print(j['relative_rms_error'], j['iterations'])")
echo "ltbake,$((2 * N)),$D,$K,$S,1,$wall,$wall,$kib,$err,$it" >> "$CSV"
rm -f "$OUT/rows2.npy"
echo "wrote $CSV"
