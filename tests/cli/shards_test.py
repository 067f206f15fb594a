"""Sharded stage outputs: `--shard I --nshards N`, `ltbake commit`, stage manifests, `ltbake merge`.

- For 1 (unsharded), 2, 3 and 7 shards (7 is more than the chunks of some arrays, so some
  shards own nothing), sample (plain and fused with row-transform) -> row-transform ->
  transpose -> column-transform (per-column and --budget) -> quantize, each stage sharded
  and reading the previous stage's manifest: every committed manifest has the unsharded
  output's content_hash, converts to the same .npy bytes, merges into one container with
  that content_hash which verifies and is no manifest. Oracles independent of ltbake's own
  transforms: the transposed matrix decodes to the rows matrix; the rows matrix is
  PyWavelets' haar of the raw matrix, face by face.
- Mixing: a sharded stage reading an unsharded input; an unsharded stage reading a manifest.
- Idempotence: rerunning a complete shard writes no chunk and leaves its file untouched
  (bytes and mtime); committing twice writes the same manifest.
- Damage after the commit (missing, other parameters, corrupt chunk, truncated, another
  shard's file): inspect, verify, convert and the next stage fail with exit 1 naming the
  shard and its file; commit refuses missing / foreign / damaged shards naming them, and
  an OUT that is not a manifest without --overwrite.
- SLURM_ARRAY_TASK_ID / SLURM_ARRAY_TASK_COUNT give the same files as the flags; bad
  combinations are usage errors (exit 2); cpca refuses --nshards 2.
- A shard SIGKILLed mid-run resumes to the same content.

usage: shards_test.py PATH_TO_LTBAKE
"""
import json
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
TINY = os.path.join(REPO, "samples", "tiny.toml")  # 32x32 pixels (1024 rows), R = 8 (384 columns)
CHUNK_ROWS = 256  # 4 row blocks: 7 shards leave 3 of them without a chunk
FRAME_HEADER_BYTES = 64  # docs/FORMAT.md "Chunk frames"
T0 = time.monotonic()


def shard_path(out, i, n):
    stem = out[:-4] if out.endswith(".ltm") else out
    return f"{stem}.shards/{i:05d}-of-{n:05d}.ltm"


def inspect(path):
    p = run("inspect", "--json", path)
    return json.loads(p.stdout) if p.returncode == 0 else {}


def content_hash(path):
    return inspect(path).get("content_hash")


def to_npy(path, npy, *extra):
    run("convert", path, npy, "-q", *extra)
    with open(npy, "rb") as f:
        return f.read()


def out_err(p):
    return p.stdout + p.stderr


def sharded(stage_args, out, n, commit=True):
    """Runs `ltbake STAGE_ARGS -o OUT` as shards 0..n-1 (n = 1: the plain stage), then commits."""
    procs = []
    for i in range(n):
        shard = ["--shard", i, "--nshards", n] if n > 1 else []
        procs.append(run(*stage_args, "-o", out, "--progress", "never", *shard))
    if n > 1 and commit:
        p = run("commit", out, "--nshards", n)
        check(f"committed {out}: {n} shards" in p.stdout, f"commit {out}: unexpected report {p.stdout!r}")
    return procs


def names_shard(p, i, n, path, what):
    """The command failed with exit 1 and its message names shard i of n and its file."""
    msg = out_err(p)
    check(p.returncode == 1, f"{what}: exit {p.returncode}, expected 1\n{msg}")
    check(f"shard {i} of {n}" in msg, f"{what}: message does not name shard {i} of {n}:\n{msg}")
    check(os.path.basename(path) in msg, f"{what}: message does not name the file {path}:\n{msg}")


def file_state(path):
    st = os.stat(path)
    with open(path, "rb") as f:
        return st.st_mtime_ns, st.st_size, f.read()


def copy_output(out, dst_dir):
    """Copies a manifest and its shard directory into dst_dir; returns the copy's path."""
    os.makedirs(dst_dir, exist_ok=True)
    dst = os.path.join(dst_dir, os.path.basename(out))
    shutil.copy2(out, dst)
    src_shards = out[:-4] + ".shards"
    shutil.copytree(src_shards, dst[:-4] + ".shards")
    return dst


def haar_rows(raw, r):
    """PyWavelets' haar (periodization) of each cube face of each row, Mallat layout."""
    import pywt
    faces = raw.astype(np.float64).reshape(raw.shape[0], 6, r, r)
    coeffs = pywt.wavedec2(faces, "haar", mode="periodization", axes=(-2, -1))
    arr, _ = pywt.coeffs_to_array(coeffs, axes=(-2, -1))
    return arr.reshape(raw.shape[0], 6 * r * r)


with tempfile.TemporaryDirectory() as d:
    def P(*parts):
        return os.path.join(d, *parts)

    # --- unsharded reference chain --------------------------------------------------------
    os.makedirs(P("ref"))
    ref = {k: P("ref", k + ".ltm") for k in ["raw", "fused", "rows", "cols", "cols4d", "budget", "final"]}
    run("sample", TINY, "-o", ref["raw"], "--chunk-rows", CHUNK_ROWS, "-q")
    run("sample", TINY, "-o", ref["fused"], "--chunk-rows", CHUNK_ROWS, "--row-transform", "haar", "-q")
    run("row-transform", ref["raw"], "-o", ref["rows"], "-q")
    run("transpose", ref["rows"], "-o", ref["cols"], "-q")
    run("column-transform", ref["cols"], "-o", ref["cols4d"], "-q")
    run("column-transform", ref["cols"], "-o", ref["budget"], "--budget", "2%", "-q")
    run("quantize", ref["cols4d"], "-o", ref["final"], "-q")
    want = {k: content_hash(v) for k, v in ref.items()}
    check(all(isinstance(h, str) and len(h) == 16 for h in want.values()), f"reference hashes: {want}")
    check(want["fused"] == want["rows"], "fused sample + row-transform != sample then row-transform")
    ref_npy = {k: to_npy(ref[k], P("ref", k + ".npy")) for k in ["raw", "rows", "cols", "cols4d", "budget", "final"]}
    check(ref_npy["cols"] == ref_npy["rows"], "the transposed matrix does not decode to the rows matrix")
    chunks = {k: [a["chunks"]["expected"] for a in inspect(ref[k])["arrays"]] for k in ["raw", "cols", "final"]}
    check(min(chunks["raw"]) < 7 and min(chunks["cols"]) < 7,
          f"7 shards should exceed the chunks of some array: {chunks}")

    # Independent oracle: the rows matrix is PyWavelets' per-face haar of the raw matrix.
    raw_m = np.load(P("ref", "raw.npy"))
    rows_m = np.load(P("ref", "rows.npy"))
    err = np.max(np.abs(haar_rows(raw_m, 8) - rows_m))
    check(err <= 1e-6 * max(1.0, float(np.max(np.abs(raw_m)))), f"rows != pywt haar of raw (max error {err})")

    # --shard 0 --nshards 1 is the whole output, the plain container at OUT (no shard files).
    one = P("one", "raw.ltm")
    os.makedirs(P("one"))
    run("sample", TINY, "-o", one, "--chunk-rows", CHUNK_ROWS, "--shard", 0, "--nshards", 1, "-q")
    check(content_hash(one) == want["raw"] and not os.path.exists(P("one", "raw.shards")),
          "--nshards 1 did not write the whole container at OUT")
    check("manifest" not in inspect(one) and "shard" not in inspect(one), "--nshards 1 wrote a shard or manifest")

    # --- sharded chains: 2, 3 and 7 shards ------------------------------------------------
    outs = {}
    for n in [2, 3, 7]:
        w = P(f"n{n}")
        os.makedirs(w)
        o = {k: os.path.join(w, k + ".ltm") for k in ref}
        outs[n] = o
        sharded(["sample", TINY, "--chunk-rows", CHUNK_ROWS], o["raw"], n)
        sharded(["sample", TINY, "--chunk-rows", CHUNK_ROWS, "--row-transform", "haar"], o["fused"], n)
        sharded(["row-transform", o["raw"]], o["rows"], n)  # input: the raw manifest
        sharded(["transpose", o["rows"]], o["cols"], n)
        sharded(["column-transform", o["cols"]], o["cols4d"], n)
        if n == 3:
            sharded(["column-transform", o["cols"], "--budget", "2%"], o["budget"], n)
        sharded(["quantize", o["cols4d"]], o["final"], n)
        for k, out in o.items():
            if k == "budget" and n != 3:
                continue
            info = inspect(out)
            check(info.get("manifest", {}).get("nshards") == n, f"n={n} {k}: inspect shows no manifest of {n} shards")
            check(info.get("complete") is True, f"n={n} {k}: manifest not complete")
            check(info.get("content_hash") == want[k],
                  f"n={n} {k}: content_hash {info.get('content_hash')} != unsharded {want[k]}")
            for i in range(n):
                si = inspect(shard_path(out, i, n))
                check(si.get("shard", {}).get("index") == i and si.get("shard", {}).get("count") == n,
                      f"n={n} {k}: shard file {i} does not say it is shard {i} of {n}")
            if k in ref_npy:
                check(to_npy(out, os.path.join(w, k + ".npy")) == ref_npy[k], f"n={n} {k}: .npy != unsharded .npy")
            merged = os.path.join(w, k + ".merged.ltm")
            p = run("merge", out, "-o", merged)
            check(f"wrote {merged}" in p.stdout, f"n={n} {k}: merge report {p.stdout!r}")
            mi = inspect(merged)
            check(mi.get("content_hash") == want[k], f"n={n} {k}: merged content_hash {mi.get('content_hash')}")
            check("manifest" not in mi and "shard" not in mi and mi.get("complete") and mi.get("sealed"),
                  f"n={n} {k}: merged file is not one sealed complete container: {mi.get('manifest')} {mi.get('shard')}")
            run("verify", merged)
            run("verify", out)
        # Independent of the transforms: the transposed matrix decodes to the rows matrix.
        check(np.array_equal(np.load(os.path.join(w, "cols.npy")), rows_m), f"n={n}: cols manifest != rows matrix")
        # Shards that own no chunk of the 4-block arrays are complete, sealed and empty.
        # (sample balances its shards by the rows that see geometry, so which of the raw matrix's
        # seven shards are the empty ones depends on the image: at least three of them are.)
        if n == 7:
            infos = [inspect(shard_path(o["raw"], i, 7)) for i in range(7)]
            empty = [si for si in infos if si["arrays"][0]["chunks"]["expected"] == 0]
            check(len(empty) >= 3 and all(si.get("complete") and si.get("sealed") for si in empty),
                  f"n=7: {len(empty)} of the raw matrix's shards own nothing (4 blocks: expected >= 3), "
                  f"complete and sealed: {[si.get('arrays', [{}])[0].get('chunks') for si in infos]}")
    # relight reads a manifest like a container: the same image, bit for bit.
    env = P("env.npy")
    np.save(env, (np.random.default_rng(5).uniform(0, 1, (6 * 8 * 8, 3)) ** 4 * 5).astype(np.float32))
    run("relight", ref["final"], "--env", env, "-o", P("ref", "relit.npy"), "--terms", 50, "-q")
    for n in [2, 7]:
        run("relight", outs[n]["final"], "--env", env, "-o", P(f"n{n}", "relit.npy"), "--terms", 50, "-q")
        check(os.path.exists(P(f"n{n}", "relit.npy")) and
              open(P(f"n{n}", "relit.npy"), "rb").read() == open(P("ref", "relit.npy"), "rb").read(),
              f"n={n}: relight of the final manifest != relight of the unsharded final.ltm")
    print(f"chains: {time.monotonic() - T0:.1f} s", flush=True)

    # --- mixing sharded and unsharded stages ----------------------------------------------
    os.makedirs(P("mix"))
    mix_cols = P("mix", "cols.ltm")
    sharded(["transpose", ref["rows"]], mix_cols, 3)  # sharded stage, unsharded input
    check(content_hash(mix_cols) == want["cols"], "sharded transpose of an unsharded input: other content_hash")
    mix_final = P("mix", "final.ltm")
    run("quantize", outs[2]["cols4d"], "-o", mix_final, "-q")  # unsharded stage, manifest input
    check(content_hash(mix_final) == want["final"], "unsharded quantize of a manifest: other content_hash")
    mix_c4 = P("mix", "cols4d.ltm")
    sharded(["column-transform", outs[7]["cols"]], mix_c4, 2)  # 2 shards reading a 7-shard manifest
    check(content_hash(mix_c4) == want["cols4d"], "2 column-transform shards reading a 7-shard manifest")

    # --- idempotence: a complete shard rerun writes nothing -------------------------------
    o = outs[3]
    stage_args = {
        "raw": ["sample", TINY, "--chunk-rows", CHUNK_ROWS],
        "rows": ["row-transform", o["raw"]],
        "cols": ["transpose", o["rows"]],
        "cols4d": ["column-transform", o["cols"], "--json"],
        "final": ["quantize", o["cols4d"], "--json"],
    }
    for k, args in stage_args.items():
        f = shard_path(o[k], 1, 3)
        before = file_state(f)
        owned = sum(a["chunks"]["expected"] for a in inspect(f)["arrays"])
        p = run(*args, "-o", o[k], "--shard", 1, "--nshards", 3, "--progress", "never")
        check(file_state(f) == before, f"rerun of complete shard 1 of {k}: file changed (bytes or mtime)")
        s = p.stdout
        if k == "raw":
            ok = f"resumed ({owned} chunks were committed)" in s and "rays traced: 0 " in s
        elif k == "rows":
            ok = f"(resumed: {owned} already committed)" in s
        elif k == "cols":
            ok = f"(resumed: {owned} already committed)" in s and s.rstrip().endswith("wrote 0")
        else:
            j = json.loads(s) if p.returncode == 0 else {}
            ok = j.get("chunks_written") == 0 and j.get("chunks_already_committed") == owned \
                and j.get("file") == shard_path(o[k], 1, 3)
        check(ok and owned > 0, f"rerun of complete shard 1 of {k} ({owned} chunks owned) does not report "
                                f"0 new chunks:\n{s}")
    m_before = open(o["final"], "rb").read()
    run("commit", o["final"], "--nshards", 3)
    check(open(o["final"], "rb").read() == m_before, "committing twice gave other manifest bytes")
    check(m_before.startswith(b"LTBAKE-MANIFEST 1\n"), "manifest lacks its magic line")
    mj = json.loads(m_before.split(b"\n", 1)[1])
    check(mj.get("version") == 1 and mj.get("nshards") == 3 and mj.get("content_hash") == want["final"]
          and [s["index"] for s in mj.get("shards", [])] == [0, 1, 2]
          and all(set(s) >= {"path", "bytes", "fingerprint", "content_hash", "hash_sum"} for s in mj["shards"])
          and "shard" not in mj.get("metadata", {}), f"manifest JSON not as specified: {list(mj)}")
    p = run("commit", o["final"], "--nshards", 3, "--json")
    cj = json.loads(p.stdout) if p.returncode == 0 else {}
    check(cj.get("content_hash") == want["final"] and len(cj.get("shards", [])) == 3, f"commit --json: {cj}")
    print(f"idempotence: {time.monotonic() - T0:.1f} s", flush=True)

    # --- damage after the commit ----------------------------------------------------------
    def fresh(name, src):
        return copy_output(src, P("dmg", name))

    # A manifest moved with its shard directory still reads (shard paths are relative).
    moved = fresh("moved", outs[3]["final"])
    check(content_hash(moved) == want["final"], "a manifest copied with its shards reads otherwise")
    run("verify", moved)
    # A manifest that names itself (or another manifest) as a shard: an error, not a crash.
    with open(moved, "rb") as f:
        magic, body = f.read().split(b"\n", 1)
    mj = json.loads(body)
    mj["shards"][1]["path"] = os.path.basename(moved)
    selfref = P("dmg", "moved", "self.ltm")
    with open(selfref, "wb") as f:
        f.write(magic + b"\n" + json.dumps(mj).encode())
    mj["shards"][1]["path"] = "self.ltm"
    with open(moved, "wb") as f:
        f.write(magic + b"\n" + json.dumps(mj).encode())
    for path in (selfref, moved):
        for cmd in ("inspect", "verify"):
            p = run(cmd, path, expect=1)
            check("is itself a manifest" in out_err(p), f"{cmd} of a manifest naming a manifest as shard 1:\n"
                                                        f"{out_err(p)}")

    # A missing shard: inspect, verify, convert and the next stage name it.
    rows = fresh("missing", outs[3]["rows"])
    s1 = shard_path(rows, 1, 3)
    os.remove(s1)
    names_shard(run("inspect", rows, expect=None), 1, 3, s1, "inspect, missing shard")
    names_shard(run("inspect", "--json", rows, expect=None), 1, 3, s1, "inspect --json, missing shard")
    names_shard(run("verify", rows, expect=None), 1, 3, s1, "verify, missing shard")
    names_shard(run("convert", rows, P("dmg", "missing", "x.npy"), expect=None), 1, 3, s1, "convert, missing shard")
    check(not os.path.exists(P("dmg", "missing", "x.npy")), "convert of a broken manifest left an .npy")
    names_shard(run("transpose", rows, "-o", P("dmg", "missing", "cols.ltm"), expect=None), 1, 3, s1,
                "transpose of a manifest with a missing shard")
    names_shard(run("transpose", rows, "-o", P("dmg", "missing", "c.ltm"), "--shard", 0, "--nshards", 2,
                    expect=None), 1, 3, s1, "sharded transpose of a manifest with a missing shard")
    names_shard(run("merge", rows, "-o", P("dmg", "missing", "m.ltm"), expect=None), 1, 3, s1, "merge, missing shard")

    # Shard 1 made with other parameters (--spp 2), in its own directory.
    other = P("dmg", "other", "raw.ltm")
    os.makedirs(P("dmg", "other"))
    run("sample", TINY, "-o", other, "--chunk-rows", CHUNK_ROWS, "--spp", 2, "--shard", 1, "--nshards", 3, "-q")
    # ... at commit time: the shard and the differing key are named, nothing written.
    w = P("dmg", "spp-commit")
    os.makedirs(w)
    shutil.copytree(outs[3]["raw"][:-4] + ".shards", os.path.join(w, "raw.shards"))
    raw = os.path.join(w, "raw.ltm")
    shutil.copy(shard_path(other, 1, 3), shard_path(raw, 1, 3))
    p = run("commit", raw, "--nshards", 3, expect=None)
    names_shard(p, 1, 3, shard_path(raw, 1, 3), "commit of a shard with other --spp")
    check("spp" in out_err(p), f"commit of a shard with other --spp does not name spp:\n{out_err(p)}")
    check(not os.path.exists(raw), "a refused commit wrote the manifest")
    # ... at read time of an already committed manifest.
    raw = fresh("spp-read", outs[3]["raw"])
    shutil.copy(shard_path(other, 1, 3), shard_path(raw, 1, 3))
    same_size = os.path.getsize(shard_path(other, 1, 3)) == os.path.getsize(shard_path(outs[3]["raw"], 1, 3))
    for cmd in (["inspect", raw], ["verify", raw], ["convert", raw, P("dmg", "spp-read", "x.npy")],
                ["row-transform", raw, "-o", P("dmg", "spp-read", "rows.ltm")]):
        p = run(*cmd, expect=None)
        names_shard(p, 1, 3, shard_path(raw, 1, 3), f"{cmd[0]}: shard with other --spp")
        # (A shard of another size is refused for its size before its parameters are compared.)
        check(not same_size or "spp" in out_err(p), f"{cmd[0]}: shard with other --spp, spp not named:\n{out_err(p)}")
    # ... rerun in place: refused without --overwrite (naming spp), then overwritten.
    raw = fresh("spp-overwrite", outs[3]["raw"])
    p = run("sample", TINY, "-o", raw, "--chunk-rows", CHUNK_ROWS, "--spp", 2, "--shard", 1, "--nshards", 3,
            expect=1)
    check("spp" in out_err(p), f"sample rerun with other --spp does not say which parameter:\n{out_err(p)}")
    run("sample", TINY, "-o", raw, "--chunk-rows", CHUNK_ROWS, "--spp", 2, "--shard", 1, "--nshards", 3,
        "--overwrite", "-q")
    names_shard(run("inspect", raw, expect=None), 1, 3, shard_path(raw, 1, 3), "inspect: shard overwritten with --spp 2")
    names_shard(run("commit", raw, "--nshards", 3, expect=None), 1, 3, shard_path(raw, 1, 3),
                "recommit: shard overwritten with --spp 2")

    # A corrupt chunk payload in the middle of a shard file.
    cols = fresh("corrupt", outs[3]["cols"])  # 24 column blocks: shard 1 holds 8
    s1 = shard_path(cols, 1, 3)
    listing = run("inspect", "--json", "--chunks", s1)
    chunk_list = json.loads(listing.stdout).get("chunk_list", []) if listing.returncode == 0 else []
    frames = [c for c in chunk_list if c["array"] == "matrix" and c["stored_bytes"] > 0]
    check(len(frames) >= 3, f"shard 1 of the cols matrix has too few stored chunks to damage: {len(frames)}")
    if frames:
        victim = frames[len(frames) // 2]
        size = os.path.getsize(s1)
        at = victim["offset"] + FRAME_HEADER_BYTES + victim["stored_bytes"] // 2
        check(size // 4 < at < size * 3 // 4, f"the damaged chunk is not in the middle of the file ({at} of {size})")
        with open(s1, "r+b") as f:
            f.seek(at)
            b = f.read(4)
            f.seek(at)
            f.write(bytes(x ^ 0x5A for x in b))
        p = run("verify", cols, expect=None)
        names_shard(p, 1, 3, s1, "verify, corrupt chunk")
        check(f"chunk {victim['index']}" in out_err(p), f"verify does not name chunk {victim['index']}:\n{out_err(p)}")
        p = run("verify", "--json", cols, expect=None)
        vj = json.loads(p.stdout)[0] if p.stdout.strip().startswith("[") else {}
        check(vj.get("ok") is False and any("shard 1 of 3" in x for x in vj.get("problems", [])),
              f"verify --json does not list the damaged shard: {vj}")
        p = run("convert", cols, P("dmg", "corrupt", "x.npy"), expect=None)
        check(p.returncode == 1 and os.path.basename(s1) in out_err(p),
              f"convert of a corrupt shard: exit {p.returncode}, must fail naming the shard file:\n{out_err(p)}")
        check(not os.path.exists(P("dmg", "corrupt", "x.npy")), "convert of a corrupt shard left an .npy")
        p = run("column-transform", cols, "-o", P("dmg", "corrupt", "cols4d.ltm"), expect=None)
        check(p.returncode == 1 and os.path.basename(s1) in out_err(p),
              f"column-transform of a corrupt shard: exit {p.returncode}, must fail naming the shard file:\n{out_err(p)}")
        # ... and at commit time.
        os.remove(cols)
        names_shard(run("commit", cols, "--nshards", 3, expect=None), 1, 3, s1, "commit of a corrupt shard")
        check(not os.path.exists(cols), "a refused commit wrote the manifest")

    # A truncated shard.
    rows = fresh("truncated", outs[3]["rows"])
    s1 = shard_path(rows, 1, 3)
    os.truncate(s1, os.path.getsize(s1) // 2)
    for cmd in (["inspect", rows], ["verify", rows], ["convert", rows, P("dmg", "truncated", "x.npy")]):
        names_shard(run(*cmd, expect=None), 1, 3, s1, f"{cmd[0]}: truncated shard")

    # Another shard's file in shard 1's place.
    rows = fresh("swapped", outs[3]["rows"])
    s1 = shard_path(rows, 1, 3)
    shutil.copy(shard_path(rows, 2, 3), s1)
    for cmd in (["inspect", rows], ["verify", rows], ["convert", rows, P("dmg", "swapped", "x.npy")]):
        names_shard(run(*cmd, expect=None), 1, 3, s1, f"{cmd[0]}: shard 2's file as shard 1")
    os.remove(rows)
    names_shard(run("commit", rows, "--nshards", 3, expect=None), 1, 3, s1, "commit: shard 2's file as shard 1")

    # commit with shards missing lists them and writes nothing.
    w = P("dmg", "commit-missing")
    os.makedirs(w)
    raw = os.path.join(w, "raw.ltm")
    shutil.copytree(outs[7]["raw"][:-4] + ".shards", raw[:-4] + ".shards")
    os.remove(shard_path(raw, 2, 7))
    os.remove(shard_path(raw, 5, 7))
    p = run("commit", raw, "--nshards", 7, expect=1)
    check("2 of 7 shards missing" in out_err(p) and "shard 2, 5" in out_err(p),
          f"commit with shards 2 and 5 missing does not list them:\n{out_err(p)}")
    check(not os.path.exists(raw), "commit with missing shards wrote OUT")
    # ... and with the wrong count (the 3 shards are not the shards of 2).
    p = run("commit", outs[3]["raw"], "--nshards", 2, expect=1)
    check("2 of 2 shards missing" in out_err(p), f"commit --nshards 2 of 3 shards:\n{out_err(p)}")
    check(content_hash(outs[3]["raw"]) == want["raw"], "a refused commit damaged the existing manifest")

    # commit onto a file that is not a manifest: refused without --overwrite.
    w = P("dmg", "commit-clobber")
    os.makedirs(w)
    raw = os.path.join(w, "raw.ltm")
    shutil.copytree(outs[3]["raw"][:-4] + ".shards", raw[:-4] + ".shards")
    shutil.copy(ref["raw"], raw)
    before = open(raw, "rb").read()
    p = run("commit", raw, "--nshards", 3, expect=1)
    check("--overwrite" in out_err(p), f"commit onto a container does not mention --overwrite:\n{out_err(p)}")
    check(open(raw, "rb").read() == before, "a refused commit changed the existing OUT")
    run("commit", raw, "--nshards", 3, "--overwrite", "-q")
    check(open(raw, "rb").read().startswith(b"LTBAKE-MANIFEST 1\n") and content_hash(raw) == want["raw"],
          "commit --overwrite did not replace OUT with the manifest")
    print(f"damage: {time.monotonic() - T0:.1f} s", flush=True)

    # --- Slurm job-array environment ------------------------------------------------------
    def env_run(args, env, cwd, expect=0):
        e = dict(os.environ)
        for k in ("SLURM_ARRAY_TASK_ID", "SLURM_ARRAY_TASK_COUNT"):
            e.pop(k, None)
        e.update({k: str(v) for k, v in env.items()})
        exe = os.path.abspath(LTBAKE) if os.sep in LTBAKE else LTBAKE  # runs in another directory
        p = subprocess.run([exe, *map(str, args)], capture_output=True, text=True, env=e, cwd=cwd, timeout=300)
        check(expect is None or p.returncode == expect,
              f"{env} ltbake {' '.join(map(str, args))}: exit {p.returncode}, expected {expect}\n{out_err(p)}")
        return p

    flags_dir, env_dir = P("slurm", "flags"), P("slurm", "env")
    os.makedirs(flags_dir)
    os.makedirs(env_dir)
    # --jobs 1: chunks are committed in one order, so equal files are equal bytes.
    for i in range(3):
        env_run(["sample", TINY, "-o", "raw.ltm", "--chunk-rows", CHUNK_ROWS, "--jobs", 1, "--shard", i,
                 "--nshards", 3, "-q"], {}, flags_dir)
        env_run(["sample", TINY, "-o", "raw.ltm", "--chunk-rows", CHUNK_ROWS, "--jobs", 1, "-q"],
                {"SLURM_ARRAY_TASK_ID": i, "SLURM_ARRAY_TASK_COUNT": 3}, env_dir)
    for i in range(3):
        a, b = shard_path(os.path.join(flags_dir, "raw.ltm"), i, 3), shard_path(os.path.join(env_dir, "raw.ltm"), i, 3)
        check(os.path.exists(b) and open(a, "rb").read() == open(b, "rb").read(),
              f"shard {i}: $SLURM_ARRAY_TASK_ID/COUNT did not give the file --shard/--nshards gives")
    check(sorted(os.listdir(os.path.join(env_dir, "raw.shards"))) == [f"{i:05d}-of-00003.ltm" for i in range(3)],
          f"env shards: {os.listdir(os.path.join(env_dir, 'raw.shards'))}")
    # A job array that runs only some shards (--array=2) has COUNT 1: it must pass --nshards.
    p = env_run(["sample", TINY, "-o", "part.ltm", "-q"], {"SLURM_ARRAY_TASK_ID": 2, "SLURM_ARRAY_TASK_COUNT": 1},
                env_dir, expect=2)
    check("--nshards" in p.stderr, f"TASK_ID 2 of COUNT 1 does not say to pass --nshards:\n{p.stderr}")
    check(not os.path.exists(os.path.join(env_dir, "part.ltm")) and not os.path.exists(os.path.join(env_dir, "part.shards")),
          "a usage error wrote output")
    env_run(["sample", TINY, "-o", "raw.ltm", "--chunk-rows", CHUNK_ROWS, "--nshards", 3, "-q"],
            {"SLURM_ARRAY_TASK_ID": 2, "SLURM_ARRAY_TASK_COUNT": 1}, env_dir)  # with --nshards: shard 2 of 3
    p = env_run(["sample", TINY, "-o", "x.ltm", "-q"], {"SLURM_ARRAY_TASK_ID": "two"}, env_dir, expect=2)
    check("SLURM_ARRAY_TASK_ID" in p.stderr, f"a non-numeric $SLURM_ARRAY_TASK_ID is not named:\n{p.stderr}")
    p = run("sample", TINY, "-o", P("slurm", "u.ltm"), "--shard", 3, "--nshards", 3, expect=2)
    check("--shard 3" in p.stderr, f"--shard 3 --nshards 3: message does not name the flag:\n{p.stderr}")
    for stage in (["row-transform", ref["raw"]], ["transpose", ref["rows"]], ["column-transform", ref["cols"]],
                  ["quantize", ref["cols4d"]]):
        run(*stage, "-o", P("slurm", "u.ltm"), "--shard", 3, "--nshards", 3, expect=2)
    run("sample", TINY, "-o", P("slurm", "u.ltm"), "--nshards", 0, expect=2)
    p = run("cpca", ref["rows"], "-o", P("slurm", "cpca.ltm"), "--clusters", 2, "--basis", 2, "--nshards", 2,
            expect=2)
    check("cpca" in p.stderr and not os.path.exists(P("slurm", "cpca.ltm")), f"cpca --nshards 2:\n{p.stderr}")
    run("commit", P("slurm", "u.ltm"), "--nshards", 0, expect=2)

    # --- a shard SIGKILLed mid-run resumes to the same content ----------------------------
    # spp 64 makes a shard take ~0.25 s; 16-row chunks (64 of them) make partial files likely.
    # content_hash does not depend on the chunking, so the 16-row shards must equal 256-row blocks.
    os.makedirs(P("kill"))
    kref = P("kill", "ref.ltm")
    run("sample", TINY, "-o", kref, "--spp", 64, "-q")
    kout = P("kill", "raw.ltm")
    kargs = ["sample", TINY, "-o", kout, "--spp", 64, "--chunk-rows", 16, "--jobs", 1, "--progress", "never",
             "--nshards", 2]
    t = time.monotonic()
    run(*kargs, "--shard", 0, "-q")
    whole = time.monotonic() - t  # shard 1 has as many rows: the kills land within its run
    target = shard_path(kout, 1, 2)
    rnd = random.Random(11)
    partial = 0
    for k in range(6):
        proc = subprocess.Popen([LTBAKE, *map(str, kargs), "--shard", "1"], stdout=subprocess.DEVNULL,
                                stderr=subprocess.DEVNULL)
        time.sleep(rnd.uniform(0.15, 0.85) * whole)
        proc.send_signal(signal.SIGKILL)
        proc.wait()
        if os.path.exists(target):
            p = run("verify", "--allow-incomplete", "--json", target)
            v = json.loads(p.stdout)[0] if p.returncode == 0 else {}
            check(v.get("ok") is True, f"kill {k}: the partial shard does not verify: {v}")
            si = inspect(target)
            c = si.get("arrays", [{}])[0].get("chunks", {})
            partial += 0 < c.get("committed", 0) < c.get("expected", 0)
    p = run(*kargs, "--shard", 1)
    check(partial > 0, "no kill landed while the shard was partly written (the kills came too early or too late)")
    check(partial == 0 or "resumed (" in p.stdout, f"the rerun after the kills did not resume:\n{p.stdout}")
    run("commit", kout, "--nshards", 2, "-q")
    check(content_hash(kout) == content_hash(kref), "a killed and resumed shard: other content_hash")
    run("verify", kout)
    print(f"kills: {time.monotonic() - T0:.1f} s (an uninterrupted shard: {whole:.2f} s)", flush=True)

finish()
