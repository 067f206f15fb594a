#!/usr/bin/env python3
"""How much the shading normals (the [[object]] key `normals`, docs/SCENE.md "Normals")
change the bunny's transport, and how much reading it from Draco instead of PLY does.

From data/meshes/bunny.obj (no normals) it writes, into WORKDIR, bunny.ply (positions
only) and bunny-n.ply with angle-weighted vertex normals (what MeshLab and Blender write,
not ltbake's area weighting), encodes bunny-n.drc with draco_encoder's defaults (11-bit
positions, 8-bit normals), bakes samples/bunny-draco.toml (image mode, 64×64, cube-res 8,
spp 4) and samples/bunny-vertices.toml (vertex mode, spp 4 and 64) with each file and
`normals` value, and prints the relative L2 difference ‖T − T_ref‖/‖T_ref‖ of each matrix
(`ltbake convert X.ltm X.npy`) to the PLY's with "auto". Draco reorders the points, so its
vertex-mode rows are matched to the PLY's by position; a vertex's random stream follows its
row, so those comparisons carry the noise of two independent bakes (printed as the
difference between two seeds).

usage: /usr/bin/python3 scripts/bunny_normals.py PATH_TO_LTBAKE WORKDIR
"""
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
sys.path.insert(0, os.path.join(ROOT, "tests", "cli"))
from ltbtest import side_table  # noqa: E402  (reads argv[1] as the ltbake binary)

LTB, WORK = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])


def write_plys():
    V, F = [], []
    for line in open(os.path.join(ROOT, "data", "meshes", "bunny.obj")):
        p = line.split()
        if p and p[0] == "v":
            V.append([float(x) for x in p[1:4]])
        elif p and p[0] == "f":
            F.append([int(x.split("/")[0]) - 1 for x in p[1:]])
    V, F = np.array(V), np.array(F)
    fn = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    fn /= np.linalg.norm(fn, axis=1, keepdims=True)
    N = np.zeros_like(V)
    for k in range(3):
        a, b, c = V[F[:, k]], V[F[:, (k + 1) % 3]], V[F[:, (k + 2) % 3]]
        e1, e2 = b - a, c - a
        cos = (e1 * e2).sum(1) / np.linalg.norm(e1, axis=1) / np.linalg.norm(e2, axis=1)
        np.add.at(N, F[:, k], fn * np.arccos(np.clip(cos, -1, 1))[:, None])
    N /= np.linalg.norm(N, axis=1, keepdims=True)
    for name, normals in (("bunny.ply", False), ("bunny-n.ply", True)):
        with open(os.path.join(WORK, name), "w") as f:
            f.write(f"ply\nformat ascii 1.0\nelement vertex {len(V)}\n"
                    "property float x\nproperty float y\nproperty float z\n")
            if normals:
                f.write("property float nx\nproperty float ny\nproperty float nz\n")
            f.write(f"element face {len(F)}\nproperty list uchar int vertex_indices\nend_header\n")
            for i in range(len(V)):
                f.write(" ".join(f"{x:.7g}" for x in [*V[i], *(N[i] if normals else [])]) + "\n")
            for t in F:
                f.write("3 %d %d %d\n" % tuple(t))
    subprocess.run(["draco_encoder", "-i", os.path.join(WORK, "bunny-n.ply"), "-o",
                    os.path.join(WORK, "bunny-n.drc")], check=True, capture_output=True)


def bake(tag, sample, mesh, normals, *flags):
    text = open(os.path.join(ROOT, "samples", sample)).read()
    old = next(line for line in text.splitlines() if line.startswith("file = "))
    path = os.path.join(WORK, tag)
    with open(path + ".toml", "w") as f:
        f.write(text.replace(old, f'file = "{mesh}"\nnormals = "{normals}"'))
    subprocess.run([LTB, "sample", path + ".toml", "-o", path + ".ltm", *flags], check=True, capture_output=True)
    subprocess.run([LTB, "convert", path + ".ltm", path + ".npy"], check=True, capture_output=True)
    return np.load(path + ".npy").astype(np.float64)


def rel(a, b):
    return np.linalg.norm(a - b) / np.linalg.norm(b)


CASES = {"ply auto": ("bunny.ply", "auto"), "ply smooth": ("bunny.ply", "smooth"),
         "ply file": ("bunny-n.ply", "file"), "drc auto": ("bunny-n.drc", "auto"),
         "drc smooth": ("bunny-n.drc", "smooth"), "drc file": ("bunny-n.drc", "file")}


def main():
    os.makedirs(WORK, exist_ok=True)
    write_plys()
    T = {k: bake("img-" + k.replace(" ", "-"), "bunny-draco.toml", m, n) for k, (m, n) in CASES.items()}
    print("image mode (64x64, cube-res 8, spp 4), relative L2 to \"ply auto\":")
    for k, v in T.items():
        print(f"  {k:10s} {rel(v, T['ply auto']):.4f}")
    print(f"  drc file vs drc auto {rel(T['drc file'], T['drc auto']):.4f}")
    for spp in ("4", "64"):
        cases = {k: c for k, c in CASES.items() if c[1] != "smooth"}  # vertex mode: smooth = auto
        tags = {k: f"vtx{spp}-" + k.replace(" ", "-") for k in cases}
        T = {k: bake(tags[k], "bunny-vertices.toml", m, n, "--spp", spp) for k, (m, n) in cases.items()}
        ref = side_table(os.path.join(WORK, tags["ply auto"] + ".ltm"), "position").astype(np.float64)
        for k in T:  # rows matched to the PLY's vertices by position
            p = side_table(os.path.join(WORK, tags[k] + ".ltm"), "position").astype(np.float64)
            T[k] = T[k][((p[:, None, :] - ref[None, :, :]) ** 2).sum(-1).argmin(0)]
        seed2 = bake(f"vtx{spp}-seed2", "bunny-vertices.toml", "bunny.ply", "auto", "--spp", spp, "--seed", "2")
        print(f"vertex mode (1839 rows, cube-res 8, spp {spp}), relative L2 to \"ply auto\" "
              f"(noise: seed 2 vs 1 {rel(seed2, T['ply auto']):.4f}):")
        for k, v in T.items():
            print(f"  {k:10s} {rel(v, T['ply auto']):.4f}")
        print(f"  drc file vs drc auto {rel(T['drc file'], T['drc auto']):.4f}")


main()
