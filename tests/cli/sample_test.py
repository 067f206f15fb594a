"""sample through the ltbake binary, against closed forms.

Each row of T is a sum of n = 6·R²·spp independent stratum estimates (each stratum of
face-coordinate area h²/spp, h = 2/R, evaluated once at a jittered point), each in
[0, b] with b = (h²/spp)·max(w·f·cos) <= (h²/spp)·(albedo/π) (w = dω/du dv <= 1). The
estimator is unbiased, so by Hoeffding's inequality a row deviates from its exact value
by more than t = b·sqrt(n·ln(2/δ)/2) with probability below δ, and the mean of N rows
(independent seeds) by more than t/sqrt(N). We use δ = 1e-9.

1. An unoccluded Lambertian plane under uniform radiance 1: every row sums to the albedo.
2. A plane under a sphere of radius r: a point whose sphere subtends half-angle α at
   zenith angle θ (sphere fully above the horizon) sees the fraction 1 − sin²α·cos θ of
   the cosine-weighted hemisphere, so its row sums to albedo·(1 − sin²α·cos θ).
3. --jobs 1 and --jobs 2 give the same content_hash; so does a run killed at random
   moments and resumed.
4. Bad input: each a clear message naming the file/line/value, exit 1 or 2, and no output
   that claims to be complete.
5. normals = "file" (docs/SCENE.md "Normals"): vertex mode, an isolated triangle whose
   vertices carry file normals tilted 30° from its geometric +z: each row follows its
   file normal. The oracle is the row's first moment M = Σ_j T_j ω_j (texel centres ω_j),
   whose expectation Σ_j ω_j (albedo/π)∫_texel max(0, n·ω) dω is integrated finely in
   NumPy (scripts/cubemap.py's face parametrisation). A stratum's estimate is
   (h²/spp)(albedo/π)·g at a jittered point, g = w·max(0, n·ω) with |∇g| <= 3 in face
   coordinates, so it varies by at most c = (h²/spp)(albedo/π)·3·√2·h/√spp over its
   stratum; Hoeffding over the n = 6R²·spp strata bounds each component of M by
   c·sqrt(n·ln(2/δ)/2). Image mode: a plane mesh with tilted file normals gives another T
   than "flat", and "smooth" on a plane gives exactly the T of "flat".
6. Bounces follow the shading normal of the surface they hit: the light a floor receives
   by one bounce off a wall with file normals against a closed-form escape probability.

usage: sample_test.py PATH_TO_LTBAKE
"""
import json
import math
import os
import re
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts"))
import cubemap  # noqa: E402
from ltbtest import LTBAKE, check, failures, finish, kill_storm, run, side_table  # noqa: E402

DELTA = 1e-9




def hoeffding(R, spp, albedo):
    h = 2.0 / R
    n = 6 * R * R * spp
    b = h * h / spp * albedo / math.pi
    return b * math.sqrt(n * math.log(2 / DELTA) / 2)


def load(d, ltm):
    out = os.path.join(d, "m.npy")
    run("convert", ltm, out)
    T = np.load(out).astype(np.float64)
    return T


def scene(d, name, body):
    path = os.path.join(d, name)
    with open(path, "w") as f:
        f.write(body)
    return path


with tempfile.TemporaryDirectory() as d:
    R, spp, albedo = 16, 16, 0.8
    t_row = hoeffding(R, spp, albedo)

    # 1. Unoccluded plane.
    def plane_scene(name, eye, up, fov, size, extra=""):
        """A white plane of the test's albedo, a camera, [sampling] R and spp, plus `extra`."""
        return scene(d, name, f"""
[camera]
eye = {eye}
target = [0.0, 0.0, 0.0]
up = {up}
fov = {fov}
width = {size}
height = {size}
[sampling]
cube_res = {R}
spp = {spp}
[[material]]
name = "m"
albedo = {albedo}
[[object]]
type = "plane"
size = [100.0, 100.0]
material = "m"
""" + extra)

    s1 = plane_scene("plane.toml", "[0.0, 0.0, 5.0]", "[0.0, 1.0, 0.0]", 30.0, 8)
    out1 = os.path.join(d, "plane.ltm")
    run("sample", s1, "-o", out1)
    T = load(d, out1)
    sums = T.sum(axis=1)
    err = np.abs(sums - albedo)
    print(f"plane: row sums {sums.min():.5f}..{sums.max():.5f} (albedo {albedo}); max error {err.max():.2e}, "
          f"Hoeffding bound per row {t_row:.2e}, mean error {abs(sums.mean() - albedo):.2e} "
          f"(bound {t_row / math.sqrt(len(sums)):.2e})")
    check(len(sums) == 64, f"plane: {len(sums)} rows")
    check(err.max() <= t_row, f"plane: a row sum is off by {err.max():.3g} > {t_row:.3g}")
    check(abs(sums.mean() - albedo) <= t_row / math.sqrt(len(sums)),
          f"plane: mean row sum {sums.mean():.6f} off by more than {t_row / math.sqrt(len(sums)):.3g}")
    check(T.min() >= 0, "plane: negative transport")
    # Texels below the horizon (z < 0 half of the sphere of directions) carry nothing.
    mask = side_table(out1, "mask")
    check(mask.sum() == 64, "plane: every pixel should see the plane")

    # 2. Plane under a sphere.
    c, r = np.array([0.0, 0.0, 1.0]), 0.5
    s2 = plane_scene("sphere.toml", "[3.0, 0.0, 6.0]", "[0.0, 0.0, 1.0]", 40.0, 12, f"""[[object]]
type = "sphere"
center = [0.0, 0.0, 1.0]
radius = {r}
material = "m"
""")
    out2 = os.path.join(d, "sphere.ltm")
    run("sample", s2, "-o", out2)
    T2 = load(d, out2)
    pos = side_table(out2, "position").astype(np.float64)
    on_plane = np.abs(pos[:, 2]) < 1e-4
    check(on_plane.sum() > 50 and (~on_plane).sum() > 5, f"sphere: {on_plane.sum()} plane rows, {(~on_plane).sum()} sphere rows")
    v = c[None, :] - pos[on_plane]
    dist = np.linalg.norm(v, axis=1)
    alpha = np.arcsin(r / dist)
    cos_t = v[:, 2] / dist
    want = albedo * (1 - np.sin(alpha) ** 2 * cos_t)
    got = T2[on_plane].sum(axis=1)
    err2 = np.abs(got - want)
    print(f"sphere: {on_plane.sum()} plane rows, visible fractions {want.min() / albedo:.3f}..{want.max() / albedo:.3f}; "
          f"max error {err2.max():.2e} (bound {t_row:.2e}), mean signed error {np.mean(got - want):.2e} "
          f"(bound {t_row / math.sqrt(len(got)):.2e})")
    check(err2.max() <= t_row, f"sphere: a row is off by {err2.max():.3g} > {t_row:.3g}")
    check(abs(np.mean(got - want)) <= t_row / math.sqrt(len(got)), "sphere: mean error beyond the bound")
    # The occluded part really is occluded: shadowed rows sum well below the albedo.
    check(want.min() < 0.9 * albedo and got.min() < 0.9 * albedo, "sphere: no row is noticeably shadowed")

    # 3. Determinism across jobs and interruption.
    h = {}
    for jobs in (1, 2):
        o = os.path.join(d, f"j{jobs}.ltm")
        run("sample", s2, "-o", o, "--jobs", jobs, "--chunk-rows", 7)
        h[jobs] = json.loads(run("inspect", o, "--json").stdout)["content_hash"]
    check(h[1] == h[2], f"content_hash differs between --jobs 1 and 2: {h}")
    big = scene(d, "big.toml", open(s2).read().replace("width = 12", "width = 48").replace("height = 12", "height = 48"))
    ref = os.path.join(d, "big-ref.ltm")
    t0 = time.monotonic()
    ref_text = run("sample", big, "-o", ref, "--chunk-rows", 16).stdout
    full = time.monotonic() - t0
    ref_info = json.loads(run("inspect", ref, "--json").stdout)
    ref_hash = ref_info["content_hash"]
    # Every sample output records its rays per row (sample_rays); inspect sums them, and an
    # uninterrupted bake's sum is what it said it traced.
    traced = int(re.search(r"rays traced: (\d+)", ref_text).group(1))
    check(ref_info.get("rays") == traced, f"inspect's rays {ref_info.get('rays')} against {traced} traced")
    per_row = side_table(ref, "sample_rays").reshape(-1)
    mask = side_table(ref, "mask").reshape(-1)
    check(per_row.sum() == traced and per_row[mask == 0].sum() == 0 and per_row[mask == 1].min() > 0,
          "sample_rays: not one entry per row that sees geometry")
    out = os.path.join(d, "big-k.ltm")
    kill_storm(["sample", big, "-o", out, "--chunk-rows", 16], out, kills=6, max_delay=full, seed=3)
    run("sample", big, "-o", out, "--chunk-rows", 16, "--jobs", 1)
    resumed = json.loads(run("inspect", out, "--json").stdout)
    check(resumed["content_hash"] == ref_hash, "sample resumed after kills differs from the uninterrupted run")
    check(resumed.get("rays") == traced, f"a resumed bake's rays {resumed.get('rays')} against {traced}")

    # 4. Bad input.
    base = open(s1).read()

    def bad(name, body, needle, expect=1, extra=()):
        path = scene(d, name, body)
        o = os.path.join(d, name + ".ltm")
        p = run("sample", path, "-o", o, *extra, expect=None)
        check(p.returncode in (1, 2) and (expect is None or p.returncode == expect),
              f"{name}: exit {p.returncode}")
        check(needle in p.stderr, f"{name}: stderr lacks {needle!r}: {p.stderr}")
        if os.path.exists(o):
            check(not json.loads(run("inspect", o, "--json", "--no-content").stdout)["complete"],
                  f"{name}: left a complete-looking output")

    bad("unknown.toml", base.replace("fov = 30.0", "fov = 30.0\nfocus = 2.0\nzoom = 1"),
        "unknown key(s) in [camera]: \"focus\" (line 7), \"zoom\" (line 8)")
    bad("missing.toml", base + '[[object]]\ntype = "mesh"\nfile = "nope.obj"\n', "nope.obj: mesh file not found")
    with open(os.path.join(d, "empty.obj"), "w") as f:
        f.write("# nothing\nv 0 0 0\nv 1 0 0\n")
    bad("empty.toml", base + '[[object]]\ntype = "mesh"\nfile = "empty.obj"\n', "empty.obj: the mesh holds no triangles")
    # An OBJ's text "nan" is an error naming the line (OpenMesh, which read OBJ before, took it for a number).
    with open(os.path.join(d, "nan.obj"), "w") as f:
        f.write("v 0 0 0\nv 1 0 nan\nv 0 1 0\nf 1 2 3\n")
    bad("nanobj.toml", base + '[[object]]\ntype = "mesh"\nfile = "nan.obj"\n', 'nan.obj:2: vertex coordinate 3 is "nan"')
    # A binary PLY carries a NaN float through the reader.
    import struct
    with open(os.path.join(d, "nan.ply"), "wb") as f:
        f.write(b"ply\nformat binary_little_endian 1.0\nelement vertex 3\nproperty float x\nproperty float y\n"
                b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n")
        f.write(struct.pack("<9f", 0, 0, 0, 1, 0, 0, float("nan"), 1, 0))
        f.write(struct.pack("<B3i", 3, 0, 1, 2))
    bad("nan.toml", base + '[[object]]\ntype = "mesh"\nfile = "nan.ply"\n', "nan.ply (byte 205): vertex 2 x is nan, not a finite number")
    bad("r6.toml", base, "--cube-res: \"6\" is not a power of two in 1..1024", expect=2, extra=("--cube-res", "6"))
    bad("albedo.toml", base.replace(f"albedo = {albedo}", "albedo = 1.5"), "\"albedo\" is 1.5, outside [0, 1]")
    bad("mat.toml", base.replace('material = "m"', 'material = "steel"'), "uses material \"steel\", which no [[material]] defines")

    # 5. normals = "file".
    def ply_with_normals(path, pos, nrm, faces):
        with open(path, "w") as f:
            f.write(f"ply\nformat ascii 1.0\nelement vertex {len(pos)}\nproperty double x\nproperty double y\n"
                    "property double z\nproperty double nx\nproperty double ny\nproperty double nz\n"
                    f"element face {len(faces)}\nproperty list uchar int vertex_indices\nend_header\n")
            for p, n in zip(pos, nrm):
                f.write(" ".join(repr(float(x)) for x in (*p, *n)) + "\n")
            for t in faces:
                f.write(f"3 {t[0]} {t[1]} {t[2]}\n")

    def moment_oracle(n, R, albedo, sub=32):
        """Σ_j ω_j (albedo/π)∫_texel max(0, n·ω) dω, midpoint rule on sub² points per texel."""
        m = np.zeros(3)
        k = (np.arange(R * sub) + 0.5) * 2.0 / (R * sub) - 1.0
        u, v = np.meshgrid(k, k)
        w = (1.0 + u * u + v * v) ** -1.5 * (2.0 / (R * sub)) ** 2
        centres = cubemap.texel_directions(R).reshape(6, R, R, 3)
        for face in range(6):
            x, y, z = cubemap.face_direction(face, u, v)
            dn = np.stack([x, y, z], axis=-1)
            dn /= np.linalg.norm(dn, axis=-1, keepdims=True)
            g = albedo / math.pi * np.maximum(0.0, dn @ n) * w
            per_texel = g.reshape(R, sub, R, sub).sum(axis=(1, 3))  # [t, s]
            m += (per_texel[..., None] * centres[face]).sum(axis=(0, 1))
        return m

    Rn, sppn = 16, 16
    h = 2.0 / Rn
    c_stratum = h * h / sppn * albedo / math.pi * 3.0 * math.sqrt(2.0) * h / math.sqrt(sppn)
    t_m = c_stratum * math.sqrt(6 * Rn * Rn * sppn * math.log(2 / DELTA) / 2)
    tri = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, math.sqrt(3) / 2, 0.0]])
    centroid = tri.mean(axis=0)
    tilt = math.radians(30)
    # Each vertex's normal leans away from the triangle: no ray above its horizon can hit
    # the triangle itself, so the row sees the whole hemisphere around the file normal.
    file_n = []
    for p in tri:
        dh = (centroid - p) / np.linalg.norm(centroid - p)
        file_n.append(-math.sin(tilt) * dh + math.cos(tilt) * np.array([0.0, 0.0, 1.0]))
    ply_with_normals(os.path.join(d, "tri.ply"), tri, file_n, [(0, 1, 2)])
    vscene = f"""[output]
mode = "vertex"
objects = ["tri"]
[sampling]
cube_res = {Rn}
spp = {sppn}
[[material]]
name = "m"
albedo = {albedo}
[[object]]
type = "mesh"
name = "tri"
file = "tri.ply"
material = "m"
"""
    dirs = cubemap.texel_directions(Rn)
    geo = np.array([0.0, 0.0, 1.0])
    for mode in ("file", "smooth"):
        sv = scene(d, f"tri-{mode}.toml", vscene + f'normals = "{mode}"\n')
        ov = os.path.join(d, f"tri-{mode}.ltm")
        run("sample", sv, "-o", ov)
        Tv = load(d, ov)
        check(Tv.shape == (3, 6 * Rn * Rn), f"normals {mode}: T is {Tv.shape}")
        for i in range(3):
            want_n = file_n[i] if mode == "file" else geo
            other_n = geo if mode == "file" else file_n[i]
            got = Tv[i] @ dirs
            want = moment_oracle(want_n, Rn, albedo)
            other = moment_oracle(other_n, Rn, albedo)
            err = np.abs(got - want).max()
            print(f"normals {mode}: row {i} moment {np.round(got, 4)}, oracle {np.round(want, 4)} "
                  f"(error {err:.2e}, bound {t_m:.2e}); the other normal's oracle is "
                  f"{np.abs(other - want).max():.3f} away")
            check(err <= t_m, f"normals {mode}: row {i} moment off by {err:.3g} > {t_m:.3g}")
            check(np.abs(other - want).max() > 2 * t_m, f"normals {mode}: the oracle cannot tell the normals apart")
            check(abs(Tv[i].sum() - albedo) <= t_row, f"normals {mode}: row {i} sums to {Tv[i].sum():.4f}")

    # Image mode: a plane mesh (z = 0) whose file normals lean 30° towards +x.
    quad = [[-50.0, -50.0, 0.0], [50.0, -50.0, 0.0], [50.0, 50.0, 0.0], [-50.0, 50.0, 0.0]]
    lean = [math.sin(tilt), 0.0, math.cos(tilt)]
    ply_with_normals(os.path.join(d, "quad.ply"), quad, [lean] * 4, [(0, 1, 2), (0, 2, 3)])
    img = {}
    for mode in ("auto", "flat", "smooth", "file"):
        si = scene(d, f"quad-{mode}.toml", base.replace('type = "plane"\nsize = [100.0, 100.0]',
                                                         f'type = "mesh"\nfile = "quad.ply"\nnormals = "{mode}"'))
        oi = os.path.join(d, f"quad-{mode}.ltm")
        run("sample", si, "-o", oi)
        img[mode] = load(d, oi)
    check(np.array_equal(img["auto"], img["flat"]), "image mode: normals auto and flat differ on a plane")
    check(np.array_equal(img["smooth"], img["flat"]), "image mode: normals smooth and flat differ on a plane")
    rel = np.linalg.norm(img["file"] - img["flat"]) / np.linalg.norm(img["flat"])
    mx_file = (img["file"] @ cubemap.texel_directions(R))[:, 0].mean()
    mx_flat = (img["flat"] @ cubemap.texel_directions(R))[:, 0].mean()
    print(f"image mode: file vs flat relative L2 {rel:.3f}; mean moment x {mx_file:.4f} (file), {mx_flat:.4f} (flat)")
    check(rel > 0.1, f"image mode: file normals barely change T (relative L2 {rel:.3g})")
    # Leaning towards +x, the rows see more of the +x sky; flat rows are symmetric.
    check(mx_file > 0.05 and abs(mx_flat) < 0.02, f"image mode: moments {mx_file:.4f} (file), {mx_flat:.4f} (flat)")

    # Bad normals values and files without normals.
    bad("normals.toml", base + '[[object]]\ntype = "mesh"\nfile = "quad.ply"\nnormals = "phong"\n',
        'normals is "phong" (expected "auto", "file", "smooth" or "flat")')
    bad("nonormals.toml", base + '[[object]]\ntype = "mesh"\nfile = "nan.obj"\nnormals = "file"\n',
        "nan.obj:2: vertex coordinate 3 is \"nan\"")
    with open(os.path.join(d, "plain.obj"), "w") as f:
        f.write("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    bad("plainobj.toml", base + '[[object]]\ntype = "mesh"\nfile = "plain.obj"\nnormals = "file"\n',
        'plain.obj: normals = "file", but the file stores no vertex normals')

    # 6. Bounces follow the shading normal. A floor (albedo af) seen from above and a wall
    # (a mesh, albedo aw) at x = 1, both far larger than the view: half of each floor row's
    # cosine-weighted paths hit the wall, and with one bounce a path escapes when its new
    # direction d, cosine-weighted about the wall's shading normal n, has d_z > 0 (else it
    # meets the floor) and d_x < 0 (else it meets the wall). The indirect part of a row
    # (bounces 1 minus bounces 0: the direct part is the same estimate) sums to
    # af·aw·(1/2)·P(n), P integrated in NumPy: 1/2 for the geometric normal -x, 0.683 for a
    # file normal leaning 30° up. A row is the mean over its paths of af·aw (escaped) or 0,
    # so by Hoeffding the mean over N paths of all rows is within af·aw·sqrt(ln(2/δ)/(2N)); the floor's and
    # wall's finite sizes bias it by less than 1e-3·af·aw (paths passing over the wall or
    # escaping past the floor's edge), added to the bound.
    af, aw, Rb, sppb = 0.9, 0.8, 8, 16

    def escape_oracle(n, steps=3000):
        n = np.asarray(n, float)
        t = np.cross(n, [0.0, 1.0, 0.0])
        t /= np.linalg.norm(t)
        b = np.cross(n, t)
        u = (np.arange(steps) + 0.5) / steps
        phi = 2 * math.pi * (np.arange(steps) + 0.5) / steps
        st, ct = np.sqrt(u)[:, None, None], np.sqrt(1 - u)[:, None, None]
        dd = st * (np.cos(phi)[None, :, None] * t + np.sin(phi)[None, :, None] * b) + ct * n
        return float(np.mean((dd[..., 2] > 0) & (dd[..., 0] < 0)))

    wall = [[1.0, -2000.0, -1.0], [1.0, 2000.0, -1.0], [1.0, 2000.0, 400.0], [1.0, -2000.0, 400.0]]
    up30 = [-math.cos(tilt), 0.0, math.sin(tilt)]
    ply_with_normals(os.path.join(d, "wall.ply"), wall, [up30] * 4, [(0, 1, 2), (0, 2, 3)])
    rows_b = 64
    n_paths = rows_b * max(1, sppb * 6 * Rb * Rb // 2)
    t_b = af * aw * (math.sqrt(math.log(2 / DELTA) / (2 * n_paths)) + 1e-3)
    for mode, n_wall in (("auto", [-1.0, 0.0, 0.0]), ("file", up30)):
        want = af * aw * 0.5 * escape_oracle(n_wall)
        other = af * aw * 0.5 * escape_oracle(up30 if mode == "auto" else [-1.0, 0.0, 0.0])
        sums = []
        for bounces in (0, 1):
            sb = scene(d, f"wall-{mode}-{bounces}.toml", f"""
[camera]
eye = [0.0, 0.0, 5.0]
target = [0.0, 0.0, 0.0]
up = [0.0, 1.0, 0.0]
fov = 10.0
width = 8
height = 8
[sampling]
cube_res = {Rb}
spp = {sppb}
bounces = {bounces}
[[material]]
name = "floor"
albedo = {af}
[[material]]
name = "wall"
albedo = {aw}
[[object]]
type = "plane"
size = [4000.0, 4000.0]
material = "floor"
[[object]]
type = "mesh"
file = "wall.ply"
normals = "{mode}"
material = "wall"
""")
            ob = os.path.join(d, f"wall-{mode}-{bounces}.ltm")
            run("sample", sb, "-o", ob)
            sums.append(load(d, ob).sum(axis=1))
        indirect = sums[1] - sums[0]
        got = float(indirect.mean())
        print(f"bounces, wall normals {mode}: mean indirect row sum {got:.5f}, oracle {want:.5f} "
              f"(bound {t_b:.5f}); the other normal's oracle {other:.5f}")
        check(len(indirect) == rows_b, f"bounces: {len(indirect)} rows")
        check(abs(got - want) <= t_b, f"bounces, wall normals {mode}: indirect {got:.5f}, expected {want:.5f} +- {t_b:.5f}")
        check(abs(other - want) > 2 * t_b, "bounces: the oracle cannot tell the normals apart")

finish()
