#!/usr/bin/env python3
"""Writes the ground of the vertex-mode sparse scenes: a flat grid of N x N vertices over
SIZE x SIZE units at z = 0 (centred on the origin), as an OBJ of 2 (N-1)^2 triangles wound
counter-clockwise seen from +z (so the area-weighted vertex normals point up).

The grid is generated, not committed (160 x 160 vertices is ~1 MB of OBJ):

    python3 bench/sparse_scenes/ground_grid.py [N=160] [OUT=bench/out/sparse/ground_grid.obj] [SIZE=6]

bench/sparse_scenes/dragon_grid.toml expects the default output; bench/sparse_bench.py
writes it (and smaller grids for LTB_SPARSE_SCALE < 1) itself.
"""
import os
import sys

HERE = os.path.dirname(os.path.abspath(__file__))
DEFAULT_OUT = os.path.join(os.path.dirname(HERE), "out", "sparse", "ground_grid.obj")


def write_grid(path, n=160, size=6.0):
    """Writes the grid to PATH (through a temporary name, renamed when complete)."""
    if n < 2:
        raise ValueError(f"ground grid: N = {n}, need at least 2 vertices a side")
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        f.write(f"# ground grid: {n} x {n} vertices over {size:g} x {size:g} units at z = 0 "
                "(bench/sparse_scenes/ground_grid.py)\n")
        for j in range(n):
            y = -size / 2 + size * j / (n - 1)
            for i in range(n):
                f.write(f"v {-size / 2 + size * i / (n - 1):.6f} {y:.6f} 0\n")
        for j in range(n - 1):
            for i in range(n - 1):
                a = j * n + i + 1  # OBJ indices are 1-based; a is vertex (i, j)
                f.write(f"f {a} {a + 1} {a + n + 1}\nf {a} {a + n + 1} {a + n}\n")
    os.replace(tmp, path)
    return n * n


if __name__ == "__main__":
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 160
    out = sys.argv[2] if len(sys.argv) > 2 else DEFAULT_OUT
    size = float(sys.argv[3]) if len(sys.argv) > 3 else 6.0
    print(f"{out}: {write_grid(out, n, size)} vertices")
