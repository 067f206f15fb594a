"""`ltbake run --shards N` with the local engine (a process pool; no Slurm needed).

- A 3-shard bake gives the same content_hash for every output as the unsharded bake, each
  output a stage manifest; run.json records the engine, the shard count and every shard.
- A rerun skips every stage; a rerun with another shard count also skips (same content).
- A shard deleted after the commit: the rerun reruns that shard alone, commits again, and
  the stages after it are skipped (same content).
- A shard that fails (its file's path is taken by a directory) fails the run, naming the
  shard, its log and the command that reruns it; once fixed, the rerun runs only that
  shard (the others are "skipped": done in the recorded attempt, fingerprints unchanged).
- SIGINT during a sharded stage: exit 130; the rerun does not rerun finished shards.
- cpca in a sharded bake runs once, on the rows manifest, and gives the unsharded result.
- Intermediates that are not kept are deleted with their shard directories.
- --engine slurm without sbatch on $PATH: a clear error.

usage: run_shards_test.py PATH_TO_LTBAKE
"""
import json
import os
import shutil
import signal
import subprocess
import sys
import tempfile
import time

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run, run_report, write  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
TINY = os.path.join(REPO, "samples", "tiny.toml")
OUTPUTS = ["rows", "cols", "cols4d", "final"]
NODES = ["sample+row-transform", "transpose", "column-transform", "quantize"]


def report(workdir):
    return {s["node"]: s for s in run_report(workdir)["stages"]}


def content_hash(path):
    return json.loads(run("inspect", "--json", path).stdout).get("content_hash")


def is_manifest(path):
    with open(path, "rb") as f:
        return f.read(17) == b"LTBAKE-MANIFEST 1"


tmp = tempfile.mkdtemp(prefix="ltbake-run-shards-")
try:
    recipe = write(os.path.join(tmp, "bake.toml"), f'''name = "s"
scene = "{TINY}"
keep = ["rows", "cols", "cols4d"]
[sample]
cube_res = 8
spp = 8
''')
    whole = os.path.join(tmp, "whole")
    run("run", recipe, "--workdir", whole, "-q")
    ref = {f: content_hash(os.path.join(whole, f + ".ltm")) for f in OUTPUTS}
    check(all(ref.values()), f"unsharded bake outputs have no content_hash: {ref}")

    # --- 3 shards, local engine --------------------------------------------------------
    sh = os.path.join(tmp, "sh3")
    p = run("run", recipe, "--workdir", sh, "--shards", "3", "--jobs", "2")
    for f in OUTPUTS:
        path = os.path.join(sh, f + ".ltm")
        check(os.path.exists(path) and is_manifest(path), f"{f}.ltm is not a stage manifest")
        check(content_hash(path) == ref[f], f"{f}.ltm: content_hash {content_hash(path)}, unsharded {ref[f]}")
        check(len(os.listdir(os.path.join(sh, f + ".shards"))) == 3, f"{f}.shards does not hold 3 shard files")
    rep = report(sh)
    for n in NODES:
        e = rep[n]
        check(e.get("engine") == "local" and e.get("nshards") == 3, f"{n}: engine/nshards not recorded: {e}")
        check([s["status"] for s in e.get("shards", [])] == ["done"] * 3, f"{n}: shard records {e.get('shards')}")
        check(all(os.path.exists(s["log"]) for s in e.get("shards", [])), f"{n}: a shard log is missing")
        check(e["output"]["content_hash"] == ref[{"sample+row-transform": "rows", "transpose": "cols",
                                                    "column-transform": "cols4d", "quantize": "final"}[n]],
              f"{n}: run.json content_hash differs from the unsharded one")
    check("committed" in p.stdout and "3 of 3 shards to run" in p.stdout, f"no shard progress lines:\n{p.stdout}")
    run("verify", os.path.join(sh, "final.ltm"))

    p = run("run", recipe, "--workdir", sh, "--shards", "3")
    check(all(e["action"] == "skip" for e in report(sh).values()), f"rerun did not skip everything:\n{p.stdout}")
    p = run("run", recipe, "--workdir", sh, "--shards", "2")
    check(all(e["action"] == "skip" for e in report(sh).values()),
          f"rerun with another shard count did not skip (same content):\n{p.stdout}")

    # A shard deleted after the commit: the rerun reruns that shard alone and commits again.
    os.remove(os.path.join(sh, "cols.shards", "00001-of-00003.ltm"))
    p = run("run", recipe, "--workdir", sh, "--shards", "3")
    rep = report(sh)
    st = {s["index"]: s["status"] for s in rep["transpose"].get("shards", [])}
    check(rep["transpose"]["action"] == "resume" and st == {0: "skipped", 1: "done", 2: "skipped"},
          f"a deleted shard: transpose {rep['transpose']['action']}, shards {st}\n{p.stdout}")
    check(rep["column-transform"]["action"] == "skip", "column-transform was redone after transpose's shard came back")
    check(content_hash(os.path.join(sh, "cols.ltm")) == ref["cols"], "cols.ltm after the shard came back differs")

    # --- a failing shard, then a rerun of only that shard ----------------------------------
    fl = os.path.join(tmp, "fail")
    os.makedirs(os.path.join(fl, "rows.shards", "00001-of-00003.ltm"))  # shard 1 cannot write its file
    p = run("run", recipe, "--workdir", fl, "--shards", "3", expect=1)
    check("1 of 3 shards failed" in p.stderr and "shard 1 (" in p.stderr, f"the failure does not name shard 1:\n{p.stderr}")
    check("sample+row-transform.shard-1.log" in p.stderr, f"the failure does not name shard 1's log:\n{p.stderr}")
    check("--shard 1 --nshards 3" in p.stderr, f"no command that reruns shard 1:\n{p.stderr}")
    check(not os.path.exists(os.path.join(fl, "rows.ltm")), "rows.ltm written although a shard failed")
    st = {s["index"]: s["status"] for s in report(fl)["sample+row-transform"]["shards"]}
    check(st == {0: "done", 1: "failed", 2: "done"}, f"shard records after the failure: {st}")
    os.rmdir(os.path.join(fl, "rows.shards", "00001-of-00003.ltm"))
    before = {i: os.stat(os.path.join(fl, "rows.shards", f"0000{i}-of-00003.ltm")).st_mtime_ns for i in (0, 2)}
    p = run("run", recipe, "--workdir", fl, "--shards", "3")
    check("1 of 3 shards to run" in p.stdout, f"the rerun did not run just one shard:\n{p.stdout}")
    st = {s["index"]: (s["status"], s["attempts"]) for s in report(fl)["sample+row-transform"]["shards"]}
    check(st == {0: ("skipped", 0), 1: ("done", 1), 2: ("skipped", 0)}, f"shard records after the rerun: {st}")
    after = {i: os.stat(os.path.join(fl, "rows.shards", f"0000{i}-of-00003.ltm")).st_mtime_ns for i in (0, 2)}
    check(before == after, "a shard that was done was rewritten")
    check(content_hash(os.path.join(fl, "final.ltm")) == ref["final"], "final.ltm after the rerun differs")

    # --- SIGINT during a sharded stage ----------------------------------------------------------
    slow = write(os.path.join(tmp, "slow.toml"), f'''name = "slow"
scene = "{TINY}"
targets = ["row-transform"]
[sample]
cube_res = 32
spp = 64
''')
    si = os.path.join(tmp, "sigint")
    proc = subprocess.Popen([LTBAKE, "run", slow, "--workdir", si, "--shards", "4", "--jobs", "2"],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.time() + 60
    # Shard 0 sees few rows and finishes first; interrupt once it has.
    done0 = os.path.join(si, "rows.shards", "00000-of-00004.ltm")
    while time.time() < deadline:
        r = subprocess.run([LTBAKE, "inspect", "--json", "--no-content", done0], capture_output=True, text=True)
        if r.returncode == 0 and json.loads(r.stdout).get("complete"):
            break
        time.sleep(0.05)
    proc.send_signal(signal.SIGINT)
    out, err = proc.communicate(timeout=120)
    check(proc.returncode == 130, f"SIGINT: exit {proc.returncode}, expected 130\n{out}{err}")
    recs = {s["index"]: s["status"] for s in report(si)["sample+row-transform"]["shards"]}
    check(recs.get(0) == "done" and "interrupted" in recs.values(), f"shard records after SIGINT: {recs}")
    p = run("run", slow, "--workdir", si, "--shards", "4")
    recs = {s["index"]: s["status"] for s in report(si)["sample+row-transform"]["shards"]}
    check(recs.get(0) == "skipped", f"shard 0 was rerun after SIGINT: {recs}")
    p2 = run("run", slow, "--workdir", os.path.join(tmp, "slow-whole"), "-q")
    check(content_hash(os.path.join(si, "rows.ltm")) == content_hash(os.path.join(tmp, "slow-whole", "rows.ltm")),
          "rows.ltm after SIGINT and rerun differs from the unsharded bake")

    # --- cpca in a sharded bake; intermediates deleted with their shards ---------------------
    cp = write(os.path.join(tmp, "cpca.toml"), f'''name = "c"
scene = "{TINY}"
targets = ["cpca"]
keep = []
[sample]
cube_res = 8
spp = 8
[cpca]
clusters = 4
basis = 3
''')
    c1, c3 = os.path.join(tmp, "c1"), os.path.join(tmp, "c3")
    run("run", cp, "--workdir", c1, "-q")
    run("run", cp, "--workdir", c3, "--shards", "3", "-q")
    check(content_hash(os.path.join(c3, "cpca.ltm")) == content_hash(os.path.join(c1, "cpca.ltm")),
          "cpca on a rows manifest differs from cpca on the unsharded rows")
    e = report(c3)["cpca"]
    check("shards" not in e, "cpca ran as shards")
    check(not os.path.exists(os.path.join(c3, "rows.ltm")) and not os.path.exists(os.path.join(c3, "rows.shards")),
          "rows.ltm (not kept) or its shard directory was left behind")

    # --- slurm engine without sbatch -------------------------------------------------------------
    env = dict(os.environ, PATH="/nonexistent")
    p = subprocess.run([LTBAKE, "run", recipe, "--workdir", os.path.join(tmp, "nosl"), "--engine", "slurm",
                        "--shards", "2"], capture_output=True, text=True, env=env, timeout=120)
    check(p.returncode == 1 and "sbatch is not on $PATH" in p.stderr and "--engine local" in p.stderr,
          f"--engine slurm without sbatch: exit {p.returncode}\n{p.stderr}")
finally:
    shutil.rmtree(tmp, ignore_errors=True)
finish()
