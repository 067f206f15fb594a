"""The triple-product path (docs/TRIPLE.md) through the ltbake binary, against NumPy.

- `sample --visibility` of a flat grid: every texel wholly above the plane is visible (1),
  every one below invisible (0), decoded from the stored Haar rows by a NumPy inverse
  written here from the basis' definition; a box beside the grid hides the texels behind it.
- Two independent paths, one answer: the triple product of a diffuse scene (pixel method,
  and the linear and sublinear methods through material fields) equals `relight` of the
  same scene's vertex-mode transport matrix.
- sublinear and shared with every term equal linear; sublinear's error against linear falls as
  terms grow; shared equals linear at few terms too.
- A Phong sphere under one bright texel: the brightest vertex is where the light's mirror
  direction meets the eye (the reflection of the view about the normal is the light).
- Blinn, Ward and Cook–Torrance material rows equal the lobes' definitions (NumPy) over
  every (normal, reflection vector) pair; a Blinn sphere through its field (quadrilinear
  interpolation) matches the exact lobe.
- Orbits write one image a frame; a [triple] recipe makes the same view as the commands
  and a rerun skips; bad inputs fail with a clear message.

usage: triple_test.py PATH_TO_LTBAKE
"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import check, finish, run, write  # noqa: E402

FACE_DIRS = [  # FaceDirection(face, u, v) of docs/CUBEMAP.md
    lambda u, v: np.stack([np.ones_like(u), -v, -u], -1),
    lambda u, v: np.stack([-np.ones_like(u), -v, u], -1),
    lambda u, v: np.stack([u, np.ones_like(u), v], -1),
    lambda u, v: np.stack([u, -np.ones_like(u), -v], -1),
    lambda u, v: np.stack([u, -v, np.ones_like(u)], -1),
    lambda u, v: np.stack([-u, -v, -np.ones_like(u)], -1),
]


def texel_grid(R, offset=0.5):
    t, s = np.mgrid[0:R, 0:R]
    return 2 * (s + offset) / R - 1, 2 * (t + offset) / R - 1


def texel_centres(R):
    u, v = texel_grid(R)
    d = np.concatenate([FACE_DIRS[f](u, v).reshape(-1, 3) for f in range(6)])
    return d / np.linalg.norm(d, axis=1, keepdims=True)


def texel_corner_z(R):
    """z of the four corner directions of every texel (6R² × 4), for above/below tests."""
    out = []
    for f in range(6):
        zs = []
        for du in (0, 1):
            for dv in (0, 1):
                u, v = texel_grid(R, 0.0)
                u, v = u + du * 2 / R, v + dv * 2 / R
                d = FACE_DIRS[f](u, v).reshape(-1, 3)
                zs.append(d[:, 2] / np.linalg.norm(d, axis=1))
        out.append(np.stack(zs, 1))
    return np.concatenate(out)


def haar_inverse(c, R):
    """Pixel values (rows × R², pixel (x, y) at y·R + x) of faces' coefficients (rows × R²) in
    HaarFace's layout: c[0] the scaling coefficient, square (l, i, j) at s = (4^l - 1)/3 + j·2^l
    + i, its wavelets of types 01 (sign by y half), 10 (by x half), 11 (the product) at
    1 + 3s + type, each 2^l on its square."""
    n = int(np.log2(R))
    y, x = np.mgrid[0:R, 0:R]
    y, x = y.reshape(-1), x.reshape(-1)
    out = np.repeat(c[:, :1], R * R, axis=1).astype(np.float64)
    for lv in range(n):
        i, j = x >> (n - lv), y >> (n - lv)
        qx, qy = (x >> (n - lv - 1)) & 1, (y >> (n - lv - 1)) & 1
        sx, sy = 2 * qx - 1, 2 * qy - 1
        s = (4 ** lv - 1) // 3 + j * 2 ** lv + i
        out += 2.0 ** lv * (c[:, 1 + 3 * s] * sy + c[:, 2 + 3 * s] * sx + c[:, 3 + 3 * s] * sx * sy)
    return out


def decode_rows(m, R):
    """Every row of a haar-squares matrix back to texel values (rows × 6R²)."""
    m = m.astype(np.float64)
    return np.concatenate([haar_inverse(m[:, f * R * R:(f + 1) * R * R], R) for f in range(6)], axis=1)


def texel_solid_angles(R):
    """Exact solid angle of every texel (6R²): ∫∫ (1 + u² + v²)^(-3/2) du dv in closed form."""
    A = lambda u, v: np.arctan2(u * v, np.sqrt(u * u + v * v + 1))  # noqa: E731
    u0, v0 = texel_grid(R, 0.0)
    u1, v1 = u0 + 2 / R, v0 + 2 / R
    sa = (A(u1, v1) - A(u0, v1) - A(u1, v0) + A(u0, v0)).reshape(-1)
    return np.tile(sa, 6)


def glossy(kind, p, n, wr, w):
    """ρ̃(w) = f(w, wo)·max(0, n·w) for the lobes of docs/TRIPLE.md, from their textbook
    definitions (normalised Blinn–Phong; isotropic Ward; Cook–Torrance with Beckmann D,
    Schlick F and the V-groove G), wo the mirror of wr about n. w: (m, 3)."""
    wo = 2 * (n @ wr) * n - wr
    nw, no = w @ n, n @ wo
    h = w + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    nh = np.clip(h @ n, 0, None)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = (1 - nh ** 2) / nh ** 2
        if kind == "blinn":
            f = (p[0] + 2) / (8 * np.pi) * nh ** p[0]
        elif kind == "ward":
            a2 = p[0] ** 2
            f = np.exp(-tan2 / a2) / (4 * np.pi * a2 * np.sqrt(nw * no))
        else:
            a2 = p[0] ** 2
            D = np.exp(-tan2 / a2) / (np.pi * a2 * nh ** 4)
            F = p[1] + (1 - p[1]) * (1 - np.clip((w * h).sum(1), 0, None)) ** 5
            oh = h @ wo
            G = np.minimum(1, np.minimum(2 * nh * no / oh, 2 * nh * nw / oh))
            f = D * F * G / (4 * nw * no)
        out = f * nw
    return np.where((nw > 0) & (no > 0), np.nan_to_num(out), 0.0)


def grid_obj(path, n, half):
    with open(path, "w") as f:
        for j in range(n + 1):
            for i in range(n + 1):
                f.write(f"v {-half + 2 * half * i / n} {-half + 2 * half * j / n} 0\n")
        for j in range(n):
            for i in range(n):
                a = j * (n + 1) + i + 1
                f.write(f"f {a} {a + 1} {a + n + 2}\nf {a} {a + n + 2} {a + n + 1}\n")


def icosphere_obj(path, subdiv):
    t = (1 + 5 ** 0.5) / 2
    v = [(-1, t, 0), (1, t, 0), (-1, -t, 0), (1, -t, 0), (0, -1, t), (0, 1, t), (0, -1, -t), (0, 1, -t),
         (t, 0, -1), (t, 0, 1), (-t, 0, -1), (-t, 0, 1)]
    v = [np.array(p, float) / np.linalg.norm(p) for p in v]
    faces = [(0, 11, 5), (0, 5, 1), (0, 1, 7), (0, 7, 10), (0, 10, 11), (1, 5, 9), (5, 11, 4), (11, 10, 2),
             (10, 7, 6), (7, 1, 8), (3, 9, 4), (3, 4, 2), (3, 2, 6), (3, 6, 8), (3, 8, 9), (4, 9, 5),
             (2, 4, 11), (6, 2, 10), (8, 6, 7), (9, 8, 1)]
    for _ in range(subdiv):
        mid = {}

        def m(a, b):
            k = (min(a, b), max(a, b))
            if k not in mid:
                p = v[a] + v[b]
                v.append(p / np.linalg.norm(p))
                mid[k] = len(v) - 1
            return mid[k]
        faces = [f for a, b, c in faces for f in
                 ((a, m(a, b), m(c, a)), (b, m(b, c), m(a, b)), (c, m(c, a), m(b, c)), (m(a, b), m(b, c), m(c, a)))]
    with open(path, "w") as f:
        for p in v:
            f.write(f"v {p[0]} {p[1]} {p[2]}\n")
        for a, b, c in faces:
            f.write(f"f {a + 1} {b + 1} {c + 1}\n")
    return np.array(v)


def rel(a, b):
    return float(np.linalg.norm(a - b) / np.linalg.norm(b))


def load_matrix(ltbake_npy_dir, ltm):
    out = os.path.join(ltbake_npy_dir, os.path.basename(ltm) + ".npy")
    run("convert", ltm, out)
    return np.load(out)


with tempfile.TemporaryDirectory() as d:
    R = 8
    grid_obj(os.path.join(d, "grid.obj"), 6, 1.5)
    # --- visibility of a flat grid (no occluder): exactly the horizon ---------------------
    flat = write(os.path.join(d, "flat.toml"), f"""
[output]
mode = "vertex"
objects = ["ground"]
[sampling]
cube_res = {R}
spp = 4
[[object]]
name = "ground"
type = "mesh"
file = "grid.obj"
""")
    vis = os.path.join(d, "flat_vis.ltm")
    run("sample", flat, "--visibility", "-o", vis)
    info = json.loads(run("inspect", vis, "--json").stdout)
    check("haar-squares" in json.dumps(info), "inspect shows the field's basis")
    V = decode_rows(load_matrix(d, vis), R)
    zc = texel_corner_z(R)
    above, below = (zc >= 0).all(1), (zc <= 0).all(1)
    check(above.sum() + below.sum() == 6 * R * R, "with R even the plane's horizon runs along texel edges")
    check(np.abs(V[:, above] - 1).max() < 1e-6, f"texels above a flat grid are visible: {V[:, above].min()}")
    check(np.abs(V[:, below]).max() < 1e-6, f"texels below a flat grid are invisible: {np.abs(V[:, below]).max()}")
    run("sample", flat, "--visibility", "-o", vis)  # resumes: nothing left to do
    p = run("relight", vis, "--env", os.path.join(d, "none.exr"), "-o", os.path.join(d, "x.png"), expect=1)
    check("visibility" in p.stderr and "--material" in p.stderr,
          f"relight of a visibility field without --material says what to do: {p.stderr}")

    # --- a box beside the grid hides the texels behind it ----------------------------------
    boxed = write(os.path.join(d, "boxed.toml"), open(flat).read() + """
[[object]]
name = "wall"
type = "box"
size = [0.2, 3.0, 2.0]
center = [0.6, 0.0, 1.0]
""")
    vis_box = os.path.join(d, "box_vis.ltm")
    run("sample", boxed, "--visibility", "-o", vis_box)
    Vb = decode_rows(load_matrix(d, vis_box), R)
    # Vertex (0, 0) of the grid (row (3, 3) of 7×7) looks at +X, through the wall.
    centre_row = 3 * 7 + 3
    dirs = texel_centres(R)
    toward = (dirs[:, 0] > 0.9)  # the +X face's middle: inside the wall's angular footprint
    check(np.abs(Vb[centre_row, toward]).max() < 1e-6, "the wall hides the texels behind it")
    check(np.abs(Vb[centre_row, dirs[:, 0] < -0.5] - V[centre_row, dirs[:, 0] < -0.5]).max() < 1e-6,
          "texels away from the wall are as without it")

    # --- two paths, one answer: a diffuse scene ---------------------------------------------
    R = 16
    diffuse = write(os.path.join(d, "diffuse.toml"), f"""
[output]
mode = "vertex"
objects = ["ground", "ball"]
[sampling]
cube_res = {R}
spp = 4
[[material]]
name = "chalk"
albedo = 0.6
[[object]]
name = "ground"
type = "mesh"
file = "grid.obj"
[[object]]
name = "ball"
type = "mesh"
file = "ball.obj"
scale = 0.5
translate = [0.0, 0.0, 0.55]
material = "chalk"
""")
    icosphere_obj(os.path.join(d, "ball.obj"), 2)
    raw, visd = os.path.join(d, "raw.ltm"), os.path.join(d, "vis.ltm")
    run("sample", diffuse, "-o", raw)
    run("sample", diffuse, "--visibility", "-o", visd)
    g = np.random.default_rng(5)
    dirs = texel_centres(R)
    env = (0.3 + np.maximum(dirs @ np.array([0.3, -0.5, 0.8]), 0)[:, None] ** 4 * np.array([4.0, 3.0, 2.0]) +
           0.2 * g.random((6 * R * R, 3))).astype(np.float32)
    env_npy = os.path.join(d, "env.npy")
    np.save(env_npy, env)
    ref_npy = os.path.join(d, "ref.npy")
    run("relight", raw, "--env", env_npy, "--terms", "all", "-o", ref_npy)
    ref = np.load(ref_npy)
    eye = "0,-4,2.5"
    outs = {}
    lam = os.path.join(d, "lambert.ltm")
    run("material", "--brdf", "lambert", "--cube-res", R, "--samples-res", 16, "--energy", 1, "-o", lam)
    for method in ("pixel", "linear", "sublinear", "shared"):
        vo = os.path.join(d, f"{method}.npy")
        args = ["--material", lam] if method != "pixel" else []
        run("relight", visd, *args, "--env", env_npy, "--eye", eye, "--target", "0,0,0.3", "--method", method,
            "--terms", "all", "-o", os.path.join(d, f"{method}.png"), "--vertex-output", vo)
        outs[method] = np.load(vo)
    # The matrix integrates cos over each texel with the visibility of each ray; the triple
    # path takes V's texel average times the cosine at the texel centre: they differ at
    # second order in the texel size (docs/TRIPLE.md): measured 1.1e-3 here.
    e_pixel = rel(outs["pixel"], ref)
    check(e_pixel < 3e-3, f"triple (pixel) equals relight of the vertex transport matrix: rel. L2 {e_pixel}")
    # Through the Lambert field: its normals are sampled at 6·16², interpolated bilinearly
    # (measured 3.1e-3; 9.1e-4 at 6·32²).
    e_lin = rel(outs["linear"], ref)
    check(e_lin < 5e-3, f"triple (linear, Lambert field) equals relight of T: rel. L2 {e_lin}")
    e_sub = rel(outs["sublinear"], outs["linear"])
    check(e_sub < 1e-6, f"sublinear with every term equals linear: {e_sub}")
    e_sh = rel(outs["shared"], outs["linear"])
    check(e_sh < 1e-6, f"shared with every term equals linear: {e_sh}")
    print(f"diffuse scene, R = {R}: rel. L2 against relight of T: pixel {e_pixel:.2e}, linear {e_lin:.2e}")

    # Materials may change after the visibility bake (the field checks the geometry only);
    # the geometry may not.
    darker = write(os.path.join(d, "darker.toml"), open(diffuse).read().replace("albedo = 0.6", "albedo = 0.3"))
    vo = os.path.join(d, "darker.npy")
    run("relight", visd, "--scene", darker, "--env", env_npy, "--eye", eye, "--method", "pixel", "--terms", "all",
        "-o", os.path.join(d, "x.png"), "--vertex-output", vo)
    dk = np.load(vo)
    check(np.allclose(dk, outs["pixel"] / 2, rtol=1e-6, atol=1e-9),
          "a material changed after the bake (albedo 0.6 -> 0.3, every object's) halves every vertex")
    moved = write(os.path.join(d, "moved.toml"), open(diffuse).read().replace("[0.0, 0.0, 0.55]", "[0.1, 0.0, 0.55]"))
    p = run("relight", visd, "--scene", moved, "--env", env_npy, "--eye", eye, "--method", "pixel",
            "-o", os.path.join(d, "x.png"), expect=1)
    check("geometry" in p.stderr and "bake the visibility field again" in p.stderr,
          f"a moved object is refused: {p.stderr}")

    # --- sublinear error falls with terms; shared equals linear at any terms ----------------
    errs = []
    for n in (4, 16, 64, 256):
        vo = os.path.join(d, f"sub{n}.npy")
        run("relight", visd, "--material", lam, "--env", env_npy, "--eye", eye, "--method", "sublinear", "--terms", n,
            "-o", os.path.join(d, "s.png"), "--vertex-output", vo)
        errs.append(rel(np.load(vo), outs["linear"]))
    few = {}
    for method in ("linear", "shared"):
        vo = os.path.join(d, f"few_{method}.npy")
        run("relight", visd, "--material", lam, "--env", env_npy, "--eye", eye, "--method", method, "--terms", 16,
            "--brdf-terms", 8, "-o", os.path.join(d, "s.png"), "--vertex-output", vo)
        few[method] = np.load(vo)
    e_few = rel(few["shared"], few["linear"])
    check(e_few < 1e-6 and rel(few["linear"], outs["linear"]) > 1e-3,
          f"shared equals linear at 16 lighting and 8 BRDF terms: {e_few}")
    print("sublinear rel. L2 against every term, 4/16/64/256 lighting terms:", ", ".join(f"{e:.2e}" for e in errs))
    check(all(a > b for a, b in zip(errs, errs[1:])), f"sublinear error falls with terms: {errs}")

    # --- a Phong sphere under one bright texel ----------------------------------------------
    sphere_v = icosphere_obj(os.path.join(d, "sphere.obj"), 4)
    phong = write(os.path.join(d, "phong.toml"), f"""
[output]
mode = "vertex"
objects = ["sphere"]
[sampling]
cube_res = {R}
spp = 4
[[material]]
name = "gloss"
albedo = 0.0
ks = 1.0
exponent = 64.0
[[object]]
name = "sphere"
type = "mesh"
file = "sphere.obj"
""")
    visp = os.path.join(d, "visp.ltm")
    run("sample", phong, "--visibility", "-o", visp)
    ph = os.path.join(d, "phong64.ltm")
    run("material", "--brdf", "phong:64", "--cube-res", R, "-o", ph)
    light = np.zeros((6 * R * R, 3), np.float32)
    lt = 4 * R * R + 5 * R + 11  # a texel of the +Z face, off its centre
    light[lt] = 100.0
    np.save(os.path.join(d, "light.npy"), light)
    eye_p = np.array([3.0, -5.0, 1.0])
    vo = os.path.join(d, "phong.npy")
    run("relight", visp, "--material", ph, "--env", os.path.join(d, "light.npy"), "--eye",
        ",".join(map(str, eye_p)), "--terms", "all", "-o", os.path.join(d, "phong.png"), "--vertex-output", vo)
    B = np.load(vo)[:, 0]
    pos = sphere_v  # the rows, in file order; on the unit sphere the normal is the position
    wo = eye_p - pos
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    facing = (pos * wo).sum(1) > 0
    best = np.argmax(np.where(facing, B, -1))
    refl = 2 * (pos[best] @ wo[best]) * pos[best] - wo[best]
    ang = np.degrees(np.arccos(np.clip(refl @ dirs[lt], -1, 1)))
    print(f"Phong 64 highlight: brightest vertex reflects the view {ang:.2f} degrees from the light")
    check(ang < 6.0, f"the highlight is at the mirror direction: {ang} degrees off")

    # --- the two-direction lobes: material rows against NumPy, a glossy render -------------
    Rm, Sr, Sn = 8, 2, 2
    centres8 = texel_centres(Rm)
    sa8 = texel_solid_angles(Rm)
    for spec, kind, params in (("blinn:20", "blinn", (20.0,)), ("ward:0.3", "ward", (0.3,)),
                               ("cook-torrance:0.35,0.2", "cook-torrance", (0.35, 0.2))):
        mf = os.path.join(d, f"{kind}.ltm")
        run("material", "--brdf", spec, "--cube-res", Rm, "--samples-res", Sr, "--normals-res", Sn, "--energy", 1,
            "-o", mf)
        rows = decode_rows(load_matrix(d, mf), Rm)
        check(rows.shape == (6 * Sn * Sn * 6 * Sr * Sr, 6 * Rm * Rm), f"{spec}: rows = every (n, ω_r) pair")
        rn, rr = texel_centres(Sn), texel_centres(Sr)
        worst = 0.0
        for row in range(rows.shape[0]):
            want = glossy(kind, params, rn[row // (6 * Sr * Sr)], rr[row % (6 * Sr * Sr)], centres8) * sa8 * Rm * Rm
            scale = max(np.abs(want).max(), 1e-30)
            worst = max(worst, np.abs(rows[row] - want).max() / scale)
        check(worst < 1e-5, f"{spec}: the material rows equal the lobe (NumPy) to float precision: {worst}")
    # A Blinn sphere: the field (quadrilinear between 16 sampled (n, ω_r)) against the exact
    # lobe (pixel method), under the smooth random map.
    bl = write(os.path.join(d, "blinn.toml"), open(phong).read().replace(
        'exponent = 64.0', 'exponent = 20.0\nbrdf = "blinn"').replace('albedo = 0.0', 'albedo = 0.2').replace(
        'ks = 1.0', 'ks = 0.7'))
    visb = os.path.join(d, "visb.ltm")
    run("sample", bl, "--visibility", "-o", visb)
    ref_b = os.path.join(d, "blinn_pixel.npy")
    run("relight", visb, "--env", env_npy, "--eye", "3,-5,1", "--method", "pixel", "--terms", "all",
        "-o", os.path.join(d, "b.png"), "--vertex-output", ref_b)
    e_blinn = {}
    for nres in (2, 4):
        bf = os.path.join(d, f"blinn20_{nres}.ltm")
        run("material", "--brdf", "blinn:20", "--cube-res", R, "--normals-res", nres, "--samples-res", 8, "-o", bf)
        vo = os.path.join(d, f"blinn_{nres}.npy")
        run("relight", visb, "--material", bf, "--material", lam, "--env", env_npy, "--eye", "3,-5,1", "--terms", "all",
            "-o", os.path.join(d, "b.png"), "--vertex-output", vo)
        e_blinn[nres] = rel(np.load(vo), np.load(ref_b))
    print(f"Blinn 20 sphere through its field (S = 8) against the exact lobe: rel. L2 {e_blinn[2]:.2e} with N = 2, "
          f"{e_blinn[4]:.2e} with N = 4")
    # The interpolation between sampled normals dominates: finer normals, smaller error
    # (measured with ks = 1: 6.0% at N = 4, 2.8% at N = 8, 1.9% at N = 8 and S = 16).
    check(e_blinn[4] < 0.7 * e_blinn[2] and e_blinn[4] < 0.06,
          f"a Blinn material through its field converges to the exact lobe: {e_blinn}")
    p = run("relight", visb, "--material", ph, "--material", lam, "--env", env_npy, "--eye", "3,-5,1",
            "-o", os.path.join(d, "b.png"), expect=1)
    check("blinn:20" in p.stderr and "ltbake material --brdf blinn:20" in p.stderr,
          f"a Blinn material without its field names the command: {p.stderr}")

    # --- orbit, image outputs, errors -------------------------------------------------------
    frames = os.path.join(d, "orbit_%02d.npy")
    run("relight", visd, "--material", lam, "--env", env_npy, "--eye", eye, "--orbit", "90:4", "--size", "32x24",
        "-o", frames)
    imgs = [np.load(frames % k) for k in range(4)]
    check(all(i.shape == (32 * 24, 3) for i in imgs), f"orbit frames are height·width × 3: {[i.shape for i in imgs]}")
    check(rel(imgs[0], imgs[1]) > 1e-3, "the orbit moves the eye")
    # Light and view changing together: frame k of --light-turn D is the map at --rotate k·D,
    # pixel for pixel (a map that varies around +Z, RGBE written here).
    with open(os.path.join(d, "ramp.hdr"), "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32 +X 64\n" +
                b"".join(bytes([4 * x, 96 + y, 255 - 4 * x, 129]) for y in range(32) for x in range(64)))
    ramp = os.path.join(d, "ramp.hdr")
    turn = os.path.join(d, "turn_%02d.npy")
    run("relight", visd, "--material", lam, "--env", ramp, "--eye", eye, "--orbit", "0:3", "--light-turn", 40,
        "--size", "24x16", "-o", turn)
    run("relight", visd, "--material", lam, "--env", ramp, "--eye", eye, "--rotate", 80, "--size", "24x16",
        "-o", os.path.join(d, "r80.npy"))
    lt = [np.load(turn % k) for k in range(3)]
    check(rel(lt[0], lt[1]) > 1e-3 and np.array_equal(lt[2], np.load(os.path.join(d, "r80.npy"))),
          "--light-turn 40: frame 2 is the map turned 80 degrees, pixel for pixel")
    both = os.path.join(d, "both_%02d.npy")
    fixed = os.path.join(d, "fixed_%02d.npy")
    run("relight", visd, "--material", lam, "--env", ramp, "--eye", eye, "--orbit", "30:2", "--light-turn", 40,
        "--size", "24x16", "-o", both)
    run("relight", visd, "--material", lam, "--env", ramp, "--eye", eye, "--orbit", "30:2", "--rotate", 40,
        "--size", "24x16", "-o", fixed)
    check(np.array_equal(np.load(both % 1), np.load(fixed % 1)),
          "--orbit 30:2 --light-turn 40: frame 1 is the orbit's frame 1 under the map turned 40 degrees")
    for args, want in ((["--env", ramp, "--light-turn", 10], "--orbit"),
                       (["--env", env_npy, "--orbit", "0:2", "--light-turn", 10], ".npy")):
        p = run("relight", visd, "--material", lam, "--eye", eye, *args, "-o", turn, expect=1)
        check(want in p.stderr, f"--light-turn refused ({want}): {p.stderr}")
    p = run("relight", raw, "--env", ramp, "--light-turn", 10, "-o", os.path.join(d, "x.png"), expect=2)
    check("triple-product path" in p.stderr, f"--light-turn on a matrix: {p.stderr}")
    # A map near float32's largest value (an RGBE map at exponent 255: 255·2^119) renders at
    # 2^-k and is scaled back: exactly 2^126 times the image of the same map at exponent 129,
    # bit for bit (every step is linear in the light; docs/RELIGHT.md "Numbers").
    for e in (129, 255):
        with open(os.path.join(d, f"e{e}.hdr"), "wb") as f:
            f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 32 +X 64\n" + bytes([255, 255, 255, e]) * (64 * 32))
        run("relight", visd, "--material", lam, "--env", os.path.join(d, f"e{e}.hdr"), "--eye", eye, "--size", "16x12",
            "-o", os.path.join(d, f"bright{e}.npy"))
    small, big = np.load(os.path.join(d, "bright129.npy")), np.load(os.path.join(d, "bright255.npy"))
    check(np.all(np.isfinite(big)) and big.max() > 1e37 and np.array_equal(big, np.ldexp(small, 126)),
          f"triple view under an exponent-255 map: {np.isnan(big).sum()} NaN, max {big.max()}")
    p = run("relight", visd, "--env", env_npy, "--eye", eye, "--method", "linear", "-o", os.path.join(d, "y.png"),
            expect=1)
    check("albedo" in p.stderr and "ltbake material --brdf lambert" in p.stderr,
          f"a material without its field says which to make: {p.stderr}")
    p = run("relight", visd, "--material", ph, "--env", env_npy, "--eye", eye, "-o", os.path.join(d, "y.png"),
            expect=1)
    check("Lambert" in p.stderr, f"a diffuse scene with only a Phong field: {p.stderr}")
    lam8 = os.path.join(d, "lam8.ltm")
    run("material", "--brdf", "lambert", "--cube-res", 8, "-o", lam8)
    p = run("relight", visd, "--material", lam8, "--env", env_npy, "--eye", eye, "-o", os.path.join(d, "y.png"),
            expect=1)
    check("cube resolution 8" in p.stderr and "--cube-res 16" in p.stderr, f"a field at another R: {p.stderr}")
    p = run("relight", raw, "--material", lam, "--env", env_npy, "--eye", eye, "-o", os.path.join(d, "y.png"),
            expect=1)
    check("not a visibility field" in p.stderr, f"a transport matrix on the triple path: {p.stderr}")
    p = run("relight", visd, "--material", lam, "--env", env_npy, "--eye", eye, "--orbit", "5:3",
            "-o", os.path.join(d, "y.png"), expect=1)
    check("%d" in p.stderr, f"an orbit needs a frame pattern: {p.stderr}")
    # --- a recipe: [triple] makes the fields and one view per map, like the commands ---------
    rec = write(os.path.join(d, "triple.toml"), f"""
scene = "diffuse.toml"
[triple]
cube_res = {R}
materials = ["lambert"]
envs = ["env.npy"]
eye = [0.0, -4.0, 2.5]
target = [0.0, 0.0, 0.3]
size = [40, 30]
terms = 64
format = "npy"
""")
    wd = os.path.join(d, "work")
    run("run", rec, "--workdir", wd, "--progress", "never")
    run("material", "--brdf", "lambert", "--cube-res", R, "-o", os.path.join(d, "lam_default.ltm"))
    run("relight", visd, "--material", os.path.join(d, "lam_default.ltm"), "--env", env_npy, "--eye", "0,-4,2.5",
        "--target", "0,0,0.3", "--size", "40x30", "--terms", 64, "-o", os.path.join(d, "by_hand.npy"))
    view = os.path.join(wd, "view-env.npy")
    check(os.path.exists(view) and np.array_equal(np.load(view), np.load(os.path.join(d, "by_hand.npy"))),
          "the recipe's view equals the same relight run by hand")
    check(os.path.exists(os.path.join(wd, "vis.ltm")) and os.path.exists(os.path.join(wd, "material-lambert.ltm")),
          "the recipe keeps the fields")
    run("run", rec, "--workdir", wd, "--progress", "never")
    rep = json.load(open(os.path.join(wd, "run.json")))
    check(all(st["action"] == "skip" for st in rep["stages"]),
          f"a rerun skips every step: {[(st['node'], st['action']) for st in rep['stages']]}")

    p = run("sample", os.path.join(os.path.dirname(__file__), "..", "..", "samples", "tiny.toml"), "--visibility",
            "-o", os.path.join(d, "t.ltm"), expect=1)
    check("vertex" in p.stderr, f"--visibility on an image-mode scene: {p.stderr}")

finish()
