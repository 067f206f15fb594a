"""Colour (docs/COLOUR.md) through the CLI, against independent oracles: NumPy, closed
forms, and content hashes recorded before colour existed.

1. Scenes without colour are byte-identical to before: the matrix content_hash of
   samples/bunny-vertices.toml and of the grey Cornell box (cornell.toml as it was, at
   --cube-res 8) equal the hashes recorded in bench/results/sample.md by the code of
   2026-11-26, before this feature. A grey RGB material ([a, a, a]) bakes exactly the
   scalar material's matrix, with no reflectance table.
2. A red material under a constant white map relights to (r, 0, 0) pixels: green and blue
   exactly 0, red the grey bake's value times the tint (NumPy), in the monochrome bake
   (reflectance table) and in the per-channel bake (--channels rgb), which agree.
3. Colour bleeding with one bounce: a white floor beside a red wall is tinted red near the
   wall and not far from it (the pixels are classified by their position side table).
4. Vertex colours (a PLY with red/green/blue) become the reflectance table: the sRGB
   decode of the file's bytes (NumPy) times the material's tint.
5. The set through every stage: row-transform, transpose, column-transform, quantize,
   cpca, relight, convert (a (3, rows, cols) .npy), inspect; a recipe with
   [sample] channels = "rgb" bakes, reruns as a no-op, and in 2 shards a step makes the same
   files.
6. Refusals naming the files: a set with a missing channel, a channel file from another
   bake, a mono reference against a set, a coloured bake with bounces without
   --channels rgb, a coloured lobe that does not factor out.

usage: colour_test.py PATH_TO_LTBAKE
"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest as t  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.join(HERE, "..", "..", "samples")

# Recorded by the code before colour (bench/results/sample.md, 2026-11-26).
BUNNY_VERTICES_HASH = "703e24307fae11c5"
CORNELL_R8_HASH = "9679be368926d2ba"

GREY_CORNELL = """
[output]
mode = "image"
[camera]
eye = [2.78, 8.0, 2.73]
target = [2.78, -2.8, 2.73]
up = [0.0, 0.0, 1.0]
fov = 37.0
width = 64
height = 64
[sampling]
cube_res = 16
spp = 4
bounces = 1
[[material]]
name = "white"
albedo = 0.75
[[object]]
name = "box"
type = "mesh"
file = "/usr/share/doc/embree3/models/cornell_box.obj"
scale = 0.01
rotate = [90.0, 0.0, 0.0]
material = "white"
"""

# A floor and a ball (samples/tiny.toml's layout), materials filled in per test.
BALL = """
[output]
mode = "image"
[camera]
eye = [0.0, -3.0, 2.4]
target = [0.0, 0.0, 0.2]
up = [0.0, 0.0, 1.0]
fov = 40.0
width = 24
height = 24
[sampling]
cube_res = 4
spp = 4
bounces = {bounces}
[[material]]
name = "floor"
albedo = {floor}
[[material]]
name = "ball"
albedo = {ball}
ks = {ks}
exponent = 30.0
[[object]]
name = "ground"
type = "plane"
size = [4.0, 4.0]
material = "floor"
[[object]]
name = "ball"
type = "sphere"
center = [0.0, 0.0, 0.7]
radius = 0.45
material = "ball"
"""

# A white floor with a red wall along x = 0 (facing +x), seen from above the floor.
BLEED = """
[output]
mode = "image"
[camera]
eye = [3.0, -4.0, 5.0]
target = [3.0, 0.0, 0.0]
up = [0.0, 0.0, 1.0]
fov = 50.0
width = 40
height = 40
[sampling]
cube_res = 8
spp = 4
bounces = 1
[[material]]
name = "white"
albedo = 0.7
[[material]]
name = "red"
albedo = [0.8, 0.0, 0.0]
[[object]]
name = "floor"
type = "plane"
size = [8.0, 8.0]
translate = [3.0, 0.0, 0.0]
material = "white"
[[object]]
name = "wall"
type = "box"
size = [0.1, 8.0, 2.0]
center = [-0.05, 0.0, 1.0]
material = "red"
"""


def info(path):
    return json.loads(t.run("inspect", path, "--json").stdout)


def matrix_hash(path):
    return info(path)["arrays"][0]["content_hash"]


def array_names(path):
    return [a["name"] for a in info(path)["arrays"]]


def sample(scene, out, *args, expect=0):
    return t.run("sample", scene, "-o", out, "--progress", "never", "-q", *args, expect=expect)


def relight(matrix, env, out, *args, expect=0):
    p = t.run("relight", matrix, "--env", env, "-o", out, "--terms", "all", "-q", *args, expect=expect)
    return np.load(out).astype(np.float64) if p.returncode == 0 else None


def srgb_to_linear(c):
    c = np.asarray(c, np.float64)
    return np.where(c <= 0.04045, c / 12.92, ((c + 0.055) / 1.055) ** 2.4)


def write_ply(path, positions, faces, rgb):
    with open(path, "w") as f:
        f.write("ply\nformat ascii 1.0\nelement vertex %d\n" % len(positions))
        f.write("property float x\nproperty float y\nproperty float z\n")
        f.write("property uchar red\nproperty uchar green\nproperty uchar blue\n")
        f.write("element face %d\nproperty list uchar int vertex_indices\nend_header\n" % len(faces))
        for p, c in zip(positions, rgb):
            f.write("%g %g %g %d %d %d\n" % (*p, *c))
        for fc in faces:
            f.write("3 %d %d %d\n" % tuple(fc))


def main():
    with tempfile.TemporaryDirectory() as d:
        j = lambda *p: os.path.join(d, *p)  # noqa: E731
        white = j("white.npy")
        np.save(white, np.ones((6 * 4 * 4, 3), np.float32))
        white8 = j("white8.npy")
        np.save(white8, np.ones((6 * 8 * 8, 3), np.float32))

        # 1. Without colour: the hashes of before; grey RGB = scalar.
        sample(os.path.join(SAMPLES, "bunny-vertices.toml"), j("bunny.ltm"))
        t.check(matrix_hash(j("bunny.ltm")) == BUNNY_VERTICES_HASH,
                f"bunny-vertices.toml: matrix hash {matrix_hash(j('bunny.ltm'))}, recorded {BUNNY_VERTICES_HASH}")
        cornell = t.write(j("grey_cornell.toml"), GREY_CORNELL)
        sample(cornell, j("cornell.ltm"), "--cube-res", "8")
        t.check(matrix_hash(j("cornell.ltm")) == CORNELL_R8_HASH,
                f"grey Cornell box: matrix hash {matrix_hash(j('cornell.ltm'))}, recorded {CORNELL_R8_HASH}")
        for bounces in (0, 1):
            scalar = t.write(j(f"scalar{bounces}.toml"), BALL.format(bounces=bounces, floor="0.8", ball="0.5", ks="0.3"))
            grey = t.write(j(f"grey{bounces}.toml"),
                           BALL.format(bounces=bounces, floor="[0.8, 0.8, 0.8]", ball="[0.5, 0.5, 0.5]",
                                       ks="[0.3, 0.3, 0.3]"))
            sample(scalar, j(f"scalar{bounces}.ltm"))
            sample(grey, j(f"grey{bounces}.ltm"))
            t.check(matrix_hash(j(f"scalar{bounces}.ltm")) == matrix_hash(j(f"grey{bounces}.ltm")),
                    f"bounces {bounces}: grey RGB material bakes another matrix than the scalar one")
            t.check("reflectance" not in array_names(j(f"grey{bounces}.ltm")),
                    f"bounces {bounces}: a grey scene got a reflectance table")
            meta = info(j(f"grey{bounces}.ltm"))
            t.check("channel" not in json.dumps(meta["provenance"]),
                    f"bounces {bounces}: a grey scene's provenance names a channel")

        # A coloured material no object uses changes nothing.
        unused = t.write(j("unused.toml"), BALL.format(bounces=1, floor="0.8", ball="0.5", ks="0.3") +
                         '[[material]]\nname = "red"\nalbedo = [0.9, 0.1, 0.1]\n')
        sample(unused, j("unused.ltm"))
        t.check(matrix_hash(j("unused.ltm")) == matrix_hash(j("scalar1.ltm")) and
                "reflectance" not in array_names(j("unused.ltm")), "an unused coloured material changed the bake")

        # 2. A red material under a constant white map: (r, 0, 0).
        red = t.write(j("red.toml"), BALL.format(bounces=0, floor="[0.7, 0.0, 0.0]", ball="[0.5, 0.0, 0.0]",
                                                 ks="[0.3, 0.0, 0.0]"))
        greyref = t.write(j("greyref.toml"), BALL.format(bounces=0, floor="0.7", ball="0.5", ks="0.3"))
        sample(red, j("red.ltm"))
        sample(greyref, j("greyref.ltm"))
        t.check("reflectance" in array_names(j("red.ltm")), "red.ltm has no reflectance table")
        t.check(matrix_hash(j("red.ltm")) == matrix_hash(j("greyref.ltm")),
                "the monochrome bake of the red scene is not the grey bake of its brightest channel")
        img = relight(j("red.ltm"), white, j("red.npy"))
        ref = relight(j("greyref.ltm"), white, j("greyref.npy"))
        mask = t.side_table(j("red.ltm"), "mask")[:, 0] > 0
        t.check(np.all(img[:, 1:] == 0), "red scene: green/blue are not 0 under a white map")
        t.check(np.all(img[mask, 0] > 0), "red scene: a pixel that sees geometry has no red")
        t.check(np.array_equal(img[:, 0], ref[:, 0]), "red scene: red channel is not the grey bake's")
        sample(red, j("redset.ltm"), "--channels", "rgb")
        for c in "rgb":
            t.check(os.path.exists(j(f"redset.{c}.ltm")), f"--channels rgb wrote no redset.{c}.ltm")
        imgset = relight(j("redset.ltm"), white, j("redset.npy"))
        t.check(np.all(imgset[:, 1:] == 0), "red scene, per channel: green/blue are not 0")
        # Channel r bakes albedo 0.7/0.5, ks 0.3 exactly as the grey scene does.
        t.check(np.array_equal(imgset[:, 0], img[:, 0]), "red scene: per-channel red differs from the monochrome red")
        # A tint that is not 1 or 0: the reflectance bake vs the channel bake, to f32 rounding.
        pink = t.write(j("pink.toml"), BALL.format(bounces=0, floor="[0.8, 0.4, 0.2]", ball="[0.5, 0.25, 0.125]",
                                                   ks="[0.2, 0.1, 0.05]"))
        sample(pink, j("pink.ltm"))
        sample(pink, j("pinkset.ltm"), "--channels", "rgb")
        a = relight(j("pink.ltm"), white, j("pink.npy"))
        b = relight(j("pinkset.ltm"), white, j("pinkset.npy"))
        err = np.abs(a - b).max() / np.abs(b).max()
        t.check(err < 1e-5, f"pink scene: reflectance bake vs per-channel bake differ by {err:.2e} (f32 rounding: 1e-5)")
        refl = t.side_table(j("pink.ltm"), "reflectance")
        t.check(np.allclose(np.unique(refl[mask].round(6), axis=0), [[1.0, 0.5, 0.25]]),
                f"pink scene: reflectance rows {np.unique(refl[mask].round(6), axis=0)}, expected [1, 0.5, 0.25]")

        # A sparse bake (docs/SPARSE.md) writes the table too.
        sample(pink, j("pinksparse.ltm"), "--sparse")
        t.check("reflectance" in array_names(j("pinksparse.ltm")), "a coloured sparse bake has no reflectance table")
        sp = relight(j("pinksparse.ltm"), white, j("pinksparse.npy"))
        err = np.linalg.norm(sp - a) / np.linalg.norm(a)
        t.check(err < 0.05, f"the coloured sparse bake relights {err:.4f} off the full one (bound 5%)")

        # 3. Colour bleeding: red near the wall, none far from it.
        bleed = t.write(j("bleed.toml"), BLEED)
        p = sample(bleed, j("bleed.ltm"), expect=None)
        t.check(p.returncode in (1, 2) and "--channels rgb" in p.stderr,
                f"a coloured bake with bounces, monochrome: {p.returncode} {p.stderr}")
        sample(bleed, j("bleed.ltm"), "--channels", "rgb")
        img = relight(j("bleed.ltm"), white8, j("bleed.npy"))
        pos = t.side_table(j("bleed.r.ltm"), "position")
        nor = t.side_table(j("bleed.r.ltm"), "normal")
        m = t.side_table(j("bleed.r.ltm"), "mask")[:, 0] > 0
        floor = m & (nor[:, 2] > 0.99) & (np.abs(pos[:, 2]) < 1e-3)
        near = floor & (pos[:, 0] > 0.05) & (pos[:, 0] < 0.6)
        far = floor & (pos[:, 0] > 4.5)
        t.check(near.sum() > 10 and far.sum() > 10, f"bleed scene: {near.sum()} near / {far.sum()} far floor pixels")
        t.check(np.array_equal(img[:, 1], img[:, 2]), "bleed scene: green and blue differ (equal albedos)")
        excess = lambda sel: float(np.mean(img[sel, 0] / img[sel, 1]) - 1.0)  # noqa: E731
        en, ef = excess(near), excess(far)
        print(f"colour bleeding: red excess r/g - 1 near the wall {en:.3f}, far from it {ef:.3f}")
        t.check(en > 0.1, f"bleed scene: red excess near the wall {en:.3f} (expected > 0.1)")
        t.check(0.0 <= ef < 0.25 * en, f"bleed scene: red excess far from the wall {ef:.3f} (near {en:.3f})")

        # 4. Vertex colours: the reflectance table is the sRGB decode times the tint.
        pos4 = [(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (0.5, 0.5, 0.3)]
        rgb4 = [(255, 0, 0), (0, 128, 0), (10, 20, 30), (200, 100, 50), (255, 255, 255)]
        write_ply(j("quad.ply"), pos4, [(0, 1, 4), (1, 2, 4), (2, 3, 4), (3, 0, 4)], rgb4)
        vscene = t.write(j("vcol.toml"), f"""
[output]
mode = "vertex"
objects = ["quad"]
[sampling]
cube_res = 4
[[material]]
name = "m"
albedo = [0.6, 0.3, 0.6]
[[object]]
name = "quad"
type = "mesh"
file = "{j('quad.ply')}"
colours = "file"
material = "m"
""")
        sample(vscene, j("vcol.ltm"))
        refl = t.side_table(j("vcol.ltm"), "reflectance").astype(np.float64)
        want = srgb_to_linear(np.array(rgb4) / 255.0) * np.array([1.0, 0.5, 1.0])
        t.check(np.allclose(refl, want, rtol=1e-6, atol=1e-7), f"vertex colours: reflectance {refl} expected {want}")
        sample(vscene, j("vcolset.ltm"), "--channels", "rgb")
        # --channels rgb is one pass; each file equals the --channel c bake, bit for bit (with
        # vertex colours here, with a bounce and a red wall in the bleed scene, a lobe in pink).
        for scene_file, set_name in ((vscene, "vcolset"), (bleed, "bleed"), (pink, "pinkset")):
            for c in "rgb":
                sample(scene_file, j(f"{set_name}_one_{c}.ltm"), "--channel", c)
                t.check(matrix_hash(j(f"{set_name}_one_{c}.ltm")) == matrix_hash(j(f"{set_name}.{c}.ltm")),
                        f"{set_name}: --channels rgb's {c} differs from --channel {c}")
        a = relight(j("vcol.ltm"), white, j("vcol.npy"))
        b = relight(j("vcolset.ltm"), white, j("vcolset.npy"))
        err = np.abs(a - b).max() / np.abs(b).max()
        t.check(err < 1e-5, f"vertex colours: reflectance bake vs per-channel bake differ by {err:.2e}")

        # 5. The set through every stage.
        s = j("pinkset.ltm")
        t.run("row-transform", s, "-o", j("rows.ltm"), "-q")
        t.run("transpose", j("rows.ltm"), "-o", j("cols.ltm"), "-q")
        t.run("column-transform", j("cols.ltm"), "-o", j("cols4d.ltm"), "--budget", "100%", "-q")
        t.run("quantize", j("cols4d.ltm"), "-o", j("final.ltm"), "--bits", "16", "-q")
        t.run("cpca", j("rows.ltm"), "-o", j("cpca.ltm"), "--clusters", "2", "--basis", "8", "-q")
        for stem in ("rows", "cols", "cols4d", "final", "cpca"):
            for c in "rgb":
                got = info(j(f"{stem}.{c}.ltm")).get("channel", {}).get("name")
                t.check(got == c, f"{stem}.{c}.ltm holds channel {got}, not {c}")
        for m_ in ("final", "cpca"):
            img = relight(j(f"{m_}.ltm"), white, j(f"{m_}.npy"))
            err = np.linalg.norm(img - b_pink(j, white)) / np.linalg.norm(b_pink(j, white))
            bound = 0.01 if m_ == "final" else 0.2
            t.check(err < bound, f"{m_}.ltm set relit {err:.4f} off the uncompressed set (bound {bound})")
        t.run("convert", j("rows.ltm"), j("rows3.npy"), "--basis", "pixels", "-q")
        t.run("convert", s, j("raw3.npy"), "-q")
        r3, w3 = np.load(j("rows3.npy")), np.load(j("raw3.npy"))
        t.check(r3.shape == w3.shape == (3, 24 * 24, 96), f"convert of a set: shapes {r3.shape} {w3.shape}")
        t.check(np.allclose(r3, w3, atol=1e-5 * np.abs(w3).max()), "convert of a set: rows (pixels) != raw")
        for c, ch in enumerate("rgb"):
            t.run("convert", j(f"pinkset.{ch}.ltm"), j(f"raw_{ch}.npy"), "-q")
            t.check(np.array_equal(np.load(j(f"raw_{ch}.npy")), w3[c]), f"convert of a set: [{c}] != channel {ch}")
        out = t.run("inspect", j("final.ltm")).stdout
        t.check(all(f"final.{c}.ltm" in out for c in "rgb"), f"inspect of a set: {out[:300]}")
        recipe = t.write(j("bake.toml"), f"""
scene = "{bleed}"
workdir = "{j('wd')}"
targets = ["quantize", "relight"]
[sample]
channels = "rgb"
cube_res = 4
[relight]
envs = ["{white}"]
terms = 100000
""")
        t.run("run", recipe, "--progress", "never")
        for c in "rgb":
            t.check(os.path.exists(j("wd", f"final.{c}.ltm")), f"the recipe made no final.{c}.ltm")
        rep = t.run_report(j("wd"))
        nodes = {s_["node"]: s_["action"] for s_ in rep["stages"]}
        want = {f"{st}.{c}" for st in ("sample+row-transform", "transpose", "column-transform", "quantize")
                for c in "rgb"} | {"relight:white"}
        t.check(set(nodes) == want and all(a == "run" for a in nodes.values()), f"the channel recipe's steps: {nodes}")
        t.run("run", recipe, "--progress", "never")
        again = {s_["node"]: s_["action"] for s_ in t.run_report(j("wd"))["stages"]}
        t.check(set(again.values()) == {"skip"}, f"rerunning the channel recipe ran steps again: {again}")
        # The same recipe in 2 shards a step: the same files.
        t.run("run", recipe, "--progress", "never", "--shards", 2, "--workdir", j("wd2"))
        for c in "rgb":
            t.check(matrix_hash(j("wd2", f"final.{c}.ltm")) == matrix_hash(j("wd", f"final.{c}.ltm")),
                    f"the sharded channel recipe made another final.{c}.ltm")

        # 6. Refusals naming the files.
        os.rename(j("final.g.ltm"), j("final.g.bak"))
        p = t.run("relight", j("final.ltm"), "--env", white, "-o", j("x.npy"), expect=1)
        t.check("final.g.ltm" in p.stderr and "final.r.ltm" in p.stderr, f"missing channel: {p.stderr}")
        os.rename(j("final.g.bak"), j("final.g.ltm"))
        sample(pink, j("other.ltm"), "--channel", "g", "--cube-res", "8")
        os.replace(j("other.ltm"), j("rowsx.g.ltm"))
        for c in "rb":
            os.link(j(f"pinkset.{c}.ltm"), j(f"rowsx.{c}.ltm"))
        p = t.run("relight", j("rowsx.ltm"), "--env", white8, "-o", j("x.npy"), expect=1)
        t.check("rowsx.g.ltm" in p.stderr and "rowsx.r.ltm" in p.stderr, f"mixed bakes in a set: {p.stderr}")
        p = t.run("relight", j("final.ltm"), "--env", white, "-o", j("x.npy"), "--reference", j("pink.ltm"), expect=1)
        t.check("pink.ltm" in p.stderr and "final.ltm" in p.stderr, f"mono reference vs set: {p.stderr}")
        os.link(j("pink.ltm"), j("fake.r.ltm"))
        for c in "gb":
            os.link(j(f"pinkset.{c}.ltm"), j(f"fake.{c}.ltm"))
        p = t.run("relight", j("fake.ltm"), "--env", white, "-o", j("x.npy"), expect=1)
        t.check("fake.r.ltm" in p.stderr and "no colour channel" in p.stderr, f"a mono file in a set: {p.stderr}")
        white_lobe = t.write(j("lobe.toml"), BALL.format(bounces=0, floor="0.5", ball="[0.5, 0.1, 0.1]",
                                                         ks="[0.3, 0.3, 0.3]"))
        p = sample(white_lobe, j("lobe.ltm"), expect=None)
        t.check(p.returncode in (1, 2) and "ball" in p.stderr and "--channels rgb" in p.stderr,
                f"a white lobe on a red base, monochrome: {p.stderr}")
        sample(white_lobe, j("lobe.ltm"), "--channels", "rgb")
    t.finish()


_pink_cache = {}


def b_pink(j, white):
    """The uncompressed per-channel relight of the pink set, once."""
    if "b" not in _pink_cache:
        _pink_cache["b"] = relight(j("pinkset.ltm"), white, j("pinkset_ref.npy"))
    return _pink_cache["b"]


if __name__ == "__main__":
    main()
