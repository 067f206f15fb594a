"""column-transform and quantize through the ltbake binary, against NumPy/PyWavelets.

- haar, fixed depth and adaptive: the decoded matrix equals an independent PyWavelets
  computation (wavedec2 with mode='periodization', keep the N largest, waverec2), and the
  reported total error equals the error of the decoded matrix.
- --keep 1 (every term) round-trips to float precision for every filter; --depth none is
  the N largest pixels of each column.
- --budget K at the nonzero count of a --terms run gives no more total error.
- quantize: decoded final.ltm stays close to cols4d.ltm; --scaling level equals none at
  depth 0 and lowers the error on Haar columns; identical across --jobs; SIGKILL + rerun
  resumes.
- refusals: row-block input (names transpose), rows that are not an image (names cpca).

usage: column_transform_test.py PATH_TO_LTBAKE
"""
import json
import os
import sys
import tempfile

import numpy as np
import pywt

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import check, finish, kill_storm, run  # noqa: E402


def info(path):
    return json.loads(run("inspect", path, "--json", "--content").stdout)


def decode(path, d, name="dec.npy", *extra):
    out = os.path.join(d, name)
    run("convert", path, out, "--progress", "never", *extra)
    return np.load(out)


def column_images(w, h, cols, seed):
    """cols column images (h×w), mixing smooth light, hard shadows, single pixels and noise."""
    g = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w].astype(np.float64)
    out = []
    for j in range(cols):
        kind = j % 6
        if kind == 0:
            img = 1.0 + 0.3 * np.sin(0.2 * x + 0.05 * j) * np.cos(0.15 * y)
        elif kind == 1:
            img = np.where(x * (1 + j % 3) > y + w / 2, 0.8, 0.1) + 0.01 * g.standard_normal((h, w))
        elif kind == 2:
            img = np.zeros((h, w))
            img[g.integers(h), g.integers(w)] = 2.0
        elif kind == 3:
            img = g.standard_normal((h, w)) * 0.1
        elif kind == 4:
            img = np.full((h, w), 0.5)
        else:
            img = np.exp(-((x - w / 3) ** 2 + (y - h / 2) ** 2) / (2 * (w / 5) ** 2))
        out.append(img)
    out[7] = np.zeros((h, w))  # an empty column
    return np.stack([im.reshape(-1) for im in out], axis=1).astype(np.float32)  # rows = y*w + x


def nterm_haar(img, depth, n):
    """(error, reconstruction, kept) of the best n-term haar approximation at depth."""
    if depth == 0:
        c = img.astype(np.float64)
        flat = c.reshape(-1)
        keep = np.argsort(-np.abs(flat), kind="stable")[:n]
        keep = keep[flat[keep] != 0]
        rec = np.zeros_like(flat)
        rec[keep] = flat[keep]
        return float(((flat - rec) ** 2).sum()), rec.reshape(img.shape), len(keep)
    coeffs = pywt.wavedec2(img.astype(np.float64), "haar", mode="periodization", level=depth)
    arr, slices = pywt.coeffs_to_array(coeffs)
    flat = arr.reshape(-1)
    keep = np.argsort(-np.abs(flat), kind="stable")[:n]
    keep = keep[np.abs(flat[keep]) > 1e-6 * np.abs(flat).max()]
    kept = np.zeros_like(flat)
    kept[keep] = flat[keep]
    rec = pywt.waverec2(pywt.array_to_coeffs(kept.reshape(arr.shape), slices, output_format="wavedec2"), "haar",
                        mode="periodization")
    return float(((img - rec) ** 2).sum()), rec, len(keep)


with tempfile.TemporaryDirectory() as d:
    W = H = 16
    R = 2
    m = column_images(W, H, 6 * R * R, seed=4)
    src = os.path.join(d, "m.npy")
    np.save(src, m)
    cols = os.path.join(d, "cols.ltm")
    run("convert", src, cols, "--cube-res", R, "--image", f"{W}x{H}", "--layout", "cols", "--chunk-size", "4KiB",
        "--progress", "never")
    energy = float((m.astype(np.float64) ** 2).sum())

    def ct(out, *args, jobs=2):
        p = run("column-transform", cols, "-o", out, "--json", "--progress", "never", "--jobs", jobs, *args)
        return json.loads(p.stdout) if p.returncode == 0 else None

    # 1. haar at fixed depths and adaptive, against PyWavelets.
    N = 12
    for depth_arg in ["0", "2", "4", "adaptive"]:
        out = os.path.join(d, f"haar_{depth_arg}.ltm")
        rep = ct(out, "--filter", "haar", "--depth", depth_arg, "--terms", N)
        dec = decode(out, d)
        expect = np.zeros_like(m, dtype=np.float64)
        total = 0.0
        for j in range(m.shape[1]):
            img = m[:, j].reshape(H, W).astype(np.float64)
            if depth_arg == "adaptive":
                tries = [nterm_haar(img, dd, N) for dd in range(0, 5)]
                tol = (64 * 2.0 ** -24) ** 2 * (img ** 2).sum()
                best = 0
                for dd in range(1, 5):
                    e, _, k = tries[dd]
                    be, _, bk = tries[best]
                    if (e <= tol and be <= tol and k < bk) or (not (e <= tol and be <= tol) and e < be):
                        best = dd
                err, rec, _ = tries[best]
            else:
                err, rec, _ = nterm_haar(img, int(depth_arg), N)
            expect[:, j] = rec.reshape(-1)
            total += err
        scale = np.abs(m).max()
        diff = np.abs(dec - expect).max()
        check(diff <= 1e-5 * scale, f"haar depth {depth_arg}: decoded differs from PyWavelets by {diff}")
        actual = float(((dec.astype(np.float64) - m) ** 2).sum())
        check(abs(rep["error"] - actual) <= 1e-4 * actual + 1e-9 * energy,
              f"haar depth {depth_arg}: reported error {rep['error']} but decoded error is {actual}")
        check(abs(rep["error"] - total) <= 1e-4 * total + 1e-9 * energy,
              f"haar depth {depth_arg}: reported error {rep['error']}, PyWavelets {total}")
        check(rep["empty_columns"] == 1, f"empty columns: {rep['empty_columns']}")

    # 2. --depth none keeps the N largest pixels of each column.
    out = os.path.join(d, "none.ltm")
    ct(out, "--depth", "none", "--terms", 5)
    dec = decode(out, d)
    for j in range(m.shape[1]):
        col = m[:, j]
        order = np.argsort(-np.abs(col), kind="stable")[:5]
        thresh = np.abs(col[order[-1]])
        kept = dec[:, j] != 0
        check(np.all(dec[kept, j] == col[kept]), f"depth none column {j}: kept values changed")
        check(kept.sum() <= 5 and np.all(np.abs(col[kept]) >= thresh), f"depth none column {j}: wrong terms kept")

    # 3. Every term kept: exact to float precision, every filter (odd sizes too).
    for filt in ["haar", "db2", "db3", "db4", "legall53", "cdf97"]:
        out = os.path.join(d, f"all_{filt}.ltm")
        rep = ct(out, "--filter", filt, "--keep", 1)
        dec = decode(out, d)
        err = np.abs(dec - m).max()
        check(err <= 1e-5 * np.abs(m).max(), f"{filt} --keep 1: max error {err}")
    odd = column_images(13, 7, 24, seed=8)
    np.save(os.path.join(d, "odd.npy"), odd)
    odd_ltm = os.path.join(d, "odd.ltm")
    run("convert", os.path.join(d, "odd.npy"), odd_ltm, "--image", "13x7", "--layout", "cols", "--progress", "never")
    for filt in ["legall53", "cdf97"]:
        out = os.path.join(d, f"odd_{filt}.ltm")
        run("column-transform", odd_ltm, "-o", out, "--filter", filt, "--keep", 1, "--progress", "never")
        dec = decode(out, d)
        check(np.abs(dec - odd).max() <= 1e-5 * np.abs(odd).max(), f"odd 13x7 {filt}: not exact")
    p = run("column-transform", odd_ltm, "-o", os.path.join(d, "odd_haar.ltm"), "--filter", "haar", expect=1)
    check("power-of-two" in p.stderr, f"haar on 13x7 should explain the size: {p.stderr}")

    # 4. Budget vs per-column N at the same number of nonzeros.
    for filt in ["haar", "legall53"]:
        per = ct(os.path.join(d, f"per_{filt}.ltm"), "--filter", filt, "--terms", 10)
        bud = ct(os.path.join(d, f"bud_{filt}.ltm"), "--filter", filt, "--budget", per["nonzeros"])
        check(per["nonzeros"] * 0.99 <= bud["nonzeros"] <= per["nonzeros"],
              f"{filt}: budget {per['nonzeros']} but {bud['nonzeros']} kept (met from below, to the trimmed residue)")
        check(bud["error"] <= per["error"],
              f"{filt}: budget error {bud['error']} > per-column error {per['error']} at {per['nonzeros']} nonzeros")
        dec = decode(os.path.join(d, f"bud_{filt}.ltm"), d)
        actual = float(((dec.astype(np.float64) - m) ** 2).sum())
        check(abs(bud["error"] - actual) <= 1e-4 * actual + 1e-9 * energy,
              f"{filt} budget: reported error {bud['error']}, decoded {actual}")

    # A budget of equal values (many pixels in one energy bin) is still met exactly.
    flat = os.path.join(d, "flat.ltm")
    rep = ct(flat, "--depth", "none", "--budget", 300)
    check(rep["nonzeros"] == 300, f"depth none --budget 300 kept {rep['nonzeros']}")

    # Budgets and fractions read as every size flag reads them: K, M, G are powers of 1024
    # (a size budget is 8 bytes per nonzero), KB, MB, GB powers of 1000; "5%" is 0.05.
    for text, nonzeros in (("2K", 2048 // 8), ("2KiB", 2048 // 8), ("2KB", 2000 // 8), ("4000B", 500)):
        rep = ct(os.path.join(d, "bud_size.ltm"), "--depth", "none", "--budget", text, "--overwrite")
        check(rep is not None and nonzeros * 0.99 <= rep["nonzeros"] <= nonzeros,
              f"--budget {text}: {rep and rep['nonzeros']} nonzeros, expected {nonzeros} (met from below)")
    hk = []
    for keep in ("0.25", "25%"):
        out = os.path.join(d, f"keep_{len(hk)}.ltm")
        ct(out, "--keep", keep)
        hk.append(info(out)["content_hash"])
    check(hk[0] == hk[1], "--keep 25% and --keep 0.25 give different outputs")
    # Bad values are usage errors (exit 2) naming the flag, before any file is opened.
    for args in (("--budget", "12Q"), ("--budget", "0"), ("--budget", "150%"), ("--keep", "0"), ("--keep", "2x"),
                 ("--keep", "101%"), ("--mem-limit", "64Q")):
        p = run("column-transform", os.path.join(d, "missing.ltm"), "-o", os.path.join(d, "never.ltm"), *args,
                expect=2)
        check(p.returncode == 2 and args[0] in p.stderr, f"{args}: exit {p.returncode}, stderr {p.stderr!r}")
        check(not os.path.exists(os.path.join(d, "never.ltm")), f"{args}: an output was written")

    # 5. quantize.
    c4 = os.path.join(d, "c4.ltm")
    ct(c4, "--terms", 40)
    ref = decode(c4, d, "c4.npy")
    fin = os.path.join(d, "final.ltm")
    q = json.loads(run("quantize", c4, "-o", fin, "--bits", 9, "--json", "--progress", "never").stdout)
    got = decode(fin, d, "final.npy")
    rel = np.sqrt(((got - ref) ** 2).sum() / (ref.astype(np.float64) ** 2).sum())
    check(rel < 0.01, f"quantize 9 bits: relative RMS change {rel}")
    check(q["bytes_per_nonzero"] > 0 and q["nonzeros_out"] <= q["nonzeros_in"], f"quantize report: {q}")
    # The default, one step for the matrix (--error-ratio 1.1): against the original matrix
    # m, the decoded error is at most 1.1x column-transform's in RMS (Haar: orthonormal, so
    # truncation and quantization errors add exactly and the reported ratio is the NumPy
    # one; LeGall 5/3: biorthogonal, within the 1.2x). Larger ratios, fewer bytes.
    mm = m.astype(np.float64)
    for filt, slack in (("haar", 1.0), ("legall53", 1.2 / 1.1)):
        c_ = os.path.join(d, f"c4_{filt}.ltm")
        ct(c_, "--filter", filt, "--budget", "10%")
        e_t = float(((decode(c_, d, "ct.npy") - mm) ** 2).sum())
        sizes = {}
        for ratio in (1.1, 1.5):
            f_ = os.path.join(d, f"fs_{filt}_{ratio}.ltm")
            args = ("--error-ratio", ratio) if ratio != 1.1 else ()
            qs = json.loads(run("quantize", c_, "-o", f_, "--json", "--progress", "never", *args).stdout)
            e_q = float(((decode(f_, d, "fs.npy") - mm) ** 2).sum())
            got_ratio = np.sqrt(e_q / e_t)
            check(qs["mode"] == "step" and 1.0 <= got_ratio <= ratio * slack + 1e-6,
                  f"{filt} --error-ratio {ratio}: decoded RMS error x{got_ratio:.4f} over column-transform's")
            if filt == "haar":
                check(abs(qs["rms_error_ratio"] - got_ratio) <= 1e-3 * got_ratio,
                      f"haar: reported ratio {qs['rms_error_ratio']} vs NumPy {got_ratio}")
            sizes[ratio] = qs["matrix_bytes"]
        check(sizes[1.5] < sizes[1.1], f"{filt}: a larger --error-ratio should store fewer bytes: {sizes}")
    # --bits rounds by default (dithering costs RMS error); --dither asks for it.
    hd = {}
    for extra in ((), ("--no-dither",), ("--dither",)):
        out = os.path.join(d, "fd.ltm")
        run("quantize", c4, "-o", out, "--bits", 9, "--overwrite", "--progress", "never", *extra)
        hd[extra] = info(out)["content_hash"]
    check(hd[()] == hd[("--no-dither",)] != hd[("--dither",)], f"--bits default should round: {hd}")
    # --scaling: at depth 0 every factor is 1, so level and none store the same integers;
    # on Haar columns level scaling (factor 2^l) lowers the quantization error.
    c0 = os.path.join(d, "c0.ltm")
    ct(c0, "--depth", "none", "--terms", 40)
    h0 = []
    for scaling in ("level", "none"):
        out = os.path.join(d, f"f0_{scaling}.ltm")
        run("quantize", c0, "-o", out, "--bits", 9, "--scaling", scaling, "--progress", "never")
        h0.append(info(out)["content_hash"])
    check(h0[0] == h0[1], "depth none: --scaling level and none should store the same integers")
    ch = os.path.join(d, "ch.ltm")
    ct(ch, "--filter", "haar", "--depth", "full", "--terms", 60)
    refh = decode(ch, d, "ch.npy").astype(np.float64)
    errs = {}
    for scaling in ("level", "none"):
        out = os.path.join(d, f"fh_{scaling}.ltm")
        run("quantize", ch, "-o", out, "--scaling", scaling, "--bits", 6, "--no-dither", "--progress", "never")
        errs[scaling] = float(((decode(out, d, "fh.npy") - refh) ** 2).sum())
    check(errs["level"] < errs["none"], f"haar: level scaling should lower the quantization error: {errs}")
    inspected = json.loads(run("inspect", fin, "--json", "--content").stdout)
    check("depth_histogram" in inspected.get("column_transform", {}) and
          "bytes_per_nonzero" in inspected.get("quantization", {}), f"inspect misses depths/bytes: {inspected.keys()}")
    # Without --content inspect reads no payload: the quantized nonzeros are not counted, the
    # payload bytes come from the index (the same number).
    fast = json.loads(run("inspect", fin, "--json").stdout)
    check("stats" not in fast and "nonzeros" not in fast["quantization"] and
          fast["quantization"]["matrix_bytes"] == inspected["quantization"]["matrix_bytes"] and
          fast["content_hash"] == inspected["content_hash"], f"inspect without --content: {fast.get('quantization')}")

    # 6. Determinism across --jobs (column-transform, budget, quantize).
    for args in [("--terms", 9), ("--budget", "3%")]:
        a = os.path.join(d, "j1.ltm")
        b = os.path.join(d, "j2.ltm")
        for p_ in (a, b):
            if os.path.exists(p_):
                os.remove(p_)
        ct(a, *args, jobs=1)
        ct(b, *args, jobs=2)
        check(info(a)["content_hash"] == info(b)["content_hash"], f"{args}: content_hash differs across --jobs")
    qa, qb = os.path.join(d, "qa.ltm"), os.path.join(d, "qb.ltm")
    run("quantize", c4, "-o", qa, "--jobs", 1, "--progress", "never")
    run("quantize", c4, "-o", qb, "--jobs", 2, "--progress", "never")
    check(info(qa)["content_hash"] == info(qb)["content_hash"], "quantize: content_hash differs across --jobs")

    # 7. Kill and resume on a larger input.
    big = column_images(64, 64, 6 * 8 * 8, seed=2)
    np.save(os.path.join(d, "big.npy"), big)
    big_ltm = os.path.join(d, "big.ltm")
    run("convert", os.path.join(d, "big.npy"), big_ltm, "--image", "64x64", "--cube-res", 8, "--layout", "cols",
        "--chunk-size", "16KiB", "--progress", "never")
    ref_out = os.path.join(d, "big_ref.ltm")
    run("column-transform", big_ltm, "-o", ref_out, "--terms", 50, "--progress", "never")
    out = os.path.join(d, "big_out.ltm")
    # 16 columns per chunk here (the default puts all 384 in one): kills land between chunks,
    # and the reference's other chunking must not change the content.
    kill_storm(["column-transform", big_ltm, "-o", out, "--terms", 50, "--block-cols", 16, "--progress", "never"], out,
               kills=6, max_delay=0.6, seed=3)
    run("column-transform", big_ltm, "-o", out, "--terms", 50, "--block-cols", 16, "--progress", "never")
    check(info(out)["content_hash"] == info(ref_out)["content_hash"], "column-transform after kills: content differs")
    qref = os.path.join(d, "big_q_ref.ltm")
    run("quantize", ref_out, "-o", qref, "--progress", "never")
    qout = os.path.join(d, "big_q.ltm")
    kill_storm(["quantize", out, "-o", qout, "--progress", "never"], qout, kills=4, max_delay=0.3, seed=4)
    run("quantize", out, "-o", qout, "--progress", "never")
    check(info(qout)["content_hash"] == info(qref)["content_hash"], "quantize after kills: content differs")

    # 10. The default selection is one budget of 5% of the matrix (not 5% of each column).
    dflt, b5, k5 = (os.path.join(d, n) for n in ("dflt.ltm", "b5.ltm", "k5.ltm"))
    ct(dflt)
    ct(b5, "--budget", "5%")
    ct(k5, "--keep", 0.05)
    check(info(dflt)["content_hash"] == info(b5)["content_hash"] != info(k5)["content_hash"],
          "the default selection should be --budget 5%")

    # 11. --target-error: the fewest nonzeros within a relative RMS error. Haar is
    # orthonormal, so the histograms' estimate is the error, which NumPy measures on the
    # decoded matrix; half the nonzeros (as a budget) is over the target.
    te = os.path.join(d, "te.ltm")
    rep = ct(te, "--filter", "haar", "--target-error", "5%")
    dec = decode(te, d, "te.npy").astype(np.float64)
    err_np = np.sqrt(((dec - m.astype(np.float64)) ** 2).sum() / energy)
    check(rep["relative_rms_error"] <= 0.05 + 1e-9 and abs(err_np - rep["relative_rms_error"]) <= 1e-4 * err_np and
          abs(rep["estimated_error"] - rep["relative_rms_error"]) <= 1e-6, f"--target-error 5%: {rep}, NumPy {err_np}")
    half = ct(os.path.join(d, "te_half.ltm"), "--filter", "haar", "--budget", str(rep["nonzeros"] // 2))
    check(half["relative_rms_error"] > 0.05, f"half the nonzeros should miss 5%: {half['relative_rms_error']}")
    p_ = run("column-transform", cols, "-o", os.path.join(d, "never.ltm"), "--target-error", "5%", "--budget", "2%",
             expect=2)
    check("--target-error" in p_.stderr or "--budget" in p_.stderr, f"--target-error with --budget: {p_.stderr}")

    # 9. Column-group chunks: any --block-cols stores the same matrix and side
    # tables; the default groups columns, so the container's own bytes (frame headers,
    # index) are a small part of the file; inspect's on-disk parts add up to the file.
    hashes, disk = {}, {}
    for bc in (None, 1, 7):
        c_ = os.path.join(d, f"bc{bc}.ltm")
        q_ = os.path.join(d, f"bcq{bc}.ltm")
        ct(c_, "--budget", "4%", *(("--block-cols", bc) if bc else ()))
        run("quantize", c_, "-o", q_, "--progress", "never")
        ic, iq = info(c_), info(q_)
        hashes[bc] = [a.get("content_hash") for a in ic["arrays"] + iq["arrays"]]
        disk[bc] = iq["on_disk"]
        od = iq["on_disk"]
        check(od["total_bytes"] == os.path.getsize(q_) and
              od["matrix_bytes"] + od["side_table_bytes"] + od["overhead_bytes"] == od["total_bytes"],
              f"--block-cols {bc}: on_disk parts do not add up to the file: {od}")
        qj = json.loads(run("quantize", c_, "-o", q_, "--overwrite", "--json", "--progress", "never").stdout)
        check(qj.get("file_bytes") == os.path.getsize(q_), f"quantize --json file_bytes {qj.get('file_bytes')}")
        if bc == 7:
            check(ic["block"] == 7 and ic["chunks"]["expected"] == -(-m.shape[1] // 7), f"--block-cols 7: {ic['chunks']}")
        if bc is None:
            check(ic["block"] == m.shape[1] and iq["block"] == m.shape[1], f"default block: {ic['block']} (expected all {m.shape[1]} columns)")
    check(hashes[None] == hashes[1] == hashes[7], f"--block-cols changes the content: {hashes}")
    # Each matrix chunk costs at least its 64-byte frame header and 72-byte index entry; the
    # per-column tables of final.ltm are one chunk each whatever the grouping.
    check(disk[1]["overhead_bytes"] - disk[None]["overhead_bytes"] >= (m.shape[1] - 1) * (64 + 72) and
          disk[None]["overhead_bytes"] < 4096, f"column groups should cut the container's bytes: {disk}")

    # 8. Refusals.
    rows_ltm = os.path.join(d, "rows.ltm")
    run("convert", src, rows_ltm, "--cube-res", R, "--image", f"{W}x{H}", "--progress", "never")
    p = run("column-transform", rows_ltm, "-o", os.path.join(d, "x.ltm"), expect=1)
    check("ltbake transpose" in p.stderr, f"row-block input should point at transpose: {p.stderr}")
    gen = os.path.join(d, "generic.ltm")
    run("convert", src, gen, "--layout", "cols", "--progress", "never")
    p = run("column-transform", gen, "-o", os.path.join(d, "y.ltm"), expect=1)
    check("cpca" in p.stderr and "--depth none" in p.stderr, f"non-image rows should point at cpca: {p.stderr}")
    run("column-transform", gen, "-o", os.path.join(d, "z.ltm"), "--depth", "none", "--terms", 3)
    p = run("quantize", cols, "-o", os.path.join(d, "q.ltm"), expect=1)
    check("column-transform" in p.stderr, f"quantize of a non-transformed file: {p.stderr}")
    p = run("quantize", fin, "-o", os.path.join(d, "qq.ltm"), expect=1)
    check("already quantized" in p.stderr, f"quantize twice: {p.stderr}")

finish()
