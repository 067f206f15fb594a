#!/usr/bin/python3
"""Two environment maps no bundled map resembles, for bench/pbi_unseen.sh, written as flat
Radiance .hdr lat-long files (512 x 256, +Z up):
  sun_sky.hdr        a blue gradient sky, a dim ground and a small sun (0.5 degree radius,
                     4e4 times the sky) 35 degrees up: nearly all the energy in one texel
  three_windows.hdr  a dark room lit by three coloured rectangular area lights

    /usr/bin/python3 bench/make_unseen_maps.py OUT_DIR
"""
import os
import sys

import numpy as np

W, H = 512, 256


def directions():
    y, x = np.mgrid[0:H, 0:W]
    phi = 2 * np.pi * (x + 0.5) / W
    theta = np.pi * (y + 0.5) / H
    return np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1), phi, theta


def write_hdr(path, rgb):
    rgb = np.maximum(rgb.astype(np.float64), 1e-9)
    m = rgb.max(axis=-1)
    mant, exp = np.frexp(m)
    scale = mant * 256.0 / m
    out = np.zeros(rgb.shape[:2] + (4,), np.uint8)
    out[..., :3] = np.clip(np.floor(rgb * scale[..., None]), 0, 255).astype(np.uint8)
    out[..., 3] = (exp + 128).astype(np.uint8)
    # A flat scanline must not start like a run-length one (2, 2, ...).
    first = out[:, 0]
    first[(first[:, 0] == 2) & (first[:, 1] == 2), 0] = 3
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {H} +X {W}\n".encode())
        f.write(out.tobytes())


def main():
    out = sys.argv[1]
    os.makedirs(out, exist_ok=True)
    d, phi, theta = directions()
    z = d[..., 2]
    sky = np.where(z[..., None] > 0, np.stack([0.25 + 0.3 * (1 - z), 0.45 + 0.25 * (1 - z), 0.9 + 0 * z], -1),
                   np.stack([0.08 + 0 * z, 0.07 + 0 * z, 0.06 + 0 * z], -1))
    el, az = np.radians(35), np.radians(60)
    sun_dir = np.array([np.cos(el) * np.cos(az), np.cos(el) * np.sin(az), np.sin(el)])
    sun = (d @ sun_dir) > np.cos(np.radians(0.5))
    sky[sun] = [4e4, 3.6e4, 3e4]
    write_hdr(os.path.join(out, "sun_sky.hdr"), sky)
    room = np.full((H, W, 3), 0.02)
    for (az0, az1, el0, el1, colour) in [(10, 40, 10, 45, (30, 24, 18)), (130, 150, 5, 60, (8, 14, 30)),
                                         (250, 300, 40, 55, (25, 10, 8))]:
        a = np.degrees(phi)
        e = 90 - np.degrees(theta)
        room[(a >= az0) & (a <= az1) & (e >= el0) & (e <= el1)] = colour
    write_hdr(os.path.join(out, "three_windows.hdr"), room)


if __name__ == "__main__":
    main()
