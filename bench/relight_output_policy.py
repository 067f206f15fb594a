"""What relight's output policy (docs/RELIGHT.md "Output": mask-0 rows black, negative
radiance clamped to 0) does to the error of a compressed matrix, with every lighting term:
rel. L2 of D·L against the exact T·L, where D is the compressed matrix (final.ltm) and T
the uncompressed one (rows.ltm), both decoded to the pixel basis by `ltbake convert`.

usage: /usr/bin/python3 bench/relight_output_policy.py LTBAKE WORKDIR ENV.exr...
(WORKDIR: an `ltbake run` work directory that kept rows.ltm, e.g. of samples/medium-bake.toml)
"""
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "../tests/cli"))
import ltbtest  # noqa: E402

ltb, work, envs = sys.argv[1], sys.argv[2], sys.argv[3:]
ltbtest.LTBAKE = ltb
fin, rows = os.path.join(work, "final.ltm"), os.path.join(work, "rows.ltm")
with tempfile.TemporaryDirectory() as d:
    def dense(ltm, name):
        out = os.path.join(d, name)
        subprocess.run([ltb, "convert", ltm, out, "--basis", "pixels", "--progress", "never"], check=True,
                       capture_output=True)
        return np.load(out).astype(np.float64)
    D, T = dense(fin, "d.npy"), dense(rows, "t.npy")
    mask = ltbtest.side_table(fin, "mask")[:, 0] != 0
    R = int(round((T.shape[1] / 6) ** 0.5))
    info = json.loads(subprocess.run([ltb, "inspect", fin, "--json"], capture_output=True, text=True).stdout)
    print(f"{work}: {T.shape[0]} rows ({(~mask).sum()} see no geometry), R = {R}, final.ltm "
          f"{os.path.getsize(fin)} bytes")
    print("| map | rel. L2 as stored | mask-0 rows black | and negatives clamped | negative pixels |")
    print("|---|---|---|---|---|")
    for env in envs:
        cube = os.path.join(d, "env.npy")
        subprocess.run([ltb, "convert", env, cube, "--cube-res", str(R), "--clamp", "--progress", "never"],
                       check=True, capture_output=True)
        L = np.load(cube).astype(np.float64)
        exact, got = T @ L, D @ L
        norm = np.linalg.norm(exact)
        masked = np.where(mask[:, None], got, 0.0)
        clamped = np.maximum(masked, 0.0)
        e = [np.linalg.norm(x - exact) / norm for x in (got, masked, clamped)]
        print(f"| {os.path.basename(env)} | {e[0]:.4f} | {e[1]:.4f} | {e[2]:.4f} | {(masked < 0).any(axis=1).sum()} |")
