"""Glossy vertices from any view: `sample --factor K` and `relight --eye` (docs/GLOSSY.md),
against independent oracles.

1. K = 1 is the existing vertex bake: the same matrix content_hash; so is term 0 of any K
   (the diffuse part, exact). A Lambertian scene's terms 1..K-1 are all zero.
2. The factorisation's errors (printed by sample, K = 1..8) equal NumPy's singular values
   (LAPACK's eigenvalues of the Gram matrix) of the same solid-angle-weighted table on the
   same parabolic grids.
3. Convergence to the brute-force render: `sample` in image mode from the same eye (the
   same pinhole camera, the same Phong BRDF per pixel), relit under the same map; the
   factored render's relative L2 error on the object falls with K (the table is printed),
   for Phong exponent 4 below a bound at K = 8, and for exponent 32 it falls too. With
   --bounces 1, term 0 is the plain vertex bake with the bounce (content_hash) and the set
   converges to the brute force with the bounce; so does a colour set (`--channels rgb
   --factor 8 --bounces 1`, term 0 the `--channels rgb` bake), through a stage and a recipe.
4. An orbit writes one image a view; the set goes through row-transform, transpose,
   column-transform and quantize (100% budget, 16 bits) and renders within 1% of the raw set;
   cpca of the set renders too.
   A recipe with [sample] factor and [relight] eye bakes a term a step (each equal to the
   one-pass bake's term) and renders; its rerun skips everything.
5. Refusals naming the files: a missing term, a term of another bake (another K), a factored
   set relit without --eye, --factor in image mode, a monochrome --factor with --bounces in
   a coloured scene, --channel with --factor and no --factor-term.

usage: glossy_test.py PATH_TO_LTBAKE
"""
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest as t  # noqa: E402

SIZE = 64


def icosphere(level):
    g = (1 + 5 ** 0.5) / 2
    v = [(-1, g, 0), (1, g, 0), (-1, -g, 0), (1, -g, 0), (0, -1, g), (0, 1, g), (0, -1, -g), (0, 1, -g),
         (g, 0, -1), (g, 0, 1), (-g, 0, -1), (-g, 0, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    f = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2), (10, 7, 6),
         (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5), (2, 4, 11), (6, 2, 10),
         (8, 6, 7), (9, 8, 1)]
    for _ in range(level):
        cache, nf = {}, []

        def mid(a, b):
            k = (min(a, b), max(a, b))
            if k not in cache:
                m = v[a] + v[b]
                v.append(m / np.linalg.norm(m))
                cache[k] = len(v) - 1
            return cache[k]
        for a, b, c in f:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            nf += [(a, ab, ca), (b, bc, ab), (c, ca, bc), (ab, bc, ca)]
        f = nf
    return v, f


def write_obj(path, v, f):
    with open(path, "w") as o:
        for p in v:
            o.write("v %.7f %.7f %.7f\n" % tuple(p))
        for a, b, c in f:
            o.write("f %d %d %d\n" % (a + 1, b + 1, c + 1))


SCENE = """
[output]
mode = "{mode}"
{output}
[sampling]
cube_res = 8
spp = 4
[[material]]
name = "shiny"
albedo = 0.3
ks = {ks}
exponent = {exponent}
[[material]]
name = "floor"
albedo = 0.7
[[object]]
name = "ground"
type = "plane"
size = [6.0, 6.0]
material = "floor"
[[object]]
name = "ball"
type = "mesh"
file = "{obj}"
translate = [0.0, 0.0, 1.0]
normals = "smooth"
material = "shiny"
"""
CAMERA = f"""[camera]
eye = [0.0, -3.0, 2.0]
target = [0.0, 0.0, 1.0]
up = [0.0, 0.0, 1.0]
fov = 30.0
width = {SIZE}
height = {SIZE}"""
VIEW = ["--eye", "0,-3,2", "--target", "0,0,1", "--fov", "30", "--size", f"{SIZE}x{SIZE}"]


def info(path):
    return json.loads(t.run("inspect", path, "--json", "--content").stdout)


def matrix_hash(path):
    return info(path)["arrays"][0]["content_hash"]


def parabolic(res):
    """Cell directions and solid angles of a res x res parabolic map (docs/GLOSSY.md)."""
    h = 2.0 / res
    c = -1 + (np.arange(res) + 0.5) * h
    u, v = np.meshgrid(c, c)  # row v, column u
    s = u * u + v * v
    inside = s < 1
    d = np.stack([2 * u, 2 * v, 1 - s], -1) / (1 + s)[..., None]
    a = np.where(inside, 4 / (1 + s) ** 2 * h * h, 0.0)
    return d.reshape(-1, 3)[inside.ravel()], a.ravel()[inside.ravel()]


def numpy_errors(albedo, ks, n, kmax=8):
    """Relative L2 error of diffuse + (K-1) glossy SVD terms: the squared singular values are
    the eigenvalues of the weighted table's Gram matrix (NumPy/LAPACK, not Eigen)."""
    wi, ai = parabolic(96)
    wo, ao = parabolic(32)
    r = wo * np.array([-1, -1, 1])  # mirror about z
    c = np.clip(wi @ r.T, 0, None)
    glossy = ks * (n + 2) / (2 * np.pi) * c ** n * wi[:, 2:3]
    full = glossy + albedo / np.pi * wi[:, 2:3]
    w = np.sqrt(ai)[:, None] * np.sqrt(ao)[None, :]
    a = glossy * w
    s2 = np.sort(np.clip(np.linalg.eigvalsh(a.T @ a), 0, None))[::-1]  # σ², LAPACK's, 5x faster than svd
    total = np.sum((full * w) ** 2)
    return [np.sqrt(np.sum(s2[k - 1:]) / total) for k in range(1, kmax + 1)]


def printed_errors(stdout):
    m = re.search(r"relative L2 error of rho\*cos for K = 1\.\.\d+:((?: [0-9.]+)+)", stdout)
    return [float(x) for x in m.group(1).split()] if m else None


def main():
    with tempfile.TemporaryDirectory() as d:
        j = lambda *p: os.path.join(d, *p)  # noqa: E731
        v, f = icosphere(4)
        write_obj(j("ball.obj"), v, f)
        city = None
        maps = subprocess.run(["bash", os.path.join(os.path.dirname(__file__), "..", "..", "scripts",
                                                      "find_envmaps.sh")], capture_output=True, text=True).stdout.strip()
        if maps and os.path.exists(os.path.join(maps, "city.exr")):
            city = os.path.join(maps, "city.exr")
        else:  # a map of our own: a bright window in a dim room
            env = np.full((6 * 8 * 8, 3), 0.2, np.float32)
            env[4 * 64:4 * 64 + 16] = [8.0, 7.0, 5.0]
            city = j("window.npy")
            np.save(city, env)

        def scene(name, mode="vertex", ks=0.6, exponent=32.0):
            out = 'objects = ["ball"]' if mode == "vertex" else CAMERA
            return t.write(j(name), SCENE.format(mode=mode, output=out, ks=ks, exponent=exponent, obj=j("ball.obj")))

        # 1. K = 1 and term 0 are the plain vertex bake; a Lambertian scene's other terms are 0.
        g32 = scene("g32.toml")
        t.run("sample", g32, "-o", j("plain.ltm"), "-q")
        t.run("sample", g32, "-o", j("k1.ltm"), "--factor", 1, "-q")
        p = t.run("sample", g32, "-o", j("g32.ltm"), "--factor", 8)
        t.check(matrix_hash(j("k1.k0.ltm")) == matrix_hash(j("plain.ltm")), "--factor 1 differs from the vertex bake")
        t.check(matrix_hash(j("g32.k0.ltm")) == matrix_hash(j("plain.ltm")), "term 0 of --factor 8 is not the diffuse bake")
        lam = scene("lambert.toml", ks=0.0)
        t.run("sample", lam, "-o", j("lam.ltm"), "--factor", 3, "-q")
        for k in (1, 2):
            st = info(j(f"lam.k{k}.ltm"))["arrays"][0]["stats"]
            t.check(st["max"] == 0 and st["min"] == 0, f"Lambertian term {k} is not zero: {st}")

        # 2. The printed errors against NumPy's singular values.
        got = printed_errors(p.stdout)
        want = numpy_errors(0.3, 0.6, 32.0)
        print("factorisation error, Phong(32), K = 1..8: ltbake", got, "NumPy", [round(x, 4) for x in want])
        t.check(got is not None and np.allclose(got, want, atol=2e-4), f"errors {got} vs NumPy {want}")
        # --factor auto:T takes the fewest terms within T: T halfway between NumPy's errors at K = 4 and
        # K = 5 must give K = 5 (and its five files); a lobe no 64 terms reach is refused, naming the
        # triple-product path.
        target = (want[3] + want[4]) / 2
        p = t.run("sample", g32, "-o", j("auto.ltm"), "--factor", f"auto:{target:.6f}", "--json")
        rep = json.loads(p.stdout or "{}")
        t.check(rep.get("factor_auto", {}).get("terms") == 5 and os.path.exists(j("auto.k4.ltm")) and
                not os.path.exists(j("auto.k5.ltm")) and abs(rep["factor_auto"]["error"] - want[4]) < 2e-4,
                f"--factor auto:{target:.4f} (between K = 4 and 5): {rep.get('factor_auto')}")
        # The same in a recipe: [sample] factor = "auto:T" chooses K when the bake is planned.
        recipe = t.write(j("auto_bake.toml"), f'scene = "{g32}"\nworkdir = "{j("wauto")}"\ntargets = ["sample"]\n'
                         f'[sample]\nfactor = "auto:{target:.6f}"\n')
        p = t.run("run", recipe, "--progress", "never")
        t.check("K = 5" in p.stdout and os.path.exists(j("wauto", "raw.k4.ltm")) and
                not os.path.exists(j("wauto", "raw.k5.ltm")) and
                matrix_hash(j("wauto", "raw.k4.ltm")) == matrix_hash(j("auto.k4.ltm")),
                f"a recipe's factor = auto:{target:.4f}: {p.stdout[-600:]}")
        p = t.run("sample", scene("sharp.toml", exponent=2000.0), "-o", j("sharp.ltm"), "--factor", "auto:5%", expect=1)
        t.check("triple-product" in p.stderr and "64 terms" in p.stderr, f"auto for a Phong(2000) lobe: {p.stderr}")
        for bad in ("0", "65", "auto:2", "auto:x", "k4"):
            p = t.run("sample", g32, "-o", j("bad.ltm"), "--factor", bad, expect=2)
            t.check("--factor" in p.stderr, f"--factor {bad}: {p.stderr}")

        # 3. Convergence to the brute-force render.
        for exponent, bound in ((4.0, 0.12), (32.0, None)):
            vs, bf = scene(f"v{exponent}.toml", exponent=exponent), scene(f"bf{exponent}.toml", "image",
                                                                            exponent=exponent)
            t.run("sample", vs, "-o", j(f"f{exponent}.ltm"), "--factor", 8, "-q")
            t.run("sample", bf, "-o", j(f"bf{exponent}.ltm"), "-q")
            t.run("relight", j(f"bf{exponent}.ltm"), "--env", city, "--clamp", "--terms", "all", "-o",
                  j(f"bf{exponent}.npy"), "-q")
            ref = np.load(j(f"bf{exponent}.npy")).reshape(SIZE, SIZE, 3).astype(np.float64)
            errs = {}
            for k in (1, 2, 4, 8):
                t.run("relight", j(f"f{exponent}.ltm"), "--env", city, "--clamp", "--terms", "all", *VIEW,
                      "--brdf-terms", k, "-o", j(f"v{exponent}_{k}.npy"), "-q")
                img = np.load(j(f"v{exponent}_{k}.npy")).reshape(SIZE, SIZE, 3).astype(np.float64)
                if k == 1:
                    ball = img.sum(2) > 0
                errs[k] = float(np.linalg.norm(img[ball] - ref[ball]) / np.linalg.norm(ref[ball]))
            print(f"Phong({exponent:g}) against the brute-force render, rel. L2 on {ball.sum()} pixels: " +
                  ", ".join(f"K={k} {e:.4f}" for k, e in errs.items()))
            t.check(ball.sum() > SIZE * SIZE // 10, f"Phong({exponent}): the ball covers {ball.sum()} pixels")
            t.check(errs[1] > errs[2] > errs[4] > errs[8], f"Phong({exponent}): error does not fall with K: {errs}")
            if bound is not None:
                t.check(errs[8] < bound, f"Phong({exponent}): K = 8 error {errs[8]:.4f} (bound {bound})")

        # 3b. With --bounces 1 (the floor lights the ball from below): term 0 is the plain vertex
        # bake with the same bounces, bit for bit; the factored set converges to the image-mode brute
        # force with the same bounce, and that light matters (the set without it is farther off).
        t.run("sample", j("v4.0.toml"), "-o", j("fb.ltm"), "--factor", 8, "--bounces", 1, "-q")
        t.run("sample", j("v4.0.toml"), "-o", j("plainb.ltm"), "--bounces", 1, "-q")
        t.check(matrix_hash(j("fb.k0.ltm")) == matrix_hash(j("plainb.ltm")),
                "term 0 of --factor 8 --bounces 1 is not the vertex bake with --bounces 1")
        t.run("sample", j("bf4.0.toml"), "-o", j("bfb.ltm"), "--bounces", 1, "-q")
        # The lobe terms' bounce matters too: term 0 with its bounce and terms 1..7 without.
        for k in range(8):
            shutil.copy(j(f"fb.k{k}.ltm") if k == 0 else j(f"f4.0.k{k}.ltm"), j(f"mix.k{k}.ltm"))
        views = {}
        for name in ("bfb", "fb", "f4.0", "mix"):
            t.run("relight", j(f"{name}.ltm"), "--env", city, "--clamp", "--terms", "all",
                  *([] if name == "bfb" else VIEW), "-o", j(f"{name}_view.npy"), "-q")
            views[name] = np.load(j(f"{name}_view.npy")).reshape(SIZE, SIZE, 3).astype(np.float64)
        ref = views["bfb"]
        e_b, e_d, e_m = (float(np.linalg.norm(views[n][ball] - ref[ball]) / np.linalg.norm(ref[ball]))
                         for n in ("fb", "f4.0", "mix"))
        print(f"Phong(4), K = 8, against the brute force with one bounce: {e_b:.4f} with --bounces 1, "
              f"{e_d:.4f} without, {e_m:.4f} with the bounce in term 0 only")
        # The bound: the direct set's 0.046 and the bounce's Monte Carlo noise at spp 4 (a diffuse
        # ball's bounced set is 0.063 off its brute force; both halve at spp 16).
        t.check(e_b < 0.12 and e_d > 1.5 * e_b and e_m > 1.3 * e_b,
                f"--factor 8 --bounces 1: {e_b:.4f} off the brute force with one bounce (bound 0.12), the "
                f"direct-only set {e_d:.4f} (should be > 1.5x), the bounce in term 0 only {e_m:.4f} (> 1.3x)")

        # 3c. In colour with the bounce (a red plastic over a green floor: colour bleeds, so one
        # matrix per channel): term 0 of `--channels rgb --factor 8` is the `--channels rgb` bake, bit for
        # bit, and the set converges to the image-mode brute force in colour in every channel.
        ctext = SCENE.replace("albedo = 0.3", "albedo = [0.35, 0.12, 0.08]", 1).replace("albedo = 0.7",
                                                                                     "albedo = [0.2, 0.6, 0.3]", 1)
        cv = t.write(j("cv.toml"), ctext.format(mode="vertex", output='objects = ["ball"]', ks=0.6, exponent=4.0,
                                               obj=j("ball.obj")))
        cb = t.write(j("cb.toml"), ctext.format(mode="image", output=CAMERA, ks=0.6, exponent=4.0, obj=j("ball.obj")))
        t.run("sample", cv, "-o", j("cf.ltm"), "--factor", 8, "--channels", "rgb", "--bounces", 1, "-q")
        t.run("sample", cv, "-o", j("cp.ltm"), "--channels", "rgb", "--bounces", 1, "-q")
        t.check(all(matrix_hash(j(f"cf.k0.{c}.ltm")) == matrix_hash(j(f"cp.{c}.ltm")) for c in "rgb"),
                "term 0 of --channels rgb --factor 8 --bounces 1 is not the --channels rgb bake")
        t.run("sample", cb, "-o", j("cbf.ltm"), "--channels", "rgb", "--bounces", 1, "-q")
        t.run("relight", j("cbf.ltm"), "--env", city, "--clamp", "--terms", "all", "-o", j("cbf.npy"), "-q")
        t.run("relight", j("cf.ltm"), "--env", city, "--clamp", *VIEW, "-o", j("cf.npy"), "-q")
        a = np.load(j("cf.npy")).reshape(SIZE, SIZE, 3).astype(np.float64)
        r = np.load(j("cbf.npy")).reshape(SIZE, SIZE, 3).astype(np.float64)
        e_c = [float(np.linalg.norm(a[ball][:, c] - r[ball][:, c]) / np.linalg.norm(r[ball][:, c])) for c in range(3)]
        print("red Phong(4) plastic on a green floor, K = 8, one bounce, against the brute force per channel:",
              ", ".join(f"{x:.4f}" for x in e_c))
        t.check(max(e_c) < 0.12, f"--channels rgb --factor 8 --bounces 1: {e_c} off the brute force (bound 0.12)")
        # Its terms through a stage (each term a colour set: X.k0.r.ltm ...) and the recipe's
        # [sample] channels = "rgb" with factor: a step per term and channel, each the one-pass file.
        t.run("row-transform", j("cf.ltm"), "-o", j("cfrows.ltm"), "-q")
        t.run("relight", j("cfrows.ltm"), "--env", city, "--clamp", *VIEW, "-o", j("cfrows.npy"), "-q")
        e = float(np.linalg.norm(np.load(j("cfrows.npy")) - np.load(j("cf.npy"))) / np.linalg.norm(np.load(j("cf.npy"))))
        t.check(os.path.exists(j("cfrows.k7.b.ltm")) and e < 1e-4, f"the colour set's rows render {e:.2e} off it")
        t.run("convert", j("cf.ltm"), j("cf_all.npy"), "-q")
        t.run("convert", j("cf.k2.g.ltm"), j("cf_k2g.npy"), "-q")
        whole = np.load(j("cf_all.npy"), mmap_mode="r")
        t.check(whole.shape == (24, len(v), 384) and np.array_equal(whole[3 * 2 + 1], np.load(j("cf_k2g.npy"))),
                f"convert of the colour factored set: shape {whole.shape}, [7] not term 2's green matrix")
        t.run("sample", cv, "-o", j("c2.ltm"), "--factor", 2, "--channels", "rgb", "-q")
        recipe = t.write(j("c2_bake.toml"), f'scene = "{cv}"\nworkdir = "{j("wc2")}"\ntargets = ["sample"]\n'
                         '[sample]\nfactor = 2\nchannels = "rgb"\n')
        t.run("run", recipe, "--progress", "never")
        t.check(all(matrix_hash(j("wc2", f"raw.k{k}.{c}.ltm")) == matrix_hash(j(f"c2.k{k}.{c}.ltm"))
                    for k in range(2) for c in "rgb"), "a recipe's colour factored terms differ from the one-pass bake's")
        p = t.run("sample", cv, "-o", j("x.ltm"), "--factor", 2, "--channel", "r", expect=1)
        t.check("--factor-term" in p.stderr, f"--factor with --channel and no --factor-term: {p.stderr}")

        # 4. An orbit; the set through the stages.
        t.run("relight", j("g32.ltm"), "--env", city, "--clamp", *VIEW, "--orbit", "90:4", "-o", j("orbit_%02d.npy"),
              "-q")
        frames = [np.load(j(f"orbit_{k:02d}.npy")) for k in range(4)]
        t.check(all(fr.shape == (SIZE * SIZE, 3) for fr in frames) and not np.allclose(frames[0], frames[2]),
                "orbit: four views, the opposite one different")
        t.run("row-transform", j("g32.ltm"), "-o", j("rows.ltm"), "-q")
        t.run("transpose", j("rows.ltm"), "-o", j("cols.ltm"), "-q")
        t.run("column-transform", j("cols.ltm"), "-o", j("c4.ltm"), "--depth", "none", "--budget", "100%", "-q")
        t.run("quantize", j("c4.ltm"), "-o", j("final.ltm"), "--bits", 16, "-q")
        t.run("relight", j("g32.ltm"), "--env", city, "--clamp", "--terms", "all", *VIEW, "-o", j("raw_view.npy"), "-q")
        t.run("relight", j("final.ltm"), "--env", city, "--clamp", "--terms", "all", *VIEW, "-o", j("fin_view.npy"),
              "-q")
        a, b = np.load(j("fin_view.npy")), np.load(j("raw_view.npy"))
        e = np.linalg.norm(a - b) / np.linalg.norm(b)
        t.check(e < 0.01, f"the quantized set renders {e:.4f} off the raw set")
        # A view takes every lighting term unless --terms says otherwise, and then says what it kept.
        p = t.run("relight", j("g32.ltm"), "--env", city, "--clamp", *VIEW, "-o", j("default_view.npy"))
        t.check(np.array_equal(np.load(j("default_view.npy")), b) and "every lighting term (384)" in p.stdout,
                f"a view without --terms should be --terms all, and say so: {p.stdout}")
        p = t.run("relight", j("g32.ltm"), "--env", city, "--clamp", *VIEW, "--terms", 100, "-o", j("cut_view.npy"))
        m = re.search(r"100 of 384 lighting terms \(the brightest texels, ([0-9.]+)% of the map's energy", p.stdout)
        cut = np.load(j("cut_view.npy"))
        t.check(m is not None and 0 < float(m.group(1)) < 100 and not np.array_equal(cut, b),
                f"a view with --terms 100 should say what it kept: {p.stdout}")
        # A coloured plastic (a red albedo, a white lobe): term 0 carries the albedo's colour, the
        # lobe's terms none, so each vertex's radiance is the red diffuse set's (albedo 1, grey,
        # times the colour) plus the lobe's own set (albedo 0), to float rounding.
        for name, albedo, ks in (("plastic", "[0.45, 0.12, 0.08]", 0.5), ("dif", "1.0", 0.0), ("lobe", "0.0", 0.5)):
            text = SCENE.format(mode="vertex", output='objects = ["ball"]', ks=ks, exponent=16.0, obj=j("ball.obj"))
            t.write(j(f"{name}.toml"), text.replace("albedo = 0.3", f"albedo = {albedo}", 1))
            t.run("sample", j(f"{name}.toml"), "-o", j(f"{name}.ltm"), "--factor", 4, "-q")
            t.run("relight", j(f"{name}.ltm"), "--env", city, "--clamp", *VIEW, "-o", j("x.npy"), "--vertex-output",
                  j(f"{name}_b.npy"), "-q")
        if all(os.path.exists(j(f"{n}_b.npy")) for n in ("plastic", "dif", "lobe")):
            got = np.load(j("plastic_b.npy")).astype(np.float64)
            want = np.load(j("dif_b.npy")) * np.array([0.45, 0.12, 0.08]) + np.load(j("lobe_b.npy"))
            e = np.linalg.norm(got - want) / np.linalg.norm(want)
            t.check(e < 1e-5 and np.linalg.norm(np.load(j("lobe_b.npy"))) > 0.1 * np.linalg.norm(want),
                    f"a red plastic's factored set is {e:.2e} off its diffuse and lobe parts")
        # A plain vertex bake (no --factor) is seen from an eye too: the same image as its K = 1 set.
        for name in ("plain", "k1"):
            t.run("relight", j(f"{name}.ltm"), "--env", city, "--clamp", *VIEW, "-o", j(f"{name}_view.npy"), "-q")
        t.check(np.array_equal(np.load(j("plain_view.npy")), np.load(j("k1_view.npy"))) and
                np.load(j("plain_view.npy")).max() > 0, "a plain vertex bake's view differs from its --factor 1 set's")
        # A map near float32's largest value (RGBE exponent 255: 255·2^119) through the quantized
        # (Haar) set, whose lighting coefficients would pass float32, is relit at 2^-k and scaled
        # back: 2^126 times the view under the same map at exponent 129, bit for bit.
        for e in (129, 255):
            with open(j(f"e{e}.hdr"), "wb") as f:
                f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32 +X 64\n" + bytes([255, 255, 255, e]) * (64 * 32))
            t.run("relight", j("final.ltm"), "--env", j(f"e{e}.hdr"), *VIEW, "-o", j(f"bright{e}.npy"), "-q")
        small, big = np.load(j("bright129.npy")), np.load(j("bright255.npy"))
        t.check(np.all(np.isfinite(big)) and big.max() > 1e37 and np.array_equal(big, np.ldexp(small, 126)),
                f"glossy view under an exponent-255 map: {np.isnan(big).sum()} NaN, max {big.max()}")
        t.run("cpca", j("rows.ltm"), "-o", j("cpca.ltm"), "--clusters", 4, "--basis", 8, "-q")
        t.run("relight", j("cpca.ltm"), "--env", city, "--clamp", "--terms", "all", *VIEW, "-o", j("cpca_view.npy"),
              "-q")
        e = np.linalg.norm(np.load(j("cpca_view.npy")) - b) / np.linalg.norm(b)
        print(f"the cpca set (4 clusters, 8 basis vectors) renders {e:.4f} off the raw set")
        t.check(e < 0.2, f"the cpca set renders {e:.4f} off the raw set")
        t.run("convert", j("final.ltm"), j("final.npy"), "-q")
        t.check(np.load(j("final.npy")).shape == (8, len(v), 384), "convert of a factored set: not (8, rows, cols)")

        # A recipe: [sample] factor = 3 bakes a term a step, each equal to the one-pass bake's;
        # [relight] eye renders the view; a rerun skips everything.
        recipe = t.write(j("bake.toml"), f"""
scene = "{g32}"
workdir = "{j('wd')}"
targets = ["quantize", "relight"]
[sample]
factor = 3
[column-transform]
depth = "none"
[relight]
envs = ["{city}"]
clamp = true
eye = [0.0, -3.0, 2.0]
target = [0.0, 0.0, 1.0]
fov = 30.0
size = [{SIZE}, {SIZE}]
""")
        t.run("run", recipe, "--progress", "never")
        t.run("sample", g32, "-o", j("one.ltm"), "--factor", 3, "--row-transform", "haar", "-q")
        for k in range(3):
            t.check(matrix_hash(j("wd", f"rows.k{k}.ltm")) == matrix_hash(j(f"one.k{k}.ltm")),
                    f"the recipe's term {k} differs from the one-pass bake's")
        steps = {s_["node"]: s_["action"] for s_ in t.run_report(j("wd"))["stages"]}
        t.check(steps.get("relight:" + os.path.splitext(os.path.basename(city))[0]) == "run" and
                "quantize.k2" in steps, f"the factored recipe's steps: {steps}")
        t.run("run", recipe, "--progress", "never")
        again = {s_["node"]: s_["action"] for s_ in t.run_report(j("wd"))["stages"]}
        t.check(set(again.values()) == {"skip"}, f"rerunning the factored recipe ran steps again: {again}")

        # 5. Refusals.
        p = t.run("relight", j("g32.ltm"), "--env", city, "-o", j("x.npy"), expect=1)
        t.check("--eye" in p.stderr, f"a factored set without --eye: {p.stderr}")
        t.run("sample", g32, "-o", j("other.ltm"), "--factor", 4, "-q")
        os.replace(j("g32.k2.ltm"), j("g32.k2.bak"))
        p = t.run("relight", j("g32.ltm"), "--env", city, *VIEW, "-o", j("x.npy"), expect=1)
        t.check("g32.k2.ltm" in p.stderr and "g32.k0.ltm" in p.stderr, f"a missing term: {p.stderr}")
        os.replace(j("other.k2.ltm"), j("g32.k2.ltm"))
        p = t.run("relight", j("g32.ltm"), "--env", city, *VIEW, "-o", j("x.npy"), expect=1)
        t.check("g32.k2.ltm" in p.stderr and "g32.k0.ltm" in p.stderr and "terms" in p.stderr,
                f"a term of another bake: {p.stderr}")
        p = t.run("sample", scene("img.toml", "image"), "-o", j("img.ltm"), "--factor", 4, expect=1)
        t.check("vertex" in p.stderr, f"--factor in image mode: {p.stderr}")
        p = t.run("sample", j("plastic.toml"), "-o", j("b.ltm"), "--factor", 4, "--bounces", 1, expect=1)
        t.check("--bounces" in p.stderr and "--channels rgb" in p.stderr and "plastic.toml" in p.stderr,
                f"a monochrome --factor with --bounces in a coloured scene: {p.stderr}")
    t.finish()


if __name__ == "__main__":
    main()
