#!/usr/bin/python3
"""What colour costs (docs/COLOUR.md), measured against the grey bake in the same script.

Issue "colour", target: an RGB direct bake costs at most 1.05x the monochrome bake.

Case "direct" (LTB_COLOUR_SCENE, default samples/medium.toml, at LTB_COLOUR_SIZE² pixels,
R = LTB_COLOUR_CUBE_RES):
 1. `sample` of the grey scene and of a coloured copy (every albedo and ks times one tint
    per material, in order of appearance: [1, 0.8, 0.55], [1, 0.35, 0.2], [0.3, 0.6, 1], ...),
    alternately LTB_COLOUR_REPEATS times each after one untimed warm-up of each: wall
    seconds (perf_counter around the child) and peak RSS (os.wait4); medians, min-max. The
    coloured monochrome bake writes the grey bake's matrix plus the reflectance table.
 2. The coloured scene with --channels rgb (three matrices), timed once per repeat too.
 3. Bytes on disk of each output (all files of a set).
 4. row-transform, transpose, column-transform (--budget 2%), quantize of the grey and the
    coloured bake; `relight final.ltm --frames LTB_COLOUR_FRAMES --terms 200` under the bundled
    city.exr: median ms per frame of each (the reflectance table's cost at relighting).

Case "cornell" (samples/cornell.toml, its materials from the OBJ's usemtl, one bounce):
 5. `sample --channels rgb` against a grey copy (every material's albedo its mean), timed
    as in 1; relit under a constant white map and under city.exr; the
    images go to bench/results/colour_cornell_{white,map}.png (the README's figure), and
    the red excess r/g - 1 of the floor near the red wall and in its middle.

Run:  /usr/bin/python3 bench/colour_bench.py [BUILD_DIR]
Knobs: LTB_COLOUR_CASES (direct,cornell), LTB_COLOUR_REPEATS (3), LTB_COLOUR_SIZE (128),
       LTB_COLOUR_CUBE_RES (32), LTB_COLOUR_FRAMES (50), LTB_COLOUR_SCENE, LTB_COLOUR_MAP
       (default the bundled city.exr), LTB_COLOUR_NAME (a suffix for the result files)
Writes bench/results/colour_bench.{md,json}.
"""
import datetime
import json
import os
import re
import shutil
import statistics
import subprocess
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import ROOT, git_describe, machine  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
OUT = os.path.join(ROOT, "bench", "out", "colour")
RESULTS = os.path.join(ROOT, "bench", "results")
KNOBS = ["LTB_COLOUR_CASES", "LTB_COLOUR_REPEATS", "LTB_COLOUR_SIZE", "LTB_COLOUR_CUBE_RES", "LTB_COLOUR_FRAMES",
         "LTB_COLOUR_SCENE", "LTB_COLOUR_MAP", "LTB_COLOUR_NAME"]
CASES = os.environ.get("LTB_COLOUR_CASES", "direct,cornell").split(",")
REPEATS = int(os.environ.get("LTB_COLOUR_REPEATS", "3"))
SIZE = int(os.environ.get("LTB_COLOUR_SIZE", "128"))
CUBE_RES = int(os.environ.get("LTB_COLOUR_CUBE_RES", "32"))
FRAMES = int(os.environ.get("LTB_COLOUR_FRAMES", "50"))
# The direct case's scene (image mode; its materials tinted in order of appearance by
# PALETTE), the map of the relight timing and the Cornell images, a suffix for the results.
SCENE = os.path.abspath(os.environ.get("LTB_COLOUR_SCENE", os.path.join(ROOT, "samples", "medium.toml")))
MAP = os.environ.get("LTB_COLOUR_MAP", "")
NAME = os.environ.get("LTB_COLOUR_NAME", "")
PALETTE = [[1, 0.8, 0.55], [1, 0.35, 0.2], [0.3, 0.6, 1], [0.5, 1, 0.4]]
Q = ["--progress", "never", "-q"]


def run(*args):
    p = subprocess.run([LTB, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))}: exit {p.returncode}\n{p.stdout}{p.stderr}")
    return p.stdout


def timed(*args):
    """Wall seconds and peak RSS (MiB) of one ltbake child."""
    t0 = time.perf_counter()
    p = subprocess.Popen([LTB, *map(str, args)], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, usage = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))}: {p.stderr.read().decode()}")
    return wall, usage.ru_maxrss / 1024


def files_of(path):
    if os.path.exists(path):
        return [path]
    stem, ext = os.path.splitext(path)
    return [f"{stem}.{c}{ext}" for c in "rgb"]


def remove(path):
    for f in files_of(path):
        if os.path.exists(f):
            os.remove(f)


def disk_bytes(path):
    return sum(os.path.getsize(f) for f in files_of(path))


def stats(xs):
    return {"median": statistics.median(xs), "min": min(xs), "max": max(xs), "n": len(xs)}


def first_map():
    """LTB_COLOUR_MAP, else city.exr of the bundled maps (scripts/find_envmaps.sh prints their folder), else the first."""
    if MAP:
        return os.path.abspath(MAP)
    d = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True).stdout.strip()
    if not d or not os.path.isdir(d):
        return None
    maps = sorted(f for f in os.listdir(d) if f.endswith(".exr"))
    return os.path.join(d, "city.exr" if "city.exr" in maps else maps[0]) if maps else None


def write_scene(src, dst, tints, size=None, grey=False):
    """A copy of scene `src` with each named material's albedo and ks times its tint (or,
    grey, every [r, g, b] albedo replaced by its mean), mesh paths made absolute."""
    text = open(src).read()
    base = os.path.dirname(os.path.abspath(src))
    text = re.sub(r'file = "(?!/)([^"]+)"', lambda m: f'file = "{os.path.join(base, m.group(1))}"', text)
    if size:
        text = re.sub(r"^width = \d+", f"width = {size}", text, flags=re.M)
        text = re.sub(r"^height = \d+", f"height = {size}", text, flags=re.M)
    out, material = [], None
    for line in text.splitlines():
        if re.match(r"\s*\[\[material\]\]", line):
            material = len([1 for x in out if re.match(r"\s*\[\[material\]\]", x)])  # its order
        m = re.match(r"(\s*)(albedo|ks) = (.+?)(\s*#.*)?$", line)
        if m and grey and m.group(3).startswith("["):
            v = [float(x) for x in m.group(3).strip("[]").split(",")]
            line = f"{m.group(1)}{m.group(2)} = {sum(v) / 3:.6g}"
        elif m and material in tints and not m.group(3).startswith("["):
            v = float(m.group(3))
            line = f"{m.group(1)}{m.group(2)} = [{', '.join(f'{v * t:.6g}' for t in tints[material])}]"
        out.append(line)
    with open(dst, "w") as f:
        f.write("\n".join(out) + "\n")
    return dst


def alternate(variants):
    """variants: name -> (output, args). Warm-up once each, then REPEATS rounds in turn."""
    times = {k: [] for k in variants}
    rss = {k: [] for k in variants}
    for rnd in range(REPEATS + 1):
        for name, (out, args) in variants.items():
            remove(out)
            w, r = timed(*args)
            if rnd > 0:
                times[name].append(w)
                rss[name].append(r)
    return {k: {"wall_s": stats(times[k]), "rss_mib": stats(rss[k])} for k in variants}


def compress(raw, d, name):
    rows, cols, c4, final = (os.path.join(d, f"{name}-{s}.ltm") for s in ("rows", "cols", "cols4d", "final"))
    run("row-transform", raw, "-o", rows, "--overwrite", *Q)
    run("transpose", rows, "-o", cols, "--overwrite", *Q)
    run("column-transform", cols, "-o", c4, "--budget", "2%", "--overwrite", *Q)
    run("quantize", c4, "-o", final, "--overwrite", *Q)
    return final


def case_direct(envmap):
    d = os.path.join(OUT, "direct")
    os.makedirs(d, exist_ok=True)
    grey = write_scene(SCENE, os.path.join(d, "grey.toml"), {}, SIZE)
    col = write_scene(SCENE, os.path.join(d, "colour.toml"), dict(enumerate(PALETTE)), SIZE)
    outs = {"grey": os.path.join(d, "grey.ltm"), "colour_mono": os.path.join(d, "colour.ltm"),
            "colour_rgb": os.path.join(d, "rgb.ltm")}
    common = ["--cube-res", CUBE_RES, "--jobs", 2, *Q]
    res = alternate({
        "grey": (outs["grey"], ["sample", grey, "-o", outs["grey"], *common]),
        "colour_mono": (outs["colour_mono"], ["sample", col, "-o", outs["colour_mono"], *common]),
        "colour_rgb": (outs["colour_rgb"], ["sample", col, "-o", outs["colour_rgb"], "--channels", "rgb", *common]),
    })
    for k, p in outs.items():
        res[k]["bytes"] = disk_bytes(p)
    g = res["grey"]["wall_s"]["median"]
    res["ratio_colour_mono"] = res["colour_mono"]["wall_s"]["median"] / g
    res["ratio_colour_rgb"] = res["colour_rgb"]["wall_s"]["median"] / g
    if envmap:
        fps = {}
        for name in ("grey", "colour_mono"):
            final = compress(outs[name], d, name)
            rep = json.loads(run("relight", final, "--env", envmap, "--clamp", "--terms", 200, "--frames", FRAMES,
                                 "-o", os.path.join(d, f"{name}.png"), "--json", "--progress", "never"))
            fps[name] = {"median_ms": rep["frames"]["median_ms"], "fps": rep["frames"]["fps"],
                         "final_bytes": disk_bytes(final)}
        fps["ratio_ms"] = fps["colour_mono"]["median_ms"] / fps["grey"]["median_ms"]
        res["relight"] = fps
    res["scene"] = f"{os.path.relpath(SCENE, ROOT)} at {SIZE}x{SIZE}, R = {CUBE_RES}"
    return res


def tonemap(img, w, h, exposure):
    x = np.clip(img.reshape(h, w, 3) * exposure, 0, 1) ** (1 / 2.2)
    return (x * 255 + 0.5).astype(np.uint8)


def case_cornell(envmap):
    from PIL import Image
    d = os.path.join(OUT, "cornell")
    os.makedirs(d, exist_ok=True)
    cornell = os.path.join(ROOT, "samples", "cornell.toml")
    shutil.copy(cornell, os.path.join(d, "colour.toml"))
    grey = write_scene(cornell, os.path.join(d, "grey.toml"), {}, grey=True)
    outs = {"grey": os.path.join(d, "grey.ltm"), "colour_rgb": os.path.join(d, "rgb.ltm")}
    res = alternate({
        "grey": (outs["grey"], ["sample", grey, "-o", outs["grey"], "--jobs", 2, *Q]),
        "colour_rgb": (outs["colour_rgb"], ["sample", cornell, "-o", outs["colour_rgb"], "--channels", "rgb",
                                            "--jobs", 2, *Q]),
    })
    for k, p in outs.items():
        res[k]["bytes"] = disk_bytes(p)
    res["ratio_colour_rgb"] = res["colour_rgb"]["wall_s"]["median"] / res["grey"]["wall_s"]["median"]
    info = json.loads(run("inspect", files_of(outs["colour_rgb"])[0], "--json", "--no-content"))
    r = info["basis"]["cols"]["cube_res"]
    w, h = info["basis"]["rows"]["width"], info["basis"]["rows"]["height"]
    white = os.path.join(d, "white.npy")
    np.save(white, np.ones((6 * r * r, 3), np.float32))
    images = {}
    for name, env in (("white", white), ("map", envmap)):
        if env is None:
            continue
        out = os.path.join(d, f"{name}.npy")
        run("relight", outs["colour_rgb"], "--env", env, "--clamp", "--terms", "all", "-o", out, *Q)
        images[name] = np.load(out)
        exposure = 1 / max(np.percentile(images[name], 99), 1e-12)
        Image.fromarray(tonemap(images[name], w, h, exposure)).save(
            os.path.join(RESULTS, f"colour_cornell{NAME}_{name}.png"))
    # The floor's red excess near the red wall and in the middle (positions of channel r).
    run("convert", files_of(outs["colour_rgb"])[0], os.path.join(d, "r.npy"), *Q)
    img = images["white"]
    pos = side_table(files_of(outs["colour_rgb"])[0], "position")
    nor = side_table(files_of(outs["colour_rgb"])[0], "normal")
    floor = (nor[:, 2] > 0.99) & (pos[:, 2] < 0.05) & (img[:, 1] > 0)
    xs = pos[floor, 0]
    lo, hi = xs.min(), xs.max()
    red_side = lo if np.mean(img[floor & (pos[:, 0] < lo + 0.1 * (hi - lo)), 0]) > np.mean(
        img[floor & (pos[:, 0] > hi - 0.1 * (hi - lo)), 0]) else hi
    near = floor & (np.abs(pos[:, 0] - red_side) < 0.15 * (hi - lo))
    mid = floor & (np.abs(pos[:, 0] - (lo + hi) / 2) < 0.1 * (hi - lo))
    res["red_excess_near_wall"] = float(np.mean(img[near, 0] / img[near, 1]) - 1)
    res["red_excess_middle"] = float(np.mean(img[mid, 0] / img[mid, 1]) - 1)
    res["scene"] = "samples/cornell.toml (usemtl materials, one bounce)"
    return res


def side_table(path, name):
    sys.path.insert(0, os.path.join(ROOT, "tests", "cli"))
    import ltbtest
    ltbtest.LTBAKE = LTB
    return ltbtest.side_table(path, name)


def main():
    os.makedirs(OUT, exist_ok=True)
    envmap = first_map()
    started = datetime.datetime.now().isoformat(timespec="seconds")
    load = os.getloadavg()
    results = {}
    for c in CASES:
        results[c] = {"direct": case_direct, "cornell": case_cornell}[c](envmap)
    meta = {"started": started, "machine": machine(), "commit": git_describe(), "load_before": load,
            "repeats": REPEATS, "envmap": envmap,
            "command": " ".join(f"{k}={os.environ[k]}" for k in KNOBS if k in os.environ)}
    with open(os.path.join(RESULTS, f"colour_bench{NAME}.json"), "w") as f:
        json.dump({"meta": meta, "results": results}, f, indent=1)
    lines = ["# Colour: what it costs (bench/colour_bench.py)", "",
             f"{started}, {meta['machine']}, commit {meta['commit']}, load before "
             f"{load[0]:.2f}; {REPEATS} timed runs of each after a warm-up, alternating; medians (min-max).", ""]
    for c, r in results.items():
        lines += [f"## {c}: {r['scene']}", "", "| bake | wall s | peak RSS MiB | bytes on disk |", "|---|---|---|---|"]
        for k in ("grey", "colour_mono", "colour_rgb"):
            if k in r:
                w, m = r[k]["wall_s"], r[k]["rss_mib"]
                lines.append(f"| {k} | {w['median']:.2f} ({w['min']:.2f}-{w['max']:.2f}) | {m['median']:.0f} | "
                             f"{r[k]['bytes']:,} |")
        lines.append("")
        for k in ("ratio_colour_mono", "ratio_colour_rgb"):
            if k in r:
                lines.append(f"- {k}: **{r[k]:.3f}x** the grey bake's wall time")
        if "relight" in r:
            rl = r["relight"]
            lines.append(f"- relight final.ltm, 200 terms: grey {rl['grey']['median_ms']:.3f} ms/frame, coloured "
                         f"{rl['colour_mono']['median_ms']:.3f} ms/frame ({rl['ratio_ms']:.3f}x)")
        if "red_excess_near_wall" in r:
            lines.append(f"- floor under a white map, r/g - 1: near the red wall {r['red_excess_near_wall']:.3f}, "
                         f"in the middle {r['red_excess_middle']:.3f}")
        lines.append("")
    with open(os.path.join(RESULTS, f"colour_bench{NAME}.md"), "w") as f:
        f.write("\n".join(lines))
    print("\n".join(lines))


if __name__ == "__main__":
    main()
