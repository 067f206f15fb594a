"""row-transform through the ltbake binary against PyWavelets.

- Each face of each row equals pywt.coeffs_to_array(pywt.wavedec2(face, F,
  mode='periodization', level=log2 R))[0] within 1e-5 * max|row| (float32 arithmetic,
  see tests/wavelet/pywt_oracle_test.py for the bound), for haar, db2, db3, db4.
- pywt.waverec2 of the output returns the input (the inverse), within the same bound.
- The content_hash does not depend on --jobs or the input's chunk size.
- Inputs that are not pixel-basis cubemap row blocks are refused with a message that says
  what was found and what to run.
- SIGKILL at random moments then rerunning gives the uninterrupted content_hash; output
  written with O_DIRECT (default) and with --no-direct-io has the same content_hash.

usage: row_transform_test.py PATH_TO_LTBAKE
"""
import json
import os
import random
import sys
import tempfile
import time
import warnings

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, failures, finish, kill_storm, run  # noqa: E402
import pywt

warnings.simplefilter("ignore")




def content_hash(path):
    return json.loads(run("inspect", path, "--json").stdout)["content_hash"]


def faces(row, R):
    return row.reshape(6, R, R)


with tempfile.TemporaryDirectory() as d:
    R, rows = 8, 37
    rng = np.random.default_rng(3)
    m = rng.standard_normal((rows, 6 * R * R)).astype(np.float32)
    m[5] = 0.0
    m[20:24] = 0.0
    src = os.path.join(d, "raw.npy")
    np.save(src, m)
    raw = os.path.join(d, "raw.ltm")
    run("convert", src, raw, "--cube-res", R, "--chunk-size", "4KiB")
    for name in ["haar", "db2", "db3", "db4"]:
        out = os.path.join(d, f"rows-{name}.ltm")
        run("row-transform", raw, "-o", out, "--filter", name)
        run("verify", out)
        info = json.loads(run("inspect", out, "--json").stdout)
        cols = info["basis"]["cols"]
        check(cols.get("basis") == "wavelet" and cols.get("filter") == name and cols.get("cube_res") == R,
              f"{name}: basis.cols {cols}")
        back = os.path.join(d, f"rows-{name}.npy")
        run("convert", out, back)
        got = np.load(back)
        level = int(np.log2(R))
        worst = worst_inv = 0.0
        for i in range(rows):
            scale = max(np.abs(m[i]).max(), 1e-30)
            for f in range(6):
                face = faces(m[i].astype(np.float64), R)[f]
                want = pywt.coeffs_to_array(pywt.wavedec2(face, name, mode="periodization", level=level))[0]
                worst = max(worst, np.abs(faces(got[i], R)[f] - want).max() / scale)
                _, slices = pywt.coeffs_to_array(pywt.wavedec2(face, name, mode="periodization", level=level))
                coeffs = pywt.array_to_coeffs(faces(got[i], R)[f].astype(np.float64), slices, output_format="wavedec2")
                inv = pywt.waverec2(coeffs, name, mode="periodization")
                worst_inv = max(worst_inv, np.abs(inv - face).max() / scale)
        check(worst <= 1e-5, f"{name}: forward differs from PyWavelets by {worst:.3g} (relative)")
        check(worst_inv <= 1e-5, f"{name}: PyWavelets inverse of the output differs from the input by {worst_inv:.3g}")
        check(np.all(got[5] == 0) and np.all(got[20:24] == 0), f"{name}: zero rows did not stay zero")

    # Determinism: jobs and input chunking do not change the result.
    h = content_hash(os.path.join(d, "rows-db2.ltm"))
    raw_big = os.path.join(d, "raw-big.ltm")
    run("convert", src, raw_big, "--cube-res", R, "--chunk-size", "64KiB", "--zstd")
    for label, inp, jobs in [("jobs 1", raw, 1), ("one chunk, jobs 2", raw_big, 2)]:
        out = os.path.join(d, f"det-{jobs}.ltm")
        run("row-transform", inp, "-o", out, "--filter", "db2", "--jobs", jobs)
        check(content_hash(out) == h, f"db2 {label}: content_hash {content_hash(out)} != {h}")

    # Refusals.
    generic = os.path.join(d, "generic.ltm")
    run("convert", src, generic)
    p = run("row-transform", generic, "-o", os.path.join(d, "x.ltm"), expect=1)
    check("not declared a cubemap" in p.stderr and "--cube-res" in p.stderr, f"generic input: {p.stderr}")
    p = run("row-transform", os.path.join(d, "rows-haar.ltm"), "-o", os.path.join(d, "x.ltm"), expect=1)
    check("already row-transformed (filter haar)" in p.stderr, f"transformed input: {p.stderr}")
    colsl = os.path.join(d, "cols.ltm")
    run("convert", src, colsl, "--cube-res", R, "--layout", "cols")
    p = run("row-transform", colsl, "-o", os.path.join(d, "x.ltm"), expect=1)
    check("column blocks" in p.stderr and "before `ltbake transpose`" in p.stderr, f"column input: {p.stderr}")
    p = run("convert", src, os.path.join(d, "bad.ltm"), "--cube-res", 4, expect=1)
    check("needs 6·R² = 96" in p.stderr, f"wrong cube-res: {p.stderr}")
    p = run("convert", src, os.path.join(d, "bad.ltm"), "--cube-res", 6, expect=1)
    check("not a power of two" in p.stderr, f"cube-res 6: {p.stderr}")
    p = run("convert", src, os.path.join(d, "bad.ltm"), "--image", "6x7", expect=1)
    check("needs 42" in p.stderr, f"wrong image size: {p.stderr}")
    p = run("row-transform", raw, "-o", os.path.join(d, "x.ltm"), "--filter", "cdf97", expect=2)
    check("cdf97" in p.stderr, f"biorthogonal row filter: {p.stderr}")

    # Kill and resume.
    R2, rows2 = 16, 3000
    big = rng.standard_normal((rows2, 6 * R2 * R2)).astype(np.float32)
    np.save(os.path.join(d, "big.npy"), big)
    bigraw = os.path.join(d, "big.ltm")
    run("convert", os.path.join(d, "big.npy"), bigraw, "--cube-res", R2, "--chunk-size", "96KiB")
    # The reference through the page cache; the timed run and the killed ones with O_DIRECT
    # (the default: 96 KiB chunks are over its 64 KiB threshold). Same content either way.
    ref = os.path.join(d, "big-ref.ltm")
    run("row-transform", bigraw, "-o", ref, "--filter", "db4", "--no-direct-io")
    ref_hash = content_hash(ref)
    t0 = time.monotonic()
    p = run("row-transform", bigraw, "-o", os.path.join(d, "big-direct.ltm"), "--filter", "db4")
    full = time.monotonic() - t0
    check("with O_DIRECT" in p.stdout or "page cache" in p.stderr, f"no direct writes and no note: {p.stdout} {p.stderr}")
    run("verify", os.path.join(d, "big-direct.ltm"))
    check(content_hash(os.path.join(d, "big-direct.ltm")) == ref_hash, "row-transform with O_DIRECT differs")
    out = os.path.join(d, "big-out.ltm")
    kill_storm(["row-transform", bigraw, "-o", out, "--filter", "db4"], out, kills=5, max_delay=full, seed=7)
    run("row-transform", bigraw, "-o", out, "--filter", "db4")
    check(content_hash(out) == ref_hash, "row-transform resumed after kills differs from the uninterrupted run")

finish()
