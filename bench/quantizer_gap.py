#!/usr/bin/python3
"""What quantization adds to the relit error, 2D against adaptive 4D (issue 39: "the 2D path's
quantiser keeps relit error within 1.2x of the unquantised"), on a scene and maps no test or
default uses.

Per budget: column-transform (`--depth none` for 2D, `adaptive` for 4D) → relit under each
map with every lighting term (`--no-clamp-output`); quantize (the defaults, or QUANTIZE_FLAGS)
→ relit the same way. Both against T·L of the raw matrix (NumPy, float64), rel. L2 over the
pixels that see geometry. Prints, per budget, the file's bytes, both errors per map and their
ratio.

    /usr/bin/python3 bench/quantizer_gap.py SCENE.toml WORKDIR [--maps A.exr,B.exr] [--cube-res 32]
        [--budgets 2d:1%,2d:4%,4d:1%] [-- QUANTIZE_FLAGS...]

The bake (sample → row-transform db2 → transpose) is kept in WORKDIR and reused.
"""
import argparse
import math
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
import benchlib  # noqa: E402
import ltbtest  # noqa: E402

LTB = os.path.join(benchlib.ROOT, "build", "ltbake")
ltbtest.LTBAKE = LTB


def ltb(*a):
    p = subprocess.run([LTB, *map(str, a)], capture_output=True, text=True)
    if p.returncode:
        raise SystemExit(" ".join(map(str, a)) + "\n" + p.stderr)


def main():
    argv = sys.argv[1:]
    qflags = argv[argv.index("--") + 1:] if "--" in argv else []
    argv = argv[:argv.index("--")] if "--" in argv else argv
    ap = argparse.ArgumentParser()
    ap.add_argument("scene")
    ap.add_argument("work")
    ap.add_argument("--maps", default="")
    ap.add_argument("--cube-res", type=int, default=32)
    ap.add_argument("--budgets", default="2d:1%,2d:2%,2d:4%,2d:8%,2d:16%,4d:0.25%,4d:1%,4d:4%")
    a = ap.parse_args(argv)
    os.makedirs(a.work, exist_ok=True)
    w = lambda f: os.path.join(a.work, f)  # noqa: E731
    if not os.path.exists(w("cols.ltm")):
        ltb("sample", a.scene, "-o", w("raw.ltm"), "--cube-res", a.cube_res, "-q", "--overwrite")
        ltb("row-transform", w("raw.ltm"), "-o", w("rows.ltm"), "--filter", "db2", "-q", "--overwrite")
        ltb("transpose", w("rows.ltm"), "-o", w("cols.ltm"), "-q", "--overwrite")
        os.remove(w("rows.ltm"))
    ltb("convert", w("raw.ltm"), w("raw.npy"), "-q", "--overwrite")
    T = np.load(w("raw.npy")).astype(np.float64)
    mask = ltbtest.side_table(w("raw.ltm"), "mask")[:, 0] != 0
    if a.maps:
        maps = a.maps.split(",")
    else:
        d = subprocess.run(["bash", os.path.join(benchlib.ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                           text=True, check=True).stdout.strip()
        maps = [os.path.join(d, f"{n}.exr") for n in ("night", "studio", "sunrise")]
    cubes, refs = [], []
    for m in maps:
        c = w(os.path.basename(m) + f".{a.cube_res}.npy")
        ltb("convert", m, c, "--cube-res", a.cube_res, "--clamp", "-q", "--overwrite")
        cubes.append(c)
        refs.append(T @ np.load(c).astype(np.float64))
    del T

    def errors(f):
        out = []
        for c, ref in zip(cubes, refs):
            ltb("relight", f, "--env", c, "--terms", "all", "--no-clamp-output", "-o", w("relit.npy"), "-q")
            d = (np.load(w("relit.npy")).reshape(-1, 3).astype(np.float64) - ref)[mask]
            out.append(math.sqrt((d ** 2).sum() / (ref[mask] ** 2).sum()))
        return np.array(out)

    names = [os.path.splitext(os.path.basename(m))[0] for m in maps]
    print(f"{benchlib.machine()}; {os.path.basename(a.scene)}, R = {a.cube_res}; quantize {' '.join(qflags) or '(defaults)'}")
    print(f"| budget | final.ltm bytes | relit rel. L2 unquantized ({', '.join(names)}) | quantized | ratio | "
          "mean ratio |\n|---|---|---|---|---|---|")
    for spec in a.budgets.split(","):
        kind, budget = spec.split(":")
        ltb("column-transform", w("cols.ltm"), "-o", w("c.ltm"), "--depth", "none" if kind == "2d" else "adaptive",
            "--budget", budget, "-q", "--overwrite")
        eu = errors(w("c.ltm"))
        ltb("quantize", w("c.ltm"), "-o", w("q.ltm"), "-q", "--overwrite", *qflags)
        eq = errors(w("q.ltm"))
        fmt = lambda v: " / ".join(f"{x:.2%}" for x in v)  # noqa: E731
        print(f"| {kind.upper()} {budget} | {os.path.getsize(w('q.ltm')):,} | {fmt(eu)} | {fmt(eq)} | "
              f"{' / '.join(f'{x:.3f}' for x in eq / eu)} | {eq.mean() / eu.mean():.3f} |", flush=True)


if __name__ == "__main__":
    main()
