"""Independent re-implementations (NumPy + xxhash) of what the tests check ltbake against.

content_hash follows docs/FORMAT.md "content_hash" literally; it shares no code with the C++.
"""
import numpy as np
import struct
import xxhash

K1 = np.uint64(0x9E3779B97F4A7C15)
K2 = np.uint64(0xC2B2AE3D27D4EB4F)
K3 = np.uint64(0x165667B19E3779F9)
SEED = np.uint64(0x27D4EB2F165667C5)
M1 = np.uint64(0xFF51AFD7ED558CCD)
M2 = np.uint64(0xC4CEB9FE1A85EC53)
S33 = np.uint64(33)
DTYPE_CODE = {"f32": 0, "f64": 1, "u8": 2, "i32": 3, "u32": 4, "u64": 5}


def fmix64(k):
    k = k ^ (k >> S33)
    k = k * M1
    k = k ^ (k >> S33)
    k = k * M2
    k = k ^ (k >> S33)
    return k


def content_hash(matrix, dtype="f32"):
    """The .ltm content_hash of a 2-D array (f32 by default), as 16 hex digits."""
    a = np.ascontiguousarray(matrix, dtype=np.float32 if dtype == "f32" else None)
    rows, cols = a.shape
    bits = a.view(np.uint32).astype(np.uint64) if a.itemsize == 4 else a.view(np.uint64)
    total = np.uint64(0)
    with np.errstate(over="ignore"):
        j = np.arange(cols, dtype=np.uint64)
        for i in range(rows):
            rk = fmix64((np.uint64(i) * K1) ^ SEED)
            u = bits[i]
            h = fmix64((rk + j * K2) ^ (u * K3))
            h[u == 0] = 0
            total = total + np.sum(h, dtype=np.uint64)
    record = b"LTMCH1\0\0" + struct.pack("<QQQQ", DTYPE_CODE[dtype], rows, cols, int(total))
    return xxhash.xxh3_64_hexdigest(record)
