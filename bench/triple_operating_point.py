"""Triple products with changing light and view at the paper's operating point, on scenes no
test or default was tuned on (issue 40): error against the pixel-basis reference and frames a
second, per method and term count, with the error split by its source.

Scenes (vertex mode, R = 32 by default): the npm `snowden` bust (bench/unseen_meshes.py) and a
torus knot generated here (bench/converged_bench.py's generator, 1200 × 64), each on a ground
grid (bench/sparse_scenes/ground_grid.py, 81 × 81 vertices over 4 × 4), a Lambert floor and a
plastic object (Lambert 0.4 + Phong 32, ks 0.4). Maps: Blender's night, studio, sunrise and
courtyard (no test uses them). For each scene × map:

- the reference: `--method pixel --terms all` (every texel, ρ̃ evaluated exactly);
- every vertex's error (rel. L2, RGB) and time (`--vertex-output`) of: shared with every term
  (the default) through the default fields (99.99% energy) and through 99.999% fields;
  sublinear at the paper's 0.5% lighting / 0.1% BRDF terms and at every term; pixel with the
  0.5% brightest texels;
- the error by source, from shared (which equals linear at any terms): the fields alone
  (every term), + the paper's lighting terms, + the paper's BRDF terms;
- frames: an orbit of 8 frames at WxH, per frame trace + relight + image ms (median), visible
  vertices, frames a second.
For the first scene: the visibility's Monte Carlo error (the reference from an spp 4 field
against spp 1's).

    /usr/bin/python3 bench/triple_operating_point.py build/ltbake OUT [--res 32] [--size 800x800]
        [--maps night,studio,sunrise,courtyard] [--scenes snowden,knot]

Writes OUT/report.md and OUT/report.json.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import benchlib  # noqa: E402
import unseen_meshes  # noqa: E402
from converged_bench import torus_knot  # noqa: E402
from sparse_scenes.ground_grid import write_grid  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("ltbake")
ap.add_argument("out")
ap.add_argument("--res", type=int, default=32)
ap.add_argument("--size", default="800x800")
ap.add_argument("--maps", default="night,studio,sunrise,courtyard")
ap.add_argument("--scenes", default="snowden,knot")
a = ap.parse_args()
LTB = os.path.abspath(a.ltbake)
os.makedirs(a.out, exist_ok=True)
WORK = os.path.abspath(a.out)
ENVDIR = subprocess.run(["bash", os.path.join(benchlib.ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                        text=True, check=True).stdout.strip()
R, COLS = a.res, 6 * a.res * a.res
PAPER_L, PAPER_B = max(1, round(0.005 * COLS)), max(1, round(0.001 * COLS))  # 0.5% / 0.1% of 6R²
VIEWS = {"snowden": ("1.6,-2.0,1.3", "0,0,0.7"), "knot": ("1.7,-2.2,1.6", "0,0,0.7")}


def ltbake(*args):
    return benchlib.run(LTB, *args)


def scene(name, spp):
    """The scene file of NAME (its mesh fetched or generated) and its visibility field at spp."""
    d = os.path.join(WORK, name)
    os.makedirs(d, exist_ok=True)
    if name == "snowden":
        obj, extra = unseen_meshes.fetch("snowden", os.path.join(WORK, "meshes")), "scale = 1.5\n"
    else:
        obj, extra = os.path.join(d, "knot.obj"), ""
        if not os.path.exists(obj):
            torus_knot(obj, nu=1200, nv=64)
    write_grid(os.path.join(d, "ground.obj"), n=81, size=4.0)
    path = os.path.join(d, "scene.toml")
    with open(path, "w") as f:
        f.write(f"""[output]
mode = "vertex"
objects = ["ground", "object"]
[sampling]
cube_res = {R}
spp = {spp}
[[material]]
name = "floor"
albedo = 0.6
[[material]]
name = "plastic"
albedo = 0.4
ks = 0.4
exponent = 32.0
[[object]]
name = "ground"
type = "mesh"
file = "ground.obj"
material = "floor"
[[object]]
name = "object"
type = "mesh"
file = "{obj}"
{extra}material = "plastic"
""")
    vis = os.path.join(d, f"vis_spp{spp}.ltm")
    if not os.path.exists(vis):
        ltbake("sample", path, "--visibility", "--spp", spp, "-o", vis, "--progress", "never")
    return d, vis


def fields(d):
    """Material field sets by name: the defaults and 99.999% energy."""
    out = {}
    for tag, energy in (("default", None), ("e99999", "0.99999")):
        mats = []
        for brdf in ("lambert", "phong:32"):
            f = os.path.join(d, f"{tag}_{brdf.replace(':', '')}.ltm")
            if not os.path.exists(f):
                ltbake("material", "--brdf", brdf, "--cube-res", R, "-o", f, *(["--energy", energy] if energy else []))
            mats += ["--material", f]
        out[tag] = mats
    return out


def vertices(d, vis, env, eye, target, method, lt, bt, mats):
    """Every vertex's B from EYE (one process) and the report."""
    vo = os.path.join(d, "v.npy")
    rep = json.loads(ltbake("relight", vis, *(mats if method != "pixel" else []), "--env", env, "--clamp", "--eye", eye,
                            "--target", target, "--method", method, "--terms", lt, "--brdf-terms", bt, "--size",
                            "16x16", "-o", os.path.join(d, "tiny.npy"), "--vertex-output", vo, "--json"))
    return rep, np.load(vo)


def frames(d, vis, env, eye, target, method, lt, bt, mats):
    rep = json.loads(ltbake("relight", vis, *(mats if method != "pixel" else []), "--env", env, "--clamp", "--eye", eye,
                            "--target", target, "--method", method, "--terms", lt, "--brdf-terms", bt, "--size", a.size,
                            "--orbit", "15:8", "-o", os.path.join(d, "f_%02d.npy"), "--json"))
    ms = [f["trace_ms"] + f["relight_ms"] + f["image_ms"] for f in rep["frames"]]
    return {"frame_ms": statistics.median(ms), "relight_ms": statistics.median(f["relight_ms"] for f in rep["frames"]),
            "visible": statistics.median(f["visible_vertices"] for f in rep["frames"]),
            "fps": 1000 / statistics.median(ms)}


def rel(x, ref):
    return float(np.linalg.norm(x - ref) / np.linalg.norm(ref))


POINTS = [  # (label, method, lighting terms, BRDF terms, field set)
    ("shared, every term (default)", "shared", "all", "all", "default"),
    ("shared, every term, 99.999% fields", "shared", "all", "all", "e99999"),
    ("shared, paper lighting terms", "shared", PAPER_L, "all", "default"),
    ("shared, paper BRDF terms", "shared", "all", PAPER_B, "default"),
    ("sublinear, paper terms", "sublinear", PAPER_L, PAPER_B, "default"),
    ("sublinear, every term", "sublinear", "all", "all", "default"),
    ("pixel, 0.5% brightest texels", "pixel", PAPER_L, "all", "default"),
]
FRAMED = ("shared, every term (default)", "shared, every term, 99.999% fields", "sublinear, paper terms",
          "sublinear, every term", "pixel, 0.5% brightest texels")

report = {"machine": benchlib.machine(), "commit": benchlib.git_describe(), "res": R, "size": a.size,
          "paper_terms": [PAPER_L, PAPER_B], "scenes": {}}
for name in a.scenes.split(","):
    d, vis = scene(name, 1)
    mats = fields(d)
    eye, target = VIEWS[name]
    sc = {"maps": {}}
    for m in a.maps.split(","):
        env = os.path.join(ENVDIR, f"{m}.exr")
        rep, ref = vertices(d, vis, env, eye, target, "pixel", "all", "all", [])
        sc["vertices"] = rep["vertices"]
        rows = [{"label": "pixel, every texel (reference)", "ms": rep["vertex_output_ms"], "error": 0.0,
                 **frames(d, vis, env, eye, target, "pixel", "all", "all", [])}]
        for label, method, lt, bt, fs in POINTS:
            r, v = vertices(d, vis, env, eye, target, method, lt, bt, mats[fs])
            row = {"label": label, "ms": r["vertex_output_ms"], "error": rel(v, ref)}
            if label in FRAMED:
                row.update(frames(d, vis, env, eye, target, method, lt, bt, mats[fs]))
            rows.append(row)
        sc["maps"][m] = rows
        print(name, m, " ".join(f"{r['label'][:12]}={r['error']:.4f}/{r.get('fps', 0):.1f}fps" for r in rows),
              flush=True)
    if not report["scenes"]:  # the visibility's Monte Carlo error: the reference through spp 4, first map
        _, vis4 = scene(name, 4)
        env = os.path.join(ENVDIR, f"{a.maps.split(',')[0]}.exr")
        _, ref1 = vertices(d, vis, env, eye, target, "pixel", "all", "all", [])
        _, ref4 = vertices(d, vis4, env, eye, target, "pixel", "all", "all", [])
        sc["visibility_spp1_vs_spp4"] = rel(ref1, ref4)
    report["scenes"][name] = sc
with open(os.path.join(WORK, "report.json"), "w") as f:
    json.dump(report, f, indent=1)

L = [f"# Triple products at the paper's operating point, unseen scenes (R = {R})", "",
     f"Machine: {report['machine']}; commit {report['commit']}. `bench/triple_operating_point.py`. Errors: rel. "
     "L2 of every vertex's RGB against `--method pixel --terms all`; *ms all*: every vertex "
     f"(`--vertex-output`); frames: an 8-frame orbit at {a.size}, median of trace + relight + image. The paper's "
     f"terms: {PAPER_L} lighting (0.5% of 6R²), {PAPER_B} BRDF (0.1%) a row.", ""]
for name, sc in report["scenes"].items():
    noise = (f"; the reference through an spp 1 visibility field against spp 4: "
             f"{100 * sc['visibility_spp1_vs_spp4']:.2f}%" if "visibility_spp1_vs_spp4" in sc else "")
    L += [f"## {name}: {sc['vertices']} vertices{noise}", ""]
    for m, rows in sc["maps"].items():
        L += [f"### {m}", "", "| method | error | ms all | visible vertices | ms a frame | frames/s |",
              "|---|---|---|---|---|---|"]
        for r in rows:
            fr = (f"{r['visible']:.0f} | {r['frame_ms']:.0f} | {r['fps']:.1f}" if "fps" in r else " | | ")
            L.append(f"| {r['label']} | {100 * r['error']:.2f}% | {r['ms']:.0f} | {fr} |")
        L.append("")
benchlib.write_report(os.path.join(WORK, "report.md"), L)
