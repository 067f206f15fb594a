"""`ltbake run` on a full disk: the work directory is a 2 MiB tmpfs (mounted in a private
mount namespace, so nothing leaks to the host). The bake must fail with a clear "no space"
message naming the file, leave every committed chunk readable, and resume once space is
freed (the tmpfs is grown), ending with the same content_hash as a bake on a roomy disk.

Needs root or unprivileged user namespaces to mount the tmpfs; exits 77 (ctest: skipped)
when neither is available.

usage: run_disk_full_test.py PATH_TO_LTBAKE
"""
import json
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
MARK = "disk-full test: inside a private mount namespace"

if "--inside" not in sys.argv:
    # Re-run this script in a private mount namespace: as root, or as a mapped root user.
    for unshare in (["unshare", "-m", "--propagation", "private"], ["unshare", "-r", "-m", "--propagation", "private"]):
        try:
            p = subprocess.run([*unshare, sys.executable, os.path.abspath(__file__), LTBAKE, "--inside"],
                               capture_output=True, text=True, timeout=900)
        except FileNotFoundError:
            break
        if MARK in p.stdout:
            sys.stdout.write(p.stdout)
            sys.stderr.write(p.stderr)
            sys.exit(p.returncode)
    print("skipped: cannot create a mount namespace to mount a small tmpfs (needs root or user namespaces)")
    sys.exit(77)

print(MARK)
with tempfile.TemporaryDirectory() as d:
    recipe = os.path.join(d, "tiny.toml")
    with open(recipe, "w") as f:
        f.write(f'name = "tiny"\nscene = "{os.path.join(REPO, "samples", "tiny.toml")}"\n')
    # The reference bake on a roomy disk.
    run("run", recipe, "--workdir", os.path.join(d, "ref"), "-q")
    ref = json.loads(run("inspect", "--json", os.path.join(d, "ref", "final.ltm")).stdout)["content_hash"]

    mnt = os.path.join(d, "small")
    os.mkdir(mnt)
    m = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=2m", "tmpfs", mnt], capture_output=True, text=True)
    if m.returncode != 0:
        print(f"skipped: cannot mount a tmpfs here: {m.stderr.strip()}")
        sys.exit(77)
    try:
        w = os.path.join(mnt, "w")
        p = run("run", recipe, "--workdir", w, expect=1)
        err = p.stderr
        check("No space left on device" in err, f"full disk: no 'no space' message:\n{err}")
        named = re.search(r"(" + re.escape(w) + r"/\S+\.ltm)", err)
        check(named is not None, f"full disk: the message names no file in the work directory:\n{err}")
        check("re-run just this stage:" in err and "free space" in err, f"full disk: no way forward given:\n{err}")
        check("chunk" in err, f"full disk: the message names no chunk:\n{err}")
        committed = {}
        for f in sorted(os.listdir(w)):
            if not f.endswith(".ltm"):
                continue
            path = os.path.join(w, f)
            v = json.loads(run("verify", "--allow-incomplete", "--json", path).stdout)[0]
            check(v["ok"], f"full disk: {f} does not verify: {v}")
            info = json.loads(run("inspect", "--json", "--no-content", path).stdout)
            committed[f] = sum(a["chunks"]["committed"] for a in info["arrays"])
        check(len(committed) >= 1, f"full disk: nothing was written at all: {os.listdir(w)}")
        stage = re.search(r"stage (\S+) failed", err)
        check(stage is not None, f"full disk: the message names no stage:\n{err}")
        failed = stage.group(1) if stage else "?"
        # run.json itself may not fit any more; the last one written still says which files are ours
        report = json.load(open(os.path.join(w, "run.json")))
        check(any(s["node"] == failed for s in report["stages"]), f"run.json has no record of {failed}")
        print(f"full disk: the bake stopped in {failed}; committed chunks: {committed}")

        # Free space (grow the tmpfs) and rerun: the failed stage resumes and the bake ends
        # with the reference content.
        subprocess.run(["mount", "-o", "remount,size=64m", mnt], check=True)
        p = run("run", recipe, "--workdir", w)
        check(re.search(re.escape(failed) + r": resume ", p.stdout) is not None,
              f"after freeing space: {failed} does not resume:\n{p.stdout}")
        for f, n in committed.items():
            info = json.loads(run("inspect", "--json", "--no-content", os.path.join(w, f)).stdout)
            check(sum(a["chunks"]["committed"] for a in info["arrays"]) >= n, f"{f}: committed chunks were lost")
        got = json.loads(run("inspect", "--json", os.path.join(w, "final.ltm")).stdout)["content_hash"]
        check(got == ref, f"after freeing space: final.ltm {got} != reference {ref}")
    finally:
        subprocess.run(["umount", mnt])

finish()
