"""Reproducers found by the libFuzzer targets (docs/FUZZING.md "Findings"), each run
through ltbake the way a user reaches that reader, with the hostile-input checks
(tests/cli/hostile.py): exit 1, a message naming the file, a time bound and a peak-memory
bound. The bytes are the minimized fuzzer inputs, written here in full.

usage: fuzz_regressions_test.py PATH_TO_LTBAKE
"""
import os
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from hostile import run_hostile, scene_for  # noqa: E402
from ltbtest import check, finish, write  # noqa: E402

# Libraries never print: whatever a reader says reaches the user once, in the error.
MAX_STDERR = 64 << 10




def mesh_case(d, name, data, what):
    with open(os.path.join(d, name), "wb") as f:
        f.write(data)
    scene = scene_for(d, "scene_" + name.replace(".", "_"), name)
    _, err = run_hostile(["sample", scene, "-o", os.path.join(d, "out.ltm"), "--overwrite"], names=[name],
                         time_limit=30, what=what)
    check(len(err) <= MAX_STDERR, f"{what}: {len(err)} bytes on stderr (a reader printing in a loop?)")


def env_case(d, name, data, what):
    path = os.path.join(d, name)
    with open(path, "wb") as f:
        f.write(data)
    run_hostile(["convert", path, os.path.join(d, "env.npy"), "--cube-res", "2"], names=[name], time_limit=30,
                what=what)


def main():
    with tempfile.TemporaryDirectory() as d:
        # obj_fuzzer, 2026-11-25: a face line whose only vertex reference has no vertex
        # index. OpenMesh's OBJ reader asserts (OBJReader.cc:633 `!vhandles.empty()`, the
        # Debian build keeps assertions): ltbake sample aborted with exit 134.
        mesh_case(d, "face-without-vertex.obj", b"f /4", "OBJ 'f /4' (OpenMesh assertion)")
        mesh_case(d, "face-without-vertex-after-valid.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf /4\n",
                  "OBJ valid face then 'f /4'")
        # ply_fuzzer, 2026-11-25: a PLY header that ends (end of file) before end_header.
        # OpenMesh's PLY header loop never sees end of file: it re-reads the last keyword
        # forever, printing "Unsupported keyword : format" to stderr (GBs per minute) and
        # ignoring SIGTERM.
        mesh_case(d, "header-without-end.ply", b"ply\nformat ascii 1.0\n", "PLY header cut after format (hang)")
        mesh_case(d, "binary-header-without-end.ply", b"ply\nformat binary_little_endian 1.0\nelement vertex 1\n",
                  "binary PLY header cut after element (hang)")
        # drc_fuzzer, 2026-11-25: 111 bytes, a Draco mesh whose POSITION attribute is of
        # type DT_BOOL. LoadDraco converts it with ConvertValue<float>, which loads a byte
        # of value 2 as a bool: undefined behaviour (UBSan: draco/attributes/
        # geometry_attribute.h:300 "load of value 2, which is not a valid value for type
        # 'const bool'"), so the ASan tree dies of it; the release build goes on with
        # positions made of bools. Positions that are not numbers must be an error.
        mesh_case(d, "bool-positions.drc", bytes.fromhex(
            "445241434f0202010000231a0b0100000000000080489e7800100000000000000027000028290101000b0100000078"
            "00000000000000000000000b0100000000000080489e780000000000000000003f000028d8d9d8da27000028290101"
            "000b010000007800000000000000000000"), "Draco mesh with bool positions (UB)")
        # exr_fuzzer, 2026-11-25: 15 bytes: the OpenEXR magic, version 2 and an attribute
        # of an unknown (empty) type whose size field says ~2 GB. OpenEXR allocates the
        # attribute (Imf::OpaqueAttribute::readValueFrom, malloc 1-2 GB) before reading it;
        # the read then fails and ltbake reports it (exit 1). The allocation is not touched,
        # so peak RSS stays small; this case guards exit 1, the message and that bound.
        env_case(d, "attribute-size.exr", bytes.fromhex("762f310102000000c700000097ed7b"),
                 "EXR header attribute of ~2 GB declared size")
        # drc_fuzzer, run 6 (2026-11-25 21:40, 10 minutes): Draco headers whose declared counts
        # make the edgebreaker decoder (libdraco, before ltbake sees any data) reserve 5.7 GB
        # (134 bytes: virtual, the release build exits 1 at 11 MB) or decode 409 MB of
        # buffers (548 bytes: 16,843,009 faces declared, libdraco's corner table) before
        # failing. The second was open until the header's counts were checked against the
        # file's size before libdraco runs (stages/mesh/draco_header.cpp, 2026-11-25).
        mesh_case(d, "reserve-5.7g.drc", bytes.fromhex(
            "445241434f0100010110f50100000000002d5555555555555555555555555555555555555555555555555555555555555555"
            "555555555555555555555555555555555555555555555555555555555555555555555555555555555555555555555555555555"
            "555555555555555555555555555555550000002000000000000000"), "Draco header declaring 5.7 GB of connectivity")
        with open(os.path.join(d, "decode-409m.drc"), "wb") as f:
            f.write(bytes.fromhex(
            "445241434f010101010101010101010101010101010101010101010101010101010101010101010101010101010101010101"
            "0101010101010194949494949494190000009494949494949494949494949494949494949494948888888888888888888894"
            "94949494949494949494949494949494949494949494949494949494949494949494949494949494942e9494949494949494"
            "949494888888888888888888888888000000000000001d888888888888888888888888888888888888888888888888888888"
            "8888888888888888888888880202010000001a010001015002020203f80044524143e302020101000002af32da1d00d91cb0"
            "00ffff011044524101f543949494949494949494949494949494949494949494949494949494949494949494949494949494"
            "94949494949494949494949494949494946cf3a6005061000001010101010101010101010101010101010101010101010101"
            "0101010101010101010101010101010101010101010101010101010101010101949494949494949494949494949494949494"
            "9494949494949494949488888888888888888888949494949494949494949494949494949494949494949494949494949494"
            "9494949494949494949494949494949494949494949494888888888888888888888888000000000000001d88888888888888"
            "88888888888888888888888888888888888888888888888888888888888888888888888888be215c234011807ccd9ab8"))
        run_hostile(["sample", scene_for(d, "scene_decode409m", "decode-409m.drc"), "-o", os.path.join(d, "out.ltm"),
                     "--overwrite"], names=["decode-409m.drc"], time_limit=30,
                    what="Draco mesh declaring 16.8M faces in 548 bytes")
        # exr_fuzzer, after CheckExrHeaderSizes (2026-11-25 17:10): 29 bytes each, an
        # attribute "n"/"s" of type chlist with size 0. OpenEXR reads a chlist by its own
        # structure, not by the size field, so its reading and a walk by sizes part ways:
        # OpenEXR then takes later bytes as an attribute (OpaqueAttribute::readValueFrom,
        # malloc ~1.6 GB) or as the image's layout (ScanLineInputFile::ScanLineInputFile,
        # malloc ~1.5 GB) before failing. Exit 1 and small RSS in the release build; the
        # allocations are over the fuzzers' 1 GiB limit.
        env_case(d, "chlist-desync.exr", bytes.fromhex("762f3101020000006e0063686c69737400000000000010000000425959"),
                 "EXR chlist of size 0 (OpenEXR opaque attribute of ~1.6 GB)")
        env_case(d, "chlist-desync-scanline.exr",
                 bytes.fromhex("762f310102000000730063686c6973740000000000000f000000000064"),
                 "EXR chlist of size 0 (OpenEXR scanline tables of ~1.5 GB)")
        # exr_fuzzer, run 6 (2026-11-25 19:56, 10 minutes): headers without a "compression"
        # attribute (its name mangled), so OpenEXR uses its default, ZIP (16 lines a chunk),
        # while the header check took "none" (1 line): a 16.8M x 2 luminance-chroma window
        # (201 bytes) and a 9.1M x 1 RGBA window (247 bytes) made newCompressor allocate
        # 1.07 and 1.17 GB.
        env_case(d, "default-zip-chroma.exr", bytes.fromhex(
            "762f3101020000006368616e6e656c730063686c6973740039000000425900010000000100000002000000020000005259"
            "000100000001000000020000000200000059000100000000000000010000000100000000636f6d707265737369f06f6e00"
            "636f6d7072657373696f6e0001000000046461746157696e646f7700626f783269001000000000000000000000000f0900"
            "0101000000000000010020000178656c41737065637452616e616d653820396039a0ffffffffffffffffffffffffff3ba0"
            "3be03b103c"), "EXR without compression attribute, 16.8M-wide chroma window (ZIP default)")
        env_case(d, "default-zip-rgba.exr", bytes.fromhex(
            "762f3101020000006368616e6e656c730063686c6973740049000000410001000000000000000100000001000000420001"
            "000000000000000100000001000000470001000000000000000100000001000000520001000000000000000100000001000000"
            "006368616e6e656c73696f6e0063526d7072657373696f6e0001000000036461746157696e646f7700626f7832690010000000"
            "000000000000000000008b00000000000000000000000000000000000000000000000000000000000000000000000000000000"
            "000000000000000000000000000000000000000000000000000000000000000000000000000000630000bcbf00"),
            "EXR without compression attribute, 9.1M-wide RGBA window (ZIP default)")
        # hdr_fuzzer, run 5 (2026-11-25 18:20): 498 bytes declaring 6432767 x 32 pixels,
        # whose scanlines are flat pixels followed by old-style repeat records (1 1 1 n, each
        # one shifting the count 8 bits further), so a 16-byte scanline is 6.4M valid pixels:
        # the reader allocated 2.47 GB (and the CLI, within its 1 GiB --mem-limit, decoded
        # 617 MB from 173 bytes for 8 such rows). Written here as that: 8 rows of one pixel
        # and three repeat records.
        w, rows = 6432767, 8
        rest = w - 1
        scan = bytes([128, 64, 32, 129]) + b"".join(bytes([1, 1, 1, (rest >> sh) & 0xFF]) for sh in (0, 8, 16))
        env_case(d, "repeat-bomb.hdr",
                 b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {rows} +X {w}\n".encode() + scan * rows,
                 "HDR of 8 x 6.4M pixels in 128 bytes of old-style repeats (decompression bomb)")
    finish()


if __name__ == "__main__":
    main()
