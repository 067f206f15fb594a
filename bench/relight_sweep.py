"""Run time against error: bake each scene once, compress it with every method and
several parameters, relight under several environment maps, and record size, relight
time and error against the exact relighting from the uncompressed matrix.

usage: /usr/bin/python3 bench/relight_sweep.py BUILD_DIR OUT_DIR [--quick] [--resume LOG]

--resume LOG: rows already printed to LOG (this script's stdout of an interrupted run)
are kept and their configurations not rerun.

Writes OUT_DIR/relight_sweep.csv (one row per configuration), relight_error_vs_size.png
(the 4D paper's Fig. 7 on relit images) and relight_error_vs_time.png (its Fig. 9b), and
prints the size and speed ratios of adaptive 4D over 2D at equal error.
"""
import csv
import json
import os
import re
import subprocess
import sys
import time

import numpy as np

BUILD, OUT = sys.argv[1], sys.argv[2]
QUICK = "--quick" in sys.argv
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
LTBAKE = os.path.join(BUILD, "ltbake")
ENVDIR = subprocess.run(["bash", os.path.join(ROOT, "scripts/find_envmaps.sh")], capture_output=True,
                        text=True).stdout.strip()
os.makedirs(OUT, exist_ok=True)

SCENES = [("medium", "samples/medium.toml", 32), ("dragon", "samples/dragon.toml", 16),
          ("cornell", "samples/cornell.toml", 16)]
ENVS = ["sunset", "forest", "studio"]
METHODS = [("2D", ["--depth", "none"]), ("full4D", ["--depth", "full"]), ("adaptive4D", ["--depth", "adaptive"])]
KEEPS = [0.005, 0.01, 0.02, 0.05, 0.1]
TERMS = [50, 100, 200, 400]
BITS = [9]
if QUICK:
    SCENES, ENVS, KEEPS, TERMS = SCENES[2:], ENVS[:1], [0.01, 0.05], [100]
ENVS, TERMS = ENVS[:2], [50, 200]  # 2 maps x 2 term counts keep the sweep under an hour on 2 vCPUs
done = []
if "--resume" in sys.argv:
    with open(sys.argv[sys.argv.index("--resume") + 1]) as f:
        done = [json.loads(line) for line in f if line.startswith("{")]


def ltbake(*args):
    t = time.monotonic()
    p = subprocess.run([LTBAKE, *map(str, args), "--progress", "never"], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))} failed:\n{p.stderr}")
    return p.stdout, time.monotonic() - t


def size_of(path):
    return os.path.getsize(path)


rows_out = list(done)


def have(scene, method, label, env, terms):
    return any(r["scene"] == scene and r["method"] == method and r["params"].startswith(label + " ") and
               r["env"] == env and r["terms"] == terms for r in rows_out)


for scene, toml, R in SCENES:
    d = os.path.join(OUT, scene)
    os.makedirs(d, exist_ok=True)
    raw, rows, cols = (os.path.join(d, n) for n in ("raw.ltm", "rows.ltm", "cols.ltm"))
    bake = {}
    prior = [r for r in done if r["scene"] == scene]
    if prior:  # baked by the interrupted run: keep its times and files
        bake = {"sample": prior[0]["sample_s"], "row_transform": prior[0]["row_transform_s"],
                "transpose": prior[0]["transpose_s"]}
    else:
        scene_file = os.path.join(ROOT, toml)
        text = open(scene_file).read()
        if "usemtl = true" in text:  # the Cornell box as it was swept: every face its white material
            scene_file = os.path.join(d, "grey.toml")
            with open(scene_file, "w") as f:
                f.write(re.sub(r"^usemtl = true.*$", "", text, flags=re.M))
        _, bake["sample"] = ltbake("sample", scene_file, "-o", raw, "--cube-res", R, "--overwrite", "-q")
        _, bake["row_transform"] = ltbake("row-transform", raw, "-o", rows, "--filter", "haar", "--overwrite", "-q")
        _, bake["transpose"] = ltbake("transpose", rows, "-o", cols, "--overwrite", "-q")
    configs = [(m, a + ["--keep", k], f"keep={k}") for m, a in METHODS for k in KEEPS]
    # The RD budget at the nonzero counts of the adaptive runs.
    for method, args, label in configs + [("budget4D", None, k) for k in KEEPS]:
        c4 = os.path.join(d, "c4.ltm")
        if args is not None and all(have(scene, method, label, e, t) for e in ENVS for t in TERMS):
            continue
        if args is None:
            ref = next(r for r in rows_out if r["scene"] == scene and r["method"] == "adaptive4D" and
                       r["params"].startswith(f"keep={label} bits="))
            args = ["--budget", ref["nonzeros_ct"]]
            label = f"budget={ref['nonzeros_ct']}"
            if all(have(scene, method, label, e, t) for e in ENVS for t in TERMS):
                continue
        out, t_ct = ltbake("column-transform", cols, "-o", c4, "--overwrite", "--json", *args)
        ct = json.loads(out)
        for bits in BITS:
            fin = os.path.join(d, "final.ltm")
            out, t_q = ltbake("quantize", c4, "-o", fin, "--bits", bits, "--overwrite", "--json")
            q = json.loads(out)
            for env in ENVS:
                for terms in TERMS:
                    if have(scene, method, label, env, terms):
                        continue
                    out, _ = ltbake("relight", fin, "--env", os.path.join(ENVDIR, f"{env}.exr"), "--clamp",
                                    "--terms", terms, "--reference", raw, "--frames", 50, "--json",
                                    "-o", os.path.join(d, "relit.npy"))
                    rl = json.loads(out)
                    rows_out.append({
                        "scene": scene, "env": env, "method": method, "params": f"{label} bits={bits}",
                        "terms": terms, "cube_res": R,
                        "sample_s": round(bake["sample"], 3), "row_transform_s": round(bake["row_transform"], 3),
                        "transpose_s": round(bake["transpose"], 3), "column_transform_s": round(t_ct, 3),
                        "quantize_s": round(t_q, 3), "size_bytes": q["matrix_bytes"], "file_bytes": size_of(fin),
                        "nonzeros": q["nonzeros_out"], "nonzeros_ct": ct["nonzeros"],
                        "nonzero_fraction": q["nonzeros_out"] / (ct["rows"] * ct["cols"]),
                        "relight_ms": rl["frames"]["median_ms"], "rel_l2": rl["error"]["rel_l2"],
                        "rel_h1": rl["error"].get("rel_h1", float("nan")), "psnr_db": rl["error"]["psnr_db"],
                        "rel_l2_lighting_only": rl["error_lighting_only"]["rel_l2"],
                        "rel_l2_matrix_only": rl["error_matrix_only"]["rel_l2"],
                    })
                    print(json.dumps(rows_out[-1]), flush=True)

fields = list(rows_out[0].keys())
with open(os.path.join(OUT, "relight_sweep.csv"), "w", newline="") as f:
    w = csv.DictWriter(f, fieldnames=fields)
    w.writeheader()
    w.writerows(rows_out)

import matplotlib  # noqa: E402
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

colors = {"2D": "tab:blue", "full4D": "tab:orange", "adaptive4D": "tab:green", "budget4D": "tab:red"}
scenes = sorted({r["scene"] for r in rows_out})
for name, xkey, xlabel in [("relight_error_vs_size.png", "size_bytes", "compressed matrix (bytes of final.ltm matrix chunks)"),
                           ("relight_error_vs_time.png", "relight_ms", "relight time per frame (ms, median)")]:
    fig, axes = plt.subplots(1, len(scenes), figsize=(5 * len(scenes), 4), squeeze=False)
    for ax, scene in zip(axes[0], scenes):
        for m in colors:
            pts = sorted((r[xkey], r["rel_l2"]) for r in rows_out
                         if r["scene"] == scene and r["method"] == m and r["terms"] == max(TERMS) and r["env"] == ENVS[0])
            if pts:
                ax.plot(*zip(*pts), "o-", color=colors[m], label=m)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_title(f"{scene}, {ENVS[0]}, {max(TERMS)} terms")
        ax.set_xlabel(xlabel)
        ax.set_ylabel("relative L2 error of the relit image")
        ax.legend()
    fig.tight_layout()
    fig.savefig(os.path.join(OUT, name), dpi=110)


def ratio_at_equal_error(scene, env, terms, key):
    """x(2D) / x(adaptive) at the errors both curves reach (log-log interpolation)."""
    out = []
    curves = {}
    for m in ("2D", "adaptive4D"):
        pts = sorted((r["rel_l2"], r[key]) for r in rows_out
                     if r["scene"] == scene and r["env"] == env and r["terms"] == terms and r["method"] == m)
        curves[m] = pts
    a, b = curves["2D"], curves["adaptive4D"]
    if len(a) < 2 or len(b) < 2:
        return out
    lo, hi = max(a[0][0], b[0][0]), min(a[-1][0], b[-1][0])
    for e in np.geomspace(lo, hi, 3) if lo < hi else []:
        xa = np.exp(np.interp(np.log(e), np.log([p[0] for p in a]), np.log([p[1] for p in a])))
        xb = np.exp(np.interp(np.log(e), np.log([p[0] for p in b]), np.log([p[1] for p in b])))
        out.append((e, xa / xb))
    return out


print("\nratio 2D : adaptive 4D at equal relit error (size, relight time)")
for scene in scenes:
    for env in ENVS:
        t = max(TERMS)
        s = ratio_at_equal_error(scene, env, t, "size_bytes")
        tm = ratio_at_equal_error(scene, env, t, "relight_ms")
        print(scene, env, f"{t} terms", "size:", [(f"{e:.3g}", f"{r:.2f}") for e, r in s],
              "time:", [(f"{e:.3g}", f"{r:.2f}") for e, r in tm])
