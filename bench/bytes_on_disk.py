#!/usr/bin/python3
"""2D against adaptive 4D in BYTES ON DISK at equal matrix error.

Bakes a scene once (sample -> row-transform db2 -> transpose), then for each method and
global budget runs `column-transform --depth D --budget B` and `quantize` (the default,
one step with --error-ratio 1.1, unless LTB_BYTES_QUANTIZE says otherwise), and measures
the size of final.ltm on disk and its matrix error against rows.ltm in NumPy
(||T - T'||_F / ||T||_F in the row-transformed basis, db2 being orthonormal: the pixel
error). The 2D curve's bytes are interpolated (log-log) at each 4D error to give the ratio.

    /usr/bin/python3 bench/bytes_on_disk.py [BUILD_DIR=build]

Relit errors: each final.ltm is relit with every lighting term (`relight --terms all
--reference rows.ltm --json`, so only the matrix compression is measured) under each of
Blender's environment maps (scripts/find_envmaps.sh; LTB_BYTES_MAPS overrides, "" skips),
and rel. L2 and rel. H1 are averaged over the maps.

Environment: LTB_BYTES_SCENE (samples/medium.toml), LTB_BYTES_SIZE (128: the image is
SIZE x SIZE), LTB_BYTES_CUBE_RES (32), LTB_BYTES_2D ("0.5% 1% 2% 4% 8% 16%"),
LTB_BYTES_4D ("0.25% 0.5% 1% 2% 4%"), LTB_BYTES_QUANTIZE (extra quantize flags, e.g.
"--bits 9"), LTB_BYTES_DIR (bench/out/bytes), LTB_BYTES_NAME (bytes_on_disk_<scene><size>).
Writes bench/results/NAME.md and .csv (observations by hand: bench/results/bytes_on_disk_notes.md).
Time here (2 vCPUs, 8 maps): about 4 minutes per scene at 128².
"""
import csv
import json
import math
import os
import platform
import re
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
SCENE = os.environ.get("LTB_BYTES_SCENE", os.path.join(ROOT, "samples", "medium.toml"))
SIZE = int(os.environ.get("LTB_BYTES_SIZE", "128"))
R = int(os.environ.get("LTB_BYTES_CUBE_RES", "32"))
B2D = os.environ.get("LTB_BYTES_2D", "0.5% 1% 2% 4% 8% 16%").split()
B4D = os.environ.get("LTB_BYTES_4D", "0.25% 0.5% 1% 2% 4%").split()
QFLAGS = os.environ.get("LTB_BYTES_QUANTIZE", "").split()
OUT = os.environ.get("LTB_BYTES_DIR", os.path.join(HERE, "out", "bytes"))


def default_maps():
    d = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True).stdout.strip()
    return " ".join(sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".exr"))) if d else ""


MAPS = os.environ.get("LTB_BYTES_MAPS", None)
MAPS = (default_maps() if MAPS is None else MAPS).split()
NAME = os.environ.get("LTB_BYTES_NAME", f"bytes_on_disk_{os.path.splitext(os.path.basename(SCENE))[0]}{SIZE}")


def run(*args):
    t = time.time()
    p = subprocess.run([str(a) for a in args], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"{' '.join(map(str, args))}\n{p.stderr}")
    return p, time.time() - t


def main():
    os.makedirs(OUT, exist_ok=True)
    # The scene at SIZE x SIZE, its relative paths made absolute.
    text = open(SCENE).read()
    text = re.sub(r"(?m)^width = \d+", f"width = {SIZE}", text)
    text = re.sub(r"(?m)^height = \d+", f"height = {SIZE}", text)
    sdir = os.path.dirname(os.path.abspath(SCENE))
    text = re.sub(r'(?m)^(file|path) = "([^"/][^"]*)"', lambda m: f'{m.group(1)} = "{os.path.join(sdir, m.group(2))}"', text)
    scene = os.path.join(OUT, "scene.toml")
    open(scene, "w").write(text)
    p = lambda n: os.path.join(OUT, n)
    run(LTB, "sample", scene, "-o", p("raw.ltm"), "--cube-res", R, "-q", "--overwrite")
    run(LTB, "row-transform", p("raw.ltm"), "-o", p("rows.ltm"), "--filter", "db2", "-q", "--overwrite")
    run(LTB, "transpose", p("rows.ltm"), "-o", p("cols.ltm"), "-q", "--overwrite")
    run(LTB, "convert", p("rows.ltm"), p("rows.npy"), "-q", "--overwrite")
    os.remove(p("raw.ltm"))
    rows = []
    for depth, budgets in (("none", B2D), ("adaptive", B4D)):
        for b in budgets:
            c4, fin, npy = p("c4.ltm"), p("final.ltm"), p("final.npy")
            ct, t_ct = run(LTB, "column-transform", p("cols.ltm"), "-o", c4, "--depth", depth, "--budget", b,
                           "--json", "-q", "--overwrite")
            q, t_q = run(LTB, "quantize", c4, "-o", fin, "--json", "-q", "--overwrite", *QFLAGS)
            run(LTB, "convert", fin, npy, "-q", "--overwrite")
            err = json.loads(run("/usr/bin/python3", os.path.join(HERE, "fig7.py"), "error", p("rows.npy"), npy)[0].stdout)
            ins = json.loads(run(LTB, "inspect", fin, "--json", "--no-content")[0].stdout)["on_disk"]
            qj, cj = json.loads(q.stdout), json.loads(ct.stdout)
            l2, h1 = [], []
            for m in MAPS:
                rep = json.loads(run(LTB, "relight", fin, "--env", m, "-o", p("relit.npy"), "--terms", "all",
                                     "--reference", p("rows.ltm"), "--clamp", "--json", "-q")[0].stdout)
                l2.append(rep["error"]["rel_l2"])
                h1.append(rep["error"].get("rel_h1", float("nan")))
            rows.append({"method": "2D" if depth == "none" else "adaptive 4D", "budget": b,
                         "nonzeros": qj["nonzeros_out"], "file_bytes": os.path.getsize(fin),
                         "matrix_bytes": ins["matrix_bytes"], "side_table_bytes": ins["side_table_bytes"],
                         "overhead_bytes": ins["overhead_bytes"],
                         "bytes_per_nonzero": qj["bytes_per_nonzero"],
                         "error_unquantized": cj["relative_rms_error"],
                         "error": next(iter(err["tests"].values()))["rel_rms_error"],
                         "relit_l2": sum(l2) / len(l2) if l2 else float("nan"),
                         "relit_h1": sum(h1) / len(h1) if h1 else float("nan"), "seconds": round(t_ct + t_q, 2)})
            os.remove(npy)
            print(rows[-1], flush=True)
    os.remove(p("rows.npy"))
    if os.path.exists(p("relit.npy")):
        os.remove(p("relit.npy"))
    with open(os.path.join(HERE, "results", NAME + ".csv"), "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=list(rows[0].keys()))
        w.writeheader()
        w.writerows(rows)
    two = sorted((r["error"], r["file_bytes"]) for r in rows if r["method"] == "2D")

    def bytes_2d_at(e):  # log-log interpolation on the 2D curve; None outside it
        for (e0, b0), (e1, b1) in zip(two, two[1:]):
            if e0 <= e <= e1 and e1 > e0:
                t = (math.log(e) - math.log(e0)) / (math.log(e1) - math.log(e0))
                return math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0)))
        return None

    two_relit = sorted((r["relit_l2"], r["file_bytes"]) for r in rows if r["method"] == "2D")

    def bytes_2d_at_relit(e):
        for (e0, b0), (e1, b1) in zip(two_relit, two_relit[1:]):
            if e0 <= e <= e1 and e1 > e0:
                t = (math.log(e) - math.log(e0)) / (math.log(e1) - math.log(e0))
                return math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0)))
        return None

    git = subprocess.run(["git", "-C", ROOT, "rev-parse", "--short", "HEAD"], capture_output=True, text=True).stdout.strip()
    lines = [f"# Bytes on disk at equal matrix error: 2D against adaptive 4D ({NAME})", "",
             f"Generated by `bench/bytes_on_disk.py`. Scene {os.path.relpath(SCENE, ROOT)} at {SIZE}x{SIZE} "
             f"pixels, R = {R} ({6 * R * R} lights), db2 rows, LeGall 5/3 columns, global budgets, "
             f"quantize {' '.join(QFLAGS) or '(default: --error-ratio 1.1)'}; git {git}; "
             f"{time.strftime('%Y-%m-%d %H:%M UTC', time.gmtime())}; {platform.node()} ({os.cpu_count()} CPUs).",
             "Error: NumPy ||T - T'||_F / ||T||_F of the decoded final.ltm against rows.ltm. "
             "Ratio: the 2D file's bytes at the same error (log-log interpolation of the 2D curve) over the 4D file's.", "",
             f"Relit: rel. L2 and H1 against rows.ltm with every lighting term, averaged over {len(MAPS)} maps "
             f"({', '.join(os.path.basename(m) for m in MAPS) or 'none'}); the last column compares bytes at equal relit L2.", "",
             "| method | budget | nonzeros | final.ltm bytes | matrix | side tables | container | bytes/nz | error (unquantized) | error | 2D bytes / 4D bytes at this error | relit L2 | relit H1 | 2D / 4D bytes at this relit L2 |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        ratio = ratio_relit = ""
        if r["method"] != "2D":
            b2 = bytes_2d_at(r["error"])
            ratio = f"{b2 / r['file_bytes']:.2f}x" if b2 else "(outside the 2D curve)"
            b2r = bytes_2d_at_relit(r["relit_l2"])
            ratio_relit = f"{b2r / r['file_bytes']:.2f}x" if b2r else "(outside the 2D curve)"
        lines.append(f"| {r['method']} | {r['budget']} | {r['nonzeros']:,} | {r['file_bytes']:,} | {r['matrix_bytes']:,} | "
                     f"{r['side_table_bytes']:,} | {r['overhead_bytes']:,} | {r['bytes_per_nonzero']:.3f} | "
                     f"{r['error_unquantized']:.4f} | {r['error']:.4f} | {ratio} | {r['relit_l2']:.4f} | {r['relit_h1']:.4f} | {ratio_relit} |")
    open(os.path.join(HERE, "results", NAME + ".md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


main()
