#!/usr/bin/python3
"""Glossy vertices from any view (`sample --factor K`, `relight --eye`; docs/GLOSSY.md)
against the per-view brute force, in one script.

Issue "colour and glossy vertices", targets: K = 4 within 3% rel. L2 of the brute force for
Phong(32); >= 60 frames/s at 30k vertices, 200 terms, RGB, on 2 cores.

Scene (written to bench/out/glossy/): the dragon (data/meshes/dragon_res3.ply, 22,998
vertices) in a Phong material (albedo 0.3, ks 0.5, exponent LTB_GLOSSY_EXPONENT) on a
diffuse ground grid of LTB_GLOSSY_GRID² vertices (bench/sparse_scenes/ground_grid.py),
smooth normals, R = LTB_GLOSSY_CUBE_RES.
 1. `sample --factor K` for each K of LTB_GLOSSY_KS: wall seconds (perf_counter around the child),
    bytes on disk of the K files, the factorisation's errors sample prints.
 2. The brute force: the same scene in image mode from the eye (the same pinhole camera and
    Phong BRDF per pixel), LTB_GLOSSY_SIZE², relit with --terms all under each bundled map.
 3. `relight SET --eye ... --terms all --brdf-terms K` of the largest K's bake (its first K terms
    are the K-term bake's, bit for bit) under each map: rel. L2 against the brute force over
    the pixels both render (object and ground).
 4. Frames: `relight SET --eye ... --terms 200 --orbit 10:36` at 256x256 for K = 4, 8, 16, 32 (those in LTB_GLOSSY_KS) and the largest:
    the median ms per view (vertex radiance from the K relit terms, primary rays,
    interpolation) and the relight of the K terms once (200 terms, RGB).

Run:  /usr/bin/python3 bench/glossy_bench.py [BUILD_DIR]
Knobs: LTB_GLOSSY_CUBE_RES (32), LTB_GLOSSY_SIZE (128), LTB_GLOSSY_GRID (100),
       LTB_GLOSSY_EXPONENT (32), LTB_GLOSSY_MAPS (comma-separated; default the bundled maps),
       LTB_GLOSSY_KS (the term counts, comma-separated; default 1,2,4,8: the largest is baked
       and kept, the others are its first terms), LTB_GLOSSY_ROWS ("all": the object and the
       ground are vertex rows, the default; "object": the glossy object alone, so the error
       is the glossy surface's), LTB_GLOSSY_BOUNCES (0: the bakes and the brute force with
       that many bounces)
Writes bench/results/glossy_bench.{md,json}, glossy_view_{brute,k1,k4,k8}.png (city),
glossy_orbit_{000,180}deg.png (the largest K, 200 terms, 256x256, from two sides) and, with
more than four K, glossy_k_curve.png (error against K).
"""
import datetime
import json
import os
import re
import shutil
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import ROOT, git_describe, machine  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
OUT = os.path.join(ROOT, "bench", "out", "glossy")
RESULTS = os.path.join(ROOT, "bench", "results")
KNOBS = ["LTB_GLOSSY_CUBE_RES", "LTB_GLOSSY_SIZE", "LTB_GLOSSY_GRID", "LTB_GLOSSY_EXPONENT", "LTB_GLOSSY_MAPS",
         "LTB_GLOSSY_MESH", "LTB_GLOSSY_NAME", "LTB_GLOSSY_KS", "LTB_GLOSSY_ROWS", "LTB_GLOSSY_BOUNCES"]
R = int(os.environ.get("LTB_GLOSSY_CUBE_RES", "32"))
SIZE = int(os.environ.get("LTB_GLOSSY_SIZE", "128"))
GRID = int(os.environ.get("LTB_GLOSSY_GRID", "100"))
EXPONENT = float(os.environ.get("LTB_GLOSSY_EXPONENT", "32"))
# "dragon" (data/meshes/dragon_res3.ply) or "torus" (generated here: 160 x 80 vertices, a
# mesh no bundled sample has); LTB_GLOSSY_NAME suffixes the result files (e.g. "_unseen").
MESH = os.environ.get("LTB_GLOSSY_MESH", "dragon")
NAME = os.environ.get("LTB_GLOSSY_NAME", "")
KS = tuple(int(k) for k in os.environ.get("LTB_GLOSSY_KS", "1,2,4,8").split(","))
KMAX = max(KS)
ROWS = '["dragon"]' if os.environ.get("LTB_GLOSSY_ROWS", "all") == "object" else '["dragon", "ground"]'
BOUNCES = int(os.environ.get("LTB_GLOSSY_BOUNCES", "0"))
EYE, TARGET, FOV = "0,-2.6,1.3", "0,0,0.35", 35.0

SCENE = """
[output]
mode = "{mode}"
{extra}
[sampling]
cube_res = {r}
spp = 4
bounces = {bounces}
[[material]]
name = "floor"
albedo = 0.6
[[material]]
name = "glossy"
albedo = 0.3
ks = 0.5
exponent = {exponent}
[[object]]
name = "ground"
type = "mesh"
file = "{grid}"
normals = "smooth"
material = "floor"
[[object]]
name = "dragon"
type = "mesh"
file = "{dragon}"
{placement}
normals = "smooth"
material = "glossy"
"""
PLACEMENT = {"dragon": "scale = 7.0\nrotate = [90.0, 0.0, 0.0]\ntranslate = [0.0, 0.0, -0.37]",
             "torus": "rotate = [60.0, 0.0, 20.0]\ntranslate = [0.0, 0.0, 0.45]"}


def write_torus(path, nu=160, nv=80, big=0.55, small=0.2):
    """A torus of nu x nv vertices (quads as two triangles), z up, centred on the origin."""
    import math
    with open(path, "w") as f:
        for i in range(nu):
            for j in range(nv):
                u, v = 2 * math.pi * i / nu, 2 * math.pi * j / nv
                f.write("v %.7f %.7f %.7f\n" % ((big + small * math.cos(v)) * math.cos(u),
                                               (big + small * math.cos(v)) * math.sin(u), small * math.sin(v)))
        for i in range(nu):
            for j in range(nv):
                a, b = i * nv + j, ((i + 1) % nu) * nv + j
                c, d = ((i + 1) % nu) * nv + (j + 1) % nv, i * nv + (j + 1) % nv
                f.write("f %d %d %d\nf %d %d %d\n" % (a + 1, b + 1, c + 1, a + 1, c + 1, d + 1))


def run(*args):
    t0 = time.perf_counter()
    p = subprocess.run([LTB, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))}: exit {p.returncode}\n{p.stdout}{p.stderr}")
    return p.stdout, time.perf_counter() - t0


def maps():
    if os.environ.get("LTB_GLOSSY_MAPS"):
        return [os.path.abspath(m) for m in os.environ["LTB_GLOSSY_MAPS"].split(",") if m.strip()]
    d = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True).stdout.strip()
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".exr"))


def name(path):
    return os.path.splitext(os.path.basename(path))[0]


def tonemap_png(npy, png, exposure):
    from PIL import Image
    x = np.load(npy).reshape(SIZE, SIZE, 3)
    Image.fromarray((np.clip(x * exposure, 0, 1) ** (1 / 2.2) * 255 + 0.5).astype(np.uint8)).save(png)


def plot_curve(res, png):
    """Rel. L2 against the brute force (median and range over the maps) and the
    factorisation's own error of rho*cos against K, with the floor and views/s."""
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    # Keys are ints in a run and strings once through JSON: one form here.
    errors = {m: {int(k): v for k, v in e.items()} for m, e in res["errors"].items()}
    bakes = {int(k): v for k, v in res["bakes"].items()}
    frames = {int(k): v for k, v in res.get("frames", {}).items()}
    ks = sorted(next(iter(errors.values())))
    errs = np.array([[e[k] for k in ks] for e in errors.values()])
    fe = bakes[max(ks)]["factor_errors"]
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    ax.plot(ks, np.median(errs, 0), "o-", label="image vs brute force (median of maps)")
    ax.fill_between(ks, errs.min(0), errs.max(0), alpha=0.2)
    ax.plot(range(1, len(fe) + 1), fe, "--", label="factorisation error of rho*cos")
    ax.axhline(float(np.median(list(res["floor"].values()))), color="grey", lw=0.8, label="floor (diffuse object)")
    ax.axhline(0.05, color="red", lw=0.8, ls=":", label="5%")
    ax.set_xscale("log", base=2)
    ax.set_yscale("log")
    ax.set_xlabel("K (terms)")
    ax.set_ylabel("relative L2")
    if frames:
        ax.set_title("views/s at 256x256: " + ", ".join(f"K={k} {frames[k]['fps']:.0f}" for k in frames), fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(png, dpi=110)


def main():
    os.makedirs(OUT, exist_ok=True)
    sys.path.insert(0, os.path.join(ROOT, "bench", "sparse_scenes"))
    import ground_grid
    grid = os.path.join(OUT, f"ground_{GRID}.obj")
    if not os.path.exists(grid):
        ground_grid.write_grid(grid, GRID, 6.0)
    dragon = os.path.join(ROOT, "data", "meshes", "dragon_res3.ply")
    if MESH == "torus":
        dragon = os.path.join(OUT, "torus.obj")
        write_torus(dragon)
    fmt = dict(r=R, exponent=EXPONENT, bounces=BOUNCES, grid=grid, dragon=dragon, placement=PLACEMENT[MESH])
    vscene = os.path.join(OUT, "vertex.toml")
    with open(vscene, "w") as f:
        f.write(SCENE.format(mode="vertex", extra=f'objects = {ROWS}', **fmt))
    bscene = os.path.join(OUT, "brute.toml")
    e, tg = EYE.split(","), TARGET.split(",")
    cam = (f"[camera]\neye = [{', '.join(e)}]\ntarget = [{', '.join(tg)}]\nup = [0.0, 0.0, 1.0]\nfov = {FOV}\n"
           f"width = {SIZE}\nheight = {SIZE}")
    with open(bscene, "w") as f:
        f.write(SCENE.format(mode="image", extra=cam, **fmt))
    started = datetime.datetime.now().isoformat(timespec="seconds")
    load = os.getloadavg()
    res = {"bakes": {}, "errors": {}, "frames": {}}
    view = ["--eye", EYE, "--target", TARGET, "--fov", FOV]
    # 1. Bakes per K (the largest K's set is kept for 3 and 4).
    for k in KS:
        out = os.path.join(OUT, f"f{k}.ltm")
        text, secs = run("sample", vscene, "-o", out, "--factor", k, "--jobs", 2, "--overwrite", "--progress", "never")
        files = [os.path.join(OUT, f"f{k}.k{i}.ltm") for i in range(k)]
        m = re.search(r"rho\*cos for K = 1\.\.\d+:((?: [0-9.]+)+)", text)
        rows = int(re.search(r": (\d+) rows x", text).group(1))
        res["bakes"][k] = {"wall_s": secs, "bytes": sum(os.path.getsize(f) for f in files), "rows": rows,
                           "factor_errors": [float(x) for x in m.group(1).split()] if m else None}
        if k != KMAX:
            for f in files:
                os.remove(f)
    s8 = os.path.join(OUT, f"f{KMAX}.ltm")
    # 2-3. Brute force and factored views per map.
    if os.path.exists(os.path.join(OUT, "brute.ltm")):  # else sample finds it up to date and times nothing
        os.remove(os.path.join(OUT, "brute.ltm"))
    _, t_brute = run("sample", bscene, "-o", os.path.join(OUT, "brute.ltm"), "--jobs", 2, "--overwrite", "-q")
    res["brute_bake_s"] = t_brute
    for m in maps():
        bnpy = os.path.join(OUT, f"brute_{name(m)}.npy")
        run("relight", os.path.join(OUT, "brute.ltm"), "--env", m, "--clamp", "--terms", "all", "-o", bnpy, "-q")
        ref = np.load(bnpy).astype(np.float64)
        res["errors"][name(m)] = {}
        for k in KS:
            vnpy = os.path.join(OUT, f"view_{name(m)}_k{k}.npy")
            run("relight", s8, "--env", m, "--clamp", "--terms", "all", *view, "--size", f"{SIZE}x{SIZE}",
                "--brdf-terms", k, "-o", vnpy, "-q")
            img = np.load(vnpy).astype(np.float64)
            both = (img.sum(1) > 0) & (ref.sum(1) > 0)
            res["errors"][name(m)][k] = float(np.linalg.norm(img[both] - ref[both]) / np.linalg.norm(ref[both]))
        if name(m) == ("city" if any(name(x) == "city" for x in maps()) else name(maps()[0])):
            exposure = 1 / max(np.percentile(ref, 99), 1e-12)
            tonemap_png(bnpy, os.path.join(RESULTS, f"glossy_view{NAME}_brute.png"), exposure)
            for k in (x for x in (1, 4, 8) if x in KS):
                tonemap_png(os.path.join(OUT, f"view_{name(m)}_k{k}.npy"), os.path.join(RESULTS, f"glossy_view{NAME}_k{k}.png"),
                            exposure)
    # The floor of the comparison: the same scene with a diffuse dragon (ks = 0), whose K = 1
    # bake is exact, against its own brute force: vertex interpolation, per-vertex normals
    # and the two bakes' Monte Carlo noise, with no BRDF approximation.
    fmt_d = dict(fmt, exponent=EXPONENT)
    dv, db = os.path.join(OUT, "diffuse_vertex.toml"), os.path.join(OUT, "diffuse_brute.toml")
    with open(dv, "w") as f:
        f.write(SCENE.format(mode="vertex", extra=f'objects = {ROWS}', **fmt_d).replace("ks = 0.5", "ks = 0.0"))
    with open(db, "w") as f:
        f.write(SCENE.format(mode="image", extra=cam, **fmt_d).replace("ks = 0.5", "ks = 0.0"))
    run("sample", dv, "-o", os.path.join(OUT, "diffuse.ltm"), "--factor", 1, "--jobs", 2, "--overwrite", "-q")
    run("sample", db, "-o", os.path.join(OUT, "diffuse_brute.ltm"), "--jobs", 2, "--overwrite", "-q")
    res["floor"] = {}
    for m in maps():
        a, b = os.path.join(OUT, f"dfloor_{name(m)}.npy"), os.path.join(OUT, f"dbrute_{name(m)}.npy")
        run("relight", os.path.join(OUT, "diffuse.ltm"), "--env", m, "--clamp", "--terms", "all", *view, "--size",
            f"{SIZE}x{SIZE}", "-o", a, "-q")
        run("relight", os.path.join(OUT, "diffuse_brute.ltm"), "--env", m, "--clamp", "--terms", "all", "-o", b, "-q")
        img, ref = np.load(a).astype(np.float64), np.load(b).astype(np.float64)
        both = (img.sum(1) > 0) & (ref.sum(1) > 0)
        res["floor"][name(m)] = float(np.linalg.norm(img[both] - ref[both]) / np.linalg.norm(ref[both]))
    for f in os.listdir(OUT):
        if f.startswith("diffuse") and f.endswith(".ltm"):
            os.remove(os.path.join(OUT, f))
    # 4. Frames along an orbit, 200 lighting terms.
    m0 = next((m for m in maps() if name(m) == "city"), maps()[0])
    for k in sorted({k for k in (4, 8, 16, 32) if k in KS} | {KMAX}):
        text, _ = run("relight", s8, "--env", m0, "--clamp", "--terms", 200, *view, "--size", "256x256",
                      "--brdf-terms", k, "--orbit", "10:36", "-o", os.path.join(OUT, "orbit_%02d.png"), "--json")
        rep = json.loads(text)
        res["frames"][k] = {"median_ms": rep["frames"]["median_ms"], "fps": rep["frames"]["fps"],
                            "relight_ms": rep["relight_ms"], "vertices": rep["vertices"]}
    for deg, frame in (("000", 0), ("180", 18)):  # the largest K's orbit from two sides (README)
        shutil.copy(os.path.join(OUT, f"orbit_{frame:02d}.png"), os.path.join(RESULTS, f"glossy_orbit{NAME}_{deg}deg.png"))
    meta = {"started": started, "machine": machine(), "commit": git_describe(), "load_before": load,
            "command": " ".join(f"{k}={os.environ[k]}" for k in KNOBS if k in os.environ),
            "scene": f"{'dragon_res3' if MESH == 'dragon' else 'a generated torus (12,800 vertices)'} + {GRID}x{GRID} "
                     f"ground grid, Phong({EXPONENT:g}), R = {R}, {SIZE}x{SIZE}; maps: "
                     + ", ".join(name(m) for m in maps())}
    with open(os.path.join(RESULTS, f"glossy_bench{NAME}.json"), "w") as f:
        json.dump({"meta": meta, "results": res}, f, indent=1)
    lines = ["# Glossy vertices from any view (bench/glossy_bench.py)", "",
             f"{started}, {meta['machine']}, commit {meta['commit']}, load before {load[0]:.2f}.", "",
             f"Scene: {meta['scene']}; {res['bakes'][1]['rows']} vertex rows. Brute force: image-mode sample "
             f"from the eye, {t_brute:.1f} s.", "",
             "| K | bake s | bytes on disk |", "|---|---|---|"]
    for k in KS:
        b = res["bakes"][k]
        lines.append(f"| {k} | {b['wall_s']:.2f} | {b['bytes']:,} |")
    fe = res["bakes"][KMAX]["factor_errors"]
    lines += ["", f"Factorisation error of rho*cos (K = 1..{len(fe)}): " + ", ".join(f"{x:.3f}" for x in fe), "",
              "Rel. L2 against the brute force (pixels both render):", "",
              "| map | " + " | ".join(f"K = {k}" for k in KS) + " |", "|---|" + "---|" * len(KS)]
    for mname, errs in res["errors"].items():
        lines.append(f"| {mname} | " + " | ".join(f"{errs[k]:.4f}" for k in KS) + " |")
    med = {k: float(np.median([e[k] for e in res["errors"].values()])) for k in KS}
    lines.append("| median | " + " | ".join(f"{med[k]:.4f}" for k in KS) + " |")
    fl = res["floor"]
    lines += ["", "The comparison's floor (the object diffuse, K = 1 exact, against its own brute force: vertex "
              "interpolation, per-vertex normals, Monte Carlo noise): " +
              ", ".join(f"{mname} {e:.4f}" for mname, e in fl.items()) + f"; median {np.median(list(fl.values())):.4f}"]
    lines += ["", "Views along an orbit (256x256, 200 lighting terms, RGB):", ""]
    for k, fr in res["frames"].items():
        lines.append(f"- K = {k}: {fr['median_ms']:.2f} ms a view (median of 36), **{fr['fps']:.0f} views/s**; "
                     f"the K terms relit once in {fr['relight_ms']:.1f} ms ({fr['vertices']} vertices)")
    if len(KS) > 4:
        plot_curve(res, os.path.join(RESULTS, f"glossy_k_curve{NAME}.png"))
        lines += ["", f"![error against K](glossy_k_curve{NAME}.png)"]
    with open(os.path.join(RESULTS, f"glossy_bench{NAME}.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
