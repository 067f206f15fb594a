#!/usr/bin/python3
"""Per-band incremental relighting (PBI, Overbeck 2006 ch. 6) against NWA as a function of how
fast the lighting turns: the speed below which PBI with 30 terms a frame is as good as NWA
with 100 (the thesis' "3-4x fewer terms"), on a scene and maps no test or default uses.

Scene: the npm Utah teapot (bench/unseen_meshes.py) at WIDTH² pixels (64), R = 64 (the
thesis' cubemap, six bands), Haar rows, adaptive 4D LeGall 5/3 at a 5% budget, quantized.
Maps: Blender's night, studio and sunrise and bench/make_unseen_maps.py's sun sky. Each map
turns about +Z at each speed for FRAMES frames (300); the mean over the frames from WARMUP
(100) on is the steady state (every method starts exact-ish at frame 0, and PBI's start
would flatter it at slow speeds). Errors against the same matrix relit with every lighting
term each frame (the lighting approximation alone): the image's rel. L2, and the lighting's
area-weighted relative L1 (the thesis' Fig. 6.2 measure).

    /usr/bin/python3 bench/pbi_speeds.py [BUILD_DIR=build] [--speeds 0.12,0.36,1.2,3.6]

Writes bench/results/pbi_speeds.{md,json,png}; the bake goes to bench/out/pbi_speeds.
"""
import argparse
import csv
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import benchlib  # noqa: E402
import unseen_meshes  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("build", nargs="?", default=os.path.join(benchlib.ROOT, "build"))
ap.add_argument("--speeds", default="0.12,0.36,1.2,3.6", help="degrees a frame")
ap.add_argument("--frames", type=int, default=300)
ap.add_argument("--warmup", type=int, default=100)
ap.add_argument("--width", type=int, default=64)
ap.add_argument("--cube-res", type=int, default=64)
args = ap.parse_args()
LTB = os.path.join(os.path.abspath(args.build), "ltbake")
OUT = os.path.join(HERE, "out", "pbi_speeds")
CONFIGS = [("nwa", 30), ("nwa", 60), ("nwa", 100), ("nwa", 200), ("pbi", 30)]
SPEEDS = [float(s) for s in args.speeds.split(",")]


def ltb(*a):
    subprocess.run([LTB, *map(str, a)], check=True, capture_output=True, text=True)


def bake():
    final = os.path.join(OUT, f"teapot{args.width}_r{args.cube_res}.ltm")
    if os.path.exists(final):
        return final
    scene = unseen_meshes.scenes(os.path.join(HERE, "out", "unseen"), args.width)["teapot"]
    w = lambda f: os.path.join(OUT, f)  # noqa: E731
    ltb("sample", scene, "-o", w("raw.ltm"), "--cube-res", args.cube_res, "-q", "--overwrite")
    ltb("row-transform", w("raw.ltm"), "-o", w("rows.ltm"), "--filter", "haar", "-q", "--overwrite")
    ltb("transpose", w("rows.ltm"), "-o", w("cols.ltm"), "-q", "--overwrite")
    ltb("column-transform", w("cols.ltm"), "-o", w("c.ltm"), "--budget", "5%", "-q", "--overwrite")
    ltb("quantize", w("c.ltm"), "-o", final + ".part", "-q", "--overwrite")
    os.replace(final + ".part", final)
    for f in ("raw.ltm", "rows.ltm", "cols.ltm", "c.ltm"):
        os.remove(w(f))
    return final


def maps():
    d = subprocess.run(["bash", os.path.join(benchlib.ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True, check=True).stdout.strip()
    gen = os.path.join(HERE, "out", "unseen_maps")
    subprocess.run(["/usr/bin/python3", os.path.join(HERE, "make_unseen_maps.py"), gen], check=True, capture_output=True)
    return [os.path.join(d, f"{n}.exr") for n in ("night", "studio", "sunrise")] + [os.path.join(gen, "sun_sky.hdr")]


def run(mat, env, speed, method, terms):
    """Mean image rel. L2 and lighting area-weighted L1 over the steady-state frames."""
    csv_path = os.path.join(OUT, "seq.csv")
    ltb("relight", mat, "--env", env, "--clamp", "--sequence", f"rotate:{speed}:{args.frames}", "--method", method,
        "--terms", terms, "--reference", mat, "-o", os.path.join(OUT, "f_%04d.npy"), "--csv", csv_path, "-q")
    for k in range(args.frames):
        os.remove(os.path.join(OUT, f"f_{k:04d}.npy"))
    with open(csv_path) as f:
        rows = [r for r in csv.DictReader(f) if int(r["frame"]) >= args.warmup]
    return (float(np.mean([float(r["rel_l2"]) for r in rows])),
            float(np.mean([float(r["lighting_l1_area"]) for r in rows])))


def crossover(speeds, pbi, nwa100):
    """The speed (log-log interpolated) where PBI's error reaches NWA 100's, or None."""
    for (s0, p0, n0), (s1, p1, n1) in zip(zip(speeds, pbi, nwa100), list(zip(speeds, pbi, nwa100))[1:]):
        d0, d1 = math.log(p0 / n0), math.log(p1 / n1)
        if d0 <= 0 < d1:
            t = -d0 / (d1 - d0)
            return math.exp(math.log(s0) + t * (math.log(s1) - math.log(s0)))
    return None


def main():
    os.makedirs(OUT, exist_ok=True)
    t0 = time.time()
    mat = bake()
    envs = maps()
    res = {}  # (speed, method, terms) -> [(image, lighting) per map]
    for speed in SPEEDS:
        for env in envs:
            for method, terms in CONFIGS:
                res.setdefault((speed, method, terms), []).append(run(mat, env, speed, method, terms))
            print(f"{speed} deg/frame {os.path.basename(env)} done", flush=True)
    minutes = (time.time() - t0) / 60
    mean = {k: (float(np.mean([v[0] for v in vs])), float(np.mean([v[1] for v in vs]))) for k, vs in res.items()}
    names = [os.path.splitext(os.path.basename(e))[0] for e in envs]
    meta = {"machine": benchlib.machine(), "commit": benchlib.git_describe(), "maps": names, "minutes": minutes,
            "frames": args.frames, "warmup": args.warmup, "width": args.width, "cube_res": args.cube_res}
    json.dump({**meta, "results": [{"speed": s, "method": m, "terms": n, "per_map": res[(s, m, n)],
                                    "image_rel_l2": mean[(s, m, n)][0], "lighting_l1_area": mean[(s, m, n)][1]}
                                   for (s, m, n) in res]},
              open(os.path.join(HERE, "results", "pbi_speeds.json"), "w"), indent=1)
    L = ["# PBI against NWA by rotation speed (bench/pbi_speeds.py)", "",
         f"Machine: {meta['machine']}; commit {meta['commit']}; {minutes:.1f} min. Matrix: the npm teapot "
         f"(bench/unseen_meshes.py), {args.width}² pixels, R = {args.cube_res}, adaptive 4D at a 5% budget, "
         f"quantized. Maps: {', '.join(names)}, each turning about +Z for {args.frames} frames; means over frames "
         f"{args.warmup}–{args.frames - 1} and the maps. Errors against the same matrix under each frame's full "
         "lighting.", ""]
    for idx, what in ((0, "image rel. L2"), (1, "lighting area-weighted rel. L1 (the thesis' Fig. 6.2 measure)")):
        L += [f"## {what}", "", "| ° a frame | " + " | ".join(f"{m.upper()} {n}" for m, n in CONFIGS) +
              " | PBI 30 / NWA 100 |", "|---|" + "---|" * (len(CONFIGS) + 1)]
        for s in SPEEDS:
            vals = [mean[(s, m, n)][idx] for m, n in CONFIGS]
            L.append(f"| {s:g} | " + " | ".join(f"{v:.4f}" for v in vals) +
                     f" | {mean[(s, 'pbi', 30)][idx] / mean[(s, 'nwa', 100)][idx]:.2f} |")
        c = crossover(SPEEDS, [mean[(s, "pbi", 30)][idx] for s in SPEEDS],
                      [mean[(s, "nwa", 100)][idx] for s in SPEEDS])
        L += ["", f"PBI 30 reaches NWA 100 at **{c:.2f}° a frame** and below (log-log interpolated)." if c else
              "PBI 30 does not cross NWA 100 in this range of speeds.", ""]
    open(os.path.join(HERE, "results", "pbi_speeds.md"), "w").write("\n".join(L) + "\n")
    plot(mean)
    print("\n".join(L))


def plot(mean):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, idx, what in ((axes[0], 0, "image rel. L2"), (axes[1], 1, "lighting area-weighted rel. L1")):
        for m, n in CONFIGS:
            ax.plot(SPEEDS, [mean[(s, m, n)][idx] for s in SPEEDS], "o-" if m == "pbi" else ":",
                    label=f"{m.upper()} {n}")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("rotation, degrees a frame")
        ax.set_ylabel(what)
        ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(HERE, "results", "pbi_speeds.png"), dpi=100)


if __name__ == "__main__":
    main()
