#!/usr/bin/python3
"""The h5py baseline for the `ltbake transpose` benchmark (bench/run_transpose.sh).

The transpose a user would write with h5py on chunked HDF5 datasets: read a band that
fits in memory, transpose it with numpy, write it to the transposed dataset. Run it with
/usr/bin/python3 (Debian's numpy and h5py). One JSON line per command on stdout.

  h5py_transpose.py convert IN.h5 --rows R --cols C --chunks 1024x1024
        Reads the R x C f32 matrix, row-major, from stdin (`ltb_transpose_bench raw`)
        and stores it as dataset "matrix" with the given chunk shape (not timed by the
        benchmark: it stands for "the matrix is already in HDF5").
  h5py_transpose.py transpose IN.h5 OUT.h5 [--out-chunks 1x65536] [--band-bytes 256MiB]
                    [--cache 1GiB] [--order cols|rows] [--slice K]
        OUT.h5 gets dataset "matrix_t" of shape (C, R): row c of it is column c of the
        input (the analogue of ltbake's column chunks). Both files are opened with
        rdcc_nbytes = --cache (the HDF5 chunk cache, per dataset) and rdcc_nslots a prime
        about 100 x the number of chunks that fit. --order cols: bands of input columns
        in[:, c0:c1] -> out[c0:c1, :] (for tiled or column-friendly input chunks);
        --order rows: bands of input rows in[r0:r1, :] -> out[:, r0:r1] (for row-block
        input chunks; needs output chunks whose width divides the band). Band width =
        --band-bytes / (4 x band length), rounded down to a multiple of the chunk edge.
        Transposition in memory: np.ascontiguousarray(block.T) (what h5py itself does
        with `out[...] = block.T`), or with --slice K in slices of K band rows into a
        preallocated array, out_t[:, i:i+K] = block[i:i+K, :].T, which keeps numpy's
        strided reads within the caches and TLB (~3x faster here for 2048-row bands).
        The clock covers opening both files, every band, flush, os.fsync of OUT.h5
        (ltbake and dd sync their output too) and close. Reports the phases and this
        process's peak RSS (getrusage).
  h5py_transpose.py check IN.h5 OUT.h5 [--samples 6]
        out[c, :] == in[:, c] for the first, last and a few random columns.
"""
import argparse
import json
import os
import random
import resource
import sys
import time

import h5py
import numpy as np


def parse_bytes(s):
    units = {"": 1, "K": 1 << 10, "KiB": 1 << 10, "M": 1 << 20, "MiB": 1 << 20, "G": 1 << 30, "GiB": 1 << 30}
    num = s.rstrip("KMGiB")
    return int(float(num) * units[s[len(num):]])


def parse_shape(s):
    return tuple(int(x) for x in s.lower().split("x"))


def next_prime(n):
    def is_prime(k):
        if k < 2:
            return False
        i = 2
        while i * i <= k:
            if k % i == 0:
                return False
            i += 1
        return True

    while not is_prime(n):
        n += 1
    return n


def nslots(cache_bytes, chunk_bytes):
    return next_prime(max(521, 100 * max(1, cache_bytes // chunk_bytes)))


def peak_rss_kib():
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss


def read_exact(f, n):
    buf = bytearray(n)
    view = memoryview(buf)
    got = 0
    while got < n:
        k = f.readinto(view[got:])
        if not k:
            raise SystemExit(f"convert: stdin ended after {got} of {n} bytes")
        got += k
    return buf


def cmd_convert(a):
    rows, cols = a.rows, a.cols
    chunks = parse_shape(a.chunks)
    t0 = time.monotonic()
    with h5py.File(a.input, "w") as f:
        d = f.create_dataset("matrix", shape=(rows, cols), dtype="<f4", chunks=chunks)
        band = max(chunks[0], (256 << 20) // (4 * cols) // chunks[0] * chunks[0])
        stdin = sys.stdin.buffer
        for r0 in range(0, rows, band):
            r1 = min(rows, r0 + band)
            d[r0:r1, :] = np.frombuffer(read_exact(stdin, (r1 - r0) * cols * 4), dtype="<f4").reshape(r1 - r0, cols)
        f.flush()
    fd = os.open(a.input, os.O_RDONLY)
    os.fsync(fd)
    os.close(fd)
    print(json.dumps({"mode": "convert", "path": a.input, "rows": rows, "cols": cols, "chunks": list(chunks),
                      "file_bytes": os.path.getsize(a.input), "seconds": time.monotonic() - t0,
                      "peak_rss_kib": peak_rss_kib()}))


def cmd_transpose(a):
    cache = parse_bytes(a.cache)
    band_bytes = parse_bytes(a.band_bytes)
    out_chunks = parse_shape(a.out_chunks)
    t_read = t_transpose = t_write = 0.0

    def transpose(block):
        if a.slice <= 0:
            return np.ascontiguousarray(block.T)
        out = np.empty((block.shape[1], block.shape[0]), dtype=block.dtype)
        for i in range(0, block.shape[0], a.slice):
            out[:, i:i + a.slice] = block[i:i + a.slice, :].T
        return out
    bands = 0
    t0 = time.monotonic()
    fin = h5py.File(a.input, "r", rdcc_nbytes=cache, rdcc_nslots=1)  # nslots set below once chunks are known
    din = fin["matrix"]
    rows, cols = din.shape
    in_chunks = din.chunks
    fin.close()
    fin = h5py.File(a.input, "r", rdcc_nbytes=cache, rdcc_nslots=nslots(cache, 4 * in_chunks[0] * in_chunks[1]))
    din = fin["matrix"]
    fout = h5py.File(a.output, "w", rdcc_nbytes=cache, rdcc_nslots=nslots(cache, 4 * out_chunks[0] * out_chunks[1]))
    dout = fout.create_dataset("matrix_t", shape=(cols, rows), dtype="<f4", chunks=out_chunks)
    if a.order == "cols":
        # Input columns [c0, c1) -> output rows [c0, c1). Multiple of both chunk edges.
        edge = np.lcm(in_chunks[1], out_chunks[0])
        width = max(edge, band_bytes // (4 * rows) // edge * edge)
        for c0 in range(0, cols, width):
            c1 = min(cols, c0 + width)
            t1 = time.monotonic()
            block = din[:, c0:c1]                    # rows x w
            t2 = time.monotonic()
            block_t = transpose(block)               # w x rows
            del block
            t3 = time.monotonic()
            dout[c0:c1, :] = block_t
            del block_t
            t4 = time.monotonic()
            t_read += t2 - t1
            t_transpose += t3 - t2
            t_write += t4 - t3
            bands += 1
    else:
        edge = np.lcm(in_chunks[0], out_chunks[1])
        width = max(edge, band_bytes // (4 * cols) // edge * edge)
        for r0 in range(0, rows, width):
            r1 = min(rows, r0 + width)
            t1 = time.monotonic()
            block = din[r0:r1, :]                    # h x cols
            t2 = time.monotonic()
            block_t = transpose(block)               # cols x h
            del block
            t3 = time.monotonic()
            dout[:, r0:r1] = block_t
            del block_t
            t4 = time.monotonic()
            t_read += t2 - t1
            t_transpose += t3 - t2
            t_write += t4 - t3
            bands += 1
    t5 = time.monotonic()
    fout.flush()
    fout.close()
    fin.close()
    t6 = time.monotonic()
    fd = os.open(a.output, os.O_RDONLY)
    os.fsync(fd)
    os.close(fd)
    t7 = time.monotonic()
    print(json.dumps({"mode": "transpose", "input": a.input, "output": a.output, "rows": rows, "cols": cols,
                      "in_chunks": list(in_chunks), "out_chunks": list(out_chunks), "order": a.order,
                      "band_width": int(width), "bands": bands, "slice": a.slice, "cache_bytes": cache,
                      "seconds": t7 - t0, "read_seconds": t_read, "transpose_seconds": t_transpose,
                      "write_seconds": t_write, "close_seconds": t6 - t5, "fsync_seconds": t7 - t6,
                      "in_file_bytes": os.path.getsize(a.input), "out_file_bytes": os.path.getsize(a.output),
                      "peak_rss_kib": peak_rss_kib()}))


def cmd_check(a):
    rng = random.Random(12345)
    with h5py.File(a.input, "r") as fin, h5py.File(a.output, "r") as fout:
        din, dout = fin["matrix"], fout["matrix_t"]
        rows, cols = din.shape
        ok = dout.shape == (cols, rows)
        picked = [0, cols - 1] + [rng.randrange(cols) for _ in range(a.samples)]
        bad = []
        for c in picked:
            if not ok:
                break
            if not np.array_equal(dout[c, :], din[:, c]):
                bad.append(c)
        ok = ok and not bad
    print(json.dumps({"mode": "check", "columns_checked": picked, "mismatched_columns": bad, "ok": ok}))
    sys.exit(0 if ok else 1)


def main():
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = p.add_subparsers(dest="mode", required=True)
    c = sub.add_parser("convert")
    c.add_argument("input")
    c.add_argument("--rows", type=int, required=True)
    c.add_argument("--cols", type=int, required=True)
    c.add_argument("--chunks", default="1024x1024")
    t = sub.add_parser("transpose")
    t.add_argument("input")
    t.add_argument("output")
    t.add_argument("--out-chunks", default="1x65536")
    t.add_argument("--band-bytes", default="256MiB")
    t.add_argument("--cache", default="1GiB")
    t.add_argument("--order", choices=["cols", "rows"], default="cols")
    t.add_argument("--slice", type=int, default=0)
    k = sub.add_parser("check")
    k.add_argument("input")
    k.add_argument("output")
    k.add_argument("--samples", type=int, default=6)
    a = p.parse_args()
    {"convert": cmd_convert, "transpose": cmd_transpose, "check": cmd_check}[a.mode](a)


if __name__ == "__main__":
    main()
