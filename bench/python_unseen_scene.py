"""import ltbake on a scene no bundled sample covers: a generated torus (96 x 48 quads, written
here, not fetched) tilted over a plane, 128 x 128 pixels, R = 16, baked by the command
(sample, row-transform, transpose, column-transform, quantize, cpca); then every output
read through the module against `ltbake convert`, and relit from Python against
`ltbake relight -o X.npy` (bit for bit) under five of Blender's maps the bundled recipes do
not use (city, night, interior, courtyard, studio).

usage: PYTHONPATH=build/python /usr/bin/python3 bench/python_unseen_scene.py WORKDIR [build/ltbake]
"""
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

import ltbake

WORK = sys.argv[1]
LTB = os.path.abspath(sys.argv[2] if len(sys.argv) > 2 else "build/ltbake")
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
os.makedirs(WORK, exist_ok=True)
os.chdir(WORK)
R_, r_, nu, nv = 1.0, 0.35, 96, 48
with open("torus.obj", "w") as f:
    for i in range(nu):
        for j in range(nv):
            u, v = 2 * math.pi * i / nu, 2 * math.pi * j / nv
            f.write(f"v {(R_ + r_ * math.cos(v)) * math.cos(u):.6f} {(R_ + r_ * math.cos(v)) * math.sin(u):.6f} "
                    f"{r_ * math.sin(v) + 0.6:.6f}\n")
    for i in range(nu):
        for j in range(nv):
            a, b = i * nv + j + 1, ((i + 1) % nu) * nv + j + 1
            c, d = ((i + 1) % nu) * nv + (j + 1) % nv + 1, i * nv + (j + 1) % nv + 1
            f.write(f"f {a} {b} {c}\nf {a} {c} {d}\n")
with open("scene.toml", "w") as f:
    f.write("""[output]
mode = "image"
[camera]
eye = [0.5, -3.2, 2.2]
target = [0.0, 0.0, 0.4]
up = [0.0, 0.0, 1.0]
fov = 45.0
width = 128
height = 128
[sampling]
cube_res = 16
spp = 4
[[material]]
name = "floor"
albedo = 0.7
[[material]]
name = "torus"
albedo = 0.6
ks = 0.25
exponent = 40.0
[[object]]
name = "ground"
type = "plane"
size = [6.0, 6.0]
material = "floor"
[[object]]
name = "torus"
type = "mesh"
file = "torus.obj"
rotate = [25.0, 10.0, 0.0]
material = "torus"
""")
Q = ["--progress", "never", "-q", "--overwrite"]
for args in [["sample", "scene.toml", "-o", "raw.ltm"], ["row-transform", "raw.ltm", "-o", "rows.ltm"],
             ["transpose", "rows.ltm", "-o", "cols.ltm"], ["column-transform", "cols.ltm", "-o", "cols4d.ltm"],
             ["quantize", "cols4d.ltm", "-o", "final.ltm"],
             ["cpca", "rows.ltm", "-o", "cpca.ltm", "--clusters", "8", "--basis", "4"]]:
    subprocess.run([LTB, *args, *Q], check=True)
ENV = subprocess.run(["bash", os.path.join(REPO, "scripts", "find_envmaps.sh")], capture_output=True, text=True,
                     check=True).stdout.strip()
L = LTB


def bits(a): return np.ascontiguousarray(a).view(np.uint32)
rows = []
# 1. every kind opens and reads like convert (whole matrix, random slices)
for name in ["raw", "rows", "cols", "cols4d", "final", "cpca"]:
    c = ltbake.open(f"{name}.ltm")
    info = json.loads(subprocess.run([L, "inspect", "--json", "--no-content", f"{name}.ltm"], capture_output=True, text=True, check=True).stdout)
    assert c.content_hash == info["content_hash"] and [c.shape[0], c.shape[1]] == info["shape"], name
    if name in ("raw", "rows", "cols"):
        subprocess.run([L, "convert", f"{name}.ltm", f"{name}.npy", "-q"], check=True)
        ref = np.load(f"{name}.npy")
        rng = np.random.default_rng(0)
        for _ in range(20):
            i, j = int(rng.integers(ref.shape[0])), int(rng.integers(ref.shape[1]))
            assert np.array_equal(bits(c[i]), bits(ref[i])) and np.array_equal(bits(c[:, j]), bits(ref[:, j])), name
        t = time.perf_counter(); whole = c.read(force=True); t = time.perf_counter() - t
        assert np.array_equal(bits(whole), bits(ref)), name
        rows.append(f"{name}.ltm {c.shape[0]}x{c.shape[1]} {c.layout}: whole matrix equals convert ({whole.nbytes/1e6:.0f} MB in {t*1e3:.0f} ms); 20 random rows and columns equal")
        os.remove(f"{name}.npy")
    else:
        subprocess.run([L, "convert", f"{name}.ltm", f"{name}.npy", "--basis", "pixels", "-q"], check=True)
        assert np.array_equal(bits(c.decode(basis="pixels")), bits(np.load(f"{name}.npy"))), name
        rows.append(f"{name}.ltm: decode(basis='pixels') equals convert --basis pixels")
        os.remove(f"{name}.npy")
# 2. relight under maps the bundled recipes do not use, Python vs the command, bit for bit
for m in ["city", "night", "interior", "courtyard", "studio"]:
    exr = os.path.join(ENV, m + ".exr")
    for name, terms in [("final", 200), ("rows", 200), ("cpca", 100)]:
        subprocess.run([L, "relight", f"{name}.ltm", "--env", exr, "--clamp", "-o", "cli.npy", "--terms", str(terms), "-q"], check=True)
        t = time.perf_counter(); img = ltbake.relight(f"{name}.ltm", exr, terms=terms, clamp_env=True); t = time.perf_counter() - t
        same = np.array_equal(bits(img), bits(np.load("cli.npy")))
        assert same, (m, name)
        rows.append(f"relight {name}.ltm under {m}.exr ({terms} terms): bit-identical to the command's .npy, {t*1e3:.0f} ms from Python")
    cube = ltbake.envmap(exr, 16, clamp=True)
    subprocess.run([L, "convert", exr, "cube.npy", "--cube-res", "16", "--clamp", "-q"], check=True)
    assert np.array_equal(bits(cube), bits(np.load("cube.npy")))
rows.append("envmap() of the five maps at R = 16 equals convert --cube-res 16")
print("\n".join(rows))
