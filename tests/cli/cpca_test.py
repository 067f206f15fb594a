"""`ltbake cpca`: clustered PCA against NumPy oracles, through the CLI.

Tolerances follow from f32 storage: a stored value carries a relative rounding error of at
most u = 2^-24, so a decoded row x̂ = mean + Σ w_i b_i (each of mean, w_i, b_i rounded once)
is off by at most about (2 + 2S)·u·(‖mean‖ + Σ|w_i|) ≤ (2 + 2S)·u·√(S+1)·‖x̂‖ from the
exact affine reconstruction; a row lying exactly in its cluster's subspace therefore comes
back with a relative error of that order, far below any modelling error.

usage: cpca_test.py PATH_TO_LTBAKE
"""
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest as t  # noqa: E402

U = 2.0 ** -24


def info(path):
    return json.loads(t.run("inspect", path, "--json").stdout)


def hashes(path):
    return [a.get("content_hash") for a in info(path)["arrays"]]


def cpca(inp, out, *args, expect=0):
    p = t.run("cpca", inp, "-o", out, "--json", "--progress", "never", *args, expect=expect)
    return json.loads(p.stdout) if expect == 0 and p.returncode == 0 else p


def decode(path, d):
    npy = os.path.join(d, "decoded.npy")
    t.run("convert", path, npy, "-q")
    return np.load(npy).astype(np.float64)


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def affine_rows(g, k, s, d, n):
    means = g.standard_normal((k, d)) * 3
    bases = [np.linalg.qr(g.standard_normal((d, s)))[0] for _ in range(k)]
    labels = g.integers(0, k, n)
    labels[:k] = np.arange(k)  # every subspace is used
    x = np.stack([means[c] + bases[c] @ g.standard_normal(s) for c in labels])
    return x.astype(np.float32), labels


with tempfile.TemporaryDirectory() as d:
    g = np.random.default_rng(7)

    # 1. Rows drawn exactly from K affine subspaces of dimension S: recovered at float
    #    precision, the partition found, reported error = decoded error.
    k, s, dim, n = 5, 3, 96, 3000
    x, labels = affine_rows(g, k, s, dim, n)
    np.save(os.path.join(d, "sub.npy"), x)
    sub = os.path.join(d, "sub.ltm")
    t.run("convert", os.path.join(d, "sub.npy"), sub, "--chunk-size", "32KiB", "-q")
    r = cpca(sub, os.path.join(d, "sub_cpca.ltm"), "-k", k, "-s", s)
    bound = (2 + 2 * s) * U * np.sqrt(s + 1) * 4  # ×4: mean and weights can exceed ‖x̂‖ a little
    xd = decode(os.path.join(d, "sub_cpca.ltm"), d)
    e_dec = rel(xd, x.astype(np.float64))
    t.check(r["relative_rms_error"] <= bound, f"subspaces: reported error {r['relative_rms_error']} > {bound}")
    t.check(e_dec <= bound, f"subspaces: decoded error {e_dec} > {bound}")
    ltm_info = info(os.path.join(d, "sub_cpca.ltm"))
    t.check(ltm_info["cpca"]["clusters"] == k and ltm_info["cpca"]["basis_dim"] == s, f"cpca block: {ltm_info.get('cpca')}")
    t.check(ltm_info["cpca"]["empty_clusters"] == 0, f"subspaces: empty clusters {ltm_info['cpca']}")

    # 2. Decoded error equals the reported error (within the f32 rounding of the decoded
    #    values: |‖x − fl(x̂)‖ − ‖x − x̂‖| ≤ u‖x̂‖), on data that is not exactly low rank.
    y = (x + 0.05 * g.standard_normal(x.shape)).astype(np.float32)
    np.save(os.path.join(d, "noisy.npy"), y)
    noisy = os.path.join(d, "noisy.ltm")
    t.run("convert", os.path.join(d, "noisy.npy"), noisy, "--chunk-size", "64KiB", "-q")
    r = cpca(noisy, os.path.join(d, "noisy_cpca.ltm"), "-k", k, "-s", s)
    yd = decode(os.path.join(d, "noisy_cpca.ltm"), d)
    e_dec = rel(yd, y.astype(np.float64))
    t.check(abs(e_dec - r["relative_rms_error"]) <= 2 * U * np.linalg.norm(yd) / np.linalg.norm(y),
            f"decoded error {e_dec} != reported {r['relative_rms_error']}")
    t.check(r["relative_rms_error"] > 1e-3, f"noisy rows cannot be exact: {r['relative_rms_error']}")

    # 3. Determinism: same content for any --jobs and input chunk size.
    ref = hashes(os.path.join(d, "noisy_cpca.ltm"))
    for jobs, chunk in [(1, "64KiB"), (3, "64KiB"), (2, "8KiB")]:
        src = os.path.join(d, f"noisy_{chunk}.ltm")
        if not os.path.exists(src):
            t.run("convert", os.path.join(d, "noisy.npy"), src, "--chunk-size", chunk, "-q")
        out = os.path.join(d, f"noisy_cpca_{jobs}_{chunk}.ltm")
        cpca(src, out, "-k", k, "-s", s, "--jobs", jobs)
        t.check(hashes(out) == ref, f"--jobs {jobs}, chunks {chunk}: content differs: {hashes(out)} vs {ref}")
    # A rerun of a finished output is a no-op; other parameters are refused without --overwrite.
    r2 = cpca(noisy, os.path.join(d, "noisy_cpca.ltm"), "-k", k, "-s", s)
    t.check(r2["already_complete"], f"rerun should find the output complete: {r2}")
    p = cpca(noisy, os.path.join(d, "noisy_cpca.ltm"), "-k", k, "-s", s + 1, expect=1)
    t.check("--overwrite" in p.stderr, f"other parameters: {p.stderr}")

    # 4. K = 1 and S = full rank: decoding reproduces the input. The error is
    #    non-increasing in S for fixed clusters (K = 1) and matches the SVD optimum.
    dim2, n2 = 24, 400
    spectrum = 2.0 ** -np.arange(dim2)
    z = (g.standard_normal((n2, dim2)) * spectrum) @ np.linalg.qr(g.standard_normal((dim2, dim2)))[0] + 1.5
    z = z.astype(np.float32)
    np.save(os.path.join(d, "z.npy"), z)
    zl = os.path.join(d, "z.ltm")
    t.run("convert", os.path.join(d, "z.npy"), zl, "-q")
    zc = z.astype(np.float64) - z.astype(np.float64).mean(axis=0)
    sv = np.linalg.svd(zc, compute_uv=False)
    norm = np.linalg.norm(z.astype(np.float64))
    errors = []
    for s2 in range(dim2 + 1):
        out = os.path.join(d, f"z_{s2}.ltm")
        r = cpca(zl, out, "-k", 1, "-s", s2, "--max-iterations", 50, "--tolerance", 1e-9)
        errors.append(r["relative_rms_error"])
        optimum = np.sqrt(np.sum(sv[s2:] ** 2)) / norm
        floor = (2 + 2 * s2) * U * np.sqrt(s2 + 1) * 4
        t.check(r["relative_rms_error"] >= optimum * (1 - 1e-6) - floor,
                f"S={s2}: error {r['relative_rms_error']} below the SVD optimum {optimum}")
        t.check(r["relative_rms_error"] <= optimum * (1 + 1e-3) + floor,
                f"S={s2}: error {r['relative_rms_error']} above the SVD optimum {optimum} by more than 0.1%")
    for s2 in range(dim2):
        t.check(errors[s2 + 1] <= errors[s2] * (1 + 1e-6) + 1e-7, f"error grows from S={s2} to {s2 + 1}: {errors}")
    zd = decode(os.path.join(d, f"z_{dim2}.ltm"), d)
    t.check(rel(zd, z.astype(np.float64)) <= (2 + 2 * dim2) * U * np.sqrt(dim2 + 1),
            f"K=1, S=D: decoded differs from the input by {rel(zd, z.astype(np.float64))}")

    # 5. Relighting a cpca.ltm equals decoded matrix × lighting; --basis pixels of a
    #    row-transformed input equals the pixel-basis rows.
    cube = 2
    cols = 6 * cube * cube
    img = 12
    m = (np.abs(g.standard_normal((img * img, cols))) * (g.random((img * img, 1)) > 0.3)).astype(np.float32)
    np.save(os.path.join(d, "m.npy"), m)
    raw = os.path.join(d, "raw.ltm")
    t.run("convert", os.path.join(d, "m.npy"), raw, "--cube-res", cube, "--image", f"{img}x{img}", "-q")
    rows = os.path.join(d, "rows.ltm")
    t.run("row-transform", raw, "-o", rows, "--filter", "haar", "-q")
    full = os.path.join(d, "rows_cpca.ltm")
    cpca(rows, full, "-k", 1, "-s", cols)
    px = os.path.join(d, "px.npy")
    t.run("convert", full, px, "--basis", "pixels", "-q")
    t.check(rel(np.load(px).astype(np.float64), m.astype(np.float64)) <= (2 + 2 * cols) * U * np.sqrt(cols + 1) * 4,
            f"--basis pixels: {rel(np.load(px).astype(np.float64), m.astype(np.float64))}")
    approx = os.path.join(d, "rows_cpca3.ltm")
    cpca(rows, approx, "-k", 3, "-s", 2)
    env = (np.abs(g.standard_normal((cols, 3))) + 0.1).astype(np.float32)
    np.save(os.path.join(d, "env.npy"), env)
    out_img = os.path.join(d, "relit.npy")
    p = t.run("relight", approx, "--env", os.path.join(d, "env.npy"), "-o", out_img, "--terms", cols,
              "--weighting", "none", "--reference", raw, "--json")
    rep = json.loads(p.stdout) if p.returncode == 0 else {}
    dec = decode(approx, d)  # in the Haar row basis: light it with the Haar-transformed env
    import pywt
    env_w = np.zeros_like(env, dtype=np.float64)
    for f in range(6):
        for c in range(3):
            face = env[f * cube * cube:(f + 1) * cube * cube, c].astype(np.float64).reshape(cube, cube)
            arr = pywt.coeffs_to_array(pywt.wavedec2(face, "haar", mode="periodization"))[0]
            env_w[f * cube * cube:(f + 1) * cube * cube, c] = arr.reshape(-1)
    want = dec @ env_w
    got = np.load(out_img).astype(np.float64).reshape(-1, 3)
    t.check(rel(got, want) <= 1e-5, f"relight cpca.ltm vs decoded @ lighting: {rel(got, want)}")
    t.check("cpca" in rep and "error" in rep, f"relight --json lacks cpca/error: {rep}")
    exact = m.astype(np.float64) @ env.astype(np.float64)
    if "error_matrix_only" in rep:
        t.check(abs(rep["error_matrix_only"]["rel_l2"] - rel(want, exact)) <= 1e-5,
                f"matrix-only error {rep['error_matrix_only']['rel_l2']} vs NumPy {rel(want, exact)}")

    # 6. Bad input: each message names the file and the value.
    p = cpca(sub, os.path.join(d, "bad.ltm"), "-k", 3, "-s", dim + 1, expect=1)
    t.check("sub.ltm" in p.stderr and str(dim + 1) in p.stderr and str(dim) in p.stderr, f"S > D: {p.stderr}")
    p = cpca(zl, os.path.join(d, "bad.ltm"), "-k", n2 + 1, "-s", 1, expect=1)
    t.check("z.ltm" in p.stderr and str(n2 + 1) in p.stderr and str(n2) in p.stderr, f"K > rows: {p.stderr}")
    colsl = os.path.join(d, "cols.ltm")
    t.run("convert", os.path.join(d, "z.npy"), colsl, "--layout", "cols", "-q")
    p = cpca(colsl, os.path.join(d, "bad.ltm"), "-k", 2, "-s", 1, expect=1)
    t.check("cols.ltm" in p.stderr and "column blocks" in p.stderr, f"column-block input: {p.stderr}")
    p = cpca(sub, os.path.join(d, "bad.ltm"), "-k", 5, "-s", 3, "--mem-limit", "1MiB", expect=1)
    t.check("--mem-limit" in p.stderr and "MiB" in p.stderr, f"mem-limit: {p.stderr}")
    t.check(not os.path.exists(os.path.join(d, "bad.ltm")), "a refused run left an output")
    # a cpca.ltm is not a transport matrix: the wavelet stages refuse it
    for stage in ["row-transform", "transpose", "column-transform"]:
        p = t.run(stage, os.path.join(d, "sub_cpca.ltm"), "-o", os.path.join(d, "bad.ltm"), expect=1)
        t.check("sub_cpca.ltm" in p.stderr and "is a cpca output" in p.stderr, f"{stage} of cpca.ltm: {p.stderr}")

    # 7. Resume after SIGKILL: kills at random moments (iterating, checkpointing or writing);
    #    every partial output verifies, and the finished file equals an uninterrupted run.
    kk, ss, dd, nn = 12, 6, 192, 40000
    big, _ = affine_rows(g, kk, ss, dd, nn)
    big = (big + 0.2 * g.standard_normal(big.shape)).astype(np.float32)
    np.save(os.path.join(d, "big.npy"), big)
    bigl = os.path.join(d, "big.ltm")
    t.run("convert", os.path.join(d, "big.npy"), bigl, "--chunk-size", "1MiB", "-q")
    args = ["-k", kk, "-s", ss, "--max-iterations", 12, "--tolerance", 0]
    ref_out = os.path.join(d, "big_ref.ltm")
    t0 = time.monotonic()
    cpca(bigl, ref_out, *args)
    full_time = time.monotonic() - t0
    out = os.path.join(d, "big_cpca.ltm")
    t.kill_storm(["cpca", bigl, "-o", out, "--progress", "never", *args], out, kills=6,
                 max_delay=full_time, seed=3)
    r = cpca(bigl, out, *args)
    t.check(hashes(out) == hashes(ref_out), f"resumed output differs: {hashes(out)} vs {hashes(ref_out)}")
    t.check(not os.path.exists(out + ".cpca-state"), "checkpoint left after a finished run")
    # SIGINT mid-run: exit 130, and the rerun resumes from the checkpoint.
    out2 = os.path.join(d, "big_int.ltm")
    pr = subprocess.Popen([t.LTBAKE, "cpca", bigl, "-o", out2, "--progress", "never", *map(str, args)],
                          stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    # Interrupt as soon as the first checkpoint exists (a condition, not a time: an
    # interrupt during initialisation keeps nothing, by design, and a finished run removes
    # its checkpoint, so the run is mid-iteration when the signal arrives).
    t_start = time.monotonic()
    while pr.poll() is None and not os.path.exists(out2 + ".cpca-state") and time.monotonic() - t_start < 600:
        time.sleep(0.01)
    t.check(pr.poll() is None, "the run ended before its first checkpoint was seen")
    pr.send_signal(2)
    _, err = pr.communicate()
    t.check(pr.returncode == 130, f"SIGINT: exit {pr.returncode}: {err}")
    t.check(os.path.exists(out2 + ".cpca-state"), "SIGINT: no checkpoint kept")
    r = cpca(bigl, out2, *args)
    t.check(r["resumed"], f"rerun after SIGINT did not resume: {r}")
    t.check(hashes(out2) == hashes(ref_out), "output after SIGINT + rerun differs")

t.finish()
