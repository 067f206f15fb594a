"""relight through the ltbake binary, against NumPy/PyWavelets on `convert` outputs.

- depth none, every term, no quantization: relighting equals T·L (NumPy, pixel basis).
- adaptive depths (Eq. 8), with and without quantization: relighting equals the decoded
  matrix times the same N-term lighting (PyWavelets Haar transform of L per face, area
  weighting re-implemented here), to float precision: Eq. 8 is exact.
- rows.ltm (streamed) equals T·L; --reference reports errors that match NumPy's.
- .exr / .png / .npy outputs; bad cubemaps fail clearly.

usage: relight_test.py PATH_TO_LTBAKE
"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import check, finish, haar_faces, run, side_table  # noqa: E402


def area_weights(R):
    a = np.ones(R * R)
    for t in range(R):
        for s in range(R):
            m = max(s, t)
            a[t * R + s] = R * R if m == 0 else (R / 2 ** int(np.floor(np.log2(m)))) ** 2
    return np.tile(a, 6)


def select(Lw, n, weights):
    mag = np.sqrt((Lw.astype(np.float64) ** 2).sum(axis=1)) * weights
    idx = np.nonzero(mag > 0)[0]
    order = idx[np.lexsort((idx, -mag[idx]))][:n]
    kept = np.zeros_like(Lw)
    kept[order] = Lw[order]
    return kept


with tempfile.TemporaryDirectory() as d:
    W, H, R = 16, 8, 4
    rows, cols = W * H, 6 * R * R
    g = np.random.default_rng(3)
    y, x = np.mgrid[0:H, 0:W]
    T = np.zeros((rows, cols), np.float32)
    for j in range(cols):
        img = np.maximum(0, np.sin(0.3 * x + 0.2 * j) + 0.5 * np.cos(0.4 * y - 0.1 * j)) * g.uniform(0.2, 1.0)
        if j % 5 == 0:
            img = img * (x > (j % W))  # hard shadow edges
        T[:, j] = img.reshape(-1)
    T[:, 7] = 0  # a light that reaches nothing
    np.save(os.path.join(d, "T.npy"), T)
    L = (g.uniform(0, 1, (cols, 3)) ** 4 * 5).astype(np.float32)  # a few bright texels
    env = os.path.join(d, "env.npy")
    np.save(env, L)
    p = lambda name: os.path.join(d, name)  # noqa: E731
    q = ["--progress", "never"]
    run("convert", p("T.npy"), p("raw.ltm"), "--cube-res", R, "--image", f"{W}x{H}", "--chunk-size", "4KiB", *q)
    run("row-transform", p("raw.ltm"), "-o", p("rows.ltm"), "--filter", "haar", *q)
    run("transpose", p("rows.ltm"), "-o", p("cols.ltm"), *q)
    run("convert", p("rows.ltm"), p("rows.npy"), *q)
    Tw = np.load(p("rows.npy")).astype(np.float64)
    exact = T.astype(np.float64) @ L.astype(np.float64)

    def relight(matrix, out, *args):
        r = run("relight", matrix, "--env", env, "-o", out, "--json", *q, *args)
        return json.loads(r.stdout) if r.returncode == 0 else {}

    # 1. depth none, every term, no quantization == T·L.
    run("column-transform", p("cols.ltm"), "-o", p("c0.ltm"), "--depth", "none", "--keep", 1, *q)
    relight(p("c0.ltm"), p("b0.npy"), "--terms", cols)
    b0 = np.load(p("b0.npy")).astype(np.float64)
    err = np.abs(b0 - exact).max() / np.abs(exact).max()
    check(err < 1e-5, f"depth none, all terms: relative max error {err} against T·L")
    # --terms all: every nonzero lighting coefficient, the same image as N = 6R².
    rep = relight(p("c0.ltm"), p("b0all.npy"), "--terms", "all")
    check(rep.get("terms") == "all" and np.array_equal(np.load(p("b0all.npy")), np.load(p("b0.npy"))),
          f"--terms all differs from --terms {cols}: {rep}")
    for bad in ("0", "-3", "some", "1.5"):
        r = run("relight", p("c0.ltm"), "--env", env, "-o", p("never.npy"), "--terms", bad, expect=2)
        check("--terms" in r.stderr and not os.path.exists(p("never.npy")), f"--terms {bad}: {r.stderr}")
    # Numbers in flags (stages/common/quantity.h ParseDecimal, which the view server uses too):
    # non-finite, hexadecimal, trailing text and out-of-range values are usage errors that
    # name the flag and quote the value, before anything is read or written.
    for flag, bad in (("--rotate", "nan"), ("--rotate", "inf"), ("--rotate", "-inf"), ("--rotate", "1e20"),
                      ("--rotate", "0x10"), ("--rotate", "5abc"), ("--rotate", " 5"), ("--exposure", "nan"),
                      ("--exposure", "inf"), ("--exposure", "-1"), ("--exposure", "1e13"), ("--fov", "nan"),
                      ("--fov", "0x10"), ("--fov", "200"), ("--fps", "inf"), ("--fps", "2000"), ("--fps", "25fps")):
        r = run("relight", p("c0.ltm"), "--env", env, "-o", p("never.png"), flag, bad, expect=2)
        check(f'{flag}: "{bad}"' in r.stderr and not os.path.exists(p("never.png")), f"{flag} {bad!r}: {r.stderr}")
    # A cubemap .npy cannot rotate: --rotate with one is refused, not ignored.
    r = run("relight", p("c0.ltm"), "--env", env, "-o", p("never.npy"), "--rotate", "30", expect=1)
    check("--rotate 30" in r.stderr and "cannot rotate" in r.stderr and not os.path.exists(p("never.npy")),
          f"--rotate with a cubemap .npy: {r.stderr}")
    check(relight(p("c0.ltm"), p("b0r.npy"), "--terms", "all", "--rotate", "0", "--exposure", "2.5e-1") != {},
          "--rotate 0 --exposure 2.5e-1 should be accepted")

    # 2. adaptive (Eq. 8): equals decoded matrix × the same N-term lighting.
    Lw = haar_faces(L, R)
    for name, extra in [("ca", []), ("cq", ["quantize"])]:
        run("column-transform", p("cols.ltm"), "-o", p(f"{name}4d.ltm"), "--keep", 0.3, "--filter", "legall53", *q)
        mat = p(f"{name}4d.ltm")
        if extra:
            run("quantize", mat, "-o", p(f"{name}.ltm"), *q)
            mat = p(f"{name}.ltm")
        run("convert", mat, p(f"{name}.npy"), *q)
        D = np.load(p(f"{name}.npy")).astype(np.float64)
        for weighting, terms in [("area", 17), ("none", 30), ("area", cols)]:
            rep = relight(mat, p("b.npy"), "--terms", terms, "--weighting", weighting)
            b = np.load(p("b.npy")).astype(np.float64)
            w = area_weights(R) if weighting == "area" else np.ones(cols)
            want = D @ select(Lw, terms, w)
            e = np.abs(b - want).max() / np.abs(want).max()
            check(e < 2e-5, f"{name} {weighting} N={terms}: Eq. 8 relighting differs from decoded × lighting by {e}")
            check(rep.get("terms_used") == min(terms, int((np.abs(Lw).sum(axis=1) > 0).sum())),
                  f"{name}: terms_used {rep.get('terms_used')}")

    # 3. transport weighting needs column norms: works on final.ltm, which records none: for
    # Haar columns (orthonormal) its estimate from the kept coefficients is the norm of the
    # decoded column, so the image is the decoded matrix times the lighting chosen by NumPy.
    rep = relight(p("cq.ltm"), p("bt.npy"), "--terms", 10, "--weighting", "transport")
    check(rep.get("terms_used") == 10, f"transport weighting: {rep}")
    run("column-transform", p("cols.ltm"), "-o", p("ch4d.ltm"), "--keep", 0.3, "--filter", "haar", *q)
    run("quantize", p("ch4d.ltm"), "-o", p("ch.ltm"), *q)
    run("convert", p("ch.ltm"), p("ch.npy"), *q)
    D = np.load(p("ch.npy")).astype(np.float64)
    for terms in (5, 17):
        relight(p("ch.ltm"), p("bt.npy"), "--terms", terms, "--weighting", "transport")
        want = D @ select(Lw, terms, np.sqrt((D ** 2).sum(axis=0)))
        e = np.abs(np.load(p("bt.npy")) - want).max() / np.abs(want).max()
        check(e < 2e-5, f"haar final.ltm, transport weighting, N={terms}: differs from NumPy's choice by {e}")

    # 3b. What a term is: in pixel-basis columns (raw.ltm) one texel, and the text says so;
    # the share of the map's energy kept is NumPy's for the 10 brightest texels (|rgb|).
    # In a row-transformed bake a term is a wavelet coefficient; with every term, all of it.
    rp = relight(p("raw.ltm"), p("bp.npy"), "--terms", 10, "--weighting", "none")
    e = (L.astype(np.float64) ** 2).sum(axis=1)
    want_kept = np.sort(e)[-10:].sum() / e.sum()
    check(rp.get("terms_basis") == "pixels" and rp.get("terms_available") == cols and
          abs(rp.get("lighting_energy_kept", -1) - want_kept) <= 1e-6, f"pixel terms: {rp} (NumPy kept {want_kept})")
    txt = run("relight", p("raw.ltm"), "--env", env, "-o", p("bp.npy"), "--terms", 10, *q).stdout
    check("10 of " + str(cols) in txt and "texels" in txt and "--terms all" in txt, f"pixel terms text: {txt}")
    rw = relight(p("c0.ltm"), p("bw.npy"), "--terms", "all")
    check(rw.get("terms_basis") == "wavelet haar" and abs(rw.get("lighting_energy_kept", -1) - 1) <= 1e-9, f"{rw}")
    txt = run("relight", p("c0.ltm"), "--env", env, "-o", p("bw.npy"), "--terms", 10, *q).stdout
    check("wavelet coefficients, haar" in txt and "note:" not in txt, f"wavelet terms text: {txt}")

    # 4. rows.ltm, streamed == T·L with all terms; the reference metrics match NumPy.
    relight(p("rows.ltm"), p("br.npy"), "--terms", cols)
    br = np.load(p("br.npy")).astype(np.float64)
    check(np.abs(br - exact).max() / np.abs(exact).max() < 1e-5, "rows.ltm streamed relighting differs from T·L")
    rep = relight(p("cq.ltm"), p("bq.npy"), "--terms", 25, "--reference", p("raw.ltm"))
    bq = np.load(p("bq.npy")).astype(np.float64)
    l2 = np.sqrt(((bq - exact) ** 2).sum() / (exact ** 2).sum())
    check(abs(rep["error"]["rel_l2"] - l2) <= 1e-4 * l2 + 1e-7, f"reported rel L2 {rep['error']['rel_l2']}, NumPy {l2}")
    img_d = (bq - exact).reshape(H, W, 3)
    img_r = exact.reshape(H, W, 3)
    grad = lambda a: (np.diff(a, axis=0) ** 2).sum() + (np.diff(a, axis=1) ** 2).sum()  # noqa: E731
    h1 = np.sqrt(grad(img_d) / grad(img_r))
    check(abs(rep["error"]["rel_h1"] - h1) <= 1e-4 * h1 + 1e-7, f"reported rel H1 {rep['error']['rel_h1']}, NumPy {h1}")
    psnr = 20 * np.log10(exact.max() / np.sqrt(((bq - exact) ** 2).mean()))
    check(abs(rep["error"]["psnr_db"] - psnr) < 1e-3, f"PSNR {rep['error']['psnr_db']} vs {psnr}")
    for k in ("error_lighting_only", "error_matrix_only"):
        check(k in rep and rep[k]["rel_l2"] <= rep["error"]["rel_l2"] * 1.5 + 1e-6, f"{k}: {rep.get(k)}")
    rep_all = relight(p("c0.ltm"), p("b0b.npy"), "--terms", cols, "--reference", p("raw.ltm"))
    check(rep_all["error"]["rel_l2"] < 1e-6, f"lossless path should have ~0 error: {rep_all['error']}")

    # 5. Output formats.
    relight(p("cq.ltm"), p("img.exr"), "--terms", 20)
    relight(p("cq.ltm"), p("img.png"), "--terms", 20)
    with open(p("img.exr"), "rb") as f:
        check(f.read(4) == bytes([0x76, 0x2F, 0x31, 0x01]), "img.exr is not an OpenEXR file")
    with open(p("img.png"), "rb") as f:
        check(f.read(8) == b"\x89PNG\r\n\x1a\n", "img.png is not a PNG file")
    check(not any(".partial" in n for n in os.listdir(d)), "partial files left")

    # 6. Bad lighting.
    np.save(p("bad_shape.npy"), L[:10])
    r = run("relight", p("cq.ltm"), "--env", p("bad_shape.npy"), "-o", p("x.npy"), expect=1)
    check("96 x 3" in r.stderr or "(96, 3)" in r.stderr, f"wrong-size cubemap: {r.stderr}")
    Lbad = L.copy()
    Lbad[5, 1] = np.nan
    np.save(p("bad_nan.npy"), Lbad)
    r = run("relight", p("cq.ltm"), "--env", p("bad_nan.npy"), "-o", p("x.npy"), expect=1)
    check("texel 5 channel 1" in r.stderr, f"NaN texel should be named: {r.stderr}")
    # A tiny negative texel (what `convert`'s cancellation used to write) is named in full, not
    # as -0.000000, and --clamp applies to a cubemap .npy as to a map: the texel becomes 0.
    Lneg = L.copy()
    Lneg[9, 2] = -5.551115123125783e-17
    np.save(p("neg.npy"), Lneg)
    r = run("relight", p("c0.ltm"), "--env", p("neg.npy"), "-o", p("x.npy"), expect=1)
    check("texel 9 channel 2 is -5.55111512e-17 (negative)" in r.stderr and "--clamp" in r.stderr,
          f"a negative texel should be named in full with the fix: {r.stderr}")
    rep = json.loads(run("relight", p("c0.ltm"), "--env", p("neg.npy"), "-o", p("bneg.npy"), "--terms", "all", "--clamp",
                         "--json", *q).stdout or "{}")
    want = T.astype(np.float64) @ np.maximum(Lneg, 0).astype(np.float64)
    err = np.abs(np.load(p("bneg.npy")) - want).max() / np.abs(want).max() if os.path.exists(p("bneg.npy")) else 1
    check(rep.get("clamped_values") == 1 and err < 1e-5, f"--clamp with a cubemap .npy: {rep}, error {err}")
    r = run("relight", p("cq.ltm"), "--env", env, "-o", p("x.png"), "--weighting", "sideways", expect=2)
    r = run("relight", p("cols.ltm"), "--env", env, "-o", p("x.npy"), "--mem-limit", "10KiB", expect=1)
    check("--mem-limit" in r.stderr, f"a matrix over --mem-limit should be refused naming it: {r.stderr}")

    # 6b. The documented workflow on a map that is black outside a window (as an OpenEXR display
    # window larger than its data window reads): `convert` writes no negative texel (cancellation
    # in prefix sums used to leave ±3e-16 over the black part, which relight then refused), and
    # relighting from the .npy equals relighting from the map.
    Hm, Wm = 128, 256
    win = np.zeros((Hm, Wm, 3))
    win[Hm // 5:Hm // 2, Wm // 4:Wm // 2] = g.uniform(0.5, 1.5, (Hm // 2 - Hm // 5, Wm // 2 - Wm // 4, 3))
    mx = win.max(-1)
    ex = np.where(mx > 0, np.floor(np.log2(np.where(mx > 0, mx, 1))) + 1, 0).astype(int)
    rgbe = np.zeros((Hm, Wm, 4), np.uint8)
    rgbe[..., :3] = np.floor(win * np.where(mx > 0, 2.0 ** (8 - ex), 0)[..., None]).astype(np.uint8)
    rgbe[..., 3] = np.where(mx > 0, ex + 128, 0)
    with open(p("win.hdr"), "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (Hm, Wm) + rgbe.tobytes())
    run("convert", p("win.hdr"), p("win.npy"), "--cube-res", R, *q)
    cube = np.load(p("win.npy"))
    check(cube.min() >= 0 and (cube == 0).sum() > 0 and cube.max() > 0,
          f"convert of a windowed map: min texel {cube.min()}, {(cube < 0).sum()} negative, {(cube == 0).sum()} zero")
    for envfile, out in ((p("win.hdr"), p("bwh.npy")), (p("win.npy"), p("bwn.npy"))):
        run("relight", p("c0.ltm"), "--env", envfile, "-o", out, "--terms", "all", *q)
    if os.path.exists(p("bwh.npy")) and os.path.exists(p("bwn.npy")):
        a, b = np.load(p("bwh.npy")), np.load(p("bwn.npy"))
        check(np.array_equal(a, b), f"relight from win.npy differs from win.hdr by {np.abs(a - b).max()}")

    # 7. A real environment map (blender-data, CC0) through convert and relight.
    import subprocess
    envdir = subprocess.run(["bash", os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../scripts/find_envmaps.sh")],
                            capture_output=True, text=True).stdout.strip()
    exr = os.path.join(envdir, "forest.exr")
    if os.path.exists(exr):
        r = run("convert", exr, p("forest.npy"), "--cube-res", R, expect=1)
        check("--clamp" in r.stderr and "negative" in r.stderr, f"DWAB negatives should be refused: {r.stderr}")
        run("convert", exr, p("forest.npy"), "--cube-res", R, "--clamp", *q)
        cube = np.load(p("forest.npy"))
        check(cube.shape == (cols, 3) and np.all(np.isfinite(cube)) and np.all(cube >= 0) and cube.sum() > 0,
              f"forest cubemap: shape {cube.shape}")
        a = json.loads(run("relight", p("cq.ltm"), "--env", exr, "--clamp", "-o", p("fa.npy"), "--terms", 30,
                           "--json", *q).stdout)
        b = json.loads(run("relight", p("cq.ltm"), "--env", p("forest.npy"), "-o", p("fb.npy"), "--terms", 30,
                           "--json", *q).stdout)
        check(np.allclose(np.load(p("fa.npy")), np.load(p("fb.npy")), rtol=1e-5, atol=1e-7),
              "relighting from the .exr and from its converted cubemap differ")
        check(a.get("clamped_values", 0) > 0 and b.get("terms_used") == 30, f"env reports: {a} {b}")
    else:
        check(False, f"blender-data maps not found under {envdir!r}: scripts/setup.sh installs blender-data")

    # 8. What every output gets (docs/RELIGHT.md "Output"): negative radiance clamped to 0
    # unless --no-clamp-output. A transport matrix with negative entries makes T·L negative
    # in places; with every term the image is T·L exactly, so the clamped one is max(T·L, 0).
    Tn = T.copy()
    Tn[:, ::3] *= -1
    np.save(p("Tn.npy"), Tn)
    run("convert", p("Tn.npy"), p("tn.ltm"), "--cube-res", R, "--image", f"{W}x{H}", "--layout", "cols", *q)
    want = Tn.astype(np.float64) @ L.astype(np.float64)
    kept = relight(p("tn.ltm"), p("tn_keep.npy"), "--terms", "all", "--no-clamp-output")
    clamped = relight(p("tn.ltm"), p("tn_clamp.npy"), "--terms", "all")
    nk, nc = np.load(p("tn_keep.npy")), np.load(p("tn_clamp.npy"))
    check((want < 0).sum() > 0 and np.abs(nk - want).max() <= 1e-5 * np.abs(want).max(),
          f"--no-clamp-output: differs from T·L by {np.abs(nk - want).max()} ({(want < 0).sum()} negative pixels)")
    check(np.array_equal(nc, np.maximum(nk, 0)), "default output is not max(T·L, 0)")
    check(clamped.get("output", {}).get("clamped_values") == int((nk < 0).sum()) and
          kept.get("output", {}).get("clamped_values") is None, f"clamp counts: {clamped.get('output')} {kept.get('output')}")

    # ... and rows that see no geometry (mask 0) are black: a real bake's final.ltm carries
    # the mask, and its column transform rings into those rows (the matrix decoded to pixels
    # holds nonzeros there). With every term, the image is D·L on mask-1 rows, 0 elsewhere.
    bake = p("bake")
    run("run", os.path.join(os.path.dirname(os.path.abspath(__file__)), "../../samples/tiny-bake.toml"), "--workdir",
        bake, "-q")
    fin = os.path.join(bake, "final.ltm")
    mask = side_table(fin, "mask")[:, 0]
    run("convert", fin, p("fin.npy"), "--basis", "pixels", *q)
    D = np.load(p("fin.npy")).astype(np.float64)
    Lb = np.random.default_rng(5).uniform(0.1, 1.0, (D.shape[1], 3)).astype(np.float32)
    np.save(p("envb.npy"), Lb)
    want = D @ Lb.astype(np.float64)
    bg = mask == 0
    check(bg.sum() > 0 and (~bg).sum() > 0 and np.abs(want[bg]).max() > 0,
          f"tiny bake: expected background rows holding ringing ({bg.sum()} mask-0 rows)")
    for extra in ((), ("--no-clamp-output",)):
        rep = json.loads(run("relight", fin, "--env", p("envb.npy"), "-o", p("bm.npy"), "--terms", "all", "--json",
                             *q, *extra).stdout)
        img = np.load(p("bm.npy")).astype(np.float64)
        expect = np.where(bg[:, None], 0.0, want if extra else np.maximum(want, 0))
        err = np.abs(img - expect).max()
        check(err <= 1e-4 * np.abs(want).max(), f"mask {extra}: differs from D·L with black background by {err}")
        check(rep.get("output", {}).get("masked_rows") == int(bg.sum()), f"mask {extra}: report {rep.get('output')}")

    # 8b. final.ltm carries what relighting reads and no more (docs/COLUMN-TRANSFORM.md, "Output
    # of quantize"): the mask, then depth in one chunk (and with --bits the scales, one chunk;
    # one step for the matrix needs none); position, normal and sample_rays stay in rows.ltm; column_stats
    # becomes totals in the metadata, which are cols4d.ltm's column_stats summed in NumPy (its
    # bytes read through the zstd tool); the depths are cols4d.ltm's; with --bits every column
    # with a kept coefficient has a positive scale, the others 0.
    c4b = os.path.join(bake, "cols4d.ltm")
    st = side_table(c4b, "column_stats")
    for fq, qargs in ((fin, ()), (p("fin9.ltm"), ("--bits", 9))):
        if qargs:
            run("quantize", c4b, "-o", fq, *qargs, *q)
        fi = json.loads(run("inspect", fq, "--json").stdout)
        names = [a["name"] for a in fi["arrays"]]
        check(names == ["matrix", "mask", "depth"] + (["scale"] if qargs else []) and
              all(a["chunks"]["expected"] == 1 for a in fi["arrays"][2:]) and
              {"position", "normal"} <= {a["name"] for a in json.loads(run("inspect", os.path.join(bake, "rows.ltm"),
                                                                          "--json").stdout)["arrays"]} and
              fi["column_transform"].get("row_tables_dropped") == ["position", "normal", "sample_rays"],
              f"{qargs}: final.ltm arrays {fi['arrays']}")
        tot = fi["column_transform"]["totals"]
        check(tot["nonzeros"] == int(st[:, 2].sum()) and abs(tot["energy"] - st[:, 0].sum()) <= 1e-12 * st[:, 0].sum()
              and abs(tot["error"] - st[:, 1].sum()) <= 1e-12 * st[:, 0].sum() and
              tot["empty_columns"] == int((st[:, 0] == 0).sum()),
              f"totals {tot} against cols4d.ltm's column_stats: nonzeros {st[:, 2].sum()}, energy {st[:, 0].sum()}")
        check(np.array_equal(side_table(fq, "depth"), side_table(c4b, "depth")), f"{qargs}: depths != cols4d.ltm's")
        if qargs:
            scale = side_table(fq, "scale")[:, 0]
            check(np.array_equal(scale > 0, st[:, 2] > 0), f"--bits 9 scales: {scale[:8]}")
        # Killed after its last matrix chunk, before the tables: the rerun computes the scales
        # of the committed chunks again and ends with the same content (the file cut at the
        # first table frame, as a kill leaves it).
        chunks = json.loads(run("inspect", fq, "--json", "--chunks").stdout)["chunk_list"]
        tables = [c for c in chunks if c["array"] in ("depth", "scale")]
        with open(fq, "rb") as f, open(p("cut.ltm"), "wb") as g:
            g.write(f.read(min(c["offset"] for c in tables)))
        rq = json.loads(run("quantize", c4b, "-o", p("cut.ltm"), "--json", *qargs, *q).stdout)
        ci = json.loads(run("inspect", p("cut.ltm"), "--json").stdout)
        check(ci["complete"] and [a["content_hash"] for a in ci["arrays"]] == [a["content_hash"] for a in fi["arrays"]]
              and rq["chunks_already_committed"] == len(chunks) - len(tables) and rq["chunks_written"] == len(tables),
              f"{qargs}: quantize resumed before its tables: {rq}, content {ci['arrays']}")
        run("verify", p("cut.ltm"), *q)
        os.remove(p("cut.ltm"))

    # 9. Maps near float32's largest value (docs/RELIGHT.md "Numbers"): an RGBE map at exponent
    # 255 (mantissa 255: 255·2^119 = 1.69e38) converts to finite texels, and relights the tiny
    # bake exactly: 2^126 times the image of the same map at exponent 129 (255·2^-7), bit for bit
    # (the lighting is relit at 2^-64 and scaled back; its Haar coefficients used to overflow
    # float32 and leave NaN in the image). A bake whose image would pass float32 under it (the
    # random T, Σ T ≈ 48 a pixel) is an error naming the map, and writes nothing.
    def flat_hdr(path, e):
        with open(path, "wb") as f:
            f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32 +X 64\n" + bytes([255, 255, 255, e]) * (64 * 32))
    flat_hdr(p("e255.hdr"), 255)
    flat_hdr(p("e129.hdr"), 129)
    run("convert", p("e255.hdr"), p("e255.npy"), "--cube-res", R, *q)
    cube = np.load(p("e255.npy"))
    check(np.all(np.isfinite(cube)) and np.allclose(cube, 255 * 2.0 ** 119, rtol=1e-6),
          f"convert of an exponent-255 map: {np.isfinite(cube).sum()} finite of {cube.size}, max {cube.max()}")
    for e in (129, 255):
        run("relight", fin, "--env", p(f"e{e}.hdr"), "-o", p(f"be{e}.npy"), "--terms", "all", *q)
    if os.path.exists(p("be129.npy")) and os.path.exists(p("be255.npy")):
        small, big = np.load(p("be129.npy")), np.load(p("be255.npy"))
        check(np.all(np.isfinite(big)) and big.max() > 1e37 and np.array_equal(big, np.ldexp(small, 126)),
              f"tiny bake under the exponent-255 map: {np.isnan(big).sum()} NaN, {np.isinf(big).sum()} Inf, "
              f"max |big - 2^126·small| {np.nanmax(np.abs(big - np.ldexp(small, 126)))}")
    # The same through --sequence: one exponent for every frame (the incremental image adds up).
    for e in (129, 255):
        run("relight", fin, "--env", p(f"e{e}.hdr"), "-o", p(f"se{e}_%d.npy"), "--sequence", "rotate:10:3", *q)
    for k in range(3):
        small, big = np.load(p(f"se129_{k}.npy")), np.load(p(f"se255_{k}.npy"))
        check(np.all(np.isfinite(big)) and np.array_equal(big, np.ldexp(small, 126)),
              f"sequence frame {k} under the exponent-255 map: {np.isnan(big).sum()} NaN, max {np.nanmax(big)}")
    r = run("relight", p("raw.ltm"), "--env", p("e255.hdr"), "-o", p("never.exr"), "--terms", "all", *q, expect=1)
    check("e255.hdr is too bright to relight in float32" in r.stderr and not os.path.exists(p("never.exr")),
          f"an image beyond float32: {r.stderr}")

finish()
