"""The whole-bake ETA of `ltbake run` (pipeline/eta.h): its model fitted, then checked on bakes it
was not fitted on.

1. fit: samples/medium-bake.toml (its own options) at R = 8, 16 and 32; each stage's wall seconds
   against the matrix's gigabytes G, least squares a + b·G, printed beside the coefficients
   pipeline/eta.cpp holds.
2. check: bakes of scenes and options the fit never saw (bench/pbi_unseen_scene.toml's dragon at
   192×144, other column
   options, other maps); for every step that printed an ETA, what it said was left (eta_seconds in
   run.json) against what was left (the wall seconds of that step and the ones after it).

usage: /usr/bin/python3 bench/eta_model.py PATH_TO_LTBAKE OUT_DIR [--skip-fit]
Writes OUT_DIR/eta_model.md (the tables) and prints it. About 3 minutes on the 2-core machine.
"""
import json
import os
import re
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import benchlib  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
REPO = os.path.dirname(HERE)
MAPS = "/usr/share/blender/datafiles/studiolights/world"


def bake(ltbake, recipe, workdir):
    """`ltbake run RECIPE` from scratch; its run.json's stages."""
    return benchlib.run_bake(ltbake, recipe, workdir, "--progress", "never", env={"LTBAKE_ENVMAPS": MAPS})


def recipe_text(name, scene, cube_res, column, relight_maps, extra=""):
    maps = ", ".join(f'"{MAPS}/{m}"' for m in relight_maps)
    return f"""name = "{name}"
scene = "{scene}"
targets = ["quantize", "relight"]
{extra}
[sample]
cube_res = {cube_res}
spp = 4
[row-transform]
filter = "haar"
[column-transform]
{column}
[quantize]
error_ratio = 1.1
[relight]
matrix = "final"
envs = [{maps}]
terms = 100
clamp = true
reference = true
format = "png"
"""


def matrix_gb(ltbake, workdir, stages):
    """The bake's matrix in GB (rows × columns × 4), from the first output holding one."""
    for s in stages:
        path = s.get("output", {}).get("path")
        if not path or not os.path.exists(path):
            continue
        p = subprocess.run([ltbake, "inspect", path, "--json"], capture_output=True, text=True)
        if p.returncode == 0:
            for a in json.loads(p.stdout).get("arrays", []):
                if a.get("name") == "matrix":
                    return a["shape"][0] * a["shape"][1] * 4 / 1e9
    return None


def model_in_source():
    """The (stage, a, b) table of pipeline/eta.cpp."""
    text = open(os.path.join(REPO, "pipeline", "eta.cpp")).read()
    return {m[0]: (float(m[1]), float(m[2])) for m in re.findall(r'\{"([a-z/-]+)", ([0-9.]+), ([0-9.]+)\}', text)}


# The options that change a stage's cost, as pipeline/eta.cpp tells them apart: the column
# transform's mode (a rate-distortion budget over every column, an adaptive depth per column,
# a fixed depth) and whether a relight also relights the reference exactly.
FIT_VARIANTS = [
    ("budget", None),
    ("adaptive", ('budget = "5%"', "keep = 0.05"), ("reference = true", "reference = false")),
    ("fixed", ('depth = "adaptive"', 'depth = "3"'), ('budget = "5%"', "keep = 0.05")),
]


def step_key(s):
    """The model's key of a run.json step: stage, or stage/variant (pipeline/eta.cpp Key)."""
    stage = s["node"].split(":")[0]
    p = s.get("params", {})
    if stage == "column-transform":
        if "budget" in p or "target_error" in p:
            return "column-transform/budget"
        return "column-transform/" + ("adaptive" if p.get("depth") == "adaptive" else "fixed")
    if stage == "relight":
        return "relight/reference" if p.get("reference") else "relight"
    return stage


def fit(ltbake, out):
    lines = ["## The fit (the medium scene, samples/medium-bake.toml and two variants of its options)", "",
             "| stage | a (s) | b (s/GB) | in pipeline/eta.cpp | residuals (s) at R = 8, 16, 32 |",
             "|---|---|---|---|---|"]
    points = {}
    for variant, *edits in FIT_VARIANTS:
        for r in (8, 16, 32):
            text = open(os.path.join(REPO, "samples", "medium-bake.toml")).read()
            text = re.sub(r"(?m)^cube_res = \d+.*$", f"cube_res = {r}", text)
            text = re.sub(r'(?m)^scene = .*$', f'scene = "{REPO}/samples/medium.toml"', text)
            text = re.sub(r'(?m)^keep = .*$', 'keep = ["raw", "rows", "cols", "cols4d"]', text)  # row-transform alone
            for edit in edits:
                if edit:
                    text = re.sub(r"(?m)^" + re.escape(edit[0]) + r".*$", edit[1], text)
            path = os.path.join(out, f"fit-{variant}{r}.toml")
            with open(path, "w") as f:
                f.write(text)
            wd = path[:-5]
            stages = bake(ltbake, path, wd)
            g = matrix_gb(ltbake, wd, stages)
            for s in stages:
                key = step_key(s)
                if variant == "budget" or key.endswith("/" + variant) or key == "relight":
                    points.setdefault(key, []).append((g, s["wall_seconds"]))
    src = model_in_source()
    for key, pts in sorted(points.items()):
        x = np.array([p[0] for p in pts])
        y = np.array([p[1] for p in pts])
        a = np.stack([np.ones_like(x), x], 1)
        c = np.linalg.lstsq(a, y, rcond=None)[0]
        have = src.get(key)
        lines.append(f"| {key} | {c[0]:.2f} | {c[1]:.2f} | {'%.2f + %.2f·G' % have if have else 'not modelled'} | "
                     f"{', '.join('%+.2f' % v for v in (a @ c - y))} |")
    return lines


def check(ltbake, out):
    lines = ["## Checked on bakes the fit never saw", "",
             "ETA: what the step line said was left (this step and the ones after it, run.json's "
             "eta_seconds); left: the wall seconds those steps took.", "",
             "| bake | step | ETA (s) | left (s) | ETA / left |", "|---|---|---|---|---|"]
    dragon = os.path.join(HERE, "pbi_unseen_scene.toml")
    cases = [
        ("dragon 192×144, R = 32, adaptive LeGall 5% budget, city + night",
         recipe_text("eta-dragon", dragon, 32, 'filter = "legall53"\ndepth = "adaptive"\nbudget = "5%"',
                     ["city.exr", "night.exr"])),
        ("dragon 192×144, R = 16, LeGall depth 3, keep 2%, courtyard",
         recipe_text("eta-dragon-d3", dragon, 16, 'filter = "legall53"\ndepth = "3"\nkeep = 0.02', ["courtyard.exr"])),
        ("dragon 192×144, R = 32, CDF 9/7 adaptive, keep 5%, interior + studio",
         recipe_text("eta-dragon-cdf", dragon, 32, 'filter = "cdf97"\ndepth = "adaptive"\nkeep = 0.05',
                     ["interior.exr", "studio.exr"])),
    ]
    ratios = []
    for name, text in cases:
        path = os.path.join(out, re.sub(r"\W+", "_", name)[:40] + ".toml")
        with open(path, "w") as f:
            f.write(text)
        stages = bake(ltbake, path, path[:-5])
        walls = [s["wall_seconds"] for s in stages]
        for i, s in enumerate(stages):
            if "eta_seconds" not in s:
                continue
            left = sum(walls[i:])
            ratios.append(s["eta_seconds"] / left)
            lines.append(f"| {name} | {s['node']} | {s['eta_seconds']:.1f} | {left:.1f} | {s['eta_seconds'] / left:.2f} |")
    r = np.array(ratios)
    lines += ["", f"ETA / left over {len(r)} steps: median {np.median(r):.2f}, range {r.min():.2f}–{r.max():.2f}; "
              f"{(np.abs(np.log(r)) <= np.log(1.5)).mean() * 100:.0f}% within 1.5× either way."]
    return lines


def main():
    if len(sys.argv) < 3:
        sys.exit(__doc__)
    ltbake, out = os.path.abspath(sys.argv[1]), os.path.abspath(sys.argv[2])
    os.makedirs(out, exist_ok=True)
    lines = ["# The whole-bake ETA (`ltbake run`, pipeline/eta.h)", "",
             f"Machine: {benchlib.machine()}. Reproduce: "
             "`/usr/bin/python3 bench/eta_model.py build/ltbake OUT`.", ""]
    if "--skip-fit" not in sys.argv:
        lines += fit(ltbake, out) + [""]
    lines += check(ltbake, out)
    benchlib.write_report(os.path.join(out, "eta_model.md"), lines)

if __name__ == "__main__":
    main()
