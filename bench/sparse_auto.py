#!/usr/bin/python3
"""`sample --sparse auto` against the full bake and the forced sparse bake, on scenes no test
or default was tuned on (bench/unseen_meshes.py: npm teapot and snowden in the medium scene).

Issue "skip what a scene does not need", item 2: with cheap rays sparse must never be slower
than the full sample (a pilot decides and says why); where rays are expensive (bounces, spp)
it should pay. Per scene and (bounces, spp), in the same script and alternating:
  full   `ltbake sample SCENE -o full.ltm`
  force  `... --sparse`            (sparse regardless)
  auto   `... --sparse auto`       (the pilot decides; its record gives the decision, its
                                    predicted speed-up and its own wall time)
each REPEATS times (outputs and checkpoints removed before each run), --jobs 2; wall seconds
(perf_counter around the child) and CPU seconds of the child (os.wait4). Reports medians,
the ratios full/force and full/auto (the speed-up; < 1 is slower), the pilot's predicted
full/force ratio against the measured one, and whether auto picked the faster way.

    /usr/bin/python3 bench/sparse_auto.py [BUILD_DIR=build]

Knobs: LTB_AUTO_WIDTH (128), LTB_AUTO_REPEATS (3), LTB_AUTO_CASES ("0:4,1:4,2:4,0:16":
bounces:spp), LTB_AUTO_SCENES (teapot,snowden). Writes bench/results/sparse_auto.md and .json.
"""
import json
import os
import statistics
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import benchlib  # noqa: E402
import unseen_meshes  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(HERE, "..", "build"))
LTBAKE = os.path.join(BUILD, "ltbake")
OUT = os.path.join(HERE, "out", "sparse_auto")
WIDTH = int(os.environ.get("LTB_AUTO_WIDTH", "128"))
REPEATS = int(os.environ.get("LTB_AUTO_REPEATS", "3"))
CASES = [tuple(int(x) for x in c.split(":")) for c in os.environ.get("LTB_AUTO_CASES", "0:4,1:4,2:4,0:16").split(",")]
SCENES = os.environ.get("LTB_AUTO_SCENES", "teapot,snowden").split(",")


def run_child(args):
    """wall, cpu seconds and stdout of `ltbake ARGS` (os.wait4 for the child's rusage)."""
    t0 = time.perf_counter()
    p = subprocess.Popen([LTBAKE, *map(str, args)], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    out = p.stdout.read()
    err = p.stderr.read()
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if status != 0:
        raise SystemExit(f"ltbake {' '.join(map(str, args))} failed ({status}):\n{err.decode()}")
    return wall, ru.ru_utime + ru.ru_stime, out.decode()


def clean(path):
    for p in (path, path + ".dense.ltm"):
        if os.path.exists(p):
            os.remove(p)


def main():
    os.makedirs(OUT, exist_ok=True)
    scenes = unseen_meshes.scenes(os.path.join(HERE, "out", "unseen"), WIDTH)
    rows = []
    for name in SCENES:
        scene = scenes[name]
        for bounces, spp in CASES:
            common = ["--bounces", bounces, "--spp", spp, "--jobs", 2, "--progress", "never", "--json"]
            modes = {"full": [], "force": ["--sparse", "force"], "auto": ["--sparse", "auto"]}
            times = {m: [] for m in modes}
            record = None
            for _ in range(REPEATS):
                for mode, extra in modes.items():
                    out = os.path.join(OUT, f"{name}_{mode}.ltm")
                    clean(out)
                    wall, cpu, text = run_child(["sample", scene, "-o", out, *common, *extra])
                    times[mode].append((wall, cpu))
                    if mode == "auto":
                        record = json.loads(text)["sparse_auto"]
            med = {m: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for m, v in times.items()}
            pred = record["predicted_cpu_seconds"]
            row = {"scene": name, "bounces": bounces, "spp": spp, "repeats": REPEATS,
                   "wall": {m: med[m][0] for m in med}, "cpu": {m: med[m][1] for m in med},
                   "decision": record["decision"], "pilot_seconds": record["pilot_seconds"],
                   "predicted_speedup": pred["full"] / pred["sparse"] if pred["sparse"] > 0 else None,
                   "measured_speedup_cpu": med["full"][1] / med["force"][1],
                   "measured_speedup_wall": med["full"][0] / med["force"][0],
                   "auto_vs_full_wall": med["full"][0] / med["auto"][0],
                   "auto_vs_best_wall": min(med["full"][0], med["force"][0]) / med["auto"][0],
                   "reason": record["reason"]}
            rows.append(row)
            print(f"{name} b{bounces} spp{spp}: full {med['full'][0]:.2f} s, force {med['force'][0]:.2f} s, "
                  f"auto {med['auto'][0]:.2f} s ({record['decision']}); predicted {row['predicted_speedup']:.2f}x, "
                  f"measured {row['measured_speedup_cpu']:.2f}x (CPU)", flush=True)
    with open(os.path.join(HERE, "results", "sparse_auto.json"), "w") as f:
        json.dump(rows, f, indent=1)
    write_md(rows)


def write_md(rows):
    load = os.getloadavg()
    lines = ["# `sample --sparse auto` against the full and the forced sparse bake (bench/sparse_auto.py)", "",
             f"Machine: {benchlib.machine()}; load average at the end {load[0]:.2f} {load[1]:.2f} {load[2]:.2f}. "
             f"ltbake at `{benchlib.git_describe()}`. Scenes: bench/unseen_meshes.py (npm teapot, snowden) at "
             f"{WIDTH}², R = 32; medians of {rows[0]['repeats'] if rows else 0} alternating runs, --jobs 2.", "",
             "Speed-up = full bake's median time / the mode's (above 1: faster than the full bake). "
             "'auto picked' is right when it chose the way whose measured wall time is lower (or within 10%).", "",
             "| scene | bounces | spp | full s | force s | auto s | auto chose | predicted full/sparse (CPU) "
             "| measured full/force (CPU) | measured full/force (wall) | auto vs full (wall) | auto vs the faster (wall) "
             "| pilot s |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['scene']} | {r['bounces']} | {r['spp']} | {r['wall']['full']:.2f} | {r['wall']['force']:.2f} "
                     f"| {r['wall']['auto']:.2f} | {r['decision']} | {r['predicted_speedup']:.2f}× "
                     f"| {r['measured_speedup_cpu']:.2f}× | {r['measured_speedup_wall']:.2f}× "
                     f"| {r['auto_vs_full_wall']:.2f}× | {r['auto_vs_best_wall']:.2f}× | {r['pilot_seconds']:.2f} |")
    lines += ["", "The pilot's reasons:", ""]
    for r in rows:
        lines.append(f"- {r['scene']}, bounces {r['bounces']}, spp {r['spp']}: {r['reason']}")
    with open(os.path.join(HERE, "results", "sparse_auto.md"), "w") as f:
        f.write("\n".join(lines) + "\n")


if __name__ == "__main__":
    main()
