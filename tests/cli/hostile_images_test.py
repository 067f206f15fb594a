"""Hostile inputs for the image and .npy readers: small hand-made .hdr, .exr and
.npy files driven through `ltbake convert` and `ltbake relight`, each failing with exit 1
(2 for a bad command line), a message naming the file and the field, within a time bound
and a peak-memory bound (tests/cli/hostile.py); SIGTERM/SIGINT during `relight --frames`.

The .npy header cases also ask NumPy itself (np.load) as the oracle: every header NumPy
refuses ltbake refuses, and where both read one they agree on shape and dtype.

usage: hostile_images_test.py PATH_TO_LTBAKE   (run by /usr/bin/python3: needs NumPy)
"""
import os
import signal
import stat
import struct
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest  # noqa: E402
from hostile import SANITIZED, interrupt_while_running, run_hostile  # noqa: E402
from ltbtest import check, finish, run  # noqa: E402

Q = ["--progress", "never"]
# Hang bounds: generous (every case takes well under a second in the release build).
T = 120.0 if SANITIZED else 30.0


# ---- file builders (independent of ltbake's code) -----------------------------------------

def hdr(path, resolution, body=b"", header=b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n"):
    """A Radiance file: header lines, the resolution line, then `body` as pixel data."""
    with open(path, "wb") as f:
        f.write(header + resolution.encode() + b"\n" + body)
    return path


def hdr_flat_repeat_scanline(width):
    """One flat scanline of `width` equal pixels in a few bytes: a pixel, then (1,1,1,n)
    repeat records, the k-th repeating n << 8k pixels (the original Radiance run encoding):
    the base-256 digits of width - 1."""
    out = bytes([128, 128, 128, 129])
    left, shift = width - 1, 0
    while left >> shift:
        out += bytes([1, 1, 1, (left >> shift) & 255])
        shift += 8
    return out


def rle_scanline(width, value=128):
    """A new-style RLE scanline: 2 2 hi lo, then per component runs of up to 127."""
    out = bytes([2, 2, width >> 8, width & 255])
    for comp in range(4):
        left = width
        while left > 0:
            n = min(127, left)
            out += bytes([128 + n, value if comp < 3 else 129])
            left -= n
    return out


def exr_attr(name, typ, data):
    return name.encode() + b"\0" + typ.encode() + b"\0" + struct.pack("<i", len(data)) + data


EXR_LINES = {0: 1, 1: 1, 2: 1, 3: 16, 4: 32, 9: 256}  # lines per chunk: NONE RLE ZIPS ZIP PIZ ... DWAB


def exr_header_only(window, channels="BGR", compression=0, tiles=None):
    """An OpenEXR header (scanline, or tiled with `tiles` = (x, y)) declaring `window`,
    followed by an offset table of 8 entries and nothing else: what a few hundred bytes can
    make OpenEXR allocate before it reads any pixel."""
    ch = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in channels) + b"\0"
    head = b"\x76\x2f\x31\x01" + struct.pack("<I", 2 | (0x200 if tiles else 0))
    head += exr_attr("channels", "chlist", ch)
    if compression is not None:  # None: no attribute (OpenEXR then uses ZIP)
        head += exr_attr("compression", "compression", bytes([compression]))
    head += exr_attr("dataWindow", "box2i", struct.pack("<4i", *window))
    head += exr_attr("displayWindow", "box2i", struct.pack("<4i", *window))
    head += exr_attr("lineOrder", "lineOrder", b"\0") + exr_attr("pixelAspectRatio", "float", struct.pack("<f", 1))
    head += exr_attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
    head += exr_attr("screenWindowWidth", "float", struct.pack("<f", 1))
    if tiles:
        head += exr_attr("tiles", "tiledesc", struct.pack("<IIB", tiles[0], tiles[1], 0))
    return head + b"\0" + struct.pack("<8Q", *([len(head) + 1 + 64] * 8))


def exr(w, h, value=(1.0, 0.5, 0.25), window=None, compression=3, channels="BGR", truncate=None):
    """A scanline float OpenEXR file laid out by hand (docs: openexr.com, "OpenEXR File
    Layout"): magic, version 2, the header attributes, the chunk offset table, then chunks
    (y, size, data). Chunks are stored at their uncompressed size, which OpenEXR reads as
    uncompressed for every compression. `window` patches the data window after the fact."""
    ch = b"".join(c.encode() + b"\0" + struct.pack("<iB3xii", 2, 0, 1, 1) for c in channels) + b"\0"
    dw = window or (0, 0, w - 1, h - 1)
    head = b"\x76\x2f\x31\x01" + struct.pack("<I", 2)
    head += exr_attr("channels", "chlist", ch) + exr_attr("compression", "compression", bytes([compression]))
    head += exr_attr("dataWindow", "box2i", struct.pack("<4i", *dw))
    head += exr_attr("displayWindow", "box2i", struct.pack("<4i", 0, 0, w - 1, h - 1))
    head += exr_attr("lineOrder", "lineOrder", b"\0") + exr_attr("pixelAspectRatio", "float", struct.pack("<f", 1))
    head += exr_attr("screenWindowCenter", "v2f", struct.pack("<2f", 0, 0))
    head += exr_attr("screenWindowWidth", "float", struct.pack("<f", 1)) + b"\0"
    n = EXR_LINES[compression]
    vals = {"R": value[0], "G": value[1], "B": value[2]}
    chunks = []
    for y0 in range(0, h, n):
        data = b""
        for _ in range(y0, min(h, y0 + n)):
            for c in channels:
                data += struct.pack("<%df" % w, *([vals.get(c, 1.0)] * w))
        chunks.append(struct.pack("<ii", y0, len(data)) + data)
    off = len(head) + 8 * len(chunks)
    table = b""
    for c in chunks:
        table += struct.pack("<Q", off)
        off += len(c)
    out = head + table + b"".join(chunks)
    return out[:truncate] if truncate else out


def npy_bytes(header_text, data=b"", version=(1, 0), pad=True):
    """A .npy file with this literal header text (padded as NumPy pads it)."""
    text = header_text.encode("latin1" if version[0] < 3 else "utf8")
    prefix = 10 if version[0] == 1 else 12
    if pad:
        total = -(-(prefix + len(text) + 1) // 64) * 64
        text = text + b" " * (total - prefix - len(text) - 1) + b"\n"
    length = struct.pack("<H", len(text)) if version[0] == 1 else struct.pack("<I", len(text))
    return b"\x93NUMPY" + bytes(version) + length + text + data


def write(path, data):
    with open(path, "wb") as f:
        f.write(data)
    return path


def mib(path):
    """The size of a regular file in MiB (0 for anything else)."""
    return os.path.getsize(path) / 2**20 if os.path.isfile(path) else 0.0


with tempfile.TemporaryDirectory() as d:
    p = lambda name: os.path.join(d, name)  # noqa: E731

    # ---- Radiance .hdr through `convert` --------------------------------------------------
    def convert_env(path, names, expect=(1,), extra=(), what=None, extra_mib=0):
        out = p("out.npy")
        if os.path.exists(out):
            os.remove(out)
        code, err = run_hostile(["convert", path, out, "--cube-res", 4, *Q, *extra], names=names, expect=expect,
                                time_limit=T, extra_mib=2 * mib(path) + extra_mib, what=what)
        check(not os.path.exists(out), f"{what or path}: a failed convert left {out}")
        check(not os.path.exists(out + ".partial"), f"{what or path}: a failed convert left {out}.partial")
        return code, err

    # Width × height wraps around 2^64 (to 4 and to 0): the heap overflow a hostile-input sweep found (docs/FUZZING.md).
    for w, h in [(2**62 + 1, 4), (2**33, 2**31), (2**63, 2)]:
        f = hdr(p(f"wrap_{w}_{h}.hdr"), f"-Y {h} +X {w}", rle_scanline(8) * 4)
        convert_env(f, [f, "resolution line", str(w), "beyond"], what=f"hdr {w} x {h} (wraps)")
    # 2^32 × 2^32 (threw bad_alloc) and other sizes beyond the cap.
    f = hdr(p("huge.hdr"), "-Y 4294967296 +X 4294967296", bytes(64))
    convert_env(f, [f, "4294967296x4294967296", "beyond"], what="hdr 2^32 x 2^32")
    f = hdr(p("cap.hdr"), "-Y 16385 +X 16384", bytes(64))
    convert_env(f, [f, "16384x16385", "beyond"], what="hdr one row past the cap")
    # A 1 KB file declaring 16384²: refused before any pixel buffer (a scanline takes >= 4 bytes).
    f = hdr(p("small_big.hdr"), "-Y 16384 +X 16384", bytes(1000))
    convert_env(f, [f, "16384 scanlines", "1000 bytes of pixel data"], what="1 KB hdr declaring 16384^2")
    # Numbers that are not sizes.
    for i, res in enumerate(["-Y -5 +X 10", "-Y 0 +X 10", "-Y 99999999999999999999 +X 1", "-Y 0x10 +X 32",
                             "-Y 8 +X 16 extra", "-Y 8 +X", "-Y 8 +X 1e3"]):
        f = hdr(p(f"res{i}.hdr"), res, rle_scanline(16) * 8)
        convert_env(f, [f, "resolution line"], what=f"hdr resolution {res!r}")
    f = hdr(p("transposed.hdr"), "+X 16 -Y 8", rle_scanline(16) * 8)
    convert_env(f, [f, "orientation", "+X 16 -Y 8"], what="hdr transposed orientation")
    f = hdr(p("xyze.hdr"), "-Y 8 +X 16", rle_scanline(16) * 8, header=b"#?RADIANCE\nFORMAT=32-bit_rle_xyze\n\n")
    convert_env(f, [f, "32-bit_rle_xyze"], what="hdr XYZE format")
    f = write(p("noblank.hdr"), b"#?RADIANCE\n" + b"X=1\n" * 20000)
    convert_env(f, [f, "blank line"], what="hdr header without its blank line")
    f = write(p("sig_only.hdr"), b"#?")
    convert_env(f, [f, "signature"], what="hdr with only '#?'")
    # Truncated and damaged run-length data.
    good = rle_scanline(16) * 8
    for cut in (3, 9, len(good) // 2, len(good) - 1):
        f = hdr(p(f"trunc{cut}.hdr"), "-Y 8 +X 16", good[:cut])
        convert_env(f, [f, "scanline"], what=f"hdr RLE data cut at {cut}")
    bad_width = bytes([2, 2, 0, 17]) + rle_scanline(16)[4:]
    f = hdr(p("rle_width.hdr"), "-Y 8 +X 16", bad_width + good)
    convert_env(f, [f, "scanline 0", "says 17 pixels", "16 wide"], what="hdr RLE header width mismatch")
    overrun = bytes([2, 2, 0, 16, 128 + 127, 1]) + good
    f = hdr(p("rle_run.hdr"), "-Y 8 +X 16", overrun)
    convert_env(f, [f, "scanline 0", "a run of 127 overflows"], what="hdr RLE run past the width")
    zero_lit = bytes([2, 2, 0, 16, 0]) + good
    f = hdr(p("rle_zero.hdr"), "-Y 8 +X 16", zero_lit)
    convert_env(f, [f, "scanline 0", "literal of 0"], what="hdr RLE zero-length literal")
    f = hdr(p("flat_rep.hdr"), "-Y 1 +X 4", bytes([1, 1, 1, 9]) * 4)
    convert_env(f, [f, "scanline 0", "repeat record"], what="hdr flat repeat without a pixel")
    f = hdr(p("flat_rep_over.hdr"), "-Y 2 +X 4", bytes([5, 5, 5, 128, 1, 1, 1, 200]) * 2)
    convert_env(f, [f, "scanline 0", "repeat of 200 overflows"], what="hdr flat repeat past the width")
    # Tiny and huge: 8192 flat scanlines of 16384 equal pixels in 16 bytes each (128 KiB,
    # 1024 pixels per byte) would decode to 1.5 GiB: refused before allocating, as denser
    # than any writer makes (Radiance's run-length coding holds ~16 pixels per byte).
    f = hdr(p("repeats.hdr"), "-Y 8192 +X 16384", hdr_flat_repeat_scanline(16384) * 8192)
    convert_env(f, [f, "16384x8192", "pixels per byte"], what="hdr 1.5 GiB of repeat records")
    f = hdr(p("repeats_small.hdr"), "-Y 512 +X 1024", hdr_flat_repeat_scanline(1024) * 512)
    convert_env(f, [f, "1024x512", "memory limit", "--mem-limit"], extra=["--mem-limit", "2MiB"],
                what="hdr 6 MiB of pixels under --mem-limit 2MiB")
    # ... and read when the limit allows (the same file, valid): every pixel 128·2^(129-136).
    code, _ = run_hostile(["convert", f, p("ok.npy"), "--cube-res", 4, *Q], expect=(0,), time_limit=T,
                          extra_mib=6 + 2, what="hdr of repeat records within the limit")
    if code == 0:
        cube = np.load(p("ok.npy"))
        check(np.allclose(cube, 1.0, rtol=1e-5), f"repeat-record hdr decoded to {cube.min()}..{cube.max()}, not 1.0")

    # A square map (a light probe, most likely) is refused by auto-detection, naming what it
    # probably is, and the message must not point at --env-layout latlong as the way out.
    f = hdr(p("probe.hdr"), "-Y 16 +X 16", rle_scanline(16) * 16)
    _, err = convert_env(f, [f, "16x16", "angular", "mirror-ball", "lat-long first"], what="square .hdr (a probe?)")
    check("--env-layout latlong reads" not in err, f"square map: the message suggests latlong: {err}")
    f = hdr(p("odd.hdr"), "-Y 10 +X 16", rle_scanline(16) * 10)
    convert_env(f, [f, "16x10", "--env-layout latlong reads a lat-long map"], what="16x10 .hdr")

    # ---- OpenEXR ----------------------------------------------------------------------
    write(p("ok.exr"), exr(64, 32))
    code, _ = run_hostile(["convert", p("ok.exr"), p("ok_exr.npy"), "--cube-res", 4, *Q], expect=(0,), time_limit=T,
                          what="hand-made exr (valid)")
    if code == 0:
        cube = np.load(p("ok_exr.npy"))
        check(np.allclose(cube, [1.0, 0.5, 0.25], rtol=1e-5), "hand-made exr: wrong cubemap values")
    # A 15-25 KB file whose data window was patched to 16384² (ZIP, PIZ chunking): used to
    # allocate 3 GiB and spend 30 s; now fails at the first strip of rows.
    # Under the default --mem-limit (1 GiB) the 3 GiB it declares is refused up front; with
    # room for it, the first strip of rows fails (its chunks are not in the file).
    for comp in (3, 4):
        f = write(p(f"win{comp}.exr"), exr(64, 32, window=(0, 0, 16383, 16383), compression=comp))
        convert_env(f, [f, "16384x16384", "memory limit"], what=f"exr window 16384^2 ({comp})")
        convert_env(f, [f, "data window (0, 0) - (16383, 16383)", "rows 0.."], extra=["--mem-limit", "4GiB"],
                    what=f"exr window 16384^2 ({comp}), --mem-limit 4GiB")
    f = write(p("win_neg.exr"), exr(64, 32, window=(-8192, -8192, 8191, 8191)))
    convert_env(f, [f, "data window (-8192, -8192) - (8191, 8191)"], extra=["--mem-limit", "4GiB"],
                what="exr window centred, 16384^2")
    f = write(p("win_tall.exr"), exr(64, 32, window=(0, 0, 0, 2**28 - 1), compression=4))
    convert_env(f, [f], what="exr window 1 x 2^28")
    f = write(p("win_wide.exr"), exr(64, 32, window=(0, 0, 2**28 - 1, 0), compression=4))
    convert_env(f, [f], what="exr window 2^28 x 1")
    f = write(p("win_cap.exr"), exr(64, 32, window=(0, 0, 32767, 32767), compression=4))
    convert_env(f, [f, "beyond 268435456 pixels"], what="exr window 32768^2 (past the cap)")
    f = write(p("win_inv.exr"), exr(64, 32, window=(10, 10, 0, 0)))
    convert_env(f, [f], what="exr inverted data window")
    f = write(p("win_max.exr"), exr(64, 32, window=(-2**31, -2**31, 2**31 - 1, 2**31 - 1)))
    convert_env(f, [f], what="exr window of the whole int range")
    # exr_fuzzer run 5: OpenEXR sizes its chunk offset table and one block of lines (or one
    # tile, with its compressor's buffers) from the header alone, as it opens the file. A
    # 1 x 2^30 window without compression declares 2^30 chunks (an 8 GiB offset table) in a
    # 400-byte file; a DWAB block of 256 lines of a 2^20-wide window is 3 GiB (9 GiB with the
    # compressor's buffers); a 65536² tile 48 GiB. Each is refused from the header walk, naming what it declares.
    f = write(p("table.exr"), exr_header_only((0, 0, 0, 2**30 - 1)))
    convert_env(f, [f, "1x1073741824", "chunk offset table", "8589934592 bytes"], what="exr 8 GiB offset table")
    f = write(p("dwab.exr"), exr_header_only((0, 0, 2**20 - 1, 0), compression=9))
    convert_env(f, [f, "1048576x1", "block of 256 lines", "9216.0 MiB", "512.0 MiB ltbake allows"],
                what="exr DWAB block of 3 GiB")
    # Without a compression attribute OpenEXR reads ZIP blocks of 16 lines (exr_fuzzer run 6).
    f = write(p("nocomp.exr"), exr_header_only((0, 0, 2**23 - 1, 0), compression=None))
    convert_env(f, [f, "8388608x1", "block of 16 lines", "4608.0 MiB"], what="exr without compression attribute")
    # Luminance-chroma: RgbaInputFile keeps ~32 Rgba lines of the window's width (run 6).
    f = write(p("yc.exr"), exr_header_only((0, 0, 2**22 - 1, 0), channels=("Y", "RY", "BY")))
    convert_env(f, [f, "4194304x1", "luminance-chroma", "1024.0 MiB"], what="exr luminance-chroma 2^22 wide")
    f = write(p("tile.exr"), exr_header_only((0, 0, 63, 31), tiles=(65536, 65536)))
    convert_env(f, [f, "tile of 65536x65536"], what="exr tile of 65536^2")
    # Sizes past 2^64 (exr_fuzzer run 7: their conversion to an integer for the message was
    # undefined behaviour, which the sanitizer tree reports): a tile of (2^32 - 1)², and
    # 2^64 tiles of 1x1 over the whole int range.
    f = write(p("tile_max.exr"), exr_header_only((0, 0, 63, 31), tiles=(2**32 - 1, 2**32 - 1)))
    convert_env(f, [f, "tile of 4294967295x4294967295"], what="exr tile of (2^32-1)^2")
    f = write(p("tiles_2_64.exr"), exr_header_only((-2**31, -2**31, 2**31 - 1, 2**31 - 1), tiles=(1, 1)))
    convert_env(f, [f, "1.845e+19 chunks", "chunk offset table"], what="exr 2^64 tiles")
    # ... and a 2^20-wide, one-row Y map: ltbake's own strip buffers were sized for 256
    # rows (1 GiB of scratch for one row, refused by --mem-limit); now for the rows there are. Refused only for its
    # missing pixels, not for memory.
    f = write(p("wide_y.exr"), exr_header_only((0, 0, 2**20 - 1, 0), channels="Y"))
    # Justified: the RGB floats of the row (12 MiB), a strip of Y (4 MiB), OpenEXR's line (4 MiB).
    _, err = convert_env(f, [f], what="exr Y map 2^20 x 1", extra_mib=20)
    check("memory" not in err, f"exr Y map 2^20 x 1: refused for memory, not for its missing pixels: {err[-300:]}")
    # exr_fuzzer's finding: an attribute declaring ~2 GB in a 15-byte file (OpenEXR
    # allocated the declared size before reading); refused from the header walk.
    f = write(p("attr2g.exr"), b"\x76\x2f\x31\x01\x02\x00\x00\x00a\x00\x00\xff\xff\xff\x7f")
    convert_env(f, [f, 'attribute "a"', "2147483647 bytes"], what="exr attribute size past the file")
    for cut in (8, 60, 300, 2000, len(exr(64, 32)) - 10):
        f = write(p(f"cut{cut}.exr"), exr(64, 32, truncate=cut))
        convert_env(f, [f], what=f"exr truncated at {cut}")
    f = write(p("z.exr"), exr(64, 32, channels="Z"))
    convert_env(f, [f, "channels Z"], what="exr without R, G, B or Y")
    f = write(p("magic_only.exr"), b"\x76\x2f\x31\x01" + bytes(200))
    convert_env(f, [f, "OpenEXR"], what="exr magic then zeros")
    f = write(p("empty.exr"), b"")
    convert_env(f, [f, "empty"], what="empty .exr")
    f = write(p("text.exr"), b"hello, not an image\n")
    convert_env(f, [f, "neither the OpenEXR magic"], what="text named .exr")

    # ---- not regular files: refused without blocking -----------------------------------
    fifo = p("fifo.hdr")
    os.mkfifo(fifo)
    convert_env(fifo, [fifo, "FIFO"], what="convert from a FIFO")
    os.mkdir(p("dir.exr"))
    convert_env(p("dir.exr"), [p("dir.exr"), "directory"], what="convert from a directory")
    convert_env(p("absent.hdr"), [p("absent.hdr"), "no such file"], what="convert from a missing file")
    convert_env(p("{face}_absent.exr"), [p("px_absent.exr"), "no such file"], what="six faces, first missing")
    # Six faces, one of them hostile.
    for face in ("px", "nx", "py", "ny", "pz"):
        write(p(f"f_{face}.exr"), exr(8, 8))
    write(p("f_nz.exr"), exr(8, 8, window=(0, 0, 16383, 16383)))
    convert_env(p("f_{face}.exr"), [p("f_nz.exr"), "OpenEXR"], what="six faces, -Z patched to 16384^2")
    hdr(p("g_px.hdr"), "-Y 4294967296 +X 4294967296", bytes(64))
    convert_env(p("g_{face}.hdr"), [p("g_px.hdr"), "beyond"], what="six faces, +X 2^32 x 2^32")

    # ---- .npy headers: convert (.npy -> .ltm) and relight --env ------------------------
    data16 = np.arange(16, dtype="<f4").tobytes()

    def convert_npy(name, header, data=data16, names=(), version=(1, 0), pad=True, what=None):
        f = write(p(name), npy_bytes(header, data, version, pad))
        out = p("npy_out.ltm")
        code, err = run_hostile(["convert", f, out, *Q], names=[f, *names], time_limit=T,
                                extra_mib=2 * mib(f), what=what or f"npy header {header!r}")
        check(not os.path.exists(out), f"{what or header}: a failed convert left {out}")
        return code, err

    # A decoy: 'shape' inside another key's string (NumPy refuses the file).
    convert_npy("decoy1.npy", "{'descr': \"<f4 'shape': (1, 16), \", 'fortran_order': False, 'shape': (4, 4), }",
                names=["dtype", "<f4 'shape': (1, 16)"], what="npy decoy 'shape' inside descr")
    convert_npy("decoy2.npy", "{'descr': '<f4', 'x': \"'shape': (1, 16)\", 'fortran_order': False, 'shape': (4, 4), }",
                names=["'x'"], what="npy decoy 'shape' inside an extra key")
    convert_npy("decoy3.npy", "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 'shape': (1, 16), }",
                names=["'shape'", "twice"], what="npy 'shape' given twice")
    # (2^40, 2^40) f4: "needs 0 bytes" before; checked arithmetic now.
    convert_npy("huge.npy", "{'descr': '<f4', 'fortran_order': False, 'shape': (1099511627776, 1099511627776), }",
                names=["1099511627776", "2^64"], what="npy shape (2^40, 2^40)")
    convert_npy("big.npy", "{'descr': '<f8', 'fortran_order': False, 'shape': (1048576, 1048576), }",
                names=["1048576", "8796093022208 bytes"], what="npy shape (2^20, 2^20) in a small file")
    for i, (header, names) in enumerate([
        ("{'descr': '>f4', 'fortran_order': False, 'shape': (4, 4), }", ["'>f4'"]),
        ("{'descr': '<i4', 'fortran_order': False, 'shape': (4, 4), }", ["'<i4'"]),
        ("{'descr': '|O', 'fortran_order': False, 'shape': (4, 4), }", ["'|O'"]),
        ("{'descr': [('a', '<f4')], 'fortran_order': False, 'shape': (4, 4), }", ["[('a', '<f4')]"]),
        ("{'descr': '<f4', 'fortran_order': 1, 'shape': (4, 4), }", ["fortran_order", "1"]),
        ("{'descr': '<f4', 'fortran_order': True, 'shape': (4, 4), }", ["Fortran"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': [4, 4], }", ["'shape'", "[4, 4]"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': 16, }", ["'shape'", "16"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, -4), }", ["'shape'", "-4", "negative"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4.0), }", ["'shape'", "4.0"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 99999999999999999999), }", ["2^64"]),
        ("{'descr': '<f4', 'fortran_order': False, }", ["'shape'"]),
        ("{'descr': '<f4', 'shape': (4, 4), }", ["fortran_order"]),
        ("{'fortran_order': False, 'shape': (4, 4), }", ["descr"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 'extra': 0}", ["'extra'"]),
        ("{b'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }", ["b'descr'"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), ", ["unterminated"]),
        ("{'descr': '<f4, 'fortran_order': False, 'shape': (4, 4), }", ["Python literal"]),
        ("['descr', '<f4']", ["not a dictionary"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), } trailing", ["after the dictionary"]),
        ("{'descr': '<f4', 'fortran_order': false, 'shape': (4, 4), }", ["false"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (" + "(" * 200 + "4" + ")" * 200 + ", 4), }",
         ["nesting"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4)}\0", ["NUL"]),
        ("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 04), }", ["leading zeros"]),
    ]):
        convert_npy(f"h{i}.npy", header, names=names)
    ok_header = "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }"
    convert_npy("v11.npy", ok_header, version=(1, 1), names=["version 1.1"])
    convert_npy("v40.npy", ok_header, version=(4, 0), names=["version 4.0"])
    f = write(p("hlen.npy"), b"\x93NUMPY\x01\x00\xff\xff{'descr'")
    run_hostile(["convert", f, p("x.ltm"), *Q], names=[f, "65545 bytes"], time_limit=T, what="npy header length past EOF")
    f = write(p("hlen2.npy"), b"\x93NUMPY\x02\x00\xff\xff\xff\x7f{'descr'")
    run_hostile(["convert", f, p("x.ltm"), *Q], names=[f, "2147483647"], time_limit=T, what="npy v2 header length 2^31")
    f = write(p("short.npy"), npy_bytes(ok_header, data16[:-4]))
    run_hostile(["convert", f, p("x.ltm"), *Q], names=[f, "64 bytes of data"], time_limit=T, what="npy data cut short")
    f = write(p("utf8.npy"), npy_bytes(ok_header, data16, version=(3, 0))[:-len(data16) - 2] + b"\xff\n" + data16)
    run_hostile(["convert", f, p("x.ltm"), *Q], names=[f, "UTF-8"], time_limit=T, what="npy 3.0 header not UTF-8")
    os.mkfifo(p("fifo.npy"))
    run_hostile(["convert", p("fifo.npy"), p("x.ltm"), *Q], names=[p("fifo.npy"), "FIFO"], time_limit=T,
                what="npy from a FIFO")

    # NumPy as the oracle: what np.load refuses, ltbake refuses; what both read agrees.
    oracle = [
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }",
        "{\"descr\": \"<f4\", \"fortran_order\": False, \"shape\": (4, 4)}",
        "{'shape': (4, 4), 'fortran_order': False, 'descr': '<f4'}",
        "{'descr': '<' 'f4', 'fortran_order': False, 'shape': (4, 4), }",
        "{'descr': u'<f4', 'fortran_order': False, 'shape': ((4), 4,), }",
        "{'descr': '\\x3cf4', 'fortran_order': False, 'shape': (0x4, 0o4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4L, 4L), }",
        "{'descr': '<f4', # a comment\n 'fortran_order': False,\n 'shape': (4, 4), }",
        "{'descr': r'<f4', 'fortran_order': False, 'shape': (2, 8), }",
        "{'descr': '''<f4''', 'fortran_order': False, 'shape': (16, 1), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1_6, 1), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (+4, 4), }",
        "{'descr': \"<f4 'shape': (1, 16)\", 'fortran_order': False, 'shape': (4, 4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 'x': 1}",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4),, }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4 4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }}",
        "{'descr': '<f4', 'fortran_order': 0, 'shape': (4, 4), }",
        "{'descr': '<f4', 'fortran_order': None, 'shape': (4, 4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, '4'), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4j), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 1_), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 3: 4}",
        "{'descr': f'<f4', 'fortran_order': False, 'shape': (4, 4), }",
        "{'descr': b'<f4' '', 'fortran_order': False, 'shape': (4, 4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }\n\n",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), } # end",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), } ; 1",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, --4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, -0), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (16,), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (1, 4, 4), }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': {4, 4}, }",
        "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }\\\n",
        "  {'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }",
    ]
    for i, header in enumerate(oracle):
        for version in ((1, 0), (3, 0)):
            f = write(p(f"o{i}_{version[0]}.npy"), npy_bytes(header, data16, version))
            try:
                a = np.load(f, allow_pickle=False)
                numpy_reads = a.ndim == 2 and a.dtype == np.dtype("<f4") and not np.isfortran(a)
                shape = a.shape
            except Exception:  # noqa: BLE001 - NumPy refuses it, for any reason
                numpy_reads, shape = False, None
            out = p(f"o{i}_{version[0]}.ltm")
            r = run("convert", f, out, *Q, expect=None)
            check(r.returncode in (0, 1), f"oracle {header!r} v{version}: exit {r.returncode}\n{r.stderr}")
            if not numpy_reads:
                check(r.returncode == 1, f"oracle {header!r} v{version}: NumPy refuses it, ltbake read it")
                check(f in r.stderr, f"oracle {header!r}: the message does not name the file:\n{r.stderr}")
            elif r.returncode == 0:
                back = p(f"o{i}_{version[0]}_back.npy")
                run("convert", out, back, *Q)
                b = np.load(back)
                check(b.shape == shape and np.array_equal(b.reshape(-1), np.arange(16, dtype=np.float32)),
                      f"oracle {header!r}: NumPy reads {shape}, ltbake {b.shape}")
            else:
                print(f"note: NumPy reads {header!r} (v{version}) as {shape}; ltbake refuses: {r.stderr.strip()}")

    # ---- relight: env maps and cubemaps ----------------------------------------------
    W, H, R = 16, 8, 4
    g = np.random.default_rng(5)
    T_ = g.uniform(0, 1, (W * H, 6 * R * R)).astype(np.float32)
    np.save(p("T.npy"), T_)
    run("convert", p("T.npy"), p("raw.ltm"), "--cube-res", R, "--image", f"{W}x{H}", "--chunk-size", "4KiB", *Q)
    run("row-transform", p("raw.ltm"), "-o", p("rows.ltm"), "--filter", "haar", *Q)
    run("transpose", p("rows.ltm"), "-o", p("cols.ltm"), *Q)
    good_env = p("env.npy")
    np.save(good_env, g.uniform(0, 1, (6 * R * R, 3)).astype(np.float32))

    def relight_env(env, names, what, extra=()):
        out = p("relit.exr")
        if os.path.exists(out):
            os.remove(out)
        run_hostile(["relight", p("cols.ltm"), "--env", env, "-o", out, *Q, *extra], names=[env, *names],
                    time_limit=T, extra_mib=2 * mib(env), what=what)
        check(not os.path.exists(out), f"{what}: a failed relight wrote {out}")

    relight_env(p("wrap_4611686018427387905_4.hdr"), ["beyond"], "relight --env hdr whose size wraps")
    relight_env(p("huge.hdr"), ["beyond"], "relight --env hdr 2^32 x 2^32")
    relight_env(p("small_big.hdr"), ["16384 scanlines"], "relight --env 1 KB hdr declaring 16384^2")
    relight_env(p("repeats.hdr"), ["pixels per byte"], "relight --env hdr of 1.5 GiB repeat records")
    relight_env(p("win3.exr"), ["16384x16384", "memory limit"], "relight --env exr window patched to 16384^2")
    relight_env(p("win3.exr"), ["data window"], "relight --env exr window patched to 16384^2, --mem-limit 4GiB",
                extra=["--mem-limit", "4GiB"])
    relight_env(p("fifo.hdr"), ["FIFO"], "relight --env FIFO")
    relight_env(p("decoy1.npy"), ["<f4 'shape': (1, 16)"], "relight --env decoy npy")
    relight_env(p("huge.npy"), ["(1099511627776, 1099511627776)", "(96, 3)"], "relight --env npy (2^40, 2^40)")
    relight_env(p("fifo.npy"), ["FIFO"], "relight --env npy FIFO")
    f = write(p("cube_short.npy"), npy_bytes(f"{{'descr': '<f4', 'fortran_order': False, 'shape': ({6 * R * R}, 3), }}",
                                             bytes(100)))
    relight_env(f, ["truncated", "1152 bytes"], "relight --env cubemap npy cut short")
    f = write(p("cube_shape.npy"), npy_bytes("{'descr': '<f4', 'fortran_order': False, 'shape': (96, 4), }",
                                             bytes(96 * 16)))
    relight_env(f, ["(96, 4)", "(96, 3)"], "relight --env cubemap npy of the wrong shape")

    # ---- signals: relight --frames stops on SIGTERM / SIGINT ------------------------
    for matrix in ("cols.ltm", "raw.ltm"):  # in memory; streamed every frame
        for sig in (signal.SIGTERM, signal.SIGINT):
            out = p(f"frames_{matrix}_{sig.name}.npy")
            code, err = interrupt_while_running(
                ["relight", p(matrix), "--env", good_env, "-o", out, "--frames", 1 << 20, *Q],
                ready=lambda out=out: os.path.exists(out), sig=sig, time_limit=T,
                what=f"relight {matrix} --frames, {sig.name}")
            check(code == (143 if sig == signal.SIGTERM else 130), f"relight {matrix} --frames {sig.name}: exit {code}")
            check("interrupted" in err, f"relight {matrix} --frames {sig.name}: no word of the interruption:\n{err}")

finish()
