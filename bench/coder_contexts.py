#!/usr/bin/python3
"""How much the contexts issue 39 names could save in the coded encoding of a quantized
matrix (docs/FORMAT.md "Coded sparse payloads"), before anyone builds them: the empirical
conditional entropy of each binary decision class under today's contexts and with one more
context added, in bits per nonzero.

Static entropies (counts over the whole file, as a coder with perfect adaptation would
pay; the real coder pays a little more, for learning): significance inside a nonzero 4×4
quad (today: level, left/up/up-left neighbours, the Mallat parent, the previous column at
the same position), the magnitude's exponent k (today: level, a bucket of the neighbours'
magnitudes), the sign (today: the previous column's and the left neighbour's), and the
suffix bits (raw). Candidates, each only where the coder could know it (coded before the
position, in the same chunk):
  - lighting parent: the column of the lighting wavelet one level coarser (s/2, t/2 in the
    same face), same position;
  - lighting up: the column one lighting row up (t − 1), same position;
  - sibling: the same position in the other orientations of the image band, coded earlier;
  - up-right neighbour; the column's depth; whether the position is in the approximation band.

    PYTHONPATH=build/python /usr/bin/python3 bench/coder_contexts.py FINAL.ltm

Prints a Markdown table; memory: a few bytes per matrix element (a 128², R = 32 file: ~3 GB).
"""
import math
import os
import sys

import numpy as np

import ltbake


def entropy(bit_or_symbol, contexts, nsym=2):
    """Σ over contexts of the count × the entropy of the symbol's distribution, in bits."""
    key = np.zeros(bit_or_symbol.shape, np.int64)
    for c, n in contexts:
        key = key * n + np.asarray(c).astype(np.int64)
    key = key * nsym + bit_or_symbol
    cnt = np.bincount(key, minlength=(int(key.max()) // nsym + 1) * nsym).reshape(-1, nsym).astype(np.float64)
    tot = cnt.sum(1, keepdims=True)
    with np.errstate(divide="ignore", invalid="ignore"):
        return float(-np.where(cnt > 0, cnt * np.log2(cnt / np.maximum(tot, 1)), 0).sum())


def main():
    path = sys.argv[1]
    f = ltbake.open(path)
    mat = f.arrays["matrix"]
    Q = np.asarray(mat)
    depth = np.asarray(f.arrays["depth"]).reshape(-1).astype(int)
    rows, C = Q.shape
    H = W = int(round(math.sqrt(rows)))
    R = int(round(math.sqrt(C // 6)))
    if H * W != rows or 6 * R * R != C:
        raise SystemExit(f"{path}: expected square column images and 6R² columns, got {rows} x {C}")
    per_chunk = -(-C // mat.nchunks)  # columns a chunk holds (contexts start fresh in each)
    stored = sum(c.stored_bytes for c in f.chunks if c.array == "matrix")
    A = Q.T.reshape(C, H, W)
    del Q
    nz = A != 0
    NZ = int(nz.sum())
    mag = np.minimum(np.abs(A), 127)
    y, x = np.mgrid[0:H, 0:W]
    bw = np.vectorize(lambda v: int(v).bit_length())
    lv = np.minimum(bw(np.maximum(x, y)), 9)

    def shift(a, dy, dx):  # a at (y − dy, x − dx), 0 outside
        out = np.zeros_like(a)
        out[:, max(dy, 0):H + min(dy, 0), max(dx, 0):W + min(dx, 0)] = \
            a[:, max(-dy, 0):H - max(dy, 0), max(-dx, 0):W - max(dx, 0)]
        return out

    col = np.arange(C)
    face, j = col // (R * R), col % (R * R)
    t, s = j // R, j % R
    level = np.array([int(max(a, b)).bit_length() for a, b in zip(s, t)])

    def same_chunk_ref(ref):
        ok = (ref >= 0) & (ref // per_chunk == col // per_chunk) & (ref < col)
        return np.where(ok, ref, -1)

    prev_c = same_chunk_ref(col - 1)
    lp_c = same_chunk_ref(np.where(level >= 2, face * R * R + (t // 2) * R + s // 2, -1))
    lu_c = same_chunk_ref(np.where(t > 0, col - R, -1))

    def from_col(a, ref):
        out = np.zeros_like(a)
        ok = ref >= 0
        out[ok] = a[ref[ok]]
        return out

    quad = nz.reshape(C, H // 4, 4, W // 4, 4).any(axis=(2, 4))
    inq = np.repeat(np.repeat(quad, 4, 1), 4, 2)
    l, u, ul, ur = shift(nz, 0, 1), shift(nz, 1, 0), shift(nz, 1, 1), shift(nz, 1, -1)
    near = np.minimum(l.astype(int) + u + ul, 2)
    par = nz[:, y // 2, x // 2].copy()
    par[:, 0, 0] = False
    prev = from_col(A, prev_c)
    pm = np.minimum(np.abs(prev), 2)
    lp, lu = from_col(nz, lp_c), from_col(nz, lu_c)
    h = np.where(lv > 0, 1 << np.maximum(lv - 1, 0), 1)
    sib = np.zeros(nz.shape, bool)
    for a, b in ((1, 0), (0, 1), (1, 1)):
        sx, sy = x % h + a * h * (lv > 0), y % h + b * h * (lv > 0)
        before = ((sy < y) | ((sy == y) & (sx < x))) & (lv > 0) & (sx < W) & (sy < H)
        sib |= nz[:, np.minimum(sy, H - 1), np.minimum(sx, W - 1)] & before[None]
    apx = np.maximum(x, y)[None] < (W >> depth)[:, None, None]
    dep = np.broadcast_to(np.minimum(depth, 7)[:, None, None], nz.shape)
    lvb = np.broadcast_to(lv, nz.shape)

    sel = inq
    bit = nz[sel].astype(np.int64)
    g = lambda a: a[sel]  # noqa: E731
    base = [(g(lvb), 10), (g(near), 3), (g(par), 2), (g(pm), 3)]
    sig = {"today": entropy(bit, base)}
    for name, c, n in (("+ lighting parent", lp, 2), ("+ lighting up", lu, 2), ("+ sibling", sib, 2),
                       ("+ up-right", ur, 2), ("+ depth", dep, 8), ("+ approximation band", apx, 2)):
        sig[name] = entropy(bit, base + [(g(c), n)])
    sig["all of them"] = entropy(bit, base + [(g(lp), 2), (g(lu), 2), (g(sib), 2), (g(ur), 2), (g(apx), 2)])

    a = np.abs(A[nz]).astype(np.int64)
    k = np.floor(np.log2(a)).astype(np.int64)
    k = np.minimum(k, 31)

    def bucket(v):
        return np.select([v <= 2, v <= 4, v <= 7, v <= 12, v <= 20, v <= 40], [v, 3, 4, 5, 6, 7], 8)

    magl, magu = shift(mag, 0, 1)[nz], shift(mag, 1, 0)[nz]
    pmm = np.minimum(np.abs(prev), 127)[nz]
    kbase = [(np.minimum(lvb[nz], 6), 7), (bucket(magl + magu + 2 * pmm), 9)]
    bk = lambda v: np.minimum(bw(v), 7)  # noqa: E731
    lpm, lum = from_col(mag, lp_c)[nz], from_col(mag, lu_c)[nz]
    pmag = mag[:, y // 2, x // 2][nz]
    kk = {"today": entropy(k, kbase, 32)}
    for name, c in (("+ Mallat parent's magnitude", bk(pmag)), ("+ lighting parent's", bk(lpm)),
                    ("+ lighting up's", bk(lum))):
        kk[name] = entropy(k, kbase + [(c, 8)], 32)
    kk["all of them"] = entropy(k, kbase + [(bucket(lpm + lum), 9), (bk(pmag), 8)], 32)

    sgn = (A[nz] < 0).astype(np.int64)
    s3 = lambda v: np.where(v == 0, 0, np.where(v > 0, 1, 2))  # noqa: E731
    sbase = [(s3(prev[nz]), 3), (s3(shift(A, 0, 1)[nz]), 3)]
    sg = {"today": entropy(sgn, sbase)}
    for name, v in (("+ up", shift(A, 1, 0)), ("+ lighting parent's", from_col(A, lp_c)),
                    ("+ lighting up's", from_col(A, lu_c)), ("+ Mallat parent's", A[:, y // 2, x // 2])):
        sg[name] = entropy(sgn, sbase + [(s3(v[nz]), 3)])
    sg["all of them"] = entropy(sgn, sbase + [(s3(shift(A, 1, 0)[nz]), 3), (s3(from_col(A, lp_c)[nz]), 3),
                                              (s3(from_col(A, lu_c)[nz]), 3), (s3(A[:, y // 2, x // 2][nz]), 3)])
    suffix = float(k.sum())

    print(f"# Coder contexts: {os.path.basename(path)} ({rows} × {C}, {NZ:,} nonzeros, {per_chunk} columns a chunk)")
    print(f"\nCoded matrix today: {stored:,} bytes = {8 * stored / NZ:.2f} bits per nonzero.\n")
    print("| decision | context | bits per nonzero | saving |\n|---|---|---|---|")
    for what, table in (("significance", sig), ("exponent k", kk), ("sign", sg)):
        for name, v in table.items():
            print(f"| {what} | {name} | {v / NZ:.3f} | {(table['today'] - v) / NZ:.3f} |")
    print(f"| suffix bits | raw | {suffix / NZ:.3f} | |")
    best = (sig["today"] - sig["all of them"] + kk["today"] - kk["all of them"] + sg["today"] - sg["all of them"]) / NZ
    print(f"\nAll candidates together: {best:.3f} bits per nonzero less, {best / (8 * stored / NZ):.1%} of the "
          "coded matrix (static estimate).")


if __name__ == "__main__":
    main()
