"""`import ltbake` against the ltbake command on the same files (docs/PYTHON.md)."""
import json
import os
import shutil
import subprocess
import tracemalloc

import numpy as np
import pytest

import ltbake
from conftest import Q, REPO, cli, cli_inspect, cli_npy, ltbtest


def bits(a):
    """Bit patterns, so equality is exact (NaN and -0.0 included)."""
    a = np.ascontiguousarray(a)
    return a.view({4: np.uint32, 8: np.uint64, 1: np.uint8}[a.dtype.itemsize])


# --- reading: every kind the stages write, against `ltbake convert` -------------------------
def test_dense_kinds_read_like_convert(bake, dense):
    rng = np.random.default_rng(1)
    for name, path in dense.items():
        ref = cli_npy(path, bake["dir"])
        with ltbake.open(path) as c:
            assert c.shape == ref.shape and c.dtype == np.float32, name
            assert np.array_equal(bits(c.read(force=True)), bits(ref)), f"{name}: whole matrix"
            assert np.array_equal(bits(c[:, :]), bits(ref)), name
            for _ in range(6):
                i0, i1 = sorted(rng.integers(0, ref.shape[0], 2))
                j0, j1 = sorted(rng.integers(0, ref.shape[1], 2))
                i, j = int(rng.integers(0, ref.shape[0])), int(rng.integers(0, ref.shape[1]))
                assert np.array_equal(bits(c[i0:i1 + 1, :]), bits(ref[i0:i1 + 1, :])), f"{name} rows {i0}:{i1 + 1}"
                assert np.array_equal(bits(c[:, j0:j1 + 1]), bits(ref[:, j0:j1 + 1])), f"{name} cols {j0}:{j1 + 1}"
                assert np.array_equal(bits(c[i]), bits(ref[i])), f"{name} row {i}"
                assert np.array_equal(bits(c[:, j]), bits(ref[:, j])), f"{name} col {j}"
                assert bits(c[i, j]) == bits(ref[i, j])
                assert np.array_equal(bits(c[i0:i1 + 1, j0:j1 + 1]), bits(ref[i0:i1 + 1, j0:j1 + 1]))
                assert np.array_equal(bits(c[-1]), bits(ref[-1]))
            assert np.array_equal(bits(c[::7, 3:50:5]), bits(ref[::7, 3:50:5])), name
            assert np.array_equal(bits(c[::-3, ::-11]), bits(ref[::-3, ::-11])), name
            assert c[5:5, :].shape == (0, ref.shape[1])
            # Streaming: the chunks put back together are the matrix.
            out = np.zeros_like(ref)
            for rng_, block in c.iter_chunks():
                if c.layout == "rows":
                    out[rng_.start:rng_.stop] = block
                else:
                    out[:, rng_.start:rng_.stop] = block
            assert np.array_equal(bits(out), bits(ref)), f"{name}: iter_chunks"
            with pytest.raises(IndexError):
                c[ref.shape[0], 0]
            with pytest.raises(TypeError):
                c[[1, 2], :]


def test_numpy_protocol_like_h5py(dense, bake):
    """np.asarray, ..., len, ndim, size and .attrs, as h5py and zarr datasets have them, against
    the command's convert of the same file."""
    for name, path in dense.items():
        ref = cli_npy(path, bake["dir"])
        with ltbake.open(path) as c:
            assert len(c) == ref.shape[0] and c.ndim == 2 and c.size == ref.size, name
            assert np.array_equal(bits(np.asarray(c)), bits(ref)), f"{name}: np.asarray"
            assert np.asarray(c, dtype=np.float64).dtype == np.float64
            assert np.array_equal(bits(c[...]), bits(ref)), f"{name}: [...]"
            assert np.array_equal(bits(c[..., 3]), bits(ref[..., 3])), f"{name}: [..., 3]"
            assert np.array_equal(bits(c[-2, ...]), bits(ref[-2, ...])), f"{name}: [-2, ...]"
            assert np.array_equal(bits(c[1:9:-1, ...]), bits(ref[1:9:-1, ...]))
            assert np.array_equal(bits(c[-5:, -7::-2]), bits(ref[-5:, -7::-2])), name
            if "mask" in c.arrays:  # a side table indexes alike
                assert np.array_equal(c.arrays["mask"][...], c.arrays["mask"][:, :]), name
            with pytest.raises(IndexError):
                c[..., ...]
            attrs, info = c.attrs, cli_inspect(path)
            assert "arrays" not in attrs, name
            assert attrs["basis"] == info["basis"] and attrs["provenance"] == info["provenance"], name


def test_metadata_matches_inspect(dense, bake):
    for name, path in list(dense.items()) + [(k, bake["P"](k + ".ltm")) for k in ["cols4d", "final", "cpca"]]:
        info = cli_inspect(path, "--chunks")
        c = ltbake.open(path)
        assert [c.shape[0], c.shape[1]] == info["shape"], name
        assert c.layout == info["layout"] and c.block == info["block"], name
        assert c.dtype == np.dtype({"f32": "<f4", "u8": "u1", "i32": "<i4", "u32": "<u4"}[info["dtype"]])
        assert c.basis == info["basis"] and c.provenance == info["provenance"], name
        assert c.content_hash == info["content_hash"], name
        assert c.complete and info["complete"], name
        assert c.file_bytes == info["file_bytes"], name
        assert [a["name"] for a in info["arrays"]] == list(c.arrays), name
        for a in info["arrays"]:
            assert c.arrays[a["name"]].content_hash == a["content_hash"], (name, a["name"])
        listed = [(x["array"], x["index"], x["encoding"], x["stored_bytes"]) for x in info["chunk_list"]]
        assert [(x.array, x.index, x.encoding, x.stored_bytes) for x in c.chunks] == listed, name
        assert ltbake.inspect(path) == cli_inspect(path), name  # same JSON as the command
        assert ltbake.inspect(path, content=False, chunks=True) == cli_inspect(path, "--chunks")
    assert len(ltbake.open(dense["sh"]).shards) == 2
    assert "ltbake.Container" in repr(ltbake.open(dense["raw"]))


def test_a_dropped_container_unmaps_its_file(dense):
    """No reference cycle keeps a container's mapping alive: once the container and the
    arrays read from it are gone, the file is no longer mapped (so its pages can leave the
    page cache), and close() stops reads while the views already returned stay valid."""
    import gc
    path = os.path.realpath(dense["raw"])

    def mapped():
        with open("/proc/self/maps") as f:
            return any(line.rstrip().endswith(path) for line in f)

    gc.disable()
    try:
        c = ltbake.open(path)
        v = c[0:4]
        assert mapped()
        del c
        assert mapped(), "the view holds the mapping"
        total = float(v.sum())
        del v
        assert not mapped(), "a container and its views, dropped, still map the file"
    finally:
        gc.enable()
    c = ltbake.open(path)
    v = c[0:4]
    c.close()
    with pytest.raises(ValueError, match="closed"):
        c[0:4]
    assert float(v.sum()) == total and "closed" in repr(c)


def test_side_tables_against_the_file_bytes(bake):
    path = bake["P"]("raw.ltm")
    c = ltbake.open(path)
    tables = [n for n in c.arrays if n != "matrix"]
    assert tables, "raw.ltm has side tables"
    for name in tables:
        a = c.arrays[name]
        if a.layout != "rows" or a.dtype not in (np.float32, np.uint8):
            continue
        ref = ltbtest.side_table(path, name)  # raw bytes at the offsets inspect lists; zstd via the zstd tool
        assert np.array_equal(bits(a.read(force=True)), bits(ref)), name


def test_sparse_and_direct_written_chunks(bake, tmp_path):
    """The stored chunks of the other kinds, against independent readings of the bytes."""
    P = bake["P"]
    # raw.ltm was written with O_DIRECT: its matrix payloads sit on 4096-byte boundaries,
    # behind padding frames (docs/FORMAT.md); the module reads them like any other.
    raw = ltbake.open(P("raw.ltm"))
    assert all((x.offset + 64) % 4096 == 0 for x in raw.chunks if x.array == "matrix")
    # final.ltm: coded sparse chunks (encoding 5), decoded by the pure-Python decoder of
    # docs/FORMAT.md (tests/format/coded_oracle.py), which shares no code with the module.
    import importlib.util
    spec = importlib.util.spec_from_file_location("coded_oracle", os.path.join(REPO, "tests", "format",
                                                                             "coded_oracle.py"))
    oracle = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(oracle)
    final = ltbake.open(P("final.ltm"))
    data = open(P("final.ltm"), "rb").read()
    coded = [x for x in final.chunks if x.array == "matrix" and x.encoding == "sparse-coded"]
    assert coded, "final.ltm has coded chunks"
    for x in coded:
        payload = data[x.offset + 64:x.offset + 64 + x.stored_bytes]
        want = np.asarray(oracle.decode(payload, x.decoded_bytes // 4, final.shape[0]), np.int32)
        got = final.chunk(x.index)  # (rows, columns of the chunk)
        assert np.array_equal(got.T.reshape(-1), want), f"final.ltm chunk {x.index}"
    # cols4d.ltm: sparse+zstd chunks; their values written back give the recorded hash.
    cols4d = ltbake.open(P("cols4d.ltm"))
    assert {x.encoding for x in cols4d.chunks if x.array == "matrix"} <= {"sparse", "sparse-zstd", "zero"}
    ltbake.write(tmp_path / "c4.ltm", cols4d.read(force=True), layout="cols")
    assert cli_inspect(tmp_path / "c4.ltm")["content_hash"] == cols4d.content_hash


def test_transformed_outputs_decode_like_convert(bake):
    P = bake["P"]
    for name in ["cols4d", "final", "cpca", "rows"]:
        c = ltbake.open(P(name + ".ltm"))
        for extra, basis in [((), None), (("--basis", "pixels"), "pixels")]:
            ref = cli_npy(P(name + ".ltm"), bake["dir"], *extra)
            got = c.decode(basis=basis)
            assert np.array_equal(bits(got), bits(ref)), f"{name} decode(basis={basis})"
    # The decoded pixel basis of the row-transformed matrix is the sampled matrix.
    raw = cli_npy(P("raw.ltm"), bake["dir"])
    assert np.allclose(ltbake.open(P("rows.ltm")).decode(basis="pixels"), raw, rtol=1e-4, atol=1e-6)


# --- writing: the same content_hash as `ltbake convert` of the same values ------------------
def test_write_round_trips(bake, dense, tmp_path):
    for name, path in dense.items():
        c = ltbake.open(path)
        values = c.read(force=True)
        for layout in ["rows", "cols"]:
            for zstd in [False, True]:
                out = str(tmp_path / f"{name}-{layout}-{zstd}.ltm")
                ltbake.write(out, values, layout=layout, chunk_size=16 << 10, zstd=zstd)
                cli("verify", out)
                assert ltbake.verify(out) == []
                assert cli_inspect(out)["content_hash"] == c.content_hash, (name, layout, zstd)
                assert cli_inspect(out)["layout"] == layout
                assert np.array_equal(bits(ltbake.open(out).read(force=True)), bits(values))
    # From an iterator of uneven blocks, as row blocks and as column blocks; float64 input.
    ref = cli_npy(dense["raw"], bake["dir"])
    np.save(tmp_path / "ref.npy", ref)
    cli("convert", tmp_path / "ref.npy", tmp_path / "conv.ltm", *Q)
    want = cli_inspect(tmp_path / "conv.ltm")["content_hash"]
    cuts = [0, 1, 100, 101, 600, ref.shape[0]]
    it = (ref[a:b].astype(np.float64) for a, b in zip(cuts, cuts[1:]))
    ltbake.write(tmp_path / "it.ltm", it, shape=ref.shape, chunk_size=8 << 10)
    assert cli_inspect(tmp_path / "it.ltm")["content_hash"] == want
    ccuts = [0, 7, 8, 200, ref.shape[1]]
    it = (ref[:, a:b] for a, b in zip(ccuts, ccuts[1:]))
    ltbake.write(tmp_path / "itc.ltm", it, shape=ref.shape, layout="cols", chunk_size=8 << 10, cube_res=8,
                 metadata={"note": "from python"})
    info = cli_inspect(tmp_path / "itc.ltm")
    assert info["content_hash"] == want and info["basis"]["cols"]["cube_res"] == 8
    assert ltbake.open(tmp_path / "itc.ltm").metadata["note"] == "from python"
    # Bad input: a clear error and no complete-looking file.
    with pytest.raises(ltbake.FormatError, match="beyond the float32 range"):
        bad = ref.astype(np.float64)
        bad[3, 4] = 1e300
        ltbake.write(tmp_path / "bad.ltm", bad)
    with pytest.raises(ltbake.FormatError, match="the shape says"):
        ltbake.write(tmp_path / "short.ltm", iter([ref[:10]]), shape=ref.shape)
    assert ltbake.verify(tmp_path / "short.ltm") != []
    with pytest.raises(ltbake.FormatError, match="ltbake's own"):
        ltbake.write(tmp_path / "m.ltm", ref, metadata={"arrays": []})


# --- zero copy, guards, errors ---------------------------------------------------------
def test_raw_slices_are_read_only_views_on_the_mapping(bake):
    for path, key in [(bake["P"]("raw.ltm"), (slice(0, 256), slice(None))),
                      (bake["P"]("colsconv.ltm"), (slice(None), slice(0, 2)))]:
        c = ltbake.open(path, checksums=False)
        c[key]  # warm: the module's own first-use allocations are not the array's
        tracemalloc.start()
        v = c[key]
        _, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        assert v.nbytes >= 2048 and peak < v.nbytes // 2, f"{path}: {peak} bytes allocated for a {v.nbytes}-byte view"
        assert not v.flags.writeable and not v.flags.owndata
        base = v
        while isinstance(base, np.ndarray):
            base = base.base
        assert type(base).__name__ == "PyCapsule", f"{path}: the view's base is {type(base)}"
        with pytest.raises(ValueError):
            v[0, 0] = 1.0
        assert ltbake.open(path).chunks[0].encoding == "raw"


def test_reads_beyond_max_bytes_need_force(bake):
    c = ltbake.open(bake["P"]("raw.ltm"), max_bytes=1000)
    with pytest.raises(ltbake.TooLargeError, match=r"takes 15360 bytes"):
        c[0:10, :]
    assert c.read((slice(0, 10), slice(None)), force=True).shape == (10, 384)
    assert c[0, 0:250].shape == (250,)
    # A strided selection within the guard is read line by line, not through its whole span.
    ref = ltbake.open(bake["P"]("raw.ltm")).read(force=True)
    assert np.array_equal(c[::300, ::97], ref[::300, ::97])
    assert np.array_equal(c[5:900:400, 3], ref[5:900:400, 3])
    assert np.array_equal(c[7, ::-150], ref[7, ::-150])


def test_errors_are_exceptions_with_the_commands_messages(bake, tmp_path):
    with pytest.raises(FileNotFoundError):
        ltbake.open(tmp_path / "nope.ltm")
    (tmp_path / "text.ltm").write_text("not a container\n" * 10)
    with pytest.raises(ltbake.FormatError):
        ltbake.open(tmp_path / "text.ltm")
    assert issubclass(ltbake.FormatError, ValueError) and issubclass(ltbake.IntegrityError, ltbake.Error)
    # A damaged raw chunk: the read names the chunk; verify lists it like the command.
    src = bake["P"]("zstd.ltm")
    dam = str(tmp_path / "dam.ltm")
    shutil.copy(src, dam)
    frame = next(x for x in ltbake.open(src).chunks if x.array == "matrix" and x.index >= 2 and x.stored_bytes > 64)
    k = frame.index
    with open(dam, "r+b") as f:
        f.seek(frame.offset + 64 + frame.stored_bytes // 2)
        b = f.read(1)
        f.seek(-1, 1)
        f.write(bytes([b[0] ^ 0x10]))
    c = ltbake.open(dam)
    with pytest.raises(ltbake.IntegrityError, match=f"chunk {k}"):
        c.read(force=True)
    c[0:k * c.block, :]  # the chunks before it still read
    problems = ltbake.verify(dam)
    cli_problems = json.loads(cli("verify", "--json", dam, expect=1).stdout)[0]["problems"]
    assert problems == cli_problems and any(f"chunk {k}" in p for p in problems)
    # Truncated: the chunks past the cut are missing, which is damage, not zeros.
    size = os.path.getsize(src)
    cut = str(tmp_path / "cut.ltm")
    with open(src, "rb") as f, open(cut, "wb") as g:
        g.write(f.read(frame.offset + 10))
    c = ltbake.open(cut)
    assert not c.complete
    # Chunks are committed in the order they finish (--jobs), not by index: the first missing
    # one in index order is the lowest index among the frames at or past the cut.
    first_missing = min(x.index for x in ltbake.open(src).chunks if x.array == "matrix" and x.offset >= frame.offset)
    with pytest.raises(ltbake.IntegrityError, match=f"chunk {first_missing} "):
        c[:, :]
    assert "incomplete" in ltbake.verify(cut)[0] and ltbake.verify(cut, allow_incomplete=True) == []
    assert size > frame.offset


def test_damage_sweep_never_crashes_and_never_returns_wrong_values(bake, tmp_path):
    """Every damaged copy of a small container (byte flips across the whole file,
    truncations) opens and reads through the module without crashing the interpreter,
    and a read that succeeds returns the original values."""
    src = bake["P"]("zstd.ltm")
    data = open(src, "rb").read()
    good = ltbake.open(src).read(force=True)
    scale = float(os.environ.get("LTB_TEST_SCALE", "1") or 1)
    step = max(1, int(len(data) / max(50, 600 * scale)))
    damaged = [(f"flip@{i}", data[:i] + bytes([data[i] ^ 0x5A]) + data[i + 1:]) for i in range(0, len(data), step)]
    damaged += [(f"cut@{n}", data[:n]) for n in range(0, len(data), max(1, step * 3))]
    outcomes = {"ok": 0, "error": 0}
    path = str(tmp_path / "d.ltm")
    for what, blob in damaged:
        with open(path, "wb") as f:
            f.write(blob)
        try:
            c = ltbake.open(path)
            got = c.read(force=True)
            for name, a in c.arrays.items():
                a.read(force=True)
        except (ltbake.Error, OSError):
            outcomes["error"] += 1
            continue
        assert got.shape == good.shape and np.array_equal(bits(got), bits(good)), f"{what}: wrong values, no error"
        outcomes["ok"] += 1
    assert outcomes["error"] > len(damaged) // 4, outcomes


# --- relighting and environment maps, against the command ------------------------------------
def test_relight_equals_the_commands_npy(bake, tmp_path):
    P = bake["P"]
    for name, terms in [("final", 40), ("rows", 64), ("cpca", 30), ("raw", "all"), ("sh", 100)]:
        out = str(tmp_path / f"{name}.npy")
        cli("relight", P(name + ".ltm"), "--env", bake["env"], "-o", out, "--terms", terms, *Q)
        img, report = ltbake.relight(P(name + ".ltm"), bake["env"], terms=terms, report=True)
        assert img.shape == (1024, 3) and img.dtype == np.float32
        assert np.array_equal(bits(img), bits(np.load(out))), name
        assert report["terms"] == terms
        # The same cubemap as a NumPy array in memory (float64 too): the same image.
        lights = np.load(bake["env"])
        for arr in (lights, lights.astype(np.float64)):
            assert np.array_equal(bits(ltbake.relight(P(name + ".ltm"), arr, terms=terms)), bits(img)), name
    with pytest.raises(ltbake.FormatError):
        ltbake.relight(P("final.ltm"), bake["env"], weighting="sideways")
    with pytest.raises(ValueError):
        ltbake.relight(P("final.ltm"), bake["env"], terms=0)
    bad = np.load(bake["env"])
    bad[7, 1] = np.nan
    with pytest.raises(ltbake.FormatError, match="texel 7 channel 1 is nan"):
        ltbake.relight(P("final.ltm"), bad)
    fixed = ltbake.relight(P("final.ltm"), bad, clamp_env=True)
    bad[7, 1] = 0
    assert np.array_equal(bits(fixed), bits(ltbake.relight(P("final.ltm"), bad)))
    with pytest.raises(ltbake.FormatError, match="expected a cubemap of shape"):
        ltbake.relight(P("final.ltm"), np.ones((10, 3), np.float32))
    with pytest.raises(ValueError, match="6R\\^2 x 3"):
        ltbake.relight(P("final.ltm"), np.ones((384, 4), np.float32))


def test_envmap_equals_convert(tmp_path):
    envdir = subprocess.run(["bash", os.path.join(REPO, "scripts", "find_envmaps.sh")], capture_output=True,
                            text=True).stdout.strip()
    exr = os.path.join(envdir, "forest.exr")
    if not os.path.exists(exr):
        pytest.skip("no Blender environment maps (blender-data)")
    out = str(tmp_path / "forest.npy")
    cli("convert", exr, out, "--cube-res", 16, "--clamp", *Q)
    cube = ltbake.envmap(exr, 16, clamp=True)
    assert cube.shape == (6 * 16 * 16, 3) and np.array_equal(bits(cube), bits(np.load(out)))
    with pytest.raises(ltbake.FormatError, match="power of two"):
        ltbake.envmap(exr, 12)


def test_cmake_install_puts_an_importable_package_in_dist_packages(tmp_path):
    """`cmake --install BUILD --component python --prefix P` installs the package where
    Debian's Python looks for it under P (lib/python3.X/dist-packages), and it imports."""
    build = os.environ.get("LTB_BUILD_DIR", os.path.join(REPO, "build"))
    prefix = tmp_path / "prefix"
    subprocess.run(["cmake", "--install", build, "--component", "python", "--prefix", str(prefix)], check=True,
                   capture_output=True)
    found = sorted(prefix.glob("lib/python3*/dist-packages/ltbake/__init__.py"))
    assert found, f"nothing installed under {prefix}/lib/python3*/dist-packages"
    site = str(found[0].parent.parent)
    out = subprocess.run(["/usr/bin/python3", "-c", "import ltbake, sys; print(ltbake.__file__, ltbake.__version__)"],
                         env={**os.environ, "PYTHONPATH": site}, capture_output=True, text=True, check=True).stdout
    assert out.startswith(site)


# --- integrity at the edges (issue 36) -----------------------------------------------------
def test_write_refuses_to_resume_data_that_changed(tmp_path):
    """A rerun of write() whose data differ from the committed chunks raises instead of
    keeping the old values; overwrite=True starts over for an array."""
    path = str(tmp_path / "w.ltm")
    a = np.random.default_rng(7).random((200, 24), dtype=np.float32)
    ltbake.write(path, a, chunk_size=4096)
    ltbake.write(path, a, chunk_size=4096)  # unchanged: resumes, nothing to write
    b = a.copy()
    b[150, 3] = -2.0
    with pytest.raises(ltbake.FormatError, match=r"row 150, column 3.*the input changed since"):
        ltbake.write(path, b, chunk_size=4096)
    with ltbake.open(path) as c:
        assert np.array_equal(bits(c[:, :]), bits(a))
    ltbake.write(path, b, chunk_size=4096, overwrite=True)
    with ltbake.open(path) as c:
        assert np.array_equal(bits(c[:, :]), bits(b))
    # Blocks from an iterator cannot be read twice: a change is an error even with overwrite.
    ltbake.write(path, iter([b[:100], b[100:]]), shape=b.shape, chunk_size=4096, overwrite=True)
    with pytest.raises(ltbake.FormatError, match="the input changed since"):
        ltbake.write(path, iter([a[:100], a[100:]]), shape=a.shape, chunk_size=4096, overwrite=True)


def _frames(buf):
    """(offset, header) of each chunk frame (docs/FORMAT.md "Frames"), by scanning from the
    first 64-byte-aligned LTMF magic after the metadata."""
    off = buf.index(b"LTMF", 64)
    out = []
    while off + 64 <= len(buf) and buf[off:off + 4] == b"LTMF":
        typ = int.from_bytes(buf[off + 4:off + 6], "little")
        length = int.from_bytes(buf[off + 8:off + 16], "little")
        if typ == 1:
            out.append(off)
        elif typ != 3:
            break
        off += 64 + (length + 63) // 64 * 64
    return out, off


def test_a_chunk_committed_twice_is_never_read(tmp_path):
    """A forged file holding (array 0, chunk 0) twice, with other values in the second copy:
    Python raises IntegrityError on reading it (it returned the first copy), as verify fails."""
    xxhash = pytest.importorskip("xxhash")
    path = str(tmp_path / "dup.ltm")
    a = np.arange(2 * 64, dtype=np.float32).reshape(2, 64)
    ltbake.write(path, a, chunk_size=256)  # one row a chunk: chunks 0 and 1
    buf = bytearray(open(path, "rb").read())
    frames, end = _frames(buf)
    assert len(frames) == 2
    del buf[end:]  # drop the content hash, index and trailer: a reader scans the frames
    second = frames[1]
    buf[second + 24:second + 32] = (0).to_bytes(8, "little")  # chunk_index 1 -> 0
    buf[second + 56:second + 64] = xxhash.xxh3_64_intdigest(bytes(buf[second:second + 56])).to_bytes(8, "little")
    open(path, "wb").write(bytes(buf))
    assert cli("verify", path, expect=1)
    with ltbake.open(path) as c:
        assert any("committed twice" in p for p in c.problems)
        with pytest.raises(ltbake.IntegrityError, match="committed twice"):
            c[0, :]


@pytest.mark.parametrize("jobs", [0, -1, 1025, 100000])
def test_jobs_out_of_range_raise(tmp_path, jobs):
    """jobs as the CLI takes it (1..1024): a ValueError, never std::terminate."""
    path = str(tmp_path / "j.ltm")
    ltbake.write(path, np.ones((4, 6), np.float32))
    with pytest.raises(ValueError, match=f"jobs={jobs}"):
        ltbake.verify(path, jobs=jobs)
    with pytest.raises(ValueError, match=f"jobs={jobs}"):
        ltbake.inspect(path, jobs=jobs)
    with pytest.raises(ValueError, match=f"jobs={jobs}"):
        ltbake.open(path, jobs=jobs)
