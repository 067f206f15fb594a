#!/usr/bin/python3
"""Relight frame time from each of ltbake's representations at equal matrix quality (issue 39:
"relight from 4D ≥ 2× faster than from 2D at 200+ terms"; the 2007 paper's Fig. 9), on scenes
no test or default was tuned on.

Per scene (bench/unseen_meshes.py: the Utah teapot and a scanned bust at 128², R = 32, spp 4):
sample -> row-transform db2 -> transpose, then
- adaptive 4D: column-transform --budget B (LeGall 5/3, adaptive depth) -> quantize;
- 2D: the same with --depth none;
- CPCA: cpca of rows.ltm at a few basis sizes (16 clusters).
Quality: the relit image with every lighting term against raw.ltm's, rel. L2 (relight
--reference), averaged over the maps; time: `relight --frames 40 --terms N` (the map turning
once about +Z), N = 200, 500, 1000, under each map, median over the maps: the matrix product
alone (frames.roofline.product_median_ms: the kept columns times their lighting, which is
what the representation decides) and the whole frame (frames.median_ms: also resampling the
turned map, its wavelet transform and the choice of terms, the same for every file). At a target quality the frame time of each
representation is interpolated log-log along its budget sweep; the table gives 2D / 4D.

    /usr/bin/python3 bench/relight_fps.py [BUILD=build]

Environment: LTB_FPS_SCENES ("teapot:128 snowden:128"), LTB_FPS_MAPS (Blender's night,
studio, sunrise), LTB_FPS_DIR (bench/out/relight_fps). Writes bench/results/relight_fps.md.
"""
import json
import math
import os
import subprocess
import sys

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import benchlib  # noqa: E402
import unseen_meshes  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "build"))
LTBAKE = os.path.join(BUILD, "ltbake")
MAPDIR = "/usr/share/blender/datafiles/studiolights/world"
MAPS = os.environ.get("LTB_FPS_MAPS", "night studio sunrise").split()
SCENES = [s.split(":") for s in os.environ.get("LTB_FPS_SCENES", "teapot:128 snowden:128").split()]
OUT = os.path.abspath(os.environ.get("LTB_FPS_DIR", os.path.join(HERE, "out", "relight_fps")))
BUDGETS = {"4D": ["0.5%", "1%", "2%", "4%"], "2D": ["2%", "4%", "8%", "16%"]}  # each reaching 1–2% error
CPCA_BASIS = [8, 16, 32, 64]
TERMS = [200, 500, 1000]
TARGETS = [0.01, 0.02]
R = 32


def lt(*args, json_out=False):
    p = subprocess.run([LTBAKE, *map(str, args), "--progress", "never"], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))} failed ({p.returncode}):\n{p.stdout}{p.stderr}")
    return json.loads(p.stdout) if json_out else p


def measure(path, raw, work):
    """(mean matrix error over the maps, {terms: median ms of the product}, {terms: median ms a frame})."""
    errs, ms, whole = [], {n: [] for n in TERMS}, {n: [] for n in TERMS}
    for m in MAPS:
        env = os.path.join(MAPDIR, m + ".exr")
        rep = lt("relight", path, "--env", env, "--clamp", "--terms", "all", "--reference", raw, "-o",
                 os.path.join(work, "e.npy"), "--json", json_out=True)
        errs.append(rep["error"]["rel_l2"])
        for n in TERMS:
            rep = lt("relight", path, "--env", env, "--clamp", "--terms", n, "--frames", 40, "-o",
                     os.path.join(work, "f.npy"), "--json", json_out=True)
            # CPCA reports no product time of its own (its frame is the projection and the
            # per-cluster products): its whole frame stands in.
            ms[n].append(rep["frames"].get("roofline", {}).get("product_median_ms", rep["frames"]["median_ms"]))
            whole[n].append(rep["frames"]["median_ms"])
    med = lambda d: {n: float(np.median(v)) for n, v in d.items()}  # noqa: E731
    return float(np.mean(errs)), med(ms), med(whole)


def at_error(points, target, n):
    """ms at `target` error, log-log between the two sweep points around it (None outside)."""
    pts = sorted((e, t[n]) for e, t in points)
    for (e0, t0), (e1, t1) in zip(pts, pts[1:]):
        if min(e0, e1) <= target <= max(e0, e1) and e0 != e1:
            w = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            return math.exp(math.log(t0) + w * (math.log(t1) - math.log(t0)))
    return None


def main():
    os.makedirs(OUT, exist_ok=True)
    lines = ["# Relight frame time per representation at equal matrix quality", "",
             f"`/usr/bin/python3 bench/relight_fps.py`; machine: {benchlib.machine()}; "
             f"maps {', '.join(MAPS)} (Blender's); R = {R}, spp 4; relight --frames 40 (median frame), "
             "median over the maps; error: every lighting term against raw.ltm, mean over the maps.", ""]
    summary = []
    for name, width in SCENES:
        scene = unseen_meshes.scenes(os.path.join(HERE, "out", "unseen"), int(width))[name]
        work = os.path.join(OUT, f"{name}{width}")
        os.makedirs(work, exist_ok=True)
        p = lambda f: os.path.join(work, f)  # noqa: E731
        if not os.path.exists(p("cols.ltm")):
            lt("sample", scene, "-o", p("raw.ltm"), "--cube-res", R, "--spp", 4, "--overwrite")
            lt("row-transform", p("raw.ltm"), "-o", p("rows.ltm"), "--filter", "db2")
            lt("transpose", p("rows.ltm"), "-o", p("cols.ltm"))
        rows = {"4D": [], "2D": [], "CPCA": []}
        frames = {"4D": [], "2D": [], "CPCA": []}
        lines += [f"## {name} {width}²", "", "ms: the product alone (the whole frame in brackets; CPCA: the whole frame in both).", "",
                  "| representation | setting | file bytes | error | " +
                  " | ".join(f"ms @ {n} terms" for n in TERMS) + " |", "|---|---|---|---|" + "---|" * len(TERMS)]
        for rep, depth in (("4D", "adaptive"), ("2D", "none")):
            for b in BUDGETS[rep]:
                c4, fin = p(f"c_{rep}_{b}.ltm"), p(f"f_{rep}_{b}.ltm")
                if not os.path.exists(fin):
                    lt("column-transform", p("cols.ltm"), "-o", c4, "--depth", depth, "--budget", b)
                    lt("quantize", c4, "-o", fin)
                err, ms, whole = measure(fin, p("raw.ltm"), work)
                rows[rep].append((err, ms))
                frames[rep].append((err, whole))
                lines.append(f"| {rep} | budget {b} | {os.path.getsize(fin):,} | {100 * err:.2f}% | " +
                             " | ".join(f"{ms[n]:.2f} ({whole[n]:.2f})" for n in TERMS) + " |")
        for k in CPCA_BASIS:
            cp = p(f"cpca_{k}.ltm")
            if not os.path.exists(cp):
                lt("cpca", p("rows.ltm"), "-o", cp, "--clusters", 16, "--basis", k)
            err, ms, whole = measure(cp, p("raw.ltm"), work)
            rows["CPCA"].append((err, ms))
            frames["CPCA"].append((err, whole))
            lines.append(f"| CPCA | 16 clusters, {k} basis | {os.path.getsize(cp):,} | {100 * err:.2f}% | " +
                         " | ".join(f"{ms[n]:.2f} ({whole[n]:.2f})" for n in TERMS) + " |")
        lines += ["", "At equal error (log-log along each sweep): the product's ms and 2D / 4D; the whole "
                  "frame's 2D / 4D:", "",
                  "| error | terms | 4D ms | 2D ms | 2D / 4D | CPCA ms | whole frame 2D / 4D |",
                  "|---|---|---|---|---|---|---|"]
        fmt = lambda v: f"{v:.2f}" if v else "outside the sweep"  # noqa: E731
        for target in TARGETS:
            for n in TERMS:
                a, b, c = (at_error(rows[k], target, n) for k in ("4D", "2D", "CPCA"))
                fa, fb = (at_error(frames[k], target, n) for k in ("4D", "2D"))
                ratio = b / a if a and b else None
                if ratio:
                    summary.append(ratio)
                lines.append(f"| {100 * target:.0f}% | {n} | {fmt(a)} | {fmt(b)} | {fmt(ratio)} | {fmt(c)} | "
                             f"{fmt(fb / fa if fa and fb else None)} |")
        lines.append("")
    if summary:
        lines.append(f"2D / 4D product time at equal error over every scene, error and term count: "
                     f"{min(summary):.2f}–{max(summary):.2f} (median {float(np.median(summary)):.2f}).")
    benchlib.write_report(os.path.join(HERE, "results", "relight_fps.md"), lines)


if __name__ == "__main__":
    main()
