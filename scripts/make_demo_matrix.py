"""Builds the demo's light transport matrix in closed form: a 64x64 orthographic view of
the ground plane z = 0 over [-1, 1]^2 with a sphere (centre (0.2, 0, 0.45), radius 0.3)
floating above it, lit by a cubemap of R = 8 (384 columns). Each entry is visibility x
cosine x the texel's exact solid angle, with the direction through the texel centre (the
`sample` stage integrates properly; this is bundled demo data, not a bake).

usage: make_demo_matrix.py OUT.npy [--width 64] [--cube-res 8]
"""
import argparse
import os
import sys

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
import cubemap  # noqa: E402

ap = argparse.ArgumentParser()
ap.add_argument("out")
ap.add_argument("--width", type=int, default=64)
ap.add_argument("--cube-res", type=int, default=8)
a = ap.parse_args()

W, R = a.width, a.cube_res
dirs = cubemap.texel_directions(R)            # (6R^2, 3)
omega = cubemap.texel_solid_angles(R)         # (6R^2,)
c = np.array([0.2, 0.0, 0.45])
r = 0.3
xs = (np.arange(W) + 0.5) / W * 2 - 1
px, py = np.meshgrid(xs, -xs)                 # image row y = 0 at the top (+y)
points = np.stack([px, py, np.zeros_like(px)], axis=-1).reshape(-1, 3)  # rows y*W + x

cos = np.clip(dirs[:, 2], 0.0, None)          # normal +z
oc = points[:, None, :] - c[None, None, :]    # (P, 1, 3)
b = np.einsum("pij,kj->pk", oc, dirs)         # (P, K): o-c . d
cc = np.einsum("pij,pij->pi", oc, oc)         # (P, 1)
disc = b * b - (cc - r * r)
t_far = -b + np.sqrt(np.maximum(disc, 0.0))
blocked = (disc > 0) & (t_far > 0)
T = np.where(blocked, 0.0, cos[None, :] * omega[None, :]).astype(np.float32)
np.save(a.out, T)
print(f"{a.out}: {T.shape[0]} x {T.shape[1]} (image {W}x{W}, cube R={R}), "
      f"{np.count_nonzero(T) / T.size:.1%} nonzero, row sums (irradiance under unit sky) "
      f"{T.sum(1).min():.3f}..{T.sum(1).max():.3f} (pi = {np.pi:.3f} unshadowed)")
