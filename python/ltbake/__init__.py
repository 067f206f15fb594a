"""ltbake from Python: light transport containers (.ltm) as NumPy arrays, and relighting.

    import ltbake
    with ltbake.open("out/medium-bake/final.ltm") as c:
        print(c.shape, c.layout, c.content_hash)
        light = c[:, 1234]          # one light's image (a column)
        pixel = c[4096, :]          # one pixel's transport (a row)

The module is built from the same C++ libraries as the `ltbake` command (one implementation
of the format); docs/PYTHON.md is the guide. A raw chunk read in the container's own layout
comes back as a read-only view on the file's memory map, without a copy; other reads
return new arrays. Errors are ltbake.FormatError, ltbake.IntegrityError or OSError, with
the messages the command prints (file, chunk, value).
"""

import json as _json
import os as _os
import tempfile as _tempfile
from collections import namedtuple as _namedtuple

import numpy as _np

from . import _ltbake
from ._ltbake import Error, FormatError, IntegrityError

__all__ = [
    "open", "write", "verify", "inspect", "relight", "envmap", "Container", "Array", "ChunkInfo",
    "Error", "FormatError", "IntegrityError", "TooLargeError", "MAX_BYTES", "__version__",
]

__version__ = _ltbake.tool_version

#: The default guard of a read: larger results need ``read(..., force=True)``.
MAX_BYTES = 1 << 30


class TooLargeError(Error, MemoryError):
    """A read larger than the container's ``max_bytes`` guard (pass ``force=True``)."""


#: One committed chunk frame: its array (name), chunk index, encoding, bytes stored and
#: decoded, the frame's offset and the file holding it (a shard, for a manifest).
ChunkInfo = _namedtuple("ChunkInfo", "array index encoding stored_bytes decoded_bytes offset file")


def _axis(index, n, what):
    """(start, stop, step, is_int) of one index of an axis of length n."""
    if isinstance(index, slice):
        start, stop, step = index.indices(n)
        return start, stop, step, False
    if isinstance(index, (int, _np.integer)) and not isinstance(index, bool):
        i = int(index)
        if i < -n or i >= n:
            raise IndexError(f"{what} index {i} is out of range for {n} {what}s")
        i %= n
        return i, i + 1, 1, True
    raise TypeError(f"{what}s are indexed by an integer or a slice, not {type(index).__name__}")


class _Core:
    """What a container's arrays share: the reader (its mappings) and the read options.
    Arrays hold this, not the Container, so no reference cycle keeps a mapping alive."""

    def __init__(self, path, checksums, max_bytes, jobs):
        self.path = path
        self.max_bytes = int(max_bytes)
        self.jobs = int(jobs)
        if not 1 <= self.jobs <= 1024:
            raise ValueError(f"jobs={jobs}: expected 1..1024 worker threads (as ltbake --jobs)")
        self._reader = _ltbake.Reader(path, bool(checksums))

    @property
    def reader(self):
        if self._reader is None:
            raise ValueError(f"{self.path}: the container is closed")
        return self._reader


class Array:
    """One array of a container: the matrix (array 0) or a side table.

    ``a[i0:i1, :]`` and ``a[:, j0:j1]`` (and integers, negative ones too, slices with any
    step, ``...``) read values, as NumPy indexes a 2-D array; ``np.asarray(a)`` reads it
    whole (within ``max_bytes``); ``len(a)`` is its rows; ``a.iter_chunks()`` streams it
    chunk by chunk."""

    def __init__(self, core, index, spec):
        self._c = core
        self.index = index
        self.name = spec["name"]
        self.shape = (int(spec["shape"][0]), int(spec["shape"][1]))
        self.dtype = _np.dtype({"f32": "<f4", "f64": "<f8", "u8": "u1", "i32": "<i4", "u32": "<u4",
                                "u64": "<u8"}[spec["dtype"]])
        self.layout = spec["layout"]
        self.block = int(spec["block"])

    ndim = 2
    size = property(lambda self: self.shape[0] * self.shape[1], doc="values in the array")

    def __len__(self):
        return self.shape[0]

    def __array__(self, dtype=None, copy=None):
        out = self.read()
        return out if dtype is None else out.astype(dtype, copy=False)

    @property
    def nchunks(self):
        n = self.shape[0] if self.layout == "rows" else self.shape[1]
        return (n + self.block - 1) // self.block

    @property
    def nbytes(self):
        return self.shape[0] * self.shape[1] * self.dtype.itemsize

    @property
    def content_hash(self):
        """The content_hash its writer recorded (16 hex digits), computed when there is no
        record (an older or unsealed file: reads every chunk), None when incomplete."""
        h = self._c.reader.recorded_content_hash(self.index)
        if h:
            return h
        info = inspect(self._c.path, content=True, jobs=self._c.jobs)
        return info["arrays"][self.index].get("content_hash")

    def chunk_range(self, k):
        """The rows (rows layout) or columns (cols layout) chunk k holds."""
        n = self.shape[0] if self.layout == "rows" else self.shape[1]
        return range(k * self.block, min(n, (k + 1) * self.block))

    def chunk(self, k):
        """Chunk k as (rows, cols) of the matrix: a read-only view on the memory map for a
        raw chunk (transposed for the cols layout), decoded otherwise."""
        arr, _ = self._c.reader.read_chunk(self.index, k)
        return arr if self.layout == "rows" else arr.T

    def iter_chunks(self):
        """Yields (range, ndarray) per chunk in file order: the rows it holds and an array of
        (len(range), cols) for the rows layout, the columns and (rows, len(range)) for cols."""
        for k in range(self.nchunks):
            yield self.chunk_range(k), self.chunk(k)

    def __getitem__(self, key):
        return self.read(key)

    def read(self, key=(slice(None), slice(None)), force=False):
        """The values at ``key`` (an index of up to two axes). More than the container's
        ``max_bytes`` raises TooLargeError unless ``force``."""
        if not isinstance(key, tuple):
            key = (key,)
        if sum(k is Ellipsis for k in key) > 1:
            raise IndexError("an index can only have a single ellipsis ('...')")
        if Ellipsis in [k for k in key if k is Ellipsis]:  # ... stands for the axes not given
            at = next(i for i, k in enumerate(key) if k is Ellipsis)
            key = key[:at] + (slice(None),) * (3 - len(key)) + key[at + 1:]
        if len(key) == 1:
            key = (key[0], slice(None))
        if len(key) != 2:
            raise IndexError(f"{self.name} is 2-D; got {len(key)} indices")
        r0, r1, rs, rint = _axis(key[0], self.shape[0], "row")
        c0, c1, cs, cint = _axis(key[1], self.shape[1], "column")
        rows, cols = range(r0, r1, rs), range(c0, c1, cs)
        size = len(rows) * len(cols) * self.dtype.itemsize
        if size > self._c.max_bytes and not force:
            raise TooLargeError(f"{self._c.path}: reading {len(rows)} x {len(cols)} {self.dtype} values of "
                                f"\"{self.name}\" takes {size} bytes, more than max_bytes={self._c.max_bytes}; "
                                f"use .read(key, force=True), a smaller slice or iter_chunks()")
        if len(rows) == 0 or len(cols) == 0:
            out = _np.empty((len(rows), len(cols)), self.dtype)
        else:
            lo_r, hi_r = min(rows[0], rows[-1]), max(rows[0], rows[-1]) + 1
            lo_c, hi_c = min(cols[0], cols[-1]), max(cols[0], cols[-1]) + 1
            span = (hi_r - lo_r) * (hi_c - lo_c) * self.dtype.itemsize
            if (rs == 1 and cs == 1) or span <= max(size, self._c.max_bytes):
                out = self._region(lo_r, hi_r, lo_c, hi_c)
                if rs != 1 or cs != 1:
                    out = out[_np.asarray(rows) - lo_r][:, _np.asarray(cols) - lo_c]
            else:  # a sparse selection of a large span: line by line, never the whole span
                out = _np.empty((len(rows), len(cols)), self.dtype)
                csel, rsel = _np.asarray(cols) - lo_c, _np.asarray(rows) - lo_r
                if rs != 1 or hi_r - lo_r > hi_c - lo_c:
                    for n, r in enumerate(rows):
                        out[n] = self._region(r, r + 1, lo_c, hi_c)[0][csel]
                else:
                    for n, c in enumerate(cols):
                        out[:, n] = self._region(lo_r, hi_r, c, c + 1)[:, 0][rsel]
        if rint and cint:
            return out[0, 0]
        if rint:
            return out[0]
        if cint:
            return out[:, 0]
        return out

    def _region(self, r0, r1, c0, c1):
        lo, hi = (r0, r1) if self.layout == "rows" else (c0, c1)
        k = lo // self.block
        if (hi - 1) // self.block == k:  # one chunk: a view on it
            arr, mapped = self._c.reader.read_chunk(self.index, k, r0, r1, c0, c1)  # prefetches that part
            base = k * self.block
            if self.layout == "rows":
                view = arr[r0 - base:r1 - base, c0:c1]
            else:
                view = arr.T[r0:r1, c0 - base:c1 - base]
            # A small part of a decoded chunk is copied, so it does not keep the chunk alive.
            return view if mapped or 2 * view.nbytes >= arr.nbytes else view.copy()
        return self._c.reader.read_region(self.index, r0, r1, c0, c1, self._c.jobs)

    def __repr__(self):
        return (f"<ltbake.Array \"{self.name}\" {self.shape[0]} x {self.shape[1]} {self.dtype}, "
                f"layout {self.layout} (block {self.block})>")


class Container(Array):
    """An open .ltm container or stage manifest; indexing reads its matrix (array 0).

    ``checksums``: verify each chunk's checksum the first time a read touches it (reading
    the whole chunk once); False reads only the pages a slice needs, like a memory map.
    ``max_bytes``: the largest read without ``force=True``. ``jobs``: threads of reads
    that span several chunks."""

    def __init__(self, path, checksums=True, max_bytes=MAX_BYTES, jobs=2):
        self.path = _os.fspath(path)
        core = _Core(self.path, checksums, max_bytes, jobs)
        self.metadata = _json.loads(core.reader.metadata_json)
        specs = self.metadata["arrays"]
        super().__init__(core, 0, specs[0])
        #: Every array by name, the matrix included (as an Array of its own).
        self.arrays = {s["name"]: Array(core, i, s) for i, s in enumerate(specs)}

    basis = property(lambda self: self.metadata.get("basis"), doc="what rows and columns are")
    attrs = property(lambda self: {k: v for k, v in self.metadata.items() if k != "arrays"},
                     doc="the container's metadata but its array list (basis, provenance, stage blocks), "
                         "as h5py's and zarr's .attrs")
    provenance = property(lambda self: self.metadata.get("provenance"), doc="stage, tool, parameters, inputs")
    complete = property(lambda self: self._c.reader.complete, doc="every chunk of every array committed")
    sealed = property(lambda self: self._c.reader.sealed, doc="the writer finished the file")
    format_version = property(lambda self: self._c.reader.format_version)
    file_bytes = property(lambda self: self._c.reader.file_size, doc="bytes on disk (a manifest: with its shards)")
    shards = property(lambda self: self._c.reader.shards, doc="a manifest's shard files (else empty)")
    problems = property(lambda self: self._c.reader.problems, doc="damage found while opening")

    @property
    def chunks(self):
        """Every committed chunk frame, as ChunkInfo, in file order."""
        names = [s["name"] for s in self.metadata["arrays"]]
        return [ChunkInfo(names[a], i, enc, stored, decoded, off, f)
                for a, i, enc, stored, decoded, off, f in self._c.reader.chunk_frames()]

    def decode(self, basis=None, path=None, jobs=None, mem_limit=1 << 30):
        """The matrix as ``ltbake convert FILE OUT.npy [--basis pixels]`` writes it: column-
        transform and quantize outputs decoded to the row-transformed basis, cpca outputs to
        their approximation; ``basis="pixels"`` also inverts the row transform. Written to
        ``path`` (a .npy; a temporary file when None, removed once the array is gone) and
        returned memory-mapped, so a matrix larger than memory can be decoded."""
        if basis not in (None, "pixels"):
            raise ValueError(f"basis is None or 'pixels', not {basis!r}")
        temp = path is None
        if temp:
            fd, path = _tempfile.mkstemp(suffix=".npy", prefix="ltbake-decode-")
            _os.close(fd)
            _os.unlink(path)
        try:
            _ltbake.convert(self.path, _os.fspath(path), basis == "pixels", jobs or self._c.jobs, mem_limit)
            out = _np.load(path, mmap_mode="r")
        finally:
            if temp and _os.path.exists(path):
                _os.unlink(path)  # the mapping keeps the data until the array is gone
        return out

    def close(self):
        """Drops the reader and its mappings once no array read from it is left (each array
        returned holds the mapping it views); reading afterwards raises ValueError."""
        self._c._reader = None

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()
        return False

    def __repr__(self):
        state = "closed" if self._c._reader is None else "complete" if self.complete else "incomplete"
        return (f"<ltbake.Container '{self.path}': {self.shape[0]} x {self.shape[1]} {self.dtype}, "
                f"layout {self.layout} (block {self.block}), {len(self.arrays)} array(s), {state}>")


def open(path, checksums=True, max_bytes=MAX_BYTES, jobs=2):  # noqa: A001 (like io.open)
    """Opens a container, a shard file or a stage manifest (see Container)."""
    return Container(path, checksums=checksums, max_bytes=max_bytes, jobs=jobs)


def _as_f32(block, path, row0, col0):
    """A block as float32; a finite value beyond the float32 range is an error, as in convert."""
    block = _np.asarray(block)
    if block.dtype == _np.float32:
        return block
    if block.dtype.kind not in "fiu":
        raise FormatError(f"{path}: values of dtype {block.dtype} are not numbers")
    wide = block.astype(_np.float64, copy=False)
    bad = _np.isfinite(wide) & (_np.abs(wide) > _np.finfo(_np.float32).max)
    if bad.any():
        r, c = _np.argwhere(bad)[0]
        raise FormatError(f"{path}: value {wide[r, c]!r} at row {row0 + r}, column {col0 + c} is beyond the "
                          f"float32 range; scale the matrix first")
    return wide.astype(_np.float32)


def _blocks(data, shape, layout, path):
    """Consecutive row blocks (rows layout) or column blocks (cols layout), as float32."""
    if isinstance(data, _np.ndarray) or hasattr(data, "__array__"):
        arr = _np.asarray(data)
        if arr.shape != tuple(shape):
            raise FormatError(f"{path}: data has shape {arr.shape}, expected {tuple(shape)}")
        yield arr
        return
    for block in data:
        block = _np.asarray(block)
        if block.ndim != 2:
            raise FormatError(f"{path}: the iterator yielded a {block.ndim}-D block; blocks are 2-D")
        ok = block.shape[1] == shape[1] if layout == "rows" else block.shape[0] == shape[0]
        if not ok:
            raise FormatError(f"{path}: a block of shape {block.shape} does not fit a {shape[0]} x {shape[1]} "
                              f"matrix in the {layout} layout")
        yield block


def write(path, data, layout="rows", chunk_size=8 << 20, zstd=False, metadata=None, shape=None,
          cube_res=0, image=None, overwrite=False):
    """Writes a float32 matrix to a new .ltm container, chunk by chunk, as ``ltbake convert
    IN.npy OUT.ltm`` does (same content_hash for the same values).

    ``data``: a 2-D array (any float or integer dtype; converted to float32) or an iterator
    of 2-D blocks of consecutive rows (``layout="rows"``) or columns (``"cols"``), which
    needs ``shape``. ``chunk_size``: target bytes per chunk. ``zstd``: compress chunks where
    it saves 10%. ``metadata``: extra keys for the metadata (not "arrays" or "shard").
    ``cube_res``: the columns are a 6R² cubemap; ``image=(W, H)``: the rows are pixels.
    Interrupted, a rerun with the same arguments resumes; the file is complete only when
    this returns. A rerun whose data differ from the chunks an earlier write committed
    raises FormatError ("the input changed since"): ``overwrite=True`` then starts over for
    an array (an iterator's blocks cannot be read twice: remove the file). Returns the path."""
    path = _os.fspath(path)
    if layout not in ("rows", "cols"):
        raise ValueError(f"layout is 'rows' or 'cols', not {layout!r}")
    if shape is None:
        if not hasattr(data, "shape"):
            raise ValueError("an iterator of blocks needs shape=(rows, cols)")
        shape = data.shape
    if len(shape) != 2 or shape[0] <= 0 or shape[1] <= 0:
        raise FormatError(f"{path}: shape {tuple(shape)}: a matrix is 2-D and not empty")
    rows, cols = int(shape[0]), int(shape[1])
    block = _ltbake.block_for_target_bytes(rows, cols, layout, int(chunk_size))
    rb = _json.loads(_ltbake.axis_basis_json("image", image[0], image[1]) if image else
                     _ltbake.axis_basis_json("generic", 0, 0))
    cb = _json.loads(_ltbake.axis_basis_json("cubemap" if cube_res else "generic", int(cube_res), 0))
    if cube_res and cols != 6 * cube_res * cube_res:
        raise FormatError(f"{path}: {cols} columns; a cubemap with cube_res {cube_res} needs {6 * cube_res ** 2}")
    if image and image[0] * image[1] != rows:
        raise FormatError(f"{path}: {rows} rows; an image of {image[0]}x{image[1]} needs {image[0] * image[1]}")
    meta = {
        "arrays": [{"name": "matrix", "dtype": "f32", "shape": [rows, cols], "layout": layout, "block": block}],
        "basis": {"rows": rb, "cols": cb},
        "provenance": {"tool": "ltbake " + __version__, "stage": "python",
                       "parameters": {"source": "ndarray" if hasattr(data, "shape") else "iterator",
                                      "zstd": bool(zstd)}},
    }
    for k, v in (metadata or {}).items():
        if k in ("arrays", "shard"):
            raise FormatError(f"{path}: metadata key {k!r} is ltbake's own")
        meta[k] = v
    w = _ltbake.Writer(path, _json.dumps(meta), bool(overwrite))
    try:
        _write_chunks(w, data, (rows, cols), layout, block, zstd, path)
    except FormatError as e:
        # A file an earlier write left whose committed chunks hold other values: with
        # overwrite=True and an array (which can be read again) start over; an iterator's
        # blocks are gone, so the file must be removed first.
        if not (overwrite and hasattr(data, "shape") and "the input changed since" in str(e)):
            raise
        w.discard()
        w = _ltbake.Writer(path, _json.dumps(meta), True)
        _write_chunks(w, data, (rows, cols), layout, block, zstd, path)
    w.finish()
    return path


def _write_chunks(w, data, shape, layout, block, zstd, path):
    """Puts every chunk of `data` that `w` lacks; a chunk an interrupted earlier write
    committed must hold the same values (FormatError otherwise: the input changed)."""
    rows, cols = shape
    rows_layout = layout == "rows"
    n = rows if rows_layout else cols
    nchunks = (n + block - 1) // block
    size = (lambda b: b.shape[0]) if rows_layout else (lambda b: b.shape[1])
    buf, have, chunk = [], 0, 0  # blocks not yet written, their length along the axis
    for b in _blocks(data, (rows, cols), layout, path):
        buf.append(b)
        have += size(b)
        if chunk * block + have > n:
            raise FormatError(f"{path}: the blocks hold more than the {n} {layout} of shape {(rows, cols)}")
        while chunk < nchunks:
            need = min(n, (chunk + 1) * block) - chunk * block
            if have < need:
                break
            joined = _np.concatenate(buf, axis=0 if rows_layout else 1) if len(buf) > 1 else buf[0]
            if rows_layout:
                part, rest = joined[:need], joined[need:]
                values = _as_f32(part, path, chunk * block, 0)
            else:
                part, rest = joined[:, :need], joined[:, need:]
                values = _as_f32(part, path, 0, chunk * block).T
            values = _np.ascontiguousarray(values, dtype=_np.float32)
            if w.has(0, chunk):
                w.check(0, chunk, values)
            else:
                w.put(0, chunk, values, bool(zstd))
            buf = [rest] if size(rest) else []
            have -= need
            chunk += 1
    if chunk != nchunks:
        raise FormatError(f"{path}: the blocks held {chunk * block + have} {layout}, the shape says {n}; the "
                          f"file stays incomplete (rerun to resume)")


def verify(path, jobs=2, allow_incomplete=False):
    """Every problem ``ltbake verify`` finds (checksums, structure, recomputed content_hash
    against the recorded one), as a list of messages: empty when the file is good. An
    incomplete file is a problem unless ``allow_incomplete``."""
    r = _ltbake.verify_report(_os.fspath(path), jobs)
    problems = list(r["problems"])
    if r["readable"] and not r["complete"] and not problems and not allow_incomplete:
        problems.append(f"{r['file']}: incomplete: {r['chunks_ok']} of {r['chunks_expected']} chunks committed, "
                        f"not sealed (rerun the stage that writes it to resume)")
    return problems


def verify_report(path, jobs=2):
    """The whole report of ``ltbake verify --json`` for one file, as a dict."""
    return _ltbake.verify_report(_os.fspath(path), jobs)


def inspect(path, content=False, chunks=False, jobs=2):
    """The dict ``ltbake inspect FILE --json`` prints: from the header, metadata, index and
    recorded content_hash (fast for any size); ``content=True``: --content, every chunk
    read (value statistics, content_hash recomputed); ``chunks=True``: --chunks."""
    return _json.loads(_ltbake.inspect_json(_os.fspath(path), bool(content), bool(chunks), jobs))


def relight(path, env, terms=100, weighting="area", rotate=0.0, clamp_env=False, keep_negative=False,
            jobs=2, mem_limit=1 << 30, report=False):
    """The relit rows (rows × 3 float32, RGB), as ``ltbake relight PATH --env ENV -o OUT.npy``
    writes them, bit for bit. ``env``: an .exr/.hdr map, a 6R² × 3 cubemap .npy, or that
    cubemap as a NumPy array (in memory: e.g. ``ltbake.envmap(...)`` edited, or lighting
    computed on the fly; the same result as the array saved as .npy);
    ``terms``: an int or "all"; ``rotate``: degrees about +Z; ``report=True`` also returns
    the dict ``--json`` prints."""
    if terms == "all":
        n = 0
    else:
        n = int(terms)
        if n < 1:
            raise ValueError("terms is at least 1 (or 'all')")
    cube = None
    if isinstance(env, _np.ndarray):
        cube, env = env, "<array>"
    image, rep = _ltbake.relight(_os.fspath(path), _os.fspath(env), n, weighting, float(rotate), bool(clamp_env),
                                 bool(keep_negative), int(jobs), int(mem_limit), cube)
    return (image, _json.loads(rep)) if report else image


def envmap(path, cube_res, clamp=False, max_bytes=MAX_BYTES):
    """An environment map (.exr, .hdr, or six faces through "{face}") resampled to ltbake's
    cubemap of faces R × R: a (6R², 3) float32 array, as ``ltbake convert ENV OUT.npy
    --cube-res R`` writes it."""
    return _ltbake.envmap(_os.fspath(path), int(cube_res), bool(clamp), int(max_bytes))
