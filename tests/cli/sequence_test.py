"""Lighting sequences (`relight --sequence`, docs/SEQUENCE.md) through the ltbake binary,
against NumPy.

- The lighting approximations re-implemented here from the thesis (Overbeck 2006: NWA, BI,
  PBI's simple per-band L1 test, area-weighted ranking dealt over bands) give the same
  applied lighting L̃ as ltbake, frame after frame, on a sequence of maps and a fade.
- Bookkeeping: every frame's image equals T·L̃ (NumPy) for the streamed rows.ltm, the
  Eq. 8 relighter on a quantized adaptive final.ltm (decoded by `convert`), and cpca.ltm.
- With every term, each method equals the exact T·L every frame; on identical maps, bi and
  pbi converge to exact within ceil(coefficients / N) frames and then need no terms.
- A constant map rotated gives the same image every frame, for every method.
- nwa with N terms equals `relight` of the frame's map with N terms.
- Outputs: one file per frame through a %04d pattern, an .mp4 (ffprobe counts its frames),
  the --csv table, --json; bad specs and patterns fail naming what is wrong.

usage: sequence_test.py PATH_TO_LTBAKE
"""
import csv
import json
import os
import shutil
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import check, finish, haar_faces, run  # noqa: E402

W, H, R = 16, 8, 8
ROWS, COLS = W * H, 6 * R * R


def level_and_area():
    """Per column: the band (0: scaling and coarsest details; l: details of side R/2^l)
    and the support area in texels."""
    band, area = np.zeros(R * R, int), np.zeros(R * R)
    for t in range(R):
        for s in range(R):
            m = max(s, t)
            lv = 0 if m == 0 else int(np.floor(np.log2(m)))
            band[t * R + s] = 0 if m <= 1 else lv
            area[t * R + s] = R * R if m == 0 else (R / 2 ** lv) ** 2
    return np.tile(band, 6), np.tile(area, 6)


BAND, AREA = level_and_area()


def top_n(values, n):
    """Indices of the n largest area × |rgb| (ties: lower index), skipping zeros."""
    mag = np.sqrt((values.astype(np.float64) ** 2).sum(axis=1)) * AREA
    idx = np.nonzero(mag > 0)[0]
    return idx[np.lexsort((idx, -mag[idx]))][:n]


def simulate(method, frames_lighting, n):
    """The applied lighting per frame, from the thesis' definitions."""
    applied = np.zeros_like(frames_lighting[0])
    out = []
    for L in frames_lighting:
        if method == "nwa":
            applied = np.zeros_like(L)
            k = top_n(L, n)
            applied[k] = L[k]
        else:
            incr = np.ones(BAND.max() + 1, bool)
            if method == "pbi":
                for b in range(BAND.max() + 1):
                    sel = BAND == b
                    diff = np.abs(L[sel].astype(np.float64) - applied[sel]).sum()
                    incr[b] = diff < np.abs(L[sel].astype(np.float64)).sum()
            target = L - np.where(incr[BAND][:, None], applied, 0)
            k = top_n(target, n)
            applied = np.where(incr[BAND][:, None], applied, 0).astype(np.float32)
            applied[k] = L[k]
        out.append(applied.copy())
    return out


def write_hdr(path, width, height, value):
    """A flat (uncompressed) Radiance .hdr lat-long map of constant radiance `value`."""
    mant, exp = np.frexp(value)
    rgbe = bytes([int(mant * 256)] * 3 + [exp + 128])
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {height} +X {width}\n".encode())
        f.write(rgbe * (width * height))


with tempfile.TemporaryDirectory() as d:
    p = lambda name: os.path.join(d, name)  # noqa: E731
    q = ["--progress", "never"]
    g = np.random.default_rng(11)
    y, x = np.mgrid[0:H, 0:W]
    T = np.zeros((ROWS, COLS), np.float32)
    for j in range(COLS):
        img = np.maximum(0, np.sin(0.3 * x + 0.2 * j) + 0.5 * np.cos(0.4 * y - 0.1 * j)) * g.uniform(0.2, 1.0)
        if j % 5 == 0:
            img = img * (x > (j % W))
        T[:, j] = img.reshape(-1)
    np.save(p("T.npy"), T)
    run("convert", p("T.npy"), p("raw.ltm"), "--cube-res", R, "--image", f"{W}x{H}", "--chunk-size", "4KiB", *q)
    run("row-transform", p("raw.ltm"), "-o", p("rows.ltm"), "--filter", "haar", *q)
    run("transpose", p("rows.ltm"), "-o", p("cols.ltm"), *q)
    run("column-transform", p("cols.ltm"), "-o", p("c4.ltm"), "--keep", 0.3, "--filter", "legall53", *q)
    run("quantize", p("c4.ltm"), "-o", p("final.ltm"), *q)
    run("cpca", p("rows.ltm"), "-o", p("cpca.ltm"), "--clusters", 3, "--basis", 4, *q)
    run("convert", p("rows.ltm"), p("rows.npy"), *q)
    run("convert", p("final.ltm"), p("final.npy"), *q)
    run("convert", p("cpca.ltm"), p("cpca.npy"), *q)
    Tw = np.load(p("rows.npy")).astype(np.float64)

    # Four maps (a few bright texels each), a copy of the first, and sequences over them.
    maps = []
    for i in range(4):
        L = (g.uniform(0, 1, (COLS, 3)) ** 6 * 8).astype(np.float32)
        maps.append(L)
        np.save(p(f"m{i}.npy"), L)
    spec = f"maps:{p('m0.npy')}+{p('m1.npy')}+{p('m2.npy')},fade:{p('m2.npy')}+{p('m3.npy')}:4,hold:3"
    pixel_frames = [maps[0], maps[1], maps[2]] + [((1 - t) * maps[2] + t * maps[3]).astype(np.float32)
                                                  for t in np.arange(4) / 3] + [maps[3]] * 3

    def sequence(matrix, method, terms, pattern, *extra, expect=0):
        r = run("relight", matrix, "--env", p("m0.npy"), "--sequence", spec, "--method", method, "--terms", terms,
                "-o", pattern, "--json", "--no-clamp-output", *q, *extra, expect=expect)
        return json.loads(r.stdout) if r.returncode == 0 else r

    # 1. With every term the applied lighting is the frame's lighting itself: ltbake's
    # transform of each frame equals PyWavelets' Haar of the map (so the frames' lighting
    # is known to NumPy), and every method's image is the exact T·L.
    rep = sequence(p("rows.ltm"), "pbi", "all", p("all_%02d.npy"), "--applied-lighting", p("La_%02d.npy"))
    nframes = len(pixel_frames)
    check(len(rep.get("frames", [])) == nframes, f"{nframes} frames expected: {rep.get('summary')}")
    basis_frames = [np.load(p(f"La_{f:02d}.npy")) for f in range(nframes)]
    err = max(np.abs(basis_frames[f] - haar_faces(pixel_frames[f], R)).max() for f in range(nframes))
    check(err < 1e-5 * max(np.abs(m).max() for m in maps), f"frame lighting differs from Haar(map) by {err}")
    for method in ("nwa", "bi", "pbi"):
        for matrix in ("rows.ltm", "final.ltm"):
            sequence(p(matrix), method, "all", p(f"e_{method}_%02d.npy"))
            D = Tw if matrix == "rows.ltm" else np.load(p("final.npy")).astype(np.float64)
            worst = max(np.abs(np.load(p(f"e_{method}_{f:02d}.npy")) - D @ basis_frames[f]).max() /
                        np.abs(D @ basis_frames[f]).max() for f in range(nframes))
            check(worst < 2e-5, f"{method} {matrix}, every term: a frame differs from T·L by {worst} (relative)")

    # 2. With N terms: ltbake's applied lighting equals the thesis' algorithm (NumPy), and
    # every frame's image equals T·L̃ for each kind of matrix (the per-band bookkeeping).
    N = 20
    for method in ("nwa", "bi", "pbi"):
        want = simulate(method, basis_frames, N)
        for matrix, npy in (("rows.ltm", "rows.npy"), ("final.ltm", "final.npy"), ("cpca.ltm", "cpca.npy")):
            stem = matrix.split(".")[0]
            rep = sequence(p(matrix), method, N, p(f"n_{stem}_{method}_%02d.npy"), "--applied-lighting",
                           p(f"a_{method}_%02d.npy"), "--csv", p(f"{method}.csv"))
            D = np.load(p(npy)).astype(np.float64)
            for f in range(nframes):
                La = np.load(p(f"a_{method}_{f:02d}.npy"))
                if matrix == "rows.ltm":
                    e = np.abs(La - want[f]).max()
                    check(e <= 1e-6 * np.abs(want[f]).max(), f"{method} frame {f}: applied lighting differs from the "
                          f"thesis' algorithm by {e}")
                img = np.load(p(f"n_{stem}_{method}_{f:02d}.npy")).astype(np.float64)
                exp = D @ La.astype(np.float64)
                e = np.abs(img - exp).max() / np.abs(exp).max()
                check(e < 5e-5, f"{method} {matrix} frame {f}: image differs from T·L̃ by {e} (relative)")
            fr = rep["frames"]
            check(all(x["terms"] <= N for x in fr) and sum(b["terms"] for b in fr[1]["bands"]) == fr[1]["terms"],
                  f"{method}: terms per frame and per band disagree: {fr[1]}")
            if method == "nwa":
                check(all(b["update"] == "reset" for x in fr for b in x["bands"]), "nwa: every band restarts")
            if method == "bi":
                check(all(b["update"] == "incremental" for x in fr[1:] for b in x["bands"]), "bi: always incremental")
        with open(p(f"{method}.csv")) as fcsv:
            table = list(csv.DictReader(fcsv))
        check(len(table) == nframes and float(table[2]["terms"]) <= N, f"{method}.csv: {table[:2]}")
    # pbi resets some band somewhere in this sequence of unrelated maps, and keeps others.
    kinds = {b["update"] for x in rep["frames"][1:] for b in x["bands"]}
    check(kinds == {"reset", "incremental"}, f"pbi on unrelated maps: band updates {kinds}")

    # 3. nwa with N terms equals a single-frame relight of the frame's map.
    run("relight", p("rows.ltm"), "--env", p("m1.npy"), "--terms", N, "-o", p("single.npy"), "--no-clamp-output", *q)
    check(np.allclose(np.load(p("single.npy")), np.load(p("n_rows_nwa_01.npy")), rtol=1e-5, atol=1e-6),
          "nwa frame 1 differs from relight of map 1 with the same terms")

    # 4. Identical maps: bi and pbi converge to exact within ceil(nonzero / N) frames and then
    # use no terms; nwa stays at its N-term error.
    nonzero = int((np.abs(basis_frames[0]).sum(axis=1) > 0).sum())
    need = -(-nonzero // N)
    same = f"maps:{'+'.join([p('m0.npy')] * (need + 2))}"
    exact0 = Tw @ basis_frames[0]
    for method in ("bi", "pbi", "nwa"):
        r = run("relight", p("rows.ltm"), "--env", p("m0.npy"), "--sequence", same, "--method", method, "--terms", N,
                "-o", p(f"s_{method}_%02d.npy"), "--json", "--no-clamp-output", "--reference", p("raw.ltm"), *q)
        fr = json.loads(r.stdout)["frames"]
        last = np.load(p(f"s_{method}_{need + 1:02d}.npy")).astype(np.float64)
        e = np.abs(last - exact0).max() / np.abs(exact0).max()
        if method == "nwa":
            check(e > 1e-3 and fr[-1]["terms"] == N, f"nwa should not converge: {e}")
        else:
            check(e < 2e-5, f"{method}: not exact after {need} frames of one map ({nonzero} coefficients): {e}")
            check(fr[-1]["terms"] == 0 and fr[-1]["columns_touched"] == 0, f"{method}: converged frames use terms "
                  f"{fr[-1]}")
            check(fr[-1]["rel_l2"] < 1e-5, f"{method}: rel_l2 after convergence {fr[-1]['rel_l2']}")
            l2 = [x["rel_l2"] for x in fr]
            check(max(l2[need:]) < 1e-3 * l2[0], f"{method}: error on a static map, frame by frame: {l2}")

    # 5. A constant map rotated: its lighting is the six faces' scaling coefficients, so with
    # N >= 6 every frame is the same image, for every method; with N = 2, bi and pbi reach
    # that image by frame 3 (two faces a frame) and keep it while the map turns.
    write_hdr(p("const.hdr"), 64, 32, 1.0)
    want = Tw @ haar_faces(np.ones((COLS, 3), np.float32), R)
    for method in ("nwa", "bi", "pbi"):
        for n, first in ((6, 0), (2, 3)):
            if method == "nwa" and n == 2:
                continue
            run("relight", p("rows.ltm"), "--env", p("const.hdr"), "--sequence", "rotate:7.5:6,hold:2", "--method",
                method, "--terms", n, "-o", p(f"c_{method}_%d.npy"), "--no-clamp-output", *q)
            imgs = [np.load(p(f"c_{method}_{f}.npy")) for f in range(first, 8)]
            spread = max(np.abs(i - want).max() for i in imgs) / np.abs(want).max()
            check(spread < 1e-5, f"{method} N={n}: a rotated constant map gives images off the constant one by "
                  f"{spread} from frame {first} on")

    # 6. Outputs: PNG frames, an .mp4 (ffprobe), errors for bad specs and patterns.
    r = run("relight", p("final.ltm"), "--env", p("const.hdr"), "--sequence", "rotate:10:5,hold:2", "-o",
            p("png/f_%04d.png"), *q)
    check(sorted(os.listdir(p("png"))) == [f"f_{i:04d}.png" for i in range(7)], f"{os.listdir(p('png'))}")
    if shutil.which("ffmpeg") and shutil.which("ffprobe"):
        run("relight", p("final.ltm"), "--env", p("const.hdr"), "--sequence", "rotate:10:9", "-o", p("v.mp4"), *q)
        pr = subprocess.run(["ffprobe", "-v", "error", "-count_frames", "-select_streams", "v:0", "-show_entries",
                             "stream=nb_read_frames,width,height", "-of", "json", p("v.mp4")],
                            capture_output=True, text=True)
        st = json.loads(pr.stdout)["streams"][0] if pr.returncode == 0 else {}
        check(st.get("nb_read_frames") == "9" and st.get("width") == W, f"ffprobe of the mp4: {pr.stdout}")
        check(not [n for n in os.listdir(d) if n.startswith("v.mp4") and n != "v.mp4"], "temporary files left")
    else:
        print("note: ffmpeg/ffprobe not installed; the .mp4 output is not checked")
    # 7. Recipes: [relight] sequence makes one .mp4 a map; a rerun skips; a bad spec is
    # refused when the recipe is read (exit 2, naming the line).
    if shutil.which("ffmpeg"):
        scene = os.path.join(os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__)))), "samples",
                             "tiny.toml")
        rec = p("seq.toml")
        with open(rec, "w") as f:
            f.write(f'name = "seq"\nscene = "{scene}"\nworkdir = "{p("bake")}"\n[sample]\ncube_res = 4\nspp = 1\n'
                    f'[relight]\nenvs = ["{p("const.hdr")}"]\nterms = 8\nsequence = "rotate:30:4,hold:2"\n'
                    f'method = "bi"\n')
        run("run", rec, *q)
        check(os.path.exists(p("bake/relit-const.mp4")), f"recipe sequence: {os.listdir(p('bake'))}")
        again = run("run", rec, *q)
        check("relight:const" in again.stdout and "skip" in again.stdout.split("relight:const")[1].split("\n")[0],
              f"rerun of the sequence recipe: {again.stdout}")
        with open(rec) as f:
            text = f.read()
        with open(rec, "w") as f:
            f.write(text.replace("rotate:30:4", "rotate:30:0"))
        r = run("run", rec, *q, expect=2)
        check("seq.toml:" in r.stderr and "rotate:30:0" in r.stderr, f"bad recipe sequence: {r.stderr}")

    bad = [
        (["--sequence", "rotate:abc:3"], 1, "rotate:abc:3"),
        (["--sequence", "spin:3"], 1, "unknown kind"),
        (["--sequence", "hold:0"], 1, "hold:0"),
        (["--sequence", "fade:a.exr:3"], 1, "two maps"),
        (["--sequence", "rotate:5:3", "--env", p("m0.npy")], 1, "cannot rotate"),
        (["--sequence", "hold:2", "-o", p("noframe.png")], 1, "pattern"),
        (["--sequence", "hold:2", "-o", p("two_%d_%d.png")], 1, "pattern"),
        (["--method", "bi"], 2, "--sequence"),
        (["--sequence", "hold:2", "--method", "sideways"], 2, "--method"),
        (["--sequence", "hold:2", "--material", p("x.ltm")], 2, "triple-product"),
    ]
    for args, code, words in bad:
        argv = ["relight", p("rows.ltm"), "--env", p("const.hdr"), "-o", p("bad_%d.png"), *q]
        for k in range(0, len(args), 2):  # later flags replace the defaults above
            if args[k] in argv:
                i = argv.index(args[k])
                argv[i + 1] = args[k + 1]
            else:
                argv += args[k:k + 2]
        r = run(*argv, expect=code)
        check(words in r.stderr and not any(n.startswith("bad_") for n in os.listdir(d)),
              f"{args}: exit {r.returncode}, stderr {r.stderr!r}")

finish()
