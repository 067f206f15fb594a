"""Hostile inputs around the .ltm container: what is not a regular file, an
interrupted seal read by verify, forged manifest hashes, bad flag values, and two writers
racing for one output.

  - a FIFO, a directory, a device or a socket given as input (or output) is refused at once
    with exit 1 and a message naming the path and what it is (no wait for a FIFO writer);
  - verify reads a container whose seal ran out of space (a zero-extended hole on a full
    tmpfs) without SIGBUS, as incomplete;
  - verify recomputes a manifest's content_hash / hash_sum records;
  - a bad flag value is a usage error (exit 2) naming the flag and the value;
  - for every stage that writes, writer B started while writer A holds the output is
    refused (exit 1, "OUT is in use by PID <A>"), leaves the output untouched, and A then
    finishes with the content_hash of a solo run. A is SIGSTOPped once it holds the lock
    (a condition, not a time), so the race is the same on every run;
  - `ltbake run` takes its work-directory lock before it reads run.json.

usage: hostile_container_test.py PATH_TO_LTBAKE
"""
import fcntl
import hashlib
import json
import os
import shutil
import signal
import socket
import struct
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
from ltbtest import LTBAKE, check, finish, run  # noqa: E402
from hostile import interrupt_while_running, run_hostile  # noqa: E402

REPO = os.path.abspath(os.path.join(HERE, "..", ".."))
TINY = os.path.join(REPO, "samples", "tiny.toml")
SEAL_MARK = "hostile seal case: inside a private mount namespace"


def content_hash(path):
    p = run("inspect", "--json", path)
    return json.loads(p.stdout)["content_hash"] if p.returncode == 0 else None


def verify_ok(path):
    p = run("verify", "--json", path, expect=None)
    return p.returncode == 0 and json.loads(p.stdout)[0]["ok"]


def interrupted_seal(src, dst, truncate_to=None):
    """Writes `src` (a sealed container) to `dst` as a writer stopped while sealing leaves
    it: every chunk, the index frame's header, then zeros (a hole: the file was extended
    with ftruncate) where the index payload goes; no trailer."""
    b = open(src, "rb").read()
    index_offset = struct.unpack_from("<Q", b, len(b) - 64 + 8)[0]  # trailer: magic, index_offset
    with open(dst, "wb") as f:
        f.write(b[:index_offset + 64])
        f.truncate(truncate_to if truncate_to is not None else len(b) - 64)


# --- the tmpfs case runs in a private mount namespace (re-executed) --------------------------
if "--seal-inside" in sys.argv:
    print(SEAL_MARK)
    src, mnt = sys.argv[sys.argv.index("--seal-inside") + 1:][:2]
    room = (os.path.getsize(src) // 4096 + 4) * 4096  # the file, a few pages to spare
    m = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={room}", "tmpfs", mnt], capture_output=True, text=True)
    if m.returncode != 0:
        print(f"skipped: cannot mount a tmpfs: {m.stderr.strip()}")
        sys.exit(77)
    seal = os.path.join(mnt, "seal.ltm")
    interrupted_seal(src, seal)
    try:  # fill the tmpfs: the hole can no longer be given a page
        with open(os.path.join(mnt, "fill"), "wb") as f:
            while True:
                f.write(b"\1" * 4096)
                f.flush()
    except OSError:
        pass
    code, err = run_hostile(["verify", seal], expect=(1,), time_limit=60, what="verify, seal out of space")
    out = subprocess.run([LTBAKE, "verify", seal], capture_output=True, text=True, timeout=60).stdout
    check("INCOMPLETE" in out and "not sealed" in out, f"verify, seal out of space: not reported as incomplete:\n{out}")
    code, err = run_hostile(["verify", "--allow-incomplete", seal], expect=(0,), time_limit=60,
                            what="verify --allow-incomplete, seal out of space")
    for args in (["inspect", seal], ["convert", seal, os.path.join(mnt, "x.npy")]):
        run_hostile(args, expect=(0, 1), time_limit=60)  # read as incomplete, or out of space: never a signal
    finish()

if len(sys.argv) < 2:
    sys.exit(__doc__)

with tempfile.TemporaryDirectory() as d:
    P = lambda *p: os.path.join(d, *p)  # noqa: E731
    import numpy as np

    # Small inputs for every stage (about 2 s in all).
    run("sample", TINY, "-o", P("raw.ltm"), "--cube-res", "16", "--spp", "8", "-q")
    run("row-transform", P("raw.ltm"), "-o", P("rows.ltm"), "-q")
    run("transpose", P("rows.ltm"), "-o", P("cols.ltm"), "-q")
    run("column-transform", P("cols.ltm"), "-o", P("cols4d.ltm"), "-q")
    run("quantize", P("cols4d.ltm"), "-o", P("final.ltm"), "-q")
    g = np.random.default_rng(15)
    np.save(P("m.npy"), g.standard_normal((1024, 1024)).astype(np.float32))
    np.save(P("sky.npy"), np.abs(g.standard_normal((6 * 16 * 16, 3))).astype(np.float32))

    # --- 1. not a regular file ----------------------------------------------------------------
    os.mkfifo(P("fifo.ltm"))
    os.mkfifo(P("fifo.npy"))
    os.mkdir(P("dir.ltm"))
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    sock.bind(P("sock.ltm"))
    os.symlink("/dev/zero", P("zero.ltm"))  # a .ltm name, so convert gets as far as opening it
    kinds = {P("fifo.ltm"): "is a FIFO", P("dir.ltm"): "is a directory", P("zero.ltm"): "is a character device",
             "/dev/zero": "is a character device", P("sock.ltm"): "is a socket"}
    for path, kind in kinds.items():
        for args in (["inspect", path], ["convert", path, P("out.npy")],
                     ["relight", path, "--env", P("sky.npy"), "-o", P("out.exr")]):
            if args[0] == "convert" and not path.endswith(".ltm"):
                continue  # convert goes by the extension first
            run_hostile(args, names=(path, kind), expect=(1,), time_limit=20)
        # verify lists problems on stdout (one line per file); the exit code says it failed
        run_hostile(["verify", path], expect=(1,), time_limit=20)
        out = subprocess.run([LTBAKE, "verify", path], capture_output=True, text=True, timeout=20).stdout
        check(path in out and kind in out, f"verify {path}: does not say it {kind}:\n{out}")
    run_hostile(["convert", P("fifo.npy"), P("out.ltm")], names=(P("fifo.npy"), "is a FIFO"), time_limit=20)
    run_hostile(["relight", P("final.ltm"), "--env", P("fifo.npy"), "-o", P("out.exr")],
                names=(P("fifo.npy"), "is a FIFO"), time_limit=20)
    # ... or as an output: refused, not opened for writing
    run_hostile(["convert", P("m.npy"), P("fifo.ltm")], names=(P("fifo.ltm"), "is a FIFO"), time_limit=20)
    run_hostile(["convert", P("m.npy"), P("dir.ltm")], names=(P("dir.ltm"), "is a directory"), time_limit=20)
    check(not os.path.exists(P("out.npy")) and not os.path.exists(P("out.exr")), "an output was written")

    # --- 2. interrupted seals -------------------------------------------------------------------
    run("convert", P("rows.ltm"), P("rows.npy"), "-q")
    run("convert", P("rows.npy"), P("many.ltm"), "--chunk-size", "4KiB", "-q")  # an index of > 1 page
    interrupted_seal(P("many.ltm"), P("seal.ltm"))
    run_hostile(["verify", P("seal.ltm")], expect=(1,), time_limit=30)
    run_hostile(["verify", "--allow-incomplete", P("seal.ltm")], expect=(0,), time_limit=30)
    # the seal cut short inside the index payload: still readable, still incomplete
    size = os.path.getsize(P("many.ltm"))
    interrupted_seal(P("many.ltm"), P("seal_short.ltm"), truncate_to=size - 64 - 1000)
    run_hostile(["verify", P("seal_short.ltm")], expect=(1,), time_limit=30)
    run_hostile(["inspect", P("seal_short.ltm")], expect=(0,), time_limit=30)
    # out of space on a tmpfs (in a private mount namespace, where that is allowed)
    seal_ran = False
    for unshare in (["unshare", "-m", "--propagation", "private"], ["unshare", "-r", "-m", "--propagation", "private"]):
        os.makedirs(P("mnt"), exist_ok=True)
        try:
            p = subprocess.run([*unshare, sys.executable, os.path.abspath(__file__), LTBAKE, "--seal-inside",
                                P("many.ltm"), P("mnt")], capture_output=True, text=True, timeout=300)
        except FileNotFoundError:
            break
        if SEAL_MARK in p.stdout:
            seal_ran = p.returncode != 77
            check(p.returncode in (0, 77), f"seal out of space (tmpfs):\n{p.stdout}{p.stderr}")
            break
    if not seal_ran:
        print("note: no private mount namespace here: the full-tmpfs seal case was not run")

    # --- 3. forged manifest hashes ----------------------------------------------------------------
    for i in range(2):
        run("sample", TINY, "-o", P("sh.ltm"), "--shard", i, "--nshards", 2, "-q")
    run("commit", P("sh.ltm"), "--nshards", 2, "-q")
    check(verify_ok(P("sh.ltm")), "the committed manifest does not verify")
    text = open(P("sh.ltm")).read()
    magic, body = text.split("\n", 1)
    good = json.loads(body)

    def forged(label, edit, field):
        j = json.loads(body)
        edit(j)
        with open(P("forged.ltm"), "w") as f:
            f.write(magic + "\n" + json.dumps(j, indent=1) + "\n")
        run_hostile(["verify", P("forged.ltm")], expect=(1,), time_limit=30, what=f"verify, {label}")
        out = subprocess.run([LTBAKE, "verify", P("forged.ltm")], capture_output=True, text=True, timeout=30).stdout
        check(field in out and "commit the shards again" in out, f"verify, {label}: {field} not named:\n{out}")

    flip = lambda h: ("0" if h[0] != "0" else "1") + h[1:]  # noqa: E731
    forged("forged shard content_hash", lambda j: j["shards"][0].update(content_hash=flip(j["shards"][0]["content_hash"])),
           "shards[0].content_hash")
    forged("forged shard hash_sum", lambda j: j["shards"][1].update(hash_sum=flip(j["shards"][1]["hash_sum"])),
           "shards[1].hash_sum")
    forged("forged manifest content_hash", lambda j: j.update(content_hash=flip(j["content_hash"])), "content_hash is")
    check(good["content_hash"] == content_hash(P("sh.ltm")), "manifest content_hash differs from the shards'")

    # --- 4. bad flag values: usage errors (exit 2) naming the flag and the value -------------------
    for args, flag, value in [
        (["convert", P("m.npy"), P("x.ltm"), "--chunk-size", "abc"], "--chunk-size", "abc"),
        (["convert", P("m.npy"), P("x.ltm"), "--chunk-size", "0"], "--chunk-size", "0"),
        (["convert", P("m.npy"), P("x.ltm"), "--mem-limit", "0"], "--mem-limit", "0"),
        (["transpose", P("rows.ltm"), "-o", P("x.ltm"), "--mem-limit", "12XB"], "--mem-limit", "12XB"),
        (["relight", P("final.ltm"), "--env", P("sky.npy"), "-o", P("x.exr"), "--mem-limit", "lots"], "--mem-limit",
         "lots"),
        (["run", P("nope.toml"), "--mem-limit", "0.1"], "--mem-limit", "0.1"),
        (["sample", TINY, "-o", P("x.ltm"), "--spp", "0"], "--spp", "0"),
        (["sample", TINY, "-o", P("x.ltm"), "--cube-res", "12"], "--cube-res", "12"),
        (["sample", TINY, "-o", P("x.ltm"), "--bounces=-1"], "--bounces", "-1"),
        (["column-transform", P("cols.ltm"), "-o", P("x.ltm"), "--keep", "0"], "--keep", "0"),
        (["column-transform", P("cols.ltm"), "-o", P("x.ltm"), "--keep", "1.5"], "--keep", "1.5"),
        (["column-transform", P("cols.ltm"), "-o", P("x.ltm"), "--terms", "0"], "--terms", "0"),
        (["relight", P("final.ltm"), "--env", P("sky.npy"), "-o", P("x.exr"), "--frames=-1"], "--frames", "-1"),
        (["cpca", P("rows.ltm"), "-o", P("x.ltm"), "--clusters", "0"], "--clusters", "0"),
        (["quantize", P("cols4d.ltm"), "-o", P("x.ltm"), "--bits", "1"], "--bits", "1"),
    ]:
        run_hostile(args, names=(flag, value), expect=(2,), time_limit=20)
    check(not os.path.exists(P("x.ltm")) and not os.path.exists(P("x.exr")), "a usage error wrote an output")

    # --- 5. two writers, one output ---------------------------------------------------------------
    def state(path):
        if not os.path.exists(path):
            return None
        st = os.stat(path)
        return (st.st_ino, st.st_size, st.st_mtime_ns, hashlib.sha256(open(path, "rb").read()).hexdigest())

    def lock_pid(out):
        try:
            return int(open(out + ".lock").read().strip() or 0)
        except (OSError, ValueError):
            return 0

    def wait_stopped(pid, deadline):
        """Until every thread of `pid` is stopped (SIGSTOP is delivered asynchronously: a
        thread in the middle of a write finishes that write first), or the process is gone."""
        while time.monotonic() < deadline:
            try:
                states = []
                for t in os.listdir(f"/proc/{pid}/task"):
                    with open(f"/proc/{pid}/task/{t}/stat") as f:
                        states.append(f.read().rsplit(")", 1)[1].split()[0])
            except OSError:
                return
            if states and all(st in ("T", "t", "Z", "X") for st in states):
                return
            time.sleep(0.0005)

    def race(label, make_args, out_arg, digest=content_hash, written=lambda o: o):
        """Writer A, stopped once it holds the lock of the file it writes (`written(OUT)`);
        writer B of the same file must be refused naming A's PID and touch nothing; A then
        finishes as a solo run would."""
        solo_arg = out_arg + ".solo" + os.path.splitext(out_arg)[1]
        run(*make_args(solo_arg))
        ref = digest(written(solo_arg))
        check(ref, f"{label}: the solo run made nothing")
        out = written(out_arg)
        for attempt in range(5):
            for f in (out, out + ".lock"):
                if os.path.exists(f):
                    os.remove(f)
            a = subprocess.Popen([LTBAKE, *map(str, make_args(out_arg))], stdout=subprocess.DEVNULL,
                                 stderr=subprocess.PIPE)
            deadline = time.monotonic() + 60
            while lock_pid(out) != a.pid and a.poll() is None and time.monotonic() < deadline:
                time.sleep(0.0005)
            a.send_signal(signal.SIGSTOP)
            wait_stopped(a.pid, time.monotonic() + 30)
            if a.poll() is not None or lock_pid(out) != a.pid:  # finished before it was caught: again
                a.send_signal(signal.SIGCONT)
                a.wait()
                continue
            before = state(out)
            run_hostile(make_args(out_arg), names=(out, f"is in use by PID {a.pid}", "choose another output"),
                        expect=(1,), time_limit=60, what=f"{label}: writer B")
            check(state(out) == before, f"{label}: writer B changed {out}")
            check(lock_pid(out) == a.pid, f"{label}: writer B changed the lock file")
            a.send_signal(signal.SIGCONT)
            _, err = a.communicate(timeout=300)
            check(a.returncode == 0, f"{label}: writer A failed (exit {a.returncode}):\n{err.decode(errors='replace')}")
            if digest is content_hash:
                check(verify_ok(out), f"{label}: the output does not verify")
            check(digest(out) == ref, f"{label}: content differs from a solo run")
            check(not os.path.exists(out + ".lock"), f"{label}: the lock file was left behind")
            return
        check(False, f"{label}: writer A always finished before it could be stopped holding the lock")

    def npy_digest(path):
        return hashlib.sha256(open(path, "rb").read()).hexdigest() if os.path.exists(path) else None

    q = ["-q", "--jobs", "1"]
    race("sample", lambda o: ["sample", TINY, "-o", o, "--cube-res", 16, "--spp", 8, *q], P("r_raw.ltm"))
    race("sample, shard 1 of 2", lambda o: ["sample", TINY, "-o", o, "--cube-res", 16, "--spp", 8, "--shard", 1,
                                            "--nshards", 2, *q],
         P("r_sh.ltm"), written=lambda o: os.path.join(os.path.splitext(o)[0] + ".shards", "00001-of-00002.ltm"))
    race("row-transform", lambda o: ["row-transform", P("raw.ltm"), "-o", o, *q], P("r_rows.ltm"))
    race("transpose", lambda o: ["transpose", P("rows.ltm"), "-o", o, *q], P("r_cols.ltm"))
    race("column-transform", lambda o: ["column-transform", P("cols.ltm"), "-o", o, *q], P("r_cols4d.ltm"))
    race("quantize", lambda o: ["quantize", P("cols4d.ltm"), "-o", o, *q], P("r_final.ltm"))
    # Few passes: the race needs a cpca writer holding its lock, not a good fit (the default
    # 8 × 4 model with 30 passes took 11.6 s a run under the sanitizers, 2.2 s so).
    race("cpca", lambda o: ["cpca", P("rows.ltm"), "-o", o, "-k", 4, "-s", 2, "--max-iterations", 2,
                            "--level-iterations", 1, *q], P("r_cpca.ltm"))
    race("convert npy->ltm", lambda o: ["convert", P("m.npy"), o, "--chunk-size", "16KiB", *q], P("r_m.ltm"))
    race("convert ltm->npy", lambda o: ["convert", P("rows.ltm"), o, *q], P("r_rows.npy"), digest=npy_digest)
    race("merge", lambda o: ["merge", P("sh.ltm"), "-o", o, *q], P("r_merged.ltm"))

    # Fast writers (a relit image, a manifest commit): the lock is held here, as another
    # ltbake would hold it; they are refused naming this PID and write nothing.
    def held(out):
        fd = os.open(out + ".lock", os.O_RDWR | os.O_CREAT, 0o644)
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        os.ftruncate(fd, 0)
        os.write(fd, f"{os.getpid()}\n".encode())
        return fd

    for label, args, out in [
        ("relight", ["relight", P("final.ltm"), "--env", P("sky.npy"), "-o", P("img.exr")], P("img.exr")),
        ("commit", ["commit", P("sh.ltm"), "--nshards", 2, "--overwrite"], P("sh.ltm")),
    ]:
        before = state(out)
        fd = held(out)
        run_hostile(args, names=(out, f"is in use by PID {os.getpid()}"), expect=(1,), time_limit=30,
                    what=f"{label} while its output is locked")
        check(state(out) == before, f"{label}: changed {out} while it was locked")
        os.close(fd)
        os.remove(out + ".lock")
    run("relight", P("final.ltm"), "--env", P("sky.npy"), "-o", P("img.exr"), "-q")
    check(os.path.exists(P("img.exr")) and not os.path.exists(P("img.exr.lock")), "relight after the lock was freed")

    # --- 6. `run` locks its work directory before reading run.json --------------------------------
    recipe = P("r.toml")
    with open(recipe, "w") as f:
        f.write(f'name = "t"\nscene = "{TINY}"\n')
    w = P("w")
    run("run", recipe, "--workdir", w, "-q")
    hashes = {n: content_hash(os.path.join(w, n)) for n in ("rows.ltm", "cols.ltm", "cols4d.ltm", "final.ltm")}
    # As if another run held the directory and had not yet written its run.json: this run
    # waits for the lock, and then must see the run.json the other one left (all done).
    os.rename(os.path.join(w, "run.json"), P("run.json.done"))
    lock = os.path.join(w, ".ltbake-run.lock")
    fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o644)
    fcntl.flock(fd, fcntl.LOCK_EX)
    b = subprocess.Popen([LTBAKE, "run", recipe, "--workdir", w], stdout=subprocess.PIPE, stderr=subprocess.PIPE)

    def waits_on_lock():
        try:
            return any(os.readlink(f"/proc/{b.pid}/fd/{n}") == lock for n in os.listdir(f"/proc/{b.pid}/fd"))
        except OSError:
            return False

    deadline = time.monotonic() + 30
    while not waits_on_lock() and b.poll() is None and time.monotonic() < deadline:
        time.sleep(0.001)
    check(b.poll() is None, "run: did not wait for the work directory's lock")
    os.rename(P("run.json.done"), os.path.join(w, "run.json"))
    os.close(fd)  # the other run is done
    out, err = b.communicate(timeout=300)
    check(b.returncode == 0, f"run after waiting: exit {b.returncode}\n{err.decode(errors='replace')}")
    actions = [s.get("action") for s in json.load(open(os.path.join(w, "run.json")))["stages"]]
    check(actions and all(a == "skip" for a in actions),
          f"run after waiting for the lock redid finished steps (it read run.json before the lock): {actions}")
    check({n: content_hash(os.path.join(w, n)) for n in hashes} == hashes, "run after waiting: outputs changed")

    # A run waiting for the lock stops at SIGTERM (not when its wait runs out).
    def someone_waits():
        for pid in os.listdir("/proc"):
            if not pid.isdigit() or int(pid) == os.getpid():
                continue
            try:
                if any(os.readlink(f"/proc/{pid}/fd/{n}") == lock for n in os.listdir(f"/proc/{pid}/fd")):
                    return True
            except OSError:
                pass
        return False

    fd = os.open(lock, os.O_RDWR)
    fcntl.flock(fd, fcntl.LOCK_EX)
    code, err = interrupt_while_running(["run", recipe, "--workdir", w], someone_waits, signal.SIGTERM,
                                        what="run waiting for its work directory")
    os.close(fd)
    check(code == 143 and "interrupted while waiting" in err, f"run waiting for the lock, SIGTERM: exit {code}\n{err}")

finish()
