#!/usr/bin/python3
"""One ltbake command run by two builds in alternation, for a speed-up that must not change
the output: median wall and CPU time of each build, their ratios, and whether every array's
content_hash of the two outputs is the same.

    /usr/bin/python3 bench/ab_builds.py OLD/ltbake NEW/ltbake [--runs 5] -- quantize IN -o OUT [...]

The command's `-o OUT` is removed before every run (a stage resumes an existing output) and
suffixed .a / .b per build. Prints a Markdown table row set; the machine is named.
"""
import argparse
import json
import os
import statistics
import subprocess
import sys
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import benchlib  # noqa: E402


def run(cmd):
    t0 = time.perf_counter()
    p = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    _, status, ru = os.wait4(p.pid, 0)
    wall = time.perf_counter() - t0
    if os.waitstatus_to_exitcode(status) != 0:
        raise SystemExit(f"{' '.join(cmd)} failed: {p.stderr.read().decode()}")
    return wall, ru.ru_utime + ru.ru_stime


def hashes(ltbake, path):
    out = subprocess.run([ltbake, "inspect", path, "--content", "--json"], capture_output=True, text=True, check=True)
    return {a["name"]: a["content_hash"] for a in json.loads(out.stdout)["arrays"]}


def main():
    argv = sys.argv[1:]
    if "--" not in argv:
        raise SystemExit(__doc__)
    cut = argv.index("--")
    ap = argparse.ArgumentParser()
    ap.add_argument("old")
    ap.add_argument("new")
    ap.add_argument("--runs", type=int, default=5)
    args = ap.parse_args(argv[:cut])
    cmd = argv[cut + 1:]
    if "-o" not in cmd:
        raise SystemExit("the command needs -o OUT")
    out = cmd[cmd.index("-o") + 1]
    times = {"a": [], "b": []}
    for _ in range(args.runs):
        for tag, exe in (("a", args.old), ("b", args.new)):
            o = f"{out}.{tag}"
            if os.path.exists(o):
                os.remove(o)
            c = list(cmd)
            c[c.index("-o") + 1] = o
            times[tag].append(run([exe, *c]))
    same = hashes(args.new, f"{out}.a") == hashes(args.new, f"{out}.b")
    med = {t: (statistics.median(w for w, _ in v), statistics.median(c for _, c in v)) for t, v in times.items()}
    print(f"{benchlib.machine()}; {args.runs} alternating runs each; `ltbake {' '.join(cmd)}`")
    print("| build | median wall s | median CPU s |\n|---|---|---|")
    for t, name in (("a", args.old), ("b", args.new)):
        print(f"| {name} | {med[t][0]:.3f} | {med[t][1]:.3f} |")
    print(f"old / new: wall {med['a'][0] / med['b'][0]:.2f}x, CPU {med['a'][1] / med['b'][1]:.2f}x; "
          f"content_hash of every array {'the same' if same else 'DIFFERS'}")
    for t in ("a", "b"):
        os.remove(f"{out}.{t}")
    return 0 if same else 1


if __name__ == "__main__":
    sys.exit(main())
