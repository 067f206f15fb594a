"""Smoke run of every command on tiny inputs: the ASan/UBSan tree's CLI test.

The release tree runs every full CLI suite; under the sanitizers that would cost minutes
for little extra (the same code paths, slower). This script goes through each command
once with the smallest inputs that still reach its main paths, so that a memory error in
any of them is caught by the sanitizers:
  sample (plain and fused with row-transform), row-transform, transpose, column-transform
  (adaptive, budget), quantize, cpca, relight (final, rows, cpca; .npy and .exr maps; lighting
  sequences with nwa, bi and pbi), view (a frame, bad requests, Ctrl-C),
  convert (both directions), inspect, verify, run (a recipe; a rerun that skips),
  a sharded sample with commit and merge, one kill-and-resume of a stage, and the
  triple-product path (sample --visibility, material, relight --material, three methods).
Each output is checked against an independent fact (shapes, decoded values against the
input, same content_hash as the unsharded / uninterrupted run).

usage: smoke_test.py PATH_TO_LTBAKE
"""
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
import urllib.error
import urllib.request

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run, write  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
TINY = os.path.join(REPO, "samples", "tiny.toml")
Q = ["--progress", "never"]


def info(path, *extra):
    return json.loads(run("inspect", "--json", path, *extra).stdout)


with tempfile.TemporaryDirectory() as d:
    def P(*parts):
        return os.path.join(d, *parts)

    # --- the stage chain, one command each ------------------------------------------------
    raw, rows, cols = P("raw.ltm"), P("rows.ltm"), P("cols.ltm")
    cols4d, budget, final = P("cols4d.ltm"), P("budget.ltm"), P("final.ltm")
    run("sample", TINY, "-o", raw, "--chunk-rows", 256, *Q)
    run("sample", TINY, "-o", P("fused.ltm"), "--chunk-rows", 256, "--row-transform", "haar", *Q)
    run("row-transform", raw, "-o", rows, *Q)
    run("transpose", rows, "-o", cols, *Q)
    run("column-transform", cols, "-o", cols4d, *Q)
    run("column-transform", cols, "-o", budget, "--budget", "2%", *Q)
    run("quantize", cols4d, "-o", final, *Q)
    run("cpca", rows, "-o", P("cpca.ltm"), "--clusters", 2, "--basis", 2, *Q)
    # Sparse precomputation with a bounce, fused, then cpca dense-first on it.
    run("sample", TINY, "-o", P("sparse.ltm"), "--sparse", "--bounces", 1, "--row-transform", "haar", *Q)
    check(info(P("sparse.ltm"))["sparse"]["rows"]["dense"] > 0, "sparse: no dense rows")
    run("cpca", P("sparse.ltm"), "-o", P("sparse_cpca.ltm"), "--clusters", 2, "--basis", 2, *Q)
    # Converged sampling with a bounce (guided first directions), fused (docs/SAMPLE.md
    # "Converged sampling").
    run("sample", TINY, "-o", P("converged.ltm"), "--tolerance", "5%", "--cube-res", 4, "--bounces", 1,
        "--row-transform", "haar", *Q)
    # Colour (docs/COLOUR.md): a reflectance table through cpca, and a channel set (sample
    # --channels rgb with a bounce, every stage on the set, relight, convert to one .npy).
    with open(TINY) as f:
        red = write(P("red.toml"), f.read().replace("albedo = 0.5", "albedo = [0.5, 0.1, 0.1]")
                    .replace("ks = 0.3", "ks = [0.3, 0.06, 0.06]"))
    run("sample", red, "-o", P("red.ltm"), "--chunk-rows", 256, *Q)
    run("cpca", P("red.ltm"), "-o", P("red_cpca.ltm"), "--clusters", 2, "--basis", 2, *Q)
    run("sample", red, "-o", P("rgb.ltm"), "--channels", "rgb", "--bounces", 1, "--cube-res", 4, *Q)
    for st, src, dst in [("row-transform", "rgb", "rgb_rows"), ("transpose", "rgb_rows", "rgb_cols"),
                         ("column-transform", "rgb_cols", "rgb_c4"), ("quantize", "rgb_c4", "rgb_final")]:
        run(st, P(src + ".ltm"), "-o", P(dst + ".ltm"), *Q)
    run("convert", P("rgb_final.ltm"), P("rgb_final.npy"), *Q)
    check(np.load(P("rgb_final.npy")).shape == (3, 1024, 96), "convert of a channel set: not (3, 1024, 96)")
    np.save(P("white4.npy"), np.ones((96, 3), np.float32))
    np.save(P("white8.npy"), np.ones((384, 3), np.float32))
    for mat, env in [(P("rgb_final.ltm"), P("white4.npy")), (P("rgb_rows.ltm"), P("white4.npy")),
                     (P("red_cpca.ltm"), P("white8.npy"))]:
        run("relight", mat, "--env", env, "-o", P("rgb_relit.npy"), "--terms", 96, *Q)
        check(np.load(P("rgb_relit.npy")).shape == (1024, 3), f"relight of the set {mat}: shape")
    # Glossy vertices (docs/GLOSSY.md): a factored bake on coarse maps, two views of it.
    ball = os.path.join(REPO, "data", "meshes", "bunny.obj")
    glossy = write(P("glossy.toml"), f"""[output]
mode = "vertex"
objects = ["bunny"]
[sampling]
cube_res = 4
spp = 1
[[material]]
name = "shiny"
albedo = 0.3
ks = 0.6
exponent = 8.0
[[object]]
name = "bunny"
type = "mesh"
file = "{ball}"
scale = 0.1
rotate = [90.0, 0.0, 0.0]
material = "shiny"
""")
    run("sample", glossy, "-o", P("glossy.ltm"), "--factor", 3, "--factor-grid", "16,8", *Q)
    run("relight", P("glossy.ltm"), "--env", P("white4.npy"), "--eye", "0,-3,1", "--target", "0,0,0.5", "--size",
        "24x24", "--orbit", "90:2", "-o", P("glossy_%d.npy"), *Q)
    check(all(np.load(P(f"glossy_{k}.npy")).max() > 0 for k in range(2)), "glossy views: black")
    for f in [raw, rows, cols, cols4d, budget, final, P("cpca.ltm"), P("fused.ltm"), P("sparse.ltm"),
              P("sparse_cpca.ltm"), P("red.ltm"), P("red_cpca.ltm"), P("rgb_final.r.ltm"), P("glossy.k2.ltm")]:
        run("verify", f)
        # Text mode without content: the recorded hash, no stats (it crashed on a missing key).
        check(info(f)["content_hash"] in run("inspect", "--no-content", f).stdout,
              f"inspect --no-content {f} does not show the recorded content_hash")
    ri = info(raw)
    check(ri["shape"] == [32 * 32, 6 * 8 * 8], f"raw.ltm shape {ri['shape']}, expected [1024, 384]")
    check(info(rows)["content_hash"] == info(P("fused.ltm"))["content_hash"],
          "fused sample+row-transform differs from sample then row-transform")

    # convert both ways: raw.ltm -> .npy -> .ltm decodes to the same values.
    run("convert", raw, P("raw.npy"), *Q)
    m = np.load(P("raw.npy"))
    check(m.shape == (1024, 384) and np.isfinite(m).all() and (m >= 0).all(), f"raw.npy: shape {m.shape}")
    run("convert", P("raw.npy"), P("back.ltm"), "--zstd", *Q)
    run("convert", P("back.ltm"), P("back.npy"), *Q)
    check(np.array_equal(np.load(P("back.npy")), m), "npy -> ltm -> npy is not the identity")
    # transpose changes the layout (column blocks), not the matrix: cols decodes to rows.
    run("convert", rows, P("rows.npy"), *Q)
    run("convert", cols, P("cols.npy"), *Q)
    check(info(cols)["layout"] != info(rows)["layout"], "cols.ltm has the layout of rows.ltm")
    check(np.array_equal(np.load(P("cols.npy")), np.load(P("rows.npy"))), "cols.ltm does not decode to rows.ltm")

    # relight: a constant environment relights raw.ltm to its row sums (closed form).
    env = P("env.npy")
    np.save(env, np.ones((6 * 8 * 8, 3), np.float32))
    run("relight", raw, "--env", env, "-o", P("img_raw.npy"), "--terms", 384, *Q)
    img = np.load(P("img_raw.npy"))
    sums = m.astype(np.float64).sum(axis=1)
    check(img.shape[0] == 1024 and np.allclose(img[:, 0], sums, rtol=1e-4, atol=1e-6),
          f"relight of raw.ltm under a constant map is not the row sums (max diff "
          f"{np.abs(img[:, 0] - sums).max() if img.shape[0] == 1024 else 'shape ' + str(img.shape)})")
    for src in [rows, final, P("cpca.ltm")]:
        out = P(os.path.basename(src) + ".exr")
        run("relight", src, "--env", env, "-o", out, "--terms", 64, *Q)
        check(os.path.getsize(out) > 0, f"relight {src}: empty image")
    run("relight", final, "--env", env, "-o", P("frames.npy"), "--terms", 32, "--frames", 3, *Q)
    # The roofline report: under a map with no zero wavelet coefficient, every term a frame
    # reads every stored coefficient, 8 bytes each (position and value); quantize counts them
    # as it writes them.
    np.save(P("noise8.npy"), (0.1 + np.random.default_rng(5).random((384, 3))).astype(np.float32))
    nonzeros = json.loads(run("quantize", cols4d, "-o", P("final2.ltm"), "--json", *Q).stdout)["nonzeros_out"]
    rep = json.loads(run("relight", final, "--env", P("noise8.npy"), "-o", P("frames.npy"), "--terms", "all",
                         "--frames", 2, "--json", *Q).stdout)
    roof = rep["frames"]["roofline"]
    check(rep["terms_used"] == rep["terms_available"] == 384, f"relight --terms all: {rep['terms_used']} terms used")
    check(roof["coefficient_bytes"] == 8 * nonzeros and nonzeros > 0,
          f"relight roofline: {roof['coefficient_bytes']} coefficient bytes, quantize wrote {nonzeros} nonzeros")
    check(roof["copy_bytes_per_s"] > 0 and roof["bound_ms"] > 0 and roof["product_median_ms"] > 0
          and abs(roof["fraction_of_bound"] - roof["bound_ms"] / roof["product_median_ms"]) < 1e-9,
          f"relight roofline: inconsistent figures {roof}")
    # Lighting sequences (docs/SEQUENCE.md): every method over each kind of matrix; on one
    # map repeated, bi and pbi converge to the image of every term (with 64 terms a frame,
    # 384 coefficients take at most 6 frames).
    spec = f"maps:{'+'.join([env] * 7)},fade:{env}+{env}:2"
    for src in [rows, final, P("cpca.ltm")]:
        run("relight", src, "--env", env, "-o", P("all.npy"), "--terms", "all", "--no-clamp-output", *Q)
        for method in ("nwa", "bi", "pbi"):
            run("relight", src, "--env", env, "--sequence", spec, "--method", method, "--terms", 64, "-o",
                P("seq_%02d.npy"), "--csv", P("seq.csv"), "--no-clamp-output", *Q)
            if method != "nwa":
                a, b = np.load(P("all.npy")), np.load(P("seq_08.npy"))
                check(np.abs(a - b).max() <= 1e-4 * np.abs(a).max(), f"{method} {src}: not converged to every term")
    # ltbake view: a frame, a bad request (400), an unknown path (404), then Ctrl-C (130).
    with open(P("const.hdr"), "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 8 +X 16\n" + bytes([128, 128, 128, 129]) * 128)
    view = subprocess.Popen([LTBAKE, "view", final, "--env", P("const.hdr"), "--terms", "16"], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        url = view.stdout.readline().strip()
        check(url.startswith("http://127.0.0.1:"), f"view printed {url!r}")
        with urllib.request.urlopen(url + "frame.png?rotate=20&method=pbi", timeout=60) as resp:
            check(resp.read(8) == b"\x89PNG\r\n\x1a\n", "view: /frame.png is not a PNG")
        for path, code in (("frame.png?terms=0", 400), ("frame.png?rotate=x", 400), ("nothing", 404)):
            try:
                urllib.request.urlopen(url + path, timeout=60)
                check(False, f"view: {path} was accepted")
            except urllib.error.HTTPError as e:
                check(e.code == code, f"view: {path} gave {e.code}, expected {code}")
        # Numbers go through the flags' parser (stages/common/quantity.h): decimal only, the
        # whole value (a NUL byte ends nothing), finite and in range; the 400 names the
        # parameter and quotes the value.
        for query, name, shown in (("rotate=5%00abc", "rotate", '"5\\x00abc"'), ("rotate=0x10", "rotate", '"0x10"'),
                                   ("rotate=nan", "rotate", '"nan"'), ("rotate=1e20", "rotate", '"1e20"'),
                                   ("exposure=inf", "exposure", '"inf"'), ("exposure=-1", "exposure", '"-1"')):
            try:
                urllib.request.urlopen(url + "frame.png?" + query, timeout=60)
                check(False, f"view: {query} was accepted")
            except urllib.error.HTTPError as e:
                body = e.read().decode("utf-8", "replace")
                check(e.code == 400 and body.startswith(name) and shown in body,
                      f"view: {query} gave {e.code} {body!r}, expected 400 naming {name} and {shown}")
    finally:
        view.send_signal(signal.SIGINT)
        try:
            rc = view.wait(timeout=60)
        except subprocess.TimeoutExpired:
            view.kill()
            rc = None
    check(rc == 130, f"view after Ctrl-C: exit {rc}, stderr {view.stderr.read()!r}")

    # --- the triple-product path: visibility and material fields, three methods, an orbit ----
    with open(P("grid.obj"), "w") as f:
        f.write("".join(f"v {x} {y} 0\n" for y in (-1, 0, 1) for x in (-1, 0, 1)))
        f.write("".join(f"f {a} {a + 1} {a + 4}\nf {a} {a + 4} {a + 3}\n" for a in (1, 2, 4, 5)))
    scene = write(P("v.toml"), '[output]\nmode = "vertex"\nobjects = ["g"]\n[sampling]\ncube_res = 4\n'
                  '[[material]]\nname = "m"\nalbedo = 0.5\nks = 0.3\nbrdf = "ward"\nroughness = 0.3\n'
                  '[[object]]\nname = "g"\ntype = "mesh"\nfile = "grid.obj"\nmaterial = "m"\n'
                  '[[object]]\nname = "b"\ntype = "box"\nsize = [0.5, 0.5, 0.5]\ncenter = [0.0, 0.0, 0.5]\n')
    run("sample", scene, "--visibility", "-o", P("vis.ltm"), *Q)
    run("material", "--brdf", "lambert", "--cube-res", 4, "--samples-res", 2, "-o", P("lam.ltm"), *Q)
    run("material", "--brdf", "phong:8", "--cube-res", 4, "--samples-res", 2, "-o", P("ph.ltm"), *Q)
    run("material", "--brdf", "ward:0.3", "--cube-res", 4, "--samples-res", 2, "--normals-res", 1,
        "-o", P("ward.ltm"), *Q)
    np.save(P("env4.npy"), np.ones((6 * 4 * 4, 3), np.float32))
    vals = {}
    for method in ("pixel", "linear", "sublinear", "shared"):
        run("relight", P("vis.ltm"), "--material", P("lam.ltm"), "--material", P("ward.ltm"), "--env", P("env4.npy"),
            "--eye", "2,-3,2", "--method", method, "--size", "16x12", "--terms", "all", "-o", P(f"t_{method}.npy"),
            "--vertex-output", P(f"v_{method}.npy"), *Q)
        vals[method] = np.load(P(f"v_{method}.npy"))
    check(vals["linear"].shape == (9, 3) and np.allclose(vals["linear"], vals["sublinear"], rtol=1e-5, atol=1e-7),
          f"triple: sublinear with every term differs from linear: {vals['linear']} {vals['sublinear']}")
    check(np.allclose(vals["linear"], vals["shared"], rtol=1e-5, atol=1e-7),
          f"triple: shared with every term differs from linear: {vals['linear']} {vals['shared']}")
    run("relight", P("vis.ltm"), "--material", P("lam.ltm"), "--material", P("ward.ltm"), "--material", P("ph.ltm"),
        "--env", P("env4.npy"), "--eye", "2,-3,2", "--orbit", "30:2", "--size", "8x8", "--terms", 3, "--brdf-terms", 2,
        "-o", P("o_%d.png"), *Q)
    check(os.path.exists(P("o_1.png")), "triple: the orbit wrote no second frame")

    # --- a recipe: bake, then a rerun that skips every step --------------------------------
    rec = write(P("r.toml"), f'name = "s"\nscene = "{TINY}"\n[quantize]\nbits = 9\n')
    run("run", rec, "--workdir", P("w"), *Q)
    rep = json.load(open(P("w", "run.json")))
    check(rep["status"] == "ok", f"run: status {rep['status']}")
    run("run", rec, "--workdir", P("w"), *Q)
    rep = json.load(open(P("w", "run.json")))
    check(all(s["action"] == "skip" for s in rep["stages"]), f"rerun did not skip: {[s['action'] for s in rep['stages']]}")

    # --- shards: sample as 2 shards, commit, merge: same content as the unsharded run ------
    sh = P("sh.ltm")
    for i in range(2):
        run("sample", TINY, "-o", sh, "--chunk-rows", 256, "--shard", i, "--nshards", 2, *Q)
    run("commit", sh, "--nshards", 2)
    run("verify", sh)
    run("merge", sh, "-o", P("merged.ltm"))
    check(info(P("merged.ltm"))["content_hash"] == ri["content_hash"], "sharded sample + merge != unsharded sample")

    # --- one kill-and-resume: SIGKILL a convert once a chunk is committed, rerun resumes ----
    big = np.random.default_rng(3).standard_normal((4096, 384)).astype(np.float32)
    np.save(P("big.npy"), big)
    ref = P("ref.ltm")
    run("convert", P("big.npy"), ref, "--chunk-size", "8KiB", *Q)
    out = P("killed.ltm")
    p = subprocess.Popen([LTBAKE, "convert", P("big.npy"), out, "--chunk-size", "8KiB", *Q],
                         stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    # Wait for a condition (the output has grown past its header), never a fixed time.
    while p.poll() is None and not (os.path.exists(out) and os.path.getsize(out) > 64 * 1024):
        pass
    killed = p.poll() is None
    if killed:
        p.send_signal(signal.SIGKILL)
    p.wait()
    print(f"kill-and-resume: {'killed mid-write' if killed else 'the write finished before the kill (resume path not reached)'}")
    if killed:
        v = json.loads(run("verify", "--allow-incomplete", "--json", out).stdout)[0]
        check(v["ok"], f"killed convert left a partial output that does not verify: {v}")
    run("convert", P("big.npy"), out, "--chunk-size", "8KiB", *Q)
    check(info(out)["content_hash"] == info(ref)["content_hash"], "resumed convert != uninterrupted convert")

finish()
