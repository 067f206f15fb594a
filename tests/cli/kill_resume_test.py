"""Kill-and-resume: an `ltbake convert` writer is SIGKILLed at random points of its write until
20 (times LTB_TEST_SCALE, at least 4) have landed mid-write. A point is a size the output has
reached (a random fraction of the finished file's), so the kills land mid-write however fast
or loaded the machine is (a random delay after the start landed 7 of 40 times under load). Each
time the partial file must verify (committed chunks intact), list only whole chunks, and
a resumed run must append only the missing chunks and end with the same content_hash as
an uninterrupted write. A last trial kills the same file five times in a row.

usage: kill_resume_test.py PATH_TO_LTBAKE [--seed N]
"""
import json
import os
import random
import re
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

LTBAKE = sys.argv[1]
SEED = int(sys.argv[sys.argv.index("--seed") + 1]) if "--seed" in sys.argv else 20261122
rng = random.Random(SEED)
failures = []
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import scaled  # noqa: E402
KILLS = scaled(20, minimum=4)  # kills that land mid-write (LTB_TEST_SCALE)


def check(cond, what):
    if not cond:
        failures.append(what)


def ltbake(*args, expect=0):
    p = subprocess.run([LTBAKE, *args], capture_output=True, text=True, timeout=600)
    if expect is not None and p.returncode != expect:
        failures.append(f"ltbake {' '.join(args)}: exit {p.returncode}\n{p.stdout}{p.stderr}")
    return p


with tempfile.TemporaryDirectory() as d:
    rows, cols = 2048, 6144  # 48 MiB of f32
    g = np.random.default_rng(1)
    m = g.standard_normal((rows, cols)).astype(np.float32)
    # 64 KiB chunks hold 2 rows: every third chunk all zero, every third compressible.
    kind = (np.arange(rows) // 2) % 3
    m[kind == 0] = 0.0
    m[kind == 1] = np.arange(cols) % 8
    src = os.path.join(d, "m.npy")
    np.save(src, m)
    flags = ["--chunk-size", "64KiB", "--zstd", "--jobs", "2", "--progress", "never"]

    ref = os.path.join(d, "ref.ltm")
    t0 = time.monotonic()
    ltbake("convert", src, ref, *flags)
    full = time.monotonic() - t0
    ref_info = json.loads(ltbake("inspect", ref, "--json").stdout)
    ref_hash = ref_info["content_hash"]
    total = ref_info["chunks"]["expected"]
    check(ref_info["chunks"]["zero"] > 0 and ref_info["chunks"]["zstd"] > 0 and ref_info["chunks"]["raw"] > 0,
          f"test data should mix encodings: {ref_info['chunks']}")

    out = os.path.join(d, "out.ltm")
    mid_write = 0
    committed_sum = 0

    ref_bytes = os.path.getsize(ref)

    def size_of(path):
        try:
            return os.path.getsize(path)
        except OSError:
            return 0

    def kill_once(fraction):
        """Starts a writer (or a resume) and SIGKILLs it once its output has grown to
        `fraction` of the finished file's size: a condition, not a time."""
        target = fraction * ref_bytes
        p = subprocess.Popen([LTBAKE, "convert", src, out, *flags], stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        deadline = time.monotonic() + 120
        while size_of(out) < target and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.0002)
        p.send_signal(signal.SIGKILL)
        p.wait()
        return p.returncode

    def check_partial(tag):
        """Returns the number of committed chunks of the partial file (None: no file)."""
        if not os.path.exists(out):
            return None
        v = ltbake("verify", "--allow-incomplete", "--json", out)
        rep = json.loads(v.stdout or "[{}]")[0]
        check(rep.get("ok") is True and rep.get("problems") == [], f"{tag}: partial file does not verify: {rep}")
        info = json.loads(ltbake("inspect", out, "--json", "--chunks").stdout)
        listed = [c for c in info["chunk_list"] if c["array"] == "matrix"]
        check(len(listed) == info["chunks"]["committed"] == rep.get("chunks_ok"),
              f"{tag}: listed {len(listed)} chunks, committed {info['chunks']['committed']}")
        check(len({c['index'] for c in listed}) == len(listed), f"{tag}: a chunk is listed twice")
        return len(listed)

    def resume(tag, committed_before):
        p = ltbake("convert", src, out, *flags)
        msg = re.search(r"resumed: (\d+) already committed, (\d+) written", p.stdout)
        if committed_before:
            check(msg is not None, f"{tag}: resume did not report resuming: {p.stdout}")
            if msg:
                already, written = int(msg.group(1)), int(msg.group(2))
                check(already == committed_before, f"{tag}: resumed with {already}, partial had {committed_before}")
                check(already + written == total, f"{tag}: {already} + {written} != {total} chunks")
                return written
        return total

    # Kill at random moments until KILLS kills have landed while chunks were being written
    # (kills before the file exists or after it is sealed are retried, within a bound).
    attempts = 0
    while mid_write < KILLS and attempts < 5 * KILLS:
        attempts += 1
        if os.path.exists(out):
            os.remove(out)
        fraction = rng.uniform(0.02, 0.9)
        kill_once(fraction)
        tag = f"attempt {attempts} (kill at {fraction:.0%} of the file)"
        n = check_partial(tag)
        landed = n is not None and 0 < n < total
        if n is not None and n == total and not json.loads(ltbake("inspect", out, "--json", "--no-content").stdout)["complete"]:
            landed = True  # all chunks written, killed before sealing
        if not landed:
            continue
        mid_write += 1
        committed_sum += n
        resume(tag, n)
        info = json.loads(ltbake("inspect", out, "--json").stdout)
        check(info["content_hash"] == ref_hash and info["complete"],
              f"{tag}: content_hash {info['content_hash']} != {ref_hash}")

    # Repeated kills of one file, then a final resume.
    os.remove(out)
    history = []
    for k in range(5):  # each kill a little further on than where the last one left the file
        kill_once(min(0.95, size_of(out) / ref_bytes + rng.uniform(0.02, 0.15)))
        history.append(check_partial(f"chain kill {k}"))
    resume("chain", history[-1])
    info = json.loads(ltbake("inspect", out, "--json").stdout)
    check(info["content_hash"] == ref_hash, f"chain: content_hash {info['content_hash']} != {ref_hash}")
    committed = [h or 0 for h in history]
    check(committed == sorted(committed), f"chain: committed chunks went down across resumes: {committed}")

    print(f"uninterrupted write {full:.3f}s, {total} chunks; {mid_write} kills landed mid-write in {attempts} "
          f"attempts (mean {committed_sum / max(1, mid_write):.0f} chunks committed); chain committed counts {history}")
    check(mid_write == KILLS, f"only {mid_write} of {attempts} kills landed while chunks were being written")

if failures:
    print("\n".join(failures))
    print(f"0 passed, {len(failures)} failed")
    sys.exit(1)
print("kill_resume: all checks passed")
