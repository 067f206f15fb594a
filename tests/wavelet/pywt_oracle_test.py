"""Oracle: the 2D transform of ltbake's wavelet library against PyWavelets.

For haar, db2, db3, db4 on random square faces of sizes 2..256, the forward transform
equals pywt.coeffs_to_array(pywt.wavedec2(x, name, mode='periodization', level=L))[0],
for L = full depth (log2 N, what row-transform uses) and PyWavelets' default level, within
1e-5 * max|x| in float32 and 1e-12 * max|x| in float64 (the float32 bound: ~log2(N) levels
of F-tap sums of unit-norm filters, each rounding at 2^-24 relative, stays well under 1e-5).
For legall53 and cdf97 (not in PyWavelets with JPEG 2000 extension) it compares with an
independent NumPy implementation of the T.800 Annex F lifting steps, on odd and even sizes.

usage: pywt_oracle_test.py PATH_TO_ltb_wavelet_helper
"""
import os
import subprocess
import sys
import tempfile
import warnings

import numpy as np
import pywt

HELPER = sys.argv[1]
warnings.simplefilter("ignore")  # pywt warns that deep levels see boundary effects
failures = []
checked = 0


def run(direction, name, depth, w, h, lanes, arr, dtype):
    with tempfile.TemporaryDirectory() as d:
        src, dst = os.path.join(d, "in"), os.path.join(d, "out")
        arr.astype(dtype).tofile(src)
        tag = "f64" if dtype == np.float64 else "f32"
        subprocess.run([HELPER, direction, name, str(depth), str(w), str(h), str(lanes), tag, src, dst], check=True)
        return np.fromfile(dst, dtype=dtype)


rng = np.random.default_rng(2026)
for name in ["haar", "db2", "db3", "db4"]:
    for n in [2, 4, 8, 16, 32, 64, 128, 256]:
        x = rng.standard_normal((n, n))
        full = int(np.log2(n))
        levels = {full, pywt.dwt_max_level(n, pywt.Wavelet(name).dec_len)} - {0}
        for level in sorted(levels):
            want = pywt.coeffs_to_array(pywt.wavedec2(x, name, mode="periodization", level=level))[0]
            for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-5)):
                got = run("forward", name, level, n, n, 1, x, dtype).reshape(n, n)
                err = np.abs(got - want).max() / np.abs(x).max()
                checked += 1
                if err > tol:
                    failures.append(f"{name} {n}x{n} level {level} {dtype.__name__}: max error {err:.3g} > {tol}")

# Lanes: 5 faces transformed in one call equal 5 separate transforms.
n, lanes = 16, 5
faces = rng.standard_normal((lanes, n, n))
packed = np.moveaxis(faces, 0, -1).copy()  # (y, x, lane)
got = run("forward", "db2", 4, n, n, lanes, packed, np.float64).reshape(n, n, lanes)
for k in range(lanes):
    want = pywt.coeffs_to_array(pywt.wavedec2(faces[k], "db2", mode="periodization", level=4))[0]
    checked += 1
    if np.abs(got[:, :, k] - want).max() > 1e-12:
        failures.append(f"lane {k} differs from its own transform")


def mirror(i, n):
    return -i if i < 0 else (2 * (n - 1) - i if i >= n else i)


def lift_1d(x, name):
    """T.800 Annex F analysis on one signal; returns Mallat order (low then high)."""
    x = x.astype(np.float64).copy()
    n = len(x)
    if n == 1:
        return x
    if name == "legall53":
        steps = [(1, -0.5), (0, 0.25)]
    else:
        steps = [(1, -1.586134342059924), (0, -0.052980118572961), (1, 0.882911075530934), (0, 0.443506852043971)]
    for parity, c in steps:
        for p in range(parity, n, 2):
            x[p] += c * (x[mirror(p - 1, n)] + x[mirror(p + 1, n)])
    if name == "cdf97":
        K = 1.230174104914001
        x[1::2] *= K
        x[0::2] /= K
    return np.concatenate([x[0::2], x[1::2]])


def lift_2d(img, name, depth):
    img = img.astype(np.float64).copy()
    h, w = img.shape
    for _ in range(depth):
        if w > 1:
            img[:h, :w] = np.stack([lift_1d(r, name) for r in img[:h, :w]])
        if h > 1:
            img[:h, :w] = np.stack([lift_1d(c, name) for c in img[:h, :w].T]).T
        w, h = (w + 1) // 2, (h + 1) // 2
    return img


for name in ["legall53", "cdf97"]:
    for (h, w) in [(1, 1), (1, 9), (9, 1), (5, 3), (13, 17), (32, 32), (31, 64)]:
        x = rng.standard_normal((h, w))
        depth = int(np.ceil(np.log2(max(h, w)))) if max(h, w) > 1 else 0
        for d in sorted({0, 1, depth}):
            want = lift_2d(x, name, d)
            for dtype, tol in ((np.float64, 1e-12), (np.float32, 1e-5)):
                got = run("forward", name, d, w, h, 1, x, dtype).reshape(h, w)
                scale = max(np.abs(x).max(), 1e-30)
                # The biorthogonal transforms are not unit-gain; the bound is relative to the output.
                err = np.abs(got - want).max() / max(scale, np.abs(want).max())
                checked += 1
                if err > tol:
                    failures.append(f"{name} {h}x{w} depth {d} {dtype.__name__}: max error {err:.3g} > {tol}")
                back = run("inverse", name, d, w, h, 1, got.astype(dtype), dtype).reshape(h, w)
                if np.abs(back - x).max() / scale > tol:
                    failures.append(f"{name} {h}x{w} depth {d} {dtype.__name__}: inverse does not return the input")

for f in failures:
    print(f)
print(f"{checked - len(failures)} passed, {len(failures)} failed")
sys.exit(1 if failures else 0)
