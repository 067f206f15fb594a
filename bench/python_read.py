"""Reading one light's image (a column) and one pixel's transport (a row) of a large matrix
from Python: `import ltbake` on .ltm files in both layouts, against np.load(mmap_mode="r")
of the .npy and h5py on the same matrix in chunked datasets (issue 21's benchmark).

usage: PYTHONPATH=build/python /usr/bin/python3 bench/python_read.py WORKDIR
         [--ltbake build/ltbake] [--rows 65536] [--cube-res 64] [--reps 7] [--keep] [--out FILE.md]

The matrix is rows x 6R² float32 (65536 x 24576 = 6.4 GB by default), random values; it is
written once as raw.npy, rows.ltm (row blocks, ~8 MiB chunks, as `ltbake convert` makes
them), cols.ltm (column blocks, `convert --layout cols`) and h5py datasets chunked like each
.ltm (uncompressed), then deleted unless --keep. Each case reads a random row or column and
sums it (so every reader touches every value), `reps` times with different indices:
  cold: the file's pages dropped from the page cache before each read (POSIX_FADV_DONTNEED;
        h5py's file reopened, so its chunk cache is empty too);
  warm: the same index read once before the timed read.
Reported: median milliseconds per read and the ratios of the targets. Disk: ~32 GB free.
"""
import argparse
import os
import platform
import statistics
import subprocess
import sys
import time

import numpy as np

import ltbake

try:
    import h5py
except ImportError:  # Debian python3-h5py (scripts/setup.sh)
    h5py = None


def drop(path):
    """Drops a file's clean pages from the page cache."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
        os.posix_fadvise(fd, 0, 0, os.POSIX_FADV_DONTNEED)
    finally:
        os.close(fd)


def timed(fn):
    t = time.perf_counter()
    v = fn()
    return (time.perf_counter() - t) * 1e3, v


def make_data(work, ltbake_bin, rows, cols, log):
    npy = os.path.join(work, "raw.npy")
    if not os.path.exists(npy):
        m = np.lib.format.open_memmap(npy + ".part", mode="w+", dtype=np.float32, shape=(rows, cols))
        step = max(1, (256 << 20) // (cols * 4))
        for r in range(0, rows, step):
            rng = np.random.default_rng(r)
            m[r:r + step] = rng.random((min(step, rows - r), cols), dtype=np.float32)
        m.flush()
        del m
        os.rename(npy + ".part", npy)
        log(f"wrote {npy}")
    for layout in ["rows", "cols"]:
        out = os.path.join(work, f"{layout}.ltm")
        if not os.path.exists(out):
            t = time.perf_counter()
            subprocess.run([ltbake_bin, "convert", npy, out, "--layout", layout, "--progress", "never"], check=True)
            log(f"wrote {out} in {time.perf_counter() - t:.0f} s")
    return npy


def make_h5(work, layout, rows, cols, log):
    """A chunked, uncompressed HDF5 dataset with the chunk shape of the .ltm of `layout`."""
    path = os.path.join(work, f"{layout}.h5")
    c = ltbake.open(os.path.join(work, f"{layout}.ltm"), checksums=False)
    if os.path.exists(path):
        return path
    chunk = (c.block, cols) if layout == "rows" else (rows, c.block)
    t = time.perf_counter()
    with h5py.File(path + ".part", "w") as f:
        d = f.create_dataset("T", shape=(rows, cols), dtype="f4", chunks=chunk)
        for rng_, block in c.iter_chunks():  # one HDF5 chunk per .ltm chunk
            if layout == "rows":
                d[rng_.start:rng_.stop, :] = block
            else:
                d[:, rng_.start:rng_.stop] = block
    os.rename(path + ".part", path)
    log(f"wrote {path} (chunks {chunk}) in {time.perf_counter() - t:.0f} s")
    return path


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("work")
    ap.add_argument("--ltbake", default="build/ltbake")
    ap.add_argument("--rows", type=int, default=65536)
    ap.add_argument("--cube-res", type=int, default=64)
    ap.add_argument("--reps", type=int, default=7)
    ap.add_argument("--keep", action="store_true")
    ap.add_argument("--out", default=None, help="also write the table (markdown) here")
    a = ap.parse_args()
    if h5py is None:
        sys.exit("needs h5py: install the Debian package python3-h5py (scripts/setup.sh)")
    rows, cols = a.rows, 6 * a.cube_res ** 2
    os.makedirs(a.work, exist_ok=True)
    lines = []

    def log(s):
        print(s, flush=True)
        lines.append(s)

    npy = make_data(a.work, a.ltbake, rows, cols, log)
    rng = np.random.default_rng(7)
    picks = [(int(rng.integers(rows)), int(rng.integers(cols))) for _ in range(a.reps)]

    def readers(layout, h5path):
        """name -> (file, open(), read_row(obj, i), read_col(obj, j))."""
        ltm = os.path.join(a.work, f"{layout}.ltm")
        out = {
            f"ltbake {layout}.ltm": (ltm, lambda: ltbake.open(ltm, checksums=False),
                                     lambda c, i: c[i], lambda c, j: c[:, j]),
            f"ltbake {layout}.ltm checksums": (ltm, lambda: ltbake.open(ltm),
                                               lambda c, i: c[i], lambda c, j: c[:, j]),
            f"h5py {layout}-chunked": (h5path, lambda: h5py.File(h5path, "r")["T"],
                                       lambda d, i: d[i, :], lambda d, j: d[:, j]),
        }
        if layout == "rows":
            out["np.load mmap .npy"] = (npy, lambda: np.load(npy, mmap_mode="r"), lambda m, i: m[i], lambda m, j: m[:, j])
        return out

    results = {}  # (reader, what, cache) -> median ms
    for layout in ["rows", "cols"]:
        h5path = make_h5(a.work, layout, rows, cols, log)
        for name, (path, opener, row, col) in readers(layout, h5path).items():
            for what, fn in [("row", row), ("column", col)]:
                for cache in ["cold", "warm"]:
                    ms = []
                    for i, j in picks:
                        idx = i if what == "row" else j
                        if cache == "cold":
                            drop(path)
                        obj = opener()
                        if cache == "warm":
                            float(np.sum(fn(obj, idx), dtype=np.float64))
                        t, _ = timed(lambda o=obj, x=idx: float(np.sum(fn(o, x), dtype=np.float64)))
                        ms.append(t)
                        del obj
                    results[(name, what, cache)] = statistics.median(ms)
                    log(f"{name:28s} {what:6s} {cache}: median {results[(name, what, cache)]:9.2f} ms "
                        f"(min {min(ms):.2f}, max {max(ms):.2f}, {len(ms)} reads)")
        if not a.keep:
            os.remove(h5path)

    def r(x, y, what, cache):
        return results[(y, what, cache)] / results[(x, what, cache)]

    table = ["", f"matrix {rows} x {cols} float32 ({rows * cols * 4 / 1e9:.2f} GB); {a.reps} reads per cell, medians "
             f"(ms); machine: {platform.machine()}, {os.cpu_count()} CPUs, {platform.release()}", "",
             "| reader | row cold | row warm | column cold | column warm |", "|---|---|---|---|---|"]
    names = sorted({k[0] for k in results})
    for n in names:
        table.append(f"| {n} | " + " | ".join(f"{results[(n, w, c)]:.2f}" for w in ["row", "column"]
                                                for c in ["cold", "warm"]) + " |")
    table += ["", "targets (ratio > 1: ltbake faster):"]
    for cache in ["cold", "warm"]:
        for ck in ["", " checksums"]:
            table.append(f"- native layout, {cache}{ck}: row of rows.ltm vs np.load mmap row: "
                         f"{r(f'ltbake rows.ltm{ck}', 'np.load mmap .npy', 'row', cache):.2f}x (target >= 1)")
            table.append(f"- other layout, {cache}{ck}: column of rows.ltm vs h5py rows-chunked: "
                         f"{r(f'ltbake rows.ltm{ck}', 'h5py rows-chunked', 'column', cache):.2f}x; row of cols.ltm "
                         f"vs h5py cols-chunked: {r(f'ltbake cols.ltm{ck}', 'h5py cols-chunked', 'row', cache):.2f}x "
                         f"(target >= 3)")
    for t in table:
        log(t)
    if a.out:
        with open(a.out, "w") as f:
            f.write("\n".join(lines) + "\n")
    if not a.keep:
        for f in ["raw.npy", "rows.ltm", "cols.ltm"]:
            os.remove(os.path.join(a.work, f))


if __name__ == "__main__":
    main()
