"""transpose through the ltbake binary.

- The result is the same logical matrix stored in column blocks (each column contiguous,
  i.e. numpy.transpose of the row-major matrix), for shapes that do not divide into
  blocks; content_hash equals the input's.
- With --mem-limit 4MiB on a matrix 20x larger (80 MiB), peak RSS stays under the limit
  plus the constant RSS of the ltbake process itself (measured here with `ltbake --version`),
  plus 4 MiB slack.
- SIGKILL at 10 random moments, then rerun: same content_hash; partial outputs verify.
- The output written with O_DIRECT (default) and with --no-direct-io: same content_hash,
  both verify, direct payloads 4096-aligned.
- Bad requests: column-block input, a --mem-limit too small for one column.

usage: transpose_test.py PATH_TO_LTBAKE
"""
import json
import os
import random
import resource
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, failures, finish, kill_storm, run, scaled  # noqa: E402





def info(path):
    return json.loads(run("inspect", path, "--json").stdout)


def peak_rss_kib(*args):
    """Peak RSS of one ltbake run, measured in a fresh interpreter so no other child counts."""
    code = ("import resource, subprocess, sys\n"
            "p = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL)\n"
            "print(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss, p.returncode)\n")
    # In the sanitizer build, ASan's quarantine holds freed memory back (up to 256 MiB by
    # default), which would count against the stage; it is switched off for this measurement.
    env = dict(os.environ)
    env["ASAN_OPTIONS"] = ":".join(filter(None, [env.get("ASAN_OPTIONS", ""), "quarantine_size_mb=0"]))
    out = subprocess.run([sys.executable, "-c", code, LTBAKE, *map(str, args)], capture_output=True, text=True,
                         timeout=600, env=env).stdout.split()
    return int(out[0]), int(out[1])


with tempfile.TemporaryDirectory() as d:
    rng = np.random.default_rng(11)
    for rows, cols, chunk in [(37, 53, "1KiB"), (1, 40, "64"), (40, 1, "64"), (300, 129, "8KiB")]:
        m = rng.standard_normal((rows, cols)).astype(np.float32)
        m[:, cols // 3] = 0.0  # an all-zero column
        src = os.path.join(d, f"m{rows}x{cols}.npy")
        np.save(src, m)
        a, t = src[:-4] + ".ltm", src[:-4] + "-t.ltm"
        run("convert", src, a, "--chunk-size", chunk)
        run("transpose", a, "-o", t, "--mem-limit", "4MiB")
        run("verify", t)
        ti = info(t)
        check(ti["layout"] == "cols" and ti["shape"] == [rows, cols], f"{rows}x{cols}: {ti['layout']} {ti['shape']}")
        check(ti["content_hash"] == info(a)["content_hash"], f"{rows}x{cols}: content_hash changed")
        back = src[:-4] + "-back.npy"
        run("convert", t, back)
        check(np.load(back).tobytes() == m.tobytes(), f"{rows}x{cols}: logical matrix changed")
        # The stored chunks are the columns: numpy.transpose of the matrix, block by block.
        block = ti["block"]
        with open(t, "rb") as f:
            raw = f.read()
        chunks = json.loads(run("inspect", t, "--json", "--chunks").stdout)["chunk_list"]
        for c in chunks:
            if c["array"] != "matrix" or c["encoding"] != "raw":
                continue
            c0 = c["index"] * block
            stored = np.frombuffer(raw, np.float32, count=c["decoded_bytes"] // 4, offset=c["offset"] + 64)
            want = np.transpose(m)[c0:c0 + block].reshape(-1)
            check(stored.tobytes() == want.tobytes(), f"{rows}x{cols}: chunk {c['index']} is not numpy.transpose")

    # Memory: 4 MiB limit, 80 MiB matrix.
    big = rng.standard_normal((4096, 5120)).astype(np.float32)
    np.save(os.path.join(d, "big.npy"), big)
    bigl = os.path.join(d, "big.ltm")
    run("convert", os.path.join(d, "big.npy"), bigl, "--chunk-size", "1MiB")
    base, _ = peak_rss_kib("--version")
    rss, code = peak_rss_kib("transpose", bigl, "-o", os.path.join(d, "big-t.ltm"), "--mem-limit", "4MiB")
    check(code == 0, f"transpose at 4MiB exited {code}")
    limit = 4 * 1024 + base + 4 * 1024
    print(f"peak RSS: transpose {rss} KiB with --mem-limit 4MiB on an 80 MiB matrix; `ltbake --version` {base} KiB")
    check(rss <= limit, f"peak RSS {rss} KiB exceeds 4 MiB + process base {base} KiB + 4 MiB slack")
    ref_hash = info(bigl)["content_hash"]
    check(info(os.path.join(d, "big-t.ltm"))["content_hash"] == ref_hash, "big: content_hash changed")

    # Output written with O_DIRECT (the default; its 64 KiB chunks are over the threshold)
    # and through the page cache: the same matrix, both verify; direct payloads sit on
    # 4096-byte boundaries behind padding frames.
    p = run("transpose", bigl, "-o", os.path.join(d, "big-d.ltm"), "--mem-limit", "4MiB")
    direct = "with O_DIRECT" in p.stdout
    check(direct or "page cache" in p.stderr, f"neither direct writes nor a fallback note: {p.stdout} {p.stderr}")
    run("transpose", bigl, "-o", os.path.join(d, "big-b.ltm"), "--mem-limit", "4MiB", "--no-direct-io")
    for name in ["big-d.ltm", "big-b.ltm"]:
        run("verify", os.path.join(d, name))
        check(info(os.path.join(d, name))["content_hash"] == ref_hash, f"{name}: content_hash changed")
    if direct:
        chunks = json.loads(run("inspect", os.path.join(d, "big-d.ltm"), "--json", "--chunks").stdout)["chunk_list"]
        misaligned = [c["index"] for c in chunks if c["encoding"] == "raw" and (c["offset"] + 64) % 4096]
        check(not misaligned, f"direct payloads not 4096-aligned: chunks {misaligned[:5]}")
        sd, sb = os.path.getsize(os.path.join(d, "big-d.ltm")), os.path.getsize(os.path.join(d, "big-b.ltm"))
        check(sb < sd <= sb + len(chunks) * 4096, f"sizes: direct {sd}, buffered {sb}, {len(chunks)} chunks")
    else:
        print("note: O_DIRECT refused here; only the fallback was exercised")

    # Kill at 10 random moments (LTB_TEST_SCALE), then finish.
    out = os.path.join(d, "big-k.ltm")
    t0 = time.monotonic()
    run("transpose", bigl, "-o", os.path.join(d, "big-timing.ltm"), "--mem-limit", "4MiB")
    full = time.monotonic() - t0
    kill_storm(["transpose", bigl, "-o", out, "--mem-limit", "4MiB"], out, kills=scaled(10, minimum=3), max_delay=full, seed=5)
    run("transpose", bigl, "-o", out, "--mem-limit", "4MiB")
    check(info(out)["content_hash"] == ref_hash, "resumed transpose differs from the input")

    # SIGTERM: commits and exits 143; a rerun finishes.
    out2 = os.path.join(d, "big-term.ltm")
    p = subprocess.Popen([LTBAKE, "transpose", bigl, "-o", out2, "--mem-limit", "4MiB"],
                         stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    time.sleep(full / 3)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate()
    check(p.returncode in (143, 0), f"SIGTERM: exit {p.returncode}: {err}")
    run("transpose", bigl, "-o", out2, "--mem-limit", "4MiB")
    check(info(out2)["content_hash"] == ref_hash, "transpose after SIGTERM differs from the input")

    # A damaged input chunk: the checksum pass catches it, the run fails naming the chunk,
    # and no output built from it is left behind.
    raw = bytearray(open(bigl, "rb").read())
    chunks = json.loads(run("inspect", bigl, "--json", "--chunks", "--no-content").stdout)["chunk_list"]
    victim = chunks[len(chunks) // 2]
    raw[victim["offset"] + 64 + 1000] ^= 0x01
    bad_in = os.path.join(d, "damaged.ltm")
    open(bad_in, "wb").write(raw)
    bad_out = os.path.join(d, "from-damaged.ltm")
    p = run("transpose", bad_in, "-o", bad_out, "--mem-limit", "4MiB", expect=1)
    check(f"chunk {victim['index']}" in p.stderr and "checksum mismatch" in p.stderr, f"damaged input: {p.stderr}")
    check(not os.path.exists(bad_out), "a transpose of a damaged input left its output behind")

    # Bad requests.
    p = run("transpose", os.path.join(d, "big-t.ltm"), "-o", os.path.join(d, "x.ltm"), expect=1)
    check("already stored in column blocks" in p.stderr, f"column input: {p.stderr}")
    p = run("transpose", bigl, "-o", os.path.join(d, "x.ltm"), "--mem-limit", "2100KiB", expect=1)
    check("is too small" in p.stderr and "MiB)" in p.stderr, f"tiny mem-limit: {p.stderr}")

finish()
