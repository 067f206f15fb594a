"""Kill storm: `ltbake run` of the tiny scene (at R = 32 so every stage has work) is
SIGKILLed at 30 random moments spread over all its stages (sample + row-transform fused,
transpose, column-transform, quantize, relight), resuming each time.

After every kill: every container in the work directory verifies (committed chunks intact)
and run.json still parses. On every resume: each stage that had finished is skipped, never
redone, and the interrupted one resumes or starts (never "redo"). In the end the outputs
have the same content_hash as an uninterrupted bake. The overhead (time of all attempts
against the uninterrupted bake) is printed.

usage: run_kill_storm_test.py PATH_TO_LTBAKE [--seed N] [--kills N]
"""
import json
import os
import random
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run, scaled  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
SEED = int(sys.argv[sys.argv.index("--seed") + 1]) if "--seed" in sys.argv else 20261122
KILLS = int(sys.argv[sys.argv.index("--kills") + 1]) if "--kills" in sys.argv else scaled(30, minimum=10)
rng = random.Random(SEED)
NODES = ["sample+row-transform", "transpose", "column-transform", "quantize", "relight:sky"]


def wait_for_group(pgid, timeout=10.0):
    """Waits until no process of the bake's group is left (the stage dies with the run)."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            os.killpg(pgid, 0)
        except ProcessLookupError:
            return True
        time.sleep(0.01)
    return False


def verify_all(w, label):
    for f in sorted(os.listdir(w)):
        if f.endswith(".ltm"):
            v = json.loads(run("verify", "--allow-incomplete", "--json", os.path.join(w, f)).stdout)[0]
            check(v["ok"], f"{label}: {f} does not verify: {v}")
    if os.path.exists(os.path.join(w, "run.json")):
        try:
            json.load(open(os.path.join(w, "run.json")))
        except ValueError as e:
            check(False, f"{label}: run.json does not parse: {e}")


with tempfile.TemporaryDirectory() as d:
    R = 32
    g = np.random.default_rng(7)
    env = np.abs(g.standard_normal((6 * R * R, 3))).astype(np.float32)  # a random sky
    np.save(os.path.join(d, "sky.npy"), env)
    recipe = os.path.join(d, "storm.toml")
    with open(recipe, "w") as f:
        f.write(f'''name = "storm"
scene = "{os.path.join(REPO, "samples", "tiny.toml")}"
[sample]
cube_res = {R}
spp = 8
[relight]
envs = ["sky.npy"]
terms = 200
''')

    # The uninterrupted bake: reference hashes and per-stage wall times.
    ref_dir = os.path.join(d, "ref")
    t0 = time.monotonic()
    run("run", recipe, "--workdir", ref_dir, "-q")
    ref_wall = time.monotonic() - t0
    ref_report = json.load(open(os.path.join(ref_dir, "run.json")))
    walls = {s["node"]: s["wall_seconds"] for s in ref_report["stages"]}
    ref = {s["node"]: s["output"]["content_hash"] for s in ref_report["stages"]}
    check(sorted(walls) == sorted(NODES), f"reference bake ran {sorted(walls)}")
    print("uninterrupted stage wall times:", {k: round(v, 3) for k, v in walls.items()})

    w = os.path.join(d, "w")
    kills, bakes, attempts, spent = {n: 0 for n in NODES + ["between"]}, 0, 0, 0.0
    done_before = set()

    def complete_bake(label):
        """Runs the current bake to its end without a kill and checks it against the reference."""
        global bakes, spent
        t = time.monotonic()
        p = run("run", "-q", recipe, "--workdir", w)
        spent += time.monotonic() - t
        got = {s["node"]: s["output"]["content_hash"] for s in json.load(open(os.path.join(w, "run.json")))["stages"]}
        check(p.returncode == 0 and got == ref, f"{label}: outputs differ from the uninterrupted bake: {got} vs {ref}")
        bakes += 1

    # An equal share of the kills aimed at each stage, in random order.
    schedule = [n for n in NODES for _ in range((KILLS + len(NODES) - 1) // len(NODES))][:KILLS]
    rng.shuffle(schedule)
    for target in schedule:
        if target in done_before:  # that stage is done in this bake: finish it, start another
            complete_bake(f"bake {bakes}")
            shutil.rmtree(w)
            done_before = set()
        for _ in range(20):  # until a kill lands (a run may finish before it)
            lines = []
            proc = subprocess.Popen([LTBAKE, "run", recipe, "--workdir", w], stdout=subprocess.PIPE,
                                    stderr=subprocess.DEVNULL, text=True, start_new_session=True)
            started = threading.Event()

            def reader():
                for line in proc.stdout:
                    lines.append(line)
                    if line.startswith(f"== {target}:"):
                        started.set()
                started.set()

            th = threading.Thread(target=reader)
            t_start = time.monotonic()
            th.start()
            started.wait(timeout=120)
            time.sleep(rng.uniform(0.0, 1.3 * walls.get(target, 0.05) + 0.01))
            killed = proc.poll() is None
            if killed:
                proc.send_signal(signal.SIGKILL)
            proc.wait()
            th.join()
            spent += time.monotonic() - t_start
            attempts += 1
            check(wait_for_group(proc.pid), f"attempt {attempts}: a stage outlived the killed run")
            out = "".join(lines)
            # Bounded redo: what had finished before is skipped, the interrupted stage resumes.
            for node in done_before:
                if f"== {node}:" in out:
                    check(f"== {node}: skipped" in out,
                          f"attempt {attempts}: {node} had finished but was not skipped:\n{out}")
            check(": redo " not in out, f"attempt {attempts}: a stage was redone from scratch:\n{out}")
            verify_all(w, f"attempt {attempts}")
            if not killed:
                check(proc.returncode == 0, f"attempt {attempts}: the run failed (exit {proc.returncode}):\n{out}")
                got = {s["node"]: s["output"]["content_hash"]
                       for s in json.load(open(os.path.join(w, "run.json")))["stages"]}
                check(got == ref, f"bake {bakes}: outputs differ from the uninterrupted bake: {got} vs {ref}")
                bakes += 1
                shutil.rmtree(w)
                done_before = set()
                continue
            last = [l for l in lines if l.startswith("== ") and ": skipped" not in l]
            where = re.match(r"== (\S+): ", last[-1]).group(1) if last else "between"
            kills[where if where in kills else "between"] += 1
            if "-v" in sys.argv:
                print(f"target {target}, killed in {where}: {[l.strip() for l in last]}")
            try:
                rep = json.load(open(os.path.join(w, "run.json")))
                done_before = {s["node"] for s in rep["stages"] if s.get("status") == "done" and s["node"] in NODES
                               and os.path.exists(os.path.join(w, s["output"]["file"]))}
            except (OSError, ValueError):
                done_before = set()
            break
    complete_bake("after the storm")
    print(f"kill storm: {sum(kills.values())} kills over {attempts} attempts ({kills}); {bakes} bakes completed")
    print(f"time of all attempts {spent:.2f} s for {bakes} bakes = {spent / bakes:.2f} s per bake, "
          f"uninterrupted {ref_wall:.2f} s: overhead x{spent / bakes / ref_wall:.2f} "
          f"(each kill restarts a process and loses the chunks in flight)")

finish()
