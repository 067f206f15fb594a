#!/usr/bin/env bash
# Per-core (--jobs 1) rates of every bake stage on this machine, for the on-paper cluster
# scaling estimate in docs/cluster.md. Prints a markdown report on stdout;
# progress goes to stderr.
#
#   bash bench/cluster_rates.sh [BUILD_DIR] > bench/results/cluster_rates.md
#   REPS=3 (default) repetitions of each timed command; medians are reported.
#
# What is timed (each with /usr/bin/time, the real `ltbake` CLI, --jobs 1, --progress never):
#   sample        medium scene (samples/medium.toml) at 64x64 pixels, R = 8..128, spp 4;
#                 and at 1024x1024 pixels with R = 1 (per-row cost) and R = 8 (1M rows)
#   sample fused  + --row-transform haar, with and without --row-zstd, R = 128, 64x64
#   row-transform haar on the R = 128 raw matrix, raw and --zstd output
#   transpose     1M x 384 (1024x1024 image, R = 8; default --mem-limit 1GiB: 508-byte reads),
#                 4096 x 98304 (R = 128; 32 KiB reads), and the same from zstd row chunks
#   column-transform  defaults (legall53, adaptive depth, --keep 0.05) on 256^2, 512^2 and
#                 1024^2 column images (R = 8: 384 columns)
#   quantize      defaults (9 bits, level scaling, dither) on the 1024^2 column-transform output
# Rates are per CPU second (user + sys of the process, all its threads): the stage's work
# in core-seconds, independent of this VM's disk. Inputs are warm in the page cache; wall
# times include fdatasync of the output to the local disk. Setup steps run with --jobs 2
# and are not timed. Everything lives in a temporary directory under /tmp, removed on exit.
set -euo pipefail

ROOT=$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)
BUILD=${1:-$ROOT/build}
case $BUILD in /*) ;; *) BUILD=$ROOT/$BUILD ;; esac
LTB=$BUILD/ltbake
REPS=${REPS:-3}
PY=/usr/bin/python3
SCENE_SRC=$ROOT/samples/medium.toml
MESH=$ROOT/data/meshes/bunny.obj

die() { echo "cluster_rates.sh: $*" >&2; exit 1; }
[[ -x $LTB ]] || die "$LTB not found: run 'make build' first"
[[ -x /usr/bin/time ]] || die "/usr/bin/time not found (apt-get install time)"
[[ -x $PY ]] || die "$PY not found"
[[ -f $SCENE_SRC ]] || die "$SCENE_SRC not found"
[[ -f $MESH ]] || die "$MESH not found: run 'make samples'"
[[ $REPS =~ ^[1-9][0-9]*$ ]] || die "REPS must be a positive integer, got '$REPS'"
free_kb=$(df -Pk /tmp | awk 'NR==2 {print $4}')
(( free_kb > 12 * 1024 * 1024 )) || die "need 12 GB free under /tmp, have $((free_kb / 1024)) MiB"

T=$(mktemp -d /tmp/ltb-cluster-rates.XXXXXX)
cleanup() { rm -rf -- "$T"; }
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM

START_DATE=$(date -u '+%Y-%m-%d %H:%M UTC')
START_LOAD=$(cut -d' ' -f1-3 /proc/loadavg)
log() { echo "[cluster_rates $(date -u +%H:%M:%S)] $*" >&2; }

# A copy of the medium scene at SIZE x SIZE pixels, mesh path made absolute.
make_scene() {
  local size=$1 out=$T/scene$1.toml
  sed -e "s|^width = .*|width = $size|" -e "s|^height = .*|height = $size|" \
      -e "s|\"\.\./data/meshes/bunny\.obj\"|\"$MESH\"|" "$SCENE_SRC" > "$out"
  grep -q "^width = $size\$" "$out" && grep -q "^height = $size\$" "$out" && grep -qF "\"$MESH\"" "$out" \
    || die "could not rewrite $SCENE_SRC (width/height/mesh lines changed?)"
}

# timed KEY OUT CMD...: REPS runs of CMD (OUT removed before each, so nothing resumes);
# keeps the last OUT. Records time, stdout, and `inspect --json` of OUT per repetition.
timed() {
  local key=$1 out=$2; shift 2
  local r
  for ((r = 1; r <= REPS; r++)); do
    rm -f -- "$out"
    sync
    log "$key rep $r/$REPS"
    head -1 /proc/stat > "$T/$key.$r.stat"
    if ! /usr/bin/time -f '%e %U %S %M' -o "$T/$key.$r.time" "$@" > "$T/$key.$r.out" 2> "$T/$key.$r.err"; then
      cat "$T/$key.$r.err" >&2
      die "$key failed: $*"
    fi
    head -1 /proc/stat >> "$T/$key.$r.stat"
    "$LTB" inspect "$out" --json --no-content > "$T/$key.$r.inspect.json"
    echo "$key $r" >> "$T/runs.list"
  done
}

setup() { log "setup: $*"; "$@" -q --progress never > /dev/null; }

for s in 64 256 512 1024; do make_scene $s; done
J1=(--jobs 1 --progress never)

# --- sample: R sweep at 64x64 (rays per row grow as 6R^2 * spp) ---
for R in 8 16 32 64 128; do
  timed sample64_R$R "$T/s64_R$R.ltm" "$LTB" sample "$T/scene64.toml" -o "$T/s64_R$R.ltm" --cube-res $R "${J1[@]}"
  [[ $R == 128 ]] || rm -f "$T/s64_R$R.ltm"
done
# per-row cost (R = 1: 6 texels) and many rows (R = 8) at 1024x1024
timed sample1024_R1 "$T/s1024_R1.ltm" "$LTB" sample "$T/scene1024.toml" -o "$T/s1024_R1.ltm" --cube-res 1 "${J1[@]}"
rm -f "$T/s1024_R1.ltm"
timed sample1024_R8 "$T/s1024_R8.ltm" "$LTB" sample "$T/scene1024.toml" -o "$T/s1024_R8.ltm" --cube-res 8 "${J1[@]}"
# fused sample + row-transform (haar; zstd and raw chunks): what a sharded bake would run
timed fused64_R128 "$T/f64_R128.ltm" "$LTB" sample "$T/scene64.toml" -o "$T/f64_R128.ltm" --cube-res 128 \
  --row-transform haar --row-zstd "${J1[@]}"
timed fused64_R128_raw "$T/f64_R128_raw.ltm" "$LTB" sample "$T/scene64.toml" -o "$T/f64_R128_raw.ltm" --cube-res 128 \
  --row-transform haar "${J1[@]}"
rm -f "$T/f64_R128_raw.ltm"

# --- row-transform (haar) on the R = 128 raw matrix ---
timed rowt_R128 "$T/r128.ltm" "$LTB" row-transform "$T/s64_R128.ltm" -o "$T/r128.ltm" "${J1[@]}"
timed rowt_R128_zstd "$T/r128z.ltm" "$LTB" row-transform "$T/s64_R128.ltm" -o "$T/r128z.ltm" --zstd "${J1[@]}"
rm -f "$T/r128z.ltm" "$T/s64_R128.ltm"

# --- transpose ---
setup "$LTB" row-transform "$T/s1024_R8.ltm" -o "$T/r1024.ltm" --jobs 2
rm -f "$T/s1024_R8.ltm"
timed transpose_1M "$T/c1024.ltm" "$LTB" transpose "$T/r1024.ltm" -o "$T/c1024.ltm" "${J1[@]}"
rm -f "$T/r1024.ltm"
timed transpose_wide "$T/cw.ltm" "$LTB" transpose "$T/r128.ltm" -o "$T/cw.ltm" "${J1[@]}"
rm -f "$T/cw.ltm" "$T/r128.ltm"
timed transpose_wide_zin "$T/cwz.ltm" "$LTB" transpose "$T/f64_R128.ltm" -o "$T/cwz.ltm" "${J1[@]}"
rm -f "$T/cwz.ltm"
timed transpose_wide_zz "$T/cwzz.ltm" "$LTB" transpose "$T/f64_R128.ltm" -o "$T/cwzz.ltm" --zstd "${J1[@]}"
rm -f "$T/cwzz.ltm" "$T/f64_R128.ltm"

# --- column-transform (defaults) at three image sizes, R = 8 ---
for s in 256 512; do
  setup "$LTB" sample "$T/scene$s.toml" -o "$T/r$s.ltm" --cube-res 8 --row-transform haar --jobs 2
  setup "$LTB" transpose "$T/r$s.ltm" -o "$T/c$s.ltm" --jobs 2
  rm -f "$T/r$s.ltm"
  timed ct$s "$T/ct$s.ltm" "$LTB" column-transform "$T/c$s.ltm" -o "$T/ct$s.ltm" --json "${J1[@]}"
  rm -f "$T/c$s.ltm" "$T/ct$s.ltm"
done
timed ct1024 "$T/ct1024.ltm" "$LTB" column-transform "$T/c1024.ltm" -o "$T/ct1024.ltm" --json "${J1[@]}"

# --- quantize (defaults) ---
timed quant1024 "$T/final1024.ltm" "$LTB" quantize "$T/ct1024.ltm" -o "$T/final1024.ltm" --json "${J1[@]}"

END_LOAD=$(cut -d' ' -f1-3 /proc/loadavg)
END_DATE=$(date -u '+%H:%M UTC')
log "summarising"

CPU_MODEL=$(awk -F': *' '/^model name/ {print $2; exit}' /proc/cpuinfo)
MEM_GIB=$(awk '/^MemTotal/ {printf "%.1f", $2 / 1048576}' /proc/meminfo)
export T REPS CPU_MODEL MEM_GIB START_DATE END_DATE START_LOAD END_LOAD
export NPROC=$(nproc) KERNEL=$(uname -r) GCC=$(gcc -dumpfullversion 2>/dev/null || echo '?')
export VERSION=$("$LTB" --version | head -1) GITREV=$(git -C "$ROOT" rev-parse --short HEAD 2>/dev/null || echo '?')
export BUILD_REL=${BUILD#$ROOT/} BIN_DATE=$(date -u -r "$LTB" '+%Y-%m-%d %H:%M UTC')
"$PY" - <<'EOF'
import json, os, re, statistics as st

T = os.environ["T"]
runs = {}
for line in open(f"{T}/runs.list"):
    key, rep = line.split()
    wall, user, sys_, rss = open(f"{T}/{key}.{rep}.time").read().split()[-4:]
    out = open(f"{T}/{key}.{rep}.out").read()
    insp = json.load(open(f"{T}/{key}.{rep}.inspect.json"))
    # CPU time of the whole machine during the run (/proc/stat, USER_HZ ticks) minus the
    # stage's own: the cores other processes kept busy, on average.
    s0, s1 = ([int(x) for x in l.split()[1:9]] for l in open(f"{T}/{key}.{rep}.stat"))
    busy = sum(b - a for i, (a, b) in enumerate(zip(s0, s1)) if i not in (3, 4)) / os.sysconf("SC_CLK_TCK")
    cpu_ = float(user) + float(sys_)
    other = max(0.0, busy - cpu_) / max(float(wall), 1e-3)
    runs.setdefault(key, []).append(dict(wall=float(wall), cpu=cpu_, other=other,
                                         user=float(user), sys=float(sys_), rss=int(rss), out=out, insp=insp))

def med(key, f):
    return st.median(f(r) for r in runs[key])

def rng(key, f, fmt="{:.2f}"):
    v = sorted(f(r) for r in runs[key])
    return fmt.format(st.median(v)) + (f" ({fmt.format(v[0])}–{fmt.format(v[-1])})" if len(v) > 1 else "")

def matrix(r):
    return r["insp"]["arrays"][0]

def logical_bytes(r):
    m = matrix(r); return m["shape"][0] * m["shape"][1] * 4

def stored(r):
    return matrix(r)["chunks"]["stored_bytes"]

def grab(r, pat, conv=float):
    m = re.search(pat, r["out"])
    if not m: raise SystemExit(f"pattern {pat!r} not in output:\n{r['out']}")
    return conv(m.group(1))

def rays(r): return grab(r, r"rays traced: (\d+)", int)
def georows(r): return grab(r, r"rows that see geometry: (\d+)", int)
def js(r): return json.loads(r["out"])
def e(x, d=2): return f"{x:.{d}e}".replace("e+0", "e").replace("e+", "e").replace("e-0", "e-")
def gb(x): return f"{x / 1e9:.3f} GB"

E = os.environ
print("# Per-core stage rates for the cluster estimate\n")
print(f"`bash bench/cluster_rates.sh {E['BUILD_REL']}` (REPS={E['REPS']}); source: the script's header. "
      "Every stage is the real `ltbake` CLI with `--jobs 1`; medians of the repetitions, (min–max). "
      "**Per-core rate = work / CPU seconds** (user + sys of the whole process, all its threads, "
      "e.g. transpose's writer and checksum threads), i.e. work per core-second; wall time also "
      "includes `fdatasync` to this VM's disk. Inputs are warm in the page cache.\n")
print(f"Machine: {E['NPROC']} vCPU KVM guest (\"{E['CPU_MODEL']}\", 1 thread per core), {E['MEM_GIB']} GiB, "
      f"kernel {E['KERNEL']}, GCC {E['GCC']}, {E['VERSION']} (binary built {E['BIN_DATE']}; tree at git {E['GITREV']}; Release, x86-64-v3). "
      f"Run {E['START_DATE']} – {E['END_DATE']} (`date -u`; this VM's clock may be off), "
      f"load average {E['START_LOAD']} before, {E['END_LOAD']} after.\n")
print("Scene: `samples/medium.toml` (bunny on a plane, spp 4, no bounces) rendered at the stated "
      "size; 70.5% of its pixels see geometry (the rest are all-zero rows, stored free).\n")

print("## Per-core rates\n")
print("`other` = cores kept busy by other processes during the run (max over repetitions; "
      "machine CPU time from /proc/stat minus the stage's, per wall second): near 0 means a quiet machine.\n")
print("| stage | input (what) | wall s | CPU s | other | per-core rate (per CPU s) |")
print("|---|---|---:|---:|---:|---|")
cpu = lambda r: r["cpu"]; wall = lambda r: r["wall"]
def row(stage, what, key, rate):
    print(f"| {stage} | {what} | {rng(key, wall)} | {rng(key, cpu)} | {max(r['other'] for r in runs[key]):.2f} | {rate} |")

for R in (8, 16, 32, 64, 128):
    k = f"sample64_R{R}"
    row("sample", f"64², R = {R} ({med(k, rays)/1e6:.1f} M rays)", k,
        f"{e(med(k, lambda r: rays(r) / r['cpu']))} rays/s; {med(k, lambda r: r['cpu'] / georows(r) * 1e3):.3f} ms per geometry row; "
        f"{med(k, lambda r: logical_bytes(r) / r['cpu']) / 1e6:.0f} MB/s of f32 output")
for R in (1, 8):
    k = f"sample1024_R{R}"
    row("sample", f"1024², R = {R} ({med(k, georows)} geometry rows, {med(k, rays)/1e6:.1f} M rays)", k,
        f"{e(med(k, lambda r: rays(r) / r['cpu']))} rays/s; {med(k, lambda r: r['cpu'] / georows(r) * 1e6):.2f} µs per geometry row")
for k, what in (("fused64_R128", "haar, --row-zstd"), ("fused64_R128_raw", "haar, raw chunks")):
    row(f"sample + row-transform (fused, {what})", "64², R = 128", k,
        f"{e(med(k, lambda r: rays(r) / r['cpu']))} rays/s; {med(k, lambda r: r['cpu'] / georows(r) * 1e3):.3f} ms per geometry row")
for k, what in (("rowt_R128", "raw out"), ("rowt_R128_zstd", "--zstd out")):
    row("row-transform haar", f"64², R = 128, 1.61 GB f32, {what}", k,
        f"{med(k, lambda r: logical_bytes(r) / r['cpu']) / 1e9:.3f} GB/s of f32 matrix")

def tp(r):
    m = re.search(r"(\d+) panel\(s\) of up to (\d+) columns; .*read (\d+) \+ verified (\d+) bytes, wrote (\d+)", r["out"])
    if not m: raise SystemExit("transpose summary not found:\n" + r["out"])
    return [int(x) for x in m.groups()]
for k, what in (("transpose_1M", "1048576 × 384 (1024², R = 8), raw rows"),
                ("transpose_wide", "4096 × 98304 (64², R = 128), raw rows"),
                ("transpose_wide_zin", "4096 × 98304, zstd rows in, raw out"),
                ("transpose_wide_zz", "4096 × 98304, zstd rows in, --zstd out")):
    p = tp(runs[k][-1]); seg = p[1] * 4
    row("transpose", f"{what}; {p[0]} panels, reads of {seg} B", k,
        f"{med(k, lambda r: logical_bytes(r) / r['cpu']) / 1e9:.3f} GB/s of f32 matrix")
for s in (256, 512, 1024):
    k = f"ct{s}"
    j = js(runs[k][-1]); ne = j["cols"] - j["empty_columns"]
    row("column-transform (legall53, adaptive, keep 0.05)", f"{s}² columns, {ne} non-empty of {j['cols']}", k,
        f"{med(k, lambda r: r['cpu'] / ne):.4f} s per non-empty column; "
        f"{e(med(k, lambda r: ne * j['rows'] / r['cpu']))} elements/s")
k = "quant1024"; j = js(runs[k][-1])
row("quantize (9 bits)", f"1024², {j['nonzeros_in']/1e6:.2f} M nonzeros in", k,
    f"{e(med(k, lambda r: j['nonzeros_in'] / r['cpu']))} nonzeros/s; "
    f"{med(k, lambda r: r['cpu'] / (js(runs['ct1024'][-1])['cols'] - js(runs['ct1024'][-1])['empty_columns'])) * 1e3:.2f} ms per non-empty column")

print("\n## Sizes (last repetition)\n")
print("| file | logical f32 | stored | stored / logical | note |")
print("|---|---:|---:|---:|---|")
def size(k, name, note):
    r = runs[k][-1]; lb = logical_bytes(r); sb = stored(r)
    print(f"| {name} | {gb(lb)} | {gb(sb)} | {sb / lb:.3f} | {note} |")
size("sample64_R128", "raw, 64², R = 128", "all-zero rows free")
size("fused64_R128", "rows, haar + zstd (fused), 64², R = 128", "")
size("fused64_R128_raw", "rows, haar, raw chunks (fused)", "")
size("rowt_R128", "rows, haar, raw chunks", "")
size("rowt_R128_zstd", "rows, haar, --zstd", "")
size("transpose_wide", "cols, R = 128, raw", f"{runs['transpose_wide'][-1]['insp']['arrays'][0]['chunks']['zero']} all-zero chunks of 4 columns")
size("transpose_wide_zz", "cols, R = 128, --zstd", "")
size("transpose_1M", "cols, 1024², R = 8, raw", "")
for s in (256, 512, 1024):
    k = f"ct{s}"; j = js(runs[k][-1])
    size(k, f"cols4d, {s}², R = 8", f"{j['nonzeros']} nonzeros ({stored(runs[k][-1]) / j['nonzeros']:.2f} B each), depths {j['depth_histogram']}")
k = "quant1024"; j = js(runs[k][-1])
size(k, "final, 1024², R = 8", f"{j['nonzeros_out']} nonzeros, {j['bytes_per_nonzero']:.2f} B each")
for k in ("transpose_1M", "transpose_wide", "transpose_wide_zin", "transpose_wide_zz"):
    p = tp(runs[k][-1])
    print(f"\n- `{k}`: read {p[2]} + verified {p[3]} bytes, wrote {p[4]}; {p[0]} panels of up to {p[1]} columns"
          + (" (zstd row chunks are decoded whole once per panel)" if "zin" in k or "zz" in k else ""), end="")
print("\n\nPeak RSS (median, MiB): " + ", ".join(
    f"{k} {med(k, lambda r: r['rss']) / 1024:.0f}" for k in runs) + ".")
EOF
