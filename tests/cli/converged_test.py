"""Converged sampling (`sample --tolerance`, docs/SAMPLE.md "Converged sampling") against a
closed form, and its determinism and resume.

The scene: an exact sphere (radius 1) above a floor plane that reaches far past the view.
A point of the sphere sees every direction of its upper hemisphere (the sphere is convex)
except those that go down to the floor, i.e. exactly the directions with ω_z < 0 (the floor
spans all of them but grazing ones, ~1e-3 of a texel). So each sphere row's T_c is
(albedo/π) ∫ max(0, n·ω) dω over texel c ∩ {ω_z ≥ 0}: the texel's quad on the cube face,
clipped by the planes n·x ≥ 0 and z ≥ 0 (both through the origin, so the clipped polygon is
still a polygon of great-circle edges), integrated by Lambert's formula for the cosine over
a polygon: ½ Σ_edges θ_i n·û_i, θ_i the angle of edge (a, b) seen from the origin, û_i the
unit normal of the plane through it. Checked:
  - the oracle itself on an open hemisphere (its texels sum to albedo);
  - the converged bake's relative RMS error over the sphere rows is within its tolerance,
    where a fixed bake at the same base spp is not (so the tolerance did something);
  - the per-row error estimate (side table sample_error) is not optimistic: in at least 95%
    of the rows the actual error is at most twice the estimate (plus a hundredth of the
    tolerance);
  - lit texels whose samples saw no floor equal the closed form to float32 rounding (the
    exact unoccluded value, horizon-clipped where the horizon crosses the texel);
  - with a bounce, within its tolerance against a fixed spp-256 bake; an unreachable
    tolerance is reported;
  - the same command twice gives the same content_hash, and a killed bake resumes to it.
    converged_test.py LTBAKE"""
import json
import os
import re
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "..", "scripts"))
from cubemap import face_direction  # noqa: E402
from ltbtest import LTBAKE, check, finish, run, side_table  # noqa: E402

R = 4
ALBEDO = 0.8
SCENE = f"""[output]
mode = "image"
[camera]
eye = [0.0, -4.0, 0.4]
target = [0.0, 0.0, 0.0]
fov = 34.0
width = 24
height = 24
[sampling]
cube_res = {R}
spp = 4
[[material]]
name = "white"
albedo = {ALBEDO}
[[object]]
type = "sphere"
radius = 1.0
[[object]]
type = "plane"
size = [20000.0, 20000.0]
translate = [0.0, 0.0, -1.5]
"""


def clip(poly, normal):
    """Sutherland–Hodgman: the part of the polygon with normal·x >= 0."""
    out = []
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        da, db = normal @ a, normal @ b
        if da >= 0:
            out.append(a)
        if (da >= 0) != (db >= 0):
            out.append(a + (b - a) * (da / (da - db)))
    return out


def cosine_integral(poly, n):
    """∫ max(0, n·ω) dω over the directions through a polygon (already clipped to n·x >= 0)."""
    if len(poly) < 3:
        return 0.0
    total = 0.0
    for i in range(len(poly)):
        a, b = poly[i], poly[(i + 1) % len(poly)]
        c = np.cross(a, b)
        nc = np.linalg.norm(c)
        if nc == 0:
            continue
        theta = np.arctan2(nc, a @ b)
        total += theta * (n @ (c / nc))
    return abs(0.5 * total)


def exact_row(n, lower_blocked=True):
    """T of a sphere point with normal n: 6R² values."""
    row = np.zeros(6 * R * R)
    e = np.arange(R + 1) * 2.0 / R - 1.0
    for f in range(6):
        for t in range(R):
            for s in range(R):
                corners = [np.array(face_direction(f, np.array(u), np.array(v)), dtype=float)
                           for u, v in ((e[s], e[t]), (e[s + 1], e[t]), (e[s + 1], e[t + 1]), (e[s], e[t + 1]))]
                poly = clip(corners, n)
                if lower_blocked:
                    poly = clip(poly, np.array([0.0, 0.0, 1.0]))
                row[f * R * R + t * R + s] = ALBEDO / np.pi * cosine_integral(poly, n)
    return row


# The oracle: an open hemisphere integrates to the albedo, half of one (z >= 0 with n = +x) to half.
check(abs(exact_row(np.array([0.0, 0.0, 1.0]), False).sum() - ALBEDO) < 1e-12, "oracle: hemisphere does not sum to ρ")
check(abs(exact_row(np.array([1.0, 0.0, 0.0])).sum() - ALBEDO / 2) < 1e-12, "oracle: half hemisphere is not ρ/2")


def bake(d, name, *flags):
    out = os.path.join(d, name + ".ltm")
    text = run("sample", os.path.join(d, "scene.toml"), "-o", out, "--overwrite", *flags).stdout
    run("convert", out, os.path.join(d, name + ".npy"), "-q")
    return out, np.load(os.path.join(d, name + ".npy")).astype(np.float64), text


def content_hash(path):
    return json.loads(run("inspect", "--json", path).stdout)["content_hash"]


TOL = 0.03
with tempfile.TemporaryDirectory() as d:
    with open(os.path.join(d, "scene.toml"), "w") as f:
        f.write(SCENE)
    conv, T, text = bake(d, "conv", "--tolerance", f"{TOL * 100:g}%")
    check("converged: tolerance" in text, f"no converged summary:\n{text}")
    _, F, _ = bake(d, "fixed")
    pos = side_table(conv, "position").reshape(-1, 3).astype(np.float64)
    mask = side_table(conv, "mask").reshape(-1)
    on_sphere = (mask == 1) & (np.abs(np.linalg.norm(pos, axis=1) - 1) < 1e-3)
    check(on_sphere.sum() > 100, f"only {on_sphere.sum()} rows on the sphere")
    rows = np.nonzero(on_sphere)[0]
    X = np.array([exact_row(pos[r] / np.linalg.norm(pos[r])) for r in rows])
    err_conv = np.linalg.norm(T[rows] - X) / np.linalg.norm(X)
    err_fixed = np.linalg.norm(F[rows] - X) / np.linalg.norm(X)
    check(err_conv <= TOL, f"converged bake's error on the sphere {err_conv:.4f} is over its tolerance {TOL}")
    check(err_fixed > TOL, f"the fixed spp-4 bake is already within {TOL} ({err_fixed:.4f}): the scene tests nothing")
    # The side table's estimate (relative to the RMS row norm) against each row's actual error.
    est = side_table(conv, "sample_error").reshape(-1).astype(np.float64)
    rms = np.sqrt(np.mean(np.sum(T ** 2, axis=1)))
    actual = np.linalg.norm(T[rows] - X, axis=1) / rms
    # Errors below a hundredth of the tolerance do not count against the estimate: float32
    # storage (~1e-8), and a texel an edge crosses where neither its samples nor its
    # neighbours' saw the edge, which takes the exact unoccluded value with variance 0.
    share = np.mean(actual <= 2 * est[rows] + 0.01 * TOL)
    check(share >= 0.95, f"the row error estimate is optimistic: {share:.1%} of the rows within 2x of it")
    # Where no sample saw the floor the texel takes its exact unoccluded value (Lambert's
    # formula in sample, here the oracle's own), clipped to the horizon where it crosses it:
    # equal to float32 rounding, not Monte Carlo noise. Most texels above the floor are such.
    lit = X > 0
    exact_share = np.mean(np.abs(T[rows] - X)[lit] <= 1e-6 * X[lit])
    check(exact_share >= 0.7, f"only {exact_share:.1%} of the lit entries equal the closed form to 1e-6")
    levels = side_table(conv, "sample_level").reshape(-1)
    check(levels[rows].max() >= 1, "no texel went past level 0")
    rays = side_table(conv, "sample_rays").reshape(-1)
    check(rays[mask == 0].sum() == 0 and rays[rows].min() > 0, "the rays side table is off")
    summary = json.loads(run("inspect", "--json", conv).stdout).get("converged", {})
    check(summary.get("rays") == int(rays.sum()) and summary.get("tolerance") == TOL,
          f"inspect's converged block: {summary}")
    print(f"converged: error {err_conv:.4f} (tolerance {TOL}), fixed spp 4 {err_fixed:.4f}; "
          f"{share:.1%} of rows within 2x of their estimate; {exact_share:.1%} of the lit entries exact; "
          f"rays {rays.sum()}", file=sys.stderr)

    # Determinism, and a bake killed once its first chunk is committed resumes to the same hash.
    want = content_hash(conv)
    again, _, again_text = bake(d, "again", "--tolerance", f"{TOL * 100:g}%")
    check(content_hash(again) == want, "the same converged bake twice differs")
    # sample --json: the same bake's summary as one JSON object (its rays as the text says).
    j = json.loads(run("sample", os.path.join(d, "scene.toml"), "-o", os.path.join(d, "j.ltm"), "--tolerance",
                       f"{TOL * 100:g}%", "--json").stdout)
    traced = int(re.search(r"rays traced: (\d+)", again_text).group(1))
    check(j["rays"] == traced and j["converged"]["tolerance"] == TOL and j["rows"] == 24 * 24,
          f"sample --json: {j} (the text run traced {traced} rays)")
    # Two shards decide as the whole bake does: inspect reads each shard file's own chunks, and
    # their rays add up to the whole bake's.
    shard_rays = 0
    for k in range(2):
        run("sample", os.path.join(d, "scene.toml"), "-o", os.path.join(d, "sh.ltm"), "--tolerance", f"{TOL * 100:g}%",
            "--chunk-rows", "8", "--shard", k, "--nshards", 2)
        p = subprocess.run([LTBAKE, "inspect", "--json", os.path.join(d, "sh.shards", f"{k:05d}-of-00002.ltm")],
                           capture_output=True, text=True)
        check(p.returncode == 0, f"inspect of converged shard {k}: {p.stderr}")
        shard_rays += json.loads(p.stdout).get("converged", {}).get("rays", 0) if p.returncode == 0 else 0
    check(shard_rays == int(rays.sum()), f"the two shards' rays {shard_rays}, the whole bake's {int(rays.sum())}")
    killed = os.path.join(d, "killed.ltm")
    cmd = [LTBAKE, "sample", os.path.join(d, "scene.toml"), "-o", killed, "--tolerance", f"{TOL * 100:g}%",
           "--chunk-rows", "8", "--jobs", "1"]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.monotonic() + 60
    committed = 0
    while proc.poll() is None and time.monotonic() < deadline:
        p = subprocess.run([LTBAKE, "inspect", "--json", killed], capture_output=True, text=True)
        if p.returncode == 0:
            committed = json.loads(p.stdout).get("chunks", {}).get("committed", 0)
            if committed > 0:
                break
        time.sleep(0.01)
    if proc.poll() is None:
        proc.send_signal(signal.SIGKILL)
    proc.wait()
    r = run("sample", os.path.join(d, "scene.toml"), "-o", killed, "--tolerance", f"{TOL * 100:g}%",
            "--chunk-rows", "8")
    check(content_hash(killed) == want, f"a resumed converged bake differs (killed after {committed} chunks):\n"
          f"{r.stdout}")
    # What it refuses.
    p = run("sample", os.path.join(d, "scene.toml"), "-o", os.path.join(d, "x.ltm"), "--tolerance", "1%", "--spp",
            "1", expect=1)
    check("--spp 1 must be at least 2" in p.stderr, f"--tolerance with spp 1:\n{p.stderr}")
    p = run("sample", os.path.join(d, "scene.toml"), "-o", os.path.join(d, "x.ltm"), "--tolerance", "150%",
            expect=None)
    check(p.returncode in (1, 2), f"--tolerance 150% exits {p.returncode}")
    check("--tolerance" in p.stderr, f"--tolerance 150%:\n{p.stderr}")

    # With a bounce the indirect term's paths double per row while its own variance asks for
    # it. No closed form: the reference is a fixed bake at spp 256, whose own noise (from a
    # second reference with another seed: ‖r1 − r2‖ / √2) adds in quadrature to what is
    # measured against it; a fixed spp-4 bake (~20%) must miss the tolerance.
    TOL_B = 0.10
    _, ref_b, _ = bake(d, "ref_b", "--spp", "256", "--bounces", "1", "--seed", "7")
    _, ref_b2, _ = bake(d, "ref_b2", "--spp", "256", "--bounces", "1", "--seed", "8")
    noise = np.linalg.norm(ref_b - ref_b2) / np.sqrt(2) / np.linalg.norm(ref_b)
    _, conv_b, text_b = bake(d, "conv_b", "--tolerance", f"{TOL_B * 100:g}%", "--bounces", "1")
    _, fixed_b, _ = bake(d, "fixed_b", "--bounces", "1")
    err_b = np.linalg.norm(conv_b - ref_b) / np.linalg.norm(ref_b)
    err_fb = np.linalg.norm(fixed_b - ref_b) / np.linalg.norm(ref_b)
    # The levels are set from the pilot's 64 rows, whose variance sum is known to ~1/√64 (two
    # standard errors: 25% in variance, 12.5% in the error), on top of the reference's noise.
    check(err_b ** 2 <= (TOL_B * (1 + 1 / np.sqrt(64))) ** 2 + noise ** 2,
          f"converged bake with a bounce: error {err_b:.4f} over its tolerance {TOL_B} (reference noise {noise:.4f})")
    check(err_fb > TOL_B, f"the fixed spp-4 bake with a bounce is already within {TOL_B} ({err_fb:.4f})")
    print(f"converged with a bounce: error {err_b:.4f} (tolerance {TOL_B}, reference noise {noise:.4f}), "
          f"fixed spp 4 {err_fb:.4f}", file=sys.stderr)
    # A tolerance the levels cannot reach is said, not chased to every level's top.
    p = run("sample", os.path.join(d, "scene.toml"), "-o", os.path.join(d, "far.ltm"), "--tolerance", "0.01%",
            "--max-levels", "2")
    check("the tolerance is out of reach" in p.stdout, f"--tolerance 0.01% at --max-levels 2:\n{p.stdout}")
finish()
