#!/usr/bin/env python3
"""Environment-map resampling against an independent NumPy implementation of the documented
conventions (docs/ENVMAPS.md lat-long mapping, docs/CUBEMAP.md faces via scripts/cubemap.py).

A lat-long map of a known function is written as a flat Radiance .hdr by hand; the helper
resamples it (rotated or not) and every texel is compared with the average of the decoded,
piecewise-constant source over the texel, by supersampling with exact dω weights. Also: the
source power against NumPy's Σ L·Δφ·Δcos θ, and Σ texel·Ω_texel against it.

usage: envmap_oracle_test.py path/to/ltb_envmap_helper
"""
import os
import subprocess
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "..", "scripts"))
import cubemap  # noqa: E402


def lat_long_directions(w, h):
    u = (np.arange(w) + 0.5) / w
    v = (np.arange(h) + 0.5) / h
    phi = np.pi - 2 * np.pi * u[None, :]      # φ = π − 2πu = atan2(y, x)
    theta = np.pi * v[:, None]                # θ = πv = acos z, row 0 at the top
    return np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta) * np.ones_like(phi)


def function(x, y, z):
    return np.stack([1 + 0.5 * x + 0.3 * y * y, 1 + 0.8 * np.maximum(0, y) ** 3 + 0.5 * np.maximum(0, x) ** 8,
                     1 + 0.6 * z - 0.2 * x * y], -1)


def write_flat_hdr(path, img):
    h, w, _ = img.shape
    m = img.max(-1)
    e = np.floor(np.log2(m)).astype(int) + 1
    mant = np.floor(img * (2.0 ** (8 - e))[..., None]).astype(np.uint8)
    rgbe = np.concatenate([mant, (e + 128).astype(np.uint8)[..., None]], -1)
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w))
        f.write(rgbe.tobytes())
    return rgbe[..., :3] * 2.0 ** (rgbe[..., 3:4].astype(float) - 136)   # what a reader must decode


def texel_averages(src, r, rotation, n=48):
    h, w, _ = src.shape
    out = np.zeros((6 * r * r, 3))
    for face in range(6):
        for t in range(r):
            for s in range(r):
                uu = 2 * (s + (np.arange(n) + 0.5) / n) / r - 1
                vv = 2 * (t + (np.arange(n) + 0.5) / n) / r - 1
                u, v = np.meshgrid(uu, vv)
                x, y, z = cubemap.face_direction(face, u, v)
                length = np.sqrt(x * x + y * y + z * z)
                dw = length ** -3                       # dω = du dv / (1 + u² + v²)^{3/2}
                # The rotated map shows in d what the source shows in Rz(−rotation)·d.
                c, sn = np.cos(rotation), np.sin(rotation)
                xs, ys = c * x + sn * y, -sn * x + c * y
                col = ((np.pi - np.arctan2(ys, xs)) / (2 * np.pi)) % 1.0
                row = np.arccos(np.clip(z / length, -1, 1)) / np.pi
                px = np.minimum((col * w).astype(int), w - 1)
                py = np.minimum((row * h).astype(int), h - 1)
                out[face * r * r + t * r + s] = (src[py, px] * dw[..., None]).sum((0, 1)) / dw.sum()
    return out


def main():
    helper = sys.argv[1]
    failures = 0
    with tempfile.TemporaryDirectory() as tmp:
        w, h = 512, 256
        src = write_flat_hdr(os.path.join(tmp, "env.hdr"), function(*lat_long_directions(w, h)).astype(np.float32))
        rows_omega = 2 * np.pi / w * (np.cos(np.pi * np.arange(h) / h) - np.cos(np.pi * (np.arange(h) + 1) / h))
        power = (src.sum(1) * rows_omega[:, None]).sum(0)
        for r, rotation in [(8, 0.0), (8, 1.1), (4, -2.5)]:
            out = os.path.join(tmp, "cube.npy")
            res = subprocess.run([helper, os.path.join(tmp, "env.hdr"), out, str(r), repr(rotation)],
                                 capture_output=True, text=True, check=True)
            got = np.load(out)
            ref = texel_averages(src, r, rotation)
            rel = np.abs(got - ref) / ref
            helper_power = np.array([float(p) for p in res.stdout.split()])
            cube_power = (got.astype(float) * cubemap.texel_solid_angles(r)[:, None]).sum(0)
            ok = rel.max() < 2e-3 and np.allclose(helper_power, power, rtol=1e-9) and \
                np.allclose(cube_power, power, rtol=1e-6)
            print("R=%d rotation %+.2f: worst texel vs NumPy %.2e (mean %.2e); power %s vs NumPy %s, cube %s  %s"
                  % (r, rotation, rel.max(), rel.mean(), np.round(helper_power, 6), np.round(power, 6),
                     np.round(cube_power, 6), "ok" if ok else "FAILED"))
            failures += not ok
    return 1 if failures else 0


if __name__ == "__main__":
    sys.exit(main())
