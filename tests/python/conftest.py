"""Fixtures of the Python module's tests (tests/python, docs/PYTHON.md).

Run by `make test` through ctest (python.module) as
    PYTHONPATH=build/python LTBAKE=build/ltbake /usr/bin/python3 -m pytest tests/python
The containers come from the ltbake command (every kind the stages write), so each read
through the module is compared with what the command (an independent process, `convert`,
`inspect`, `relight`) says about the same file."""
import json
import os
import subprocess
import sys

import numpy as np
import pytest

REPO = os.path.abspath(os.path.join(os.path.dirname(__file__), "..", ".."))
LTBAKE = os.environ.get("LTBAKE", os.path.join(REPO, "build", "ltbake"))
TINY = os.path.join(REPO, "samples", "tiny.toml")
Q = ["--progress", "never"]

sys.path.insert(0, os.path.join(REPO, "tests", "cli"))
import ltbtest  # noqa: E402  (its side_table reads chunks straight from the file's bytes)

ltbtest.LTBAKE = LTBAKE


def cli(*args, expect=0):
    p = subprocess.run([LTBAKE, *map(str, args)], capture_output=True, text=True, timeout=600)
    assert p.returncode == expect, f"ltbake {' '.join(map(str, args))}: exit {p.returncode}\n{p.stdout}{p.stderr}"
    return p


def cli_inspect(path, *extra):
    return json.loads(cli("inspect", "--json", path, *extra).stdout)


def cli_npy(path, tmp, *extra):
    """The matrix as `ltbake convert PATH OUT.npy` writes it."""
    out = os.path.join(tmp, os.path.basename(path) + "-".join(extra) + ".npy")
    cli("convert", path, out, *extra, *Q)
    return np.load(out)


@pytest.fixture(scope="session")
def bake(tmp_path_factory):
    """Every kind of container the stages write, from the tiny scene (1024 rows, R = 8):
    raw (sample: O_DIRECT, with padding frames), rows, cols, cols4d and final (sparse and
    coded chunks), cpca, a 2-shard manifest, a zstd convert and a cols-layout convert."""
    d = str(tmp_path_factory.mktemp("bake"))
    P = lambda name: os.path.join(d, name)  # noqa: E731
    cli("sample", TINY, "-o", P("raw.ltm"), "--chunk-rows", 256, *Q)
    cli("row-transform", P("raw.ltm"), "-o", P("rows.ltm"), *Q)
    cli("transpose", P("rows.ltm"), "-o", P("cols.ltm"), *Q)
    cli("column-transform", P("cols.ltm"), "-o", P("cols4d.ltm"), *Q)
    cli("quantize", P("cols4d.ltm"), "-o", P("final.ltm"), *Q)
    cli("cpca", P("rows.ltm"), "-o", P("cpca.ltm"), "--clusters", 2, "--basis", 2, *Q)
    for i in range(2):
        cli("sample", TINY, "-o", P("sh.ltm"), "--chunk-rows", 256, "--shard", i, "--nshards", 2, *Q)
    cli("commit", P("sh.ltm"), "--nshards", 2)
    cli("convert", P("raw.ltm"), P("raw.npy"), *Q)
    cli("convert", P("raw.npy"), P("zstd.ltm"), "--zstd", "--chunk-size", "8KiB", *Q)
    cli("convert", P("raw.npy"), P("colsconv.ltm"), "--layout", "cols", "--chunk-size", "8KiB", *Q)
    env = P("env.npy")
    np.save(env, np.random.default_rng(3).uniform(0.0, 2.0, (6 * 8 * 8, 3)).astype(np.float32))
    return {"dir": d, "P": P, "env": env}


@pytest.fixture(scope="session")
def dense(bake):
    """The dense (not column-transformed) kinds: name -> path."""
    P = bake["P"]
    return {k: P(k + ".ltm") for k in ["raw", "rows", "cols", "sh", "zstd", "colsconv"]}
