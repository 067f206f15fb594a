"""Mesh input and the bundled scenes, through `ltbake sample`.

- The bunny written as OBJ, OFF, binary STL and ASCII PLY (converted here from the OBJ)
  gives the same transport matrix: same triangles in the same order (our own readers;
  tests/mesh/mesh_reader_test.cpp compares OBJ and STL with OpenMesh).
- The Draco file (16-bit quantised positions) gives nearly the same row sums.
- A square OBJ with one quad face matches the built-in plane (polygons are triangulated).
- Zero-area faces are dropped and counted.
- Every bundled scene samples (at a reduced cube resolution) and verifies.

usage: meshes_test.py PATH_TO_LTBAKE    (needs scripts/fetch_samples.sh to have run)
"""
import json
import os
import struct
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, failures, finish, run  # noqa: E402

ROOT = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
MESHES = os.path.join(ROOT, "data", "meshes")




def matrix(d, ltm):
    out = ltm[:-4] + ".npy"
    run("convert", ltm, out, "-q")
    return np.load(out).astype(np.float64)


if not os.path.exists(os.path.join(MESHES, "bunny.obj")):
    print(f"{MESHES}/bunny.obj missing: run scripts/fetch_samples.sh (make does)")
    print("0 passed, 1 failed")
    sys.exit(1)

with tempfile.TemporaryDirectory() as d:
    v, f = [], []
    for line in open(os.path.join(MESHES, "bunny.obj")):
        p = line.split()
        if p and p[0] == "v":
            v.append([float(x) for x in p[1:4]])
        elif p and p[0] == "f":
            f.append([int(x.split("/")[0]) - 1 for x in p[1:4]])
    v, f = np.array(v), np.array(f)
    with open(os.path.join(d, "bunny.off"), "w") as o:
        o.write(f"OFF\n{len(v)} {len(f)} 0\n")
        o.writelines(f"{a!r} {b!r} {c!r}\n" for a, b, c in v)
        o.writelines(f"3 {a} {b} {c}\n" for a, b, c in f)
    with open(os.path.join(d, "bunny.ply"), "w") as o:
        o.write(f"ply\nformat ascii 1.0\nelement vertex {len(v)}\nproperty float x\nproperty float y\nproperty float z\n"
                f"element face {len(f)}\nproperty list uchar int vertex_indices\nend_header\n")
        o.writelines(f"{a!r} {b!r} {c!r}\n" for a, b, c in v)
        o.writelines(f"3 {a} {b} {c}\n" for a, b, c in f)
    with open(os.path.join(d, "bunny.stl"), "wb") as o:
        o.write(b"ltbake test".ljust(80, b" ") + struct.pack("<I", len(f)))
        for tri in f:
            p0, p1, p2 = v[tri]
            n = np.cross(p1 - p0, p2 - p0)
            n = n / (np.linalg.norm(n) or 1)
            o.write(struct.pack("<12fH", *n, *p0, *p1, *p2, 0))

    def bunny_scene(name, mesh):
        path = os.path.join(d, name + ".toml")
        with open(path, "w") as o:
            o.write(f"""[camera]
eye = [0.0, -3.2, 2.0]
target = [0.0, 0.0, 0.45]
up = [0.0, 0.0, 1.0]
fov = 38.0
width = 32
height = 32
[sampling]
cube_res = 4
spp = 4
[[object]]
name = "ground"
type = "plane"
size = [6.0, 6.0]
[[object]]
name = "bunny"
type = "mesh"
file = "{mesh}"
scale = 0.1
rotate = [90.0, 0.0, 0.0]
""")
        out = os.path.join(d, name + ".ltm")
        run("sample", path, "-o", out)
        run("verify", out)
        return matrix(d, out)

    ref = bunny_scene("obj", os.path.join(MESHES, "bunny.obj"))
    check(np.count_nonzero(ref.sum(1)) > 500, "bunny: too few pixels see geometry")
    for fmt in ("off", "ply", "stl"):
        T = bunny_scene(fmt, os.path.join(d, "bunny." + fmt))
        diff = np.abs(T - ref).max()
        # Same float32 vertices and triangles: the rays see the same geometry.
        check(diff <= 1e-6, f"bunny.{fmt}: transport differs from the OBJ by {diff:.3g}")
    T = bunny_scene("drc", os.path.join(MESHES, "bunny.drc"))
    rel = np.abs(T.sum(1) - ref.sum(1)).mean() / ref.sum(1).mean()
    print(f"Draco (16-bit positions) vs OBJ: mean relative row-sum difference {rel:.2e}")
    check(rel < 0.02, f"bunny.drc differs from the OBJ by {rel:.3g} on average")

    # A quad face is triangulated; a zero-area face is dropped and counted.
    with open(os.path.join(d, "quad.obj"), "w") as o:
        o.write("v -3 -3 0\nv 3 -3 0\nv 3 3 0\nv -3 3 0\nv 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3 4\nf 5 6 7\n")
    scenes = {}
    for name, obj in [("quad", f'type = "mesh"\nfile = "{d}/quad.obj"'), ("plane", 'type = "plane"\nsize = [6.0, 6.0]')]:
        path = os.path.join(d, name + ".toml")
        with open(path, "w") as o:
            o.write(f"""[camera]
eye = [0.3, -2.0, 3.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 50.0
width = 16
height = 16
[sampling]
cube_res = 4
spp = 4
[[object]]
{obj}
[[object]]
type = "sphere"
center = [0.0, 0.0, 0.8]
radius = 0.4
""")
        out = os.path.join(d, name + ".ltm")
        p = run("sample", path, "-o", out)
        scenes[name] = (matrix(d, out), p.stdout)
    check(np.abs(scenes["quad"][0] - scenes["plane"][0]).max() <= 1e-6, "quad OBJ differs from the plane primitive")
    check("degenerate triangles dropped: 1" in scenes["quad"][1], f"degenerate face not counted: {scenes['quad'][1]}")

    # Every bundled scene, at a reduced cube resolution.
    for name in ("tiny", "medium", "cornell", "dragon", "bunny-draco", "bunny-vertices"):
        out = os.path.join(d, f"sample-{name}.ltm")
        # The Cornell box is in colour with a bounce: one matrix per channel (docs/COLOUR.md).
        rgb = ["--channels", "rgb"] if name == "cornell" else []
        p = run("sample", os.path.join(ROOT, "samples", name + ".toml"), "-o", out, "--cube-res", 4, "--spp", 1, *rgb)
        if p.returncode != 0:
            continue
        if rgb:
            out = os.path.join(d, f"sample-{name}.r.ltm")
        v = json.loads(run("verify", "--json", out).stdout)[0]
        info = json.loads(run("inspect", "--json", "--content", out).stdout)
        check(v["ok"], f"{name}: output does not verify")
        check(info["stats"]["nonzero_fraction"] > 0.05 and info["stats"]["nan_count"] == 0, f"{name}: stats {info['stats']}")
        if name == "bunny-vertices":
            check(info["shape"][0] == 1839 and info["basis"]["rows"]["kind"] == "vertices", f"vertex rows: {info['shape']}")

finish()
