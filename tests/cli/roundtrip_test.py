"""npy -> ltm -> npy through the ltbake binary: bit-exact for f32, correctly rounded for
f64, for shapes including 1xN, Nx1 and ones that do not divide into chunks, in both
layouts and with zstd; content_hash against an independent NumPy implementation; and
clear errors for inputs convert cannot take.

usage: roundtrip_test.py PATH_TO_LTBAKE
"""
import json
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import ltm_oracle  # noqa: E402

LTBAKE = sys.argv[1]
failures = []


def run(*args, expect=0):
    p = subprocess.run([LTBAKE, *map(str, args)], capture_output=True, text=True, timeout=300)
    if p.returncode != expect:
        failures.append(f"{' '.join(map(str, args))}: exit {p.returncode}, expected {expect}\n{p.stdout}{p.stderr}")
    return p


def check(cond, what):
    if not cond:
        failures.append(what)


def matrix(rows, cols, seed):
    rng = np.random.default_rng(seed)
    m = rng.standard_normal((rows, cols)).astype(np.float32)
    m[::3] = 0.0  # whole zero rows -> some all-zero chunks
    if rows > 4:
        m[1, 0] = np.nan
        m[2, -1] = np.inf
        m[4, 0] = -0.0
    return m


with tempfile.TemporaryDirectory() as d:
    shapes = [(1, 37), (37, 1), (53, 29), (7, 6144), (1, 1)]
    for k, (rows, cols) in enumerate(shapes):
        m = matrix(rows, cols, k)
        src = os.path.join(d, f"m{k}.npy")
        np.save(src, m)
        want_hash = ltm_oracle.content_hash(m)
        for layout in ("rows", "cols"):
            for zstd in (False, True):
                ltm = os.path.join(d, f"m{k}-{layout}-{zstd}.ltm")
                back = os.path.join(d, f"m{k}-{layout}-{zstd}.npy")
                flags = ["--chunk-size", "512", "--layout", layout] + (["--zstd"] if zstd else [])
                run("convert", src, ltm, *flags)
                run("verify", ltm)
                info = json.loads(run("inspect", ltm, "--json", "--content").stdout or "{}")
                tag = f"{rows}x{cols} {layout} zstd={zstd}"
                check(info.get("shape") == [rows, cols], f"{tag}: shape {info.get('shape')}")
                check(info.get("complete") is True, f"{tag}: not complete")
                check(info.get("content_hash") == want_hash,
                      f"{tag}: content_hash {info.get('content_hash')} != oracle {want_hash}")
                nchunks = info.get("chunks", {}).get("expected", 0)
                if rows * cols * 4 > 1024:
                    check(nchunks > 1, f"{tag}: expected several chunks, got {nchunks}")
                stats = info.get("stats", {})
                finite = m[np.isfinite(m)]
                check(stats.get("nan_count") == int(np.isnan(m).sum()), f"{tag}: nan_count {stats}")
                check(stats.get("inf_count") == int(np.isinf(m).sum()), f"{tag}: inf_count {stats}")
                check(abs(stats.get("nonzero_fraction", -1) - np.count_nonzero(m) / m.size) < 1e-12,
                      f"{tag}: nonzero_fraction {stats}")
                if finite.size:
                    check(stats.get("min") == float(finite.min()) and stats.get("max") == float(finite.max()),
                          f"{tag}: min/max {stats}")
                run("convert", ltm, back)
                got = np.load(back)
                check(got.dtype == np.float32 and got.shape == m.shape, f"{tag}: npy {got.dtype} {got.shape}")
                check(got.tobytes() == m.tobytes(), f"{tag}: round trip is not bit-exact")

    # float64 input is rounded to float32 exactly as NumPy's astype does.
    m64 = np.random.default_rng(9).standard_normal((40, 33)) * 1e3
    src = os.path.join(d, "m64.npy")
    np.save(src, m64)
    j = json.loads(run("convert", src, os.path.join(d, "m64.ltm"), "--chunk-size", "1KiB", "--json").stdout)
    on_disk = json.loads(run("inspect", "--json", "--content", os.path.join(d, "m64.ltm")).stdout)
    check((j["rows"], j["cols"]) == m64.shape and j["chunks_written"] == j["chunks_total"] ==
          on_disk["chunks"]["committed"], f"convert --json: {j}")
    run("convert", os.path.join(d, "m64.ltm"), os.path.join(d, "m64back.npy"))
    check(np.load(os.path.join(d, "m64back.npy")).tobytes() == m64.astype(np.float32).tobytes(),
          "f64 input: not equal to astype(float32)")

    # Content-hash independence from chunk size (two different chunkings, same hash).
    h1 = json.loads(run("inspect", os.path.join(d, "m2-rows-False.ltm"), "--json").stdout)["content_hash"]
    run("convert", os.path.join(d, "m2.npy"), os.path.join(d, "m2-big.ltm"), "--chunk-size", "1MiB")
    h2 = json.loads(run("inspect", os.path.join(d, "m2-big.ltm"), "--json").stdout)["content_hash"]
    check(h1 == h2, f"content_hash depends on chunking: {h1} vs {h2}")

    # Inputs convert cannot take: each a clear message naming the file and what to do.
    def expect_error(arr_or_bytes, name, needle, save=True):
        path = os.path.join(d, name)
        if save:
            np.save(path, arr_or_bytes)
        else:
            with open(path, "wb") as f:
                f.write(arr_or_bytes)
        p = run("convert", path, os.path.join(d, "x.ltm"), expect=1)
        check(needle in p.stderr and path in p.stderr, f"{name}: stderr lacks '{needle}' or the path: {p.stderr}")

    expect_error(np.zeros((2, 3, 4), np.float32), "cube.npy", "3-D; convert needs a 2-D matrix")
    expect_error(np.zeros((2, 3), np.int32), "ints.npy", "dtype '<i4' is not supported")
    expect_error(np.asfortranarray(np.ones((3, 4), np.float32)), "fortran.npy", "np.ascontiguousarray")
    big = np.ones((3, 4))
    big[2, 1] = 1e300
    expect_error(big, "huge.npy", "value 1.0000000000000001e+300 at row 2, column 1 is beyond the float32 range")
    with open(os.path.join(d, "m2.npy"), "rb") as f:
        whole = f.read()
    expect_error(whole[:-5], "short.npy", "(truncated or damaged?)", save=False)
    expect_error(b"hello world, not numpy", "text.npy", "not a .npy file", save=False)
    check(not os.path.exists(os.path.join(d, "x.ltm")), "a failed convert left an output file")

    # Refuses to convert an incomplete container to npy; names what is missing.
    p = run("convert", os.path.join(d, "nope.ltm"), os.path.join(d, "nope.npy"), expect=1)
    check("nope.ltm" in p.stderr and "No such file" in p.stderr, f"missing input: {p.stderr}")
    run("convert", "a.txt", "b.ltm", expect=1)

if failures:
    print("\n".join(failures))
    print(f"0 passed, {len(failures)} failed")
    sys.exit(1)
print("roundtrip: all checks passed")
