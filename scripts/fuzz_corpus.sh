#!/usr/bin/env bash
# Seeds the fuzzing corpora (docs/FUZZING.md), one directory per target, from the bundled
# samples and data, files written by ltbake itself, small hand-written files, and the
# encoders in ltb_fuzz_seeds (OpenEXR, OpenMesh, Draco, the container writer). Nothing is
# committed: everything is generated here, at fuzz time.
#
# usage: fuzz_corpus.sh BUILD FUZZ_BUILD CORPUS
#   BUILD       a release build holding ltbake (bakes the containers)
#   FUZZ_BUILD  the LTB_BUILD_FUZZERS build holding tests/fuzz/ltb_fuzz_seeds
#   CORPUS      output: CORPUS/<target>/ seeds, CORPUS/aux/ltm/ shard files that the
#               manifest seeds name (the ltm target copies it beside its input: LTB_FUZZ_AUX)
# Existing files in CORPUS/<target>/ (what earlier fuzzing found) are kept.
set -euo pipefail
BUILD=$(realpath "$1"); FUZZ_BUILD=$(realpath "$2"); CORPUS=$3
cd "$(dirname "$0")/.."
ROOT=$PWD
LTBAKE=$BUILD/ltbake
SEEDS=$FUZZ_BUILD/tests/fuzz/ltb_fuzz_seeds
for f in "$LTBAKE" "$SEEDS"; do
  [[ -x $f ]] || { echo "fuzz_corpus.sh: $f is missing (build it first)" >&2; exit 1; }
done
for m in data/meshes/bunny.obj data/meshes/bunny.drc data/meshes/dragon_res4.ply; do
  [[ -f $m ]] || { echo "fuzz_corpus.sh: $m is missing (make samples)" >&2; exit 1; }
done
mkdir -p "$CORPUS"
CORPUS=$(realpath "$CORPUS")
tmp=$(mktemp -d); trap 'rm -rf "$tmp"' EXIT
dir() { mkdir -p "$CORPUS/$1"; echo "$CORPUS/$1"; }
lt() { "$LTBAKE" "$@" -q --overwrite; }

# ---- small bundled-data derivatives ---------------------------------------------------
# The first 120 vertices of the bundled bunny and the faces among them: a small real mesh.
/usr/bin/python3 - "$tmp" <<'PY'
import sys
d = sys.argv[1]
vs, fs = [], []
for line in open("data/meshes/bunny.obj"):
    t = line.split()
    if not t: continue
    if t[0] == "v" and len(vs) < 120: vs.append(line.strip())
    elif t[0] == "f":
        idx = [int(x.split("/")[0]) for x in t[1:]]
        if all(0 < i <= 120 for i in idx): fs.append("f " + " ".join(map(str, idx)))
# A quad and a pentagon too (triangulated by the reader).
vs += ["v 0 0 0", "v 1 0 0", "v 1 1 0", "v 0 1 0", "v 0.5 1.5 0"]
n = len(vs)
fs += [f"f {n-4} {n-3} {n-2} {n-1}", f"f {n-4} {n-3} {n-2} {n-1} {n}"]
open(f"{d}/small.obj", "w").write("\n".join(vs + fs) + "\n")
PY
"$SEEDS" "$tmp/seeds" "$tmp/small.obj"

# ---- containers (ltm_reader_fuzzer) ---------------------------------------------------
D=$(dir ltm_reader_fuzzer); AUX=$CORPUS/aux/ltm; rm -rf "$AUX"; mkdir -p "$AUX"
cp "$tmp"/seeds/ltm/*.ltm "$D/"
/usr/bin/python3 - "$tmp" <<'PY'
import sys, numpy as np
d = sys.argv[1]
m = np.load("samples/tiny-transport.npy")
np.save(f"{d}/a.npy", m)
z = m.copy(); z[:8] = 0
np.save(f"{d}/z.npy", z)
PY
lt convert "$tmp/a.npy" "$D/rows.ltm" --chunk-size 256
lt convert "$tmp/z.npy" "$D/cols-zstd.ltm" --chunk-size 256 --layout cols --zstd
lt convert "$tmp/a.npy" "$D/one-chunk.ltm"
head -c 1200 "$D/rows.ltm" > "$D/partial.ltm"
# A bake of a tiny scene (8x8 pixels, R = 2) through every stage: real metadata (bases,
# provenance, depths, quantization, cpca), side tables, sparse and sparse-zstd chunks.
cat > "$tmp/scene.toml" <<'EOF'
[camera]
eye = [0.0, -3.0, 2.4]
target = [0.0, 0.0, 0.2]
width = 8
height = 8
[sampling]
cube_res = 2
spp = 1
[[object]]
type = "plane"
size = [4.0, 4.0]
[[object]]
type = "sphere"
center = [0.0, 0.0, 0.7]
radius = 0.45
EOF
( cd "$tmp"
  lt sample scene.toml -o raw.ltm --chunk-rows 16
  lt row-transform raw.ltm -o rows.ltm
  lt row-transform raw.ltm -o rows-db2-zstd.ltm --filter db2 --zstd
  lt transpose rows.ltm -o cols.ltm
  lt column-transform cols.ltm -o cols4d.ltm
  lt column-transform cols.ltm -o cols4d-cdf97.ltm --filter cdf97 --depth full --terms 3
  lt quantize cols4d.ltm -o final.ltm
  lt quantize cols4d-cdf97.ltm -o final-nozstd.ltm --no-zstd --bits 12 --scaling none
  lt cpca rows.ltm -o cpca.ltm --clusters 2 --basis 2
  # A stage manifest and its two shards.
  for i in 0 1; do lt row-transform raw.ltm -o m.ltm --shard $i --nshards 2; done
  "$LTBAKE" commit m.ltm --nshards 2 -q --overwrite
  cp raw.ltm rows.ltm rows-db2-zstd.ltm cols.ltm cols4d.ltm cols4d-cdf97.ltm final.ltm final-nozstd.ltm cpca.ltm "$D/"
  cp m.ltm "$D/manifest.ltm"
  cp m.shards/*.ltm "$D/"
  mkdir -p "$AUX/m.shards" && cp m.shards/*.ltm "$AUX/m.shards/"
  # The input is named input.ltm: a manifest naming m.shards/ reads the copies in AUX.
  # An unsealed copy (trailer and index cut) and an interrupted seal (trailer cut).
  size=$(stat -c %s final.ltm)
  head -c $((size - 64)) final.ltm > "$D/final-no-trailer.ltm"
  head -c $((size / 2)) final.ltm > "$D/final-half.ltm"
)
# A direct-written container as the stages write it (chunks of 64 KiB and more go through
# O_DIRECT behind padding frames): R = 8 and 48-row chunks of 72 KiB.
( cd "$tmp"
  lt sample scene.toml -o raw8.ltm --cube-res 8 --chunk-rows 48
  lt row-transform raw8.ltm -o "$D/rows-direct.ltm" --chunk-rows 48 2>/dev/null ||
    lt row-transform raw8.ltm -o "$D/rows-direct.ltm"
)

# ---- .npy (npy_fuzzer) ----------------------------------------------------------------
D=$(dir npy_fuzzer)
/usr/bin/python3 - "$D" <<'PY'
import sys, struct, numpy as np
d = sys.argv[1]
m = np.load("samples/tiny-transport.npy").astype("<f4")
np.save(f"{d}/f4.npy", m)
np.save(f"{d}/f8.npy", m.astype("<f8"))
np.save(f"{d}/f8-big-values.npy", np.array([[1e300, -1e300], [np.nan, np.inf]], "<f8"))
np.save(f"{d}/f4-nan.npy", np.array([[np.nan, np.inf, -0.0, 1.0]], "<f4"))
np.save(f"{d}/fortran.npy", np.asfortranarray(m))
np.save(f"{d}/one-d.npy", m.ravel())
np.save(f"{d}/three-d.npy", m.reshape(4, 4, 24))
np.save(f"{d}/big-endian.npy", m.astype(">f4"))
np.save(f"{d}/int.npy", np.arange(12, dtype="<i4").reshape(3, 4))
np.save(f"{d}/empty.npy", np.zeros((0, 5), "<f4"))
np.save(f"{d}/zeros.npy", np.zeros((6, 6), "<f4"))
np.save(f"{d}/scalar.npy", np.float32(1.5))
def header(version, text):
    text = text.encode("latin1" if version == 1 else "utf8")
    lenfmt, prefix = ("<H", 10) if version == 1 else ("<I", 12)
    pad = (-(prefix + len(text) + 1)) % 64
    body = text + b" " * pad + b"\n"
    return b"\x93NUMPY" + bytes([version, 0]) + struct.pack(lenfmt, len(body)) + body
data = m[:2].tobytes()
for v in (2, 3):
    open(f"{d}/v{v}.npy", "wb").write(header(v, "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 24), }") + data)
# Keys in another order, spacing, a trailing-comma-free dict, a long header.
open(f"{d}/reordered.npy", "wb").write(header(1, "{'shape':(2,24),'fortran_order':False,'descr':'<f4'}") + data)
open(f"{d}/long-header.npy", "wb").write(header(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (2, 24), }" + " " * 3000) + data)
open(f"{d}/truncated.npy", "wb").write(header(1, "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 24), }") + data)
PY

# ---- environment maps (hdr_fuzzer, exr_fuzzer) ----------------------------------------
D=$(dir exr_fuzzer)
cp "$tmp"/seeds/exr/*.exr "$D/"
D=$(dir hdr_fuzzer)
/usr/bin/python3 - "$D" <<'PY'
import sys, math
d = sys.argv[1]
def rgbe(r, g, b):
    v = max(r, g, b)
    if v < 1e-32: return bytes([0, 0, 0, 0])
    m, e = math.frexp(v)
    s = m * 256.0 / v
    return bytes([int(r * s), int(g * s), int(b * s), e + 128])
def pixels(w, h):
    return [[rgbe(0.2 + x / w, 0.1 + y / h, 40.0 if (x, y) == (w // 3, h // 4) else 0.5) for x in range(w)] for y in range(h)]
def rle_channel(vals):
    out, i = bytearray(), 0
    while i < len(vals):
        j = i
        while j < len(vals) and j - i < 127 and vals[j] == vals[i]: j += 1
        if j - i >= 3:
            out += bytes([128 + j - i, vals[i]]); i = j
        else:
            k = i
            while k < len(vals) and k - i < 128 and not (k + 2 < len(vals) and vals[k] == vals[k+1] == vals[k+2]): k += 1
            out += bytes([k - i]) + bytes(vals[i:k]); i = k
    return bytes(out)
def write(name, w, h, enc, res=None, extra=b""):
    px = pixels(w, h)
    head = b"#?RADIANCE\n# made by fuzz_corpus.sh\nFORMAT=32-bit_rle_rgbe\nEXPOSURE=1.0\n" + extra + b"\n"
    head += (res or f"-Y {h} +X {w}").encode() + b"\n"
    body = bytearray()
    for row in px:
        if enc == "flat":
            for p in row: body += p
        elif enc == "rle":
            body += bytes([2, 2, w >> 8, w & 255])
            for c in range(4): body += rle_channel([p[c] for p in row])
        elif enc == "old":  # original run-length: (1,1,1,n) repeats the previous pixel
            body += row[0] + bytes([1, 1, 1, w - 1])
    open(f"{d}/{name}.hdr", "wb").write(head + body)
write("latlong-flat", 16, 8, "flat")
write("latlong-rle", 16, 8, "rle")
write("latlong-old-rle", 16, 8, "old")
write("hcross-rle", 16, 12, "rle")
write("vcross-flat", 12, 16, "flat")
write("flipped", 16, 8, "rle", "+Y 8 -X 16")
write("xyze", 16, 8, "flat", None, b"FORMAT=32-bit_rle_xyze\n")
write("wide-rle", 64, 32, "rle")
PY

# ---- scenes (scene_fuzzer) and recipes (recipe_fuzzer) --------------------------------
D=$(dir scene_fuzzer)
cp samples/*.toml "$D/"
rm -f "$D"/*-bake.toml
cp "$tmp/scene.toml" "$D/tiny-r2.toml"
cat > "$D/everything.toml" <<'EOF'
[output]
mode = "vertex"
objects = ["bunny", "box"]
[camera]
eye = [1.0, 2.0, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 55.5
width = 3
height = 5
[sampling]
cube_res = 4
spp = 2
bounces = 3
seed = 4611686018427387904
[[material]]
name = "m"
albedo = 0.5
ks = 0.25
exponent = 7
[[object]]
type = "mesh"
name = "bunny"
file = "meshes/bunny.drc"
material = "m"
scale = 2.5
rotate = [90, 0, 45]
translate = [0.1, -0.2, 0.3]
[[object]]
type = "box"
name = "box"
size = [1, 2, 3]
center = [0, 0, 1]
scale = [1, 2, 1]
[[object]]
type = "sphere"
radius = 1e-3
center = [0, 0, 5]
[[object]]
type = "plane"
size = [1e3, 1e3]
EOF
D=$(dir recipe_fuzzer)
cp samples/*-bake.toml "$D/"
cat > "$D/everything.toml" <<'EOF'
name = "all"
scene = "tiny.toml"
workdir = "${LTB_FUZZ_DIR}/work"
targets = ["quantize", "cpca", "relight"]
keep = ["raw", "rows", "cols", "cols4d"]
[sample]
cube_res = 8
spp = 2
bounces = 1
seed = 3
[row-transform]
filter = "db2"
zstd = true
[transpose]
zstd = true
[column-transform]
filter = "cdf97"
depth = 2
budget = "2%"
zstd = false
[quantize]
bits = 12
scaling = "none"
dither = false
seed = 9
[cpca]
clusters = 4
basis = 2
max_iterations = 10
seed = 2
[relight]
matrix = "cpca"
envs = ["sky.hdr", "sky.exr", "faces/{face}.hdr"]
terms = 50
weighting = "transport"
clamp = true
reference = true
format = "exr"
exposure = -1.5
EOF
cat > "$D/inline-scene.toml" <<'EOF'
workdir = "out"
[column-transform]
terms = 10
depth = "none"
[scene.output]
mode = "vertex"
[scene.camera]
eye = [0.0, -3.0, 2.4]
[[scene.object]]
type = "mesh"
name = "m"
file = "$LTB_FUZZ_DIR/m.obj"
[[scene.object]]
type = "sphere"
EOF

# ---- meshes (off_, ply_, obj_, stl_, drc_fuzzer) ---------------------------------------
for fmt in off ply obj stl drc; do
  D=$(dir ${fmt}_fuzzer)
  cp "$tmp"/seeds/mesh/*.$fmt "$D/"
done
cp "$tmp/small.obj" "$CORPUS/obj_fuzzer/bunny-120.obj"
cp data/meshes/bunny.drc "$CORPUS/drc_fuzzer/bunny.drc"
head -c 60000 data/meshes/dragon_res4.ply > "$CORPUS/ply_fuzzer/dragon-head.ply"  # header + some vertices
D=$CORPUS/off_fuzzer
printf 'OFF\n# a comment\n4 2 0\n0 0 0\n1 0 0\n1 1 0\n0 1 0\n3 0 1 2\n4 0 1 2 3\n' > "$D/hand.off"
printf 'COFF\n3 1 0\n0 0 0 255 0 0 255\n1 0 0 0 255 0 255\n0 1 0 0 0 255 255\n3 0 1 2\n' > "$D/coff.off"
printf 'NOFF\n3 1 0\n0 0 0 0 0 1\n1 0 0 0 0 1\n0 1 0 0 0 1\n3 0 1 2\n' > "$D/noff.off"
printf 'STOFF\n3 1 0\n0 0 0 0 0\n1 0 0 1 0\n0 1 0 0 1\n3 0 1 2 1 0 0\n' > "$D/stoff.off"
D=$CORPUS/ply_fuzzer
cat > "$D/hand.ply" <<'EOF'
ply
format ascii 1.0
comment hand-written
obj_info a ply seed
element vertex 4
property float x
property float y
property float z
property uchar red
property uchar green
property uchar blue
element face 2
property list uchar int vertex_indices
end_header
0 0 0 255 0 0
1 0 0 0 255 0
1 1 0 0 0 255
0 1 0 9 9 9
3 0 1 2
3 0 2 3
EOF
cat > "$D/custom-props.ply" <<'EOF'
ply
format ascii 1.0
element vertex 3
property double x
property double y
property double z
property float nx
property float ny
property float nz
property float u
property float v
property int flags
element face 1
property list uchar uint vertex_index
property float quality
element edge 1
property int vertex1
property int vertex2
end_header
0 0 0 0 0 1 0 0 7
1 0 0 0 0 1 1 0 7
0 1 0 0 0 1 0 1 7
3 0 1 2 0.5
0 1
EOF
D=$CORPUS/obj_fuzzer
printf 'mtllib none.mtl\no thing\ng group\nusemtl x\nv 0 0 0\nv 1 0 0\nv 1 1 0\nv 0 1 0\nvt 0 0\nvt 1 0\nvt 1 1\nvn 0 0 1\ns 1\nf 1/1/1 2/2/1 3/3/1\nf -4//1 -2//1 -1//1\nf 1/1 3/3 4/2\n' > "$D/hand.obj"
D=$CORPUS/stl_fuzzer
printf 'solid t\n facet normal 0 0 1\n  outer loop\n   vertex 0 0 0\n   vertex 1 0 0\n   vertex 0 1 0\n  endloop\n endfacet\nendsolid t\n' > "$D/hand.stl"

n=0
for d in "$CORPUS"/*_fuzzer; do n=$((n + $(ls "$d" | wc -l))); done
echo "fuzz_corpus.sh: $n seeds in $CORPUS/*_fuzzer"
