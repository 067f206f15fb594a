"""The hostile sweep (issue 36), for anyone to rerun at any scale: what a hostile or unlucky
user can hand every reader and writer, and whether anything crashes, hangs, fakes data or
replaces what it should not.

  1. mutants x every reader: the containers a tiny bake writes (rows, cols, cols4d, final;
     and a convert of a .npy), each mutated N times (a flipped byte, a truncation, a zeroed
     range, a chunk frame copied over another with its header checksum repaired); each mutant
     through verify, inspect --json, convert -> .npy and relight. A reader may refuse (exit 1)
     but never crash (a signal, exit >= 128), hang (past --timeout) or succeed with values
     other than the original's (a convert that exits 0 must give the original matrix);
  2. special-file outputs: relight -o .npy/.png/.exr, convert .ltm -> .npy and convert
     env -> .npy at a FIFO, a directory and a link to /dev/null: exit 1, the node unchanged;
  3. extreme values: maps near the float32 maximum (RGBE exponents 254 and 255)
     through convert env -> .npy: exit 1, or a finite, non-negative cubemap;
  4. hostile views of a factored bake (eye = target, zero or parallel up, an eye at 1e30,
     fov nan or 180, a view over --mem-limit): exit 1 or 2, never 134 (Embree's assertion).

usage: /usr/bin/python3 bench/edge_sweep.py [--ltbake build/ltbake] [--mutants 200] [--seed 1]
       [--timeout 60] [--json results.json]
Prints a table of outcomes and exits 1 if any case crashed, hung, faked data or replaced a node.
"""
import argparse
import json
import os
import random
import stat
import subprocess
import sys
import tempfile

import numpy as np

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), ".."))


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--ltbake", default=os.path.join(REPO, "build", "ltbake"))
    ap.add_argument("--mutants", type=int, default=200, help="mutants per container kind")
    ap.add_argument("--seed", type=int, default=1)
    ap.add_argument("--timeout", type=float, default=60.0, help="seconds a reader may take on one mutant")
    ap.add_argument("--json", help="write the tallies here")
    a = ap.parse_args()
    rnd = random.Random(a.seed)
    tally, bad = {}, []

    def run(*args, timeout=a.timeout):
        try:
            return subprocess.run([a.ltbake, *map(str, args)], capture_output=True, text=True, timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def record(group, what, p, ok_codes=(0, 1)):
        code = "hang" if p is None else p.returncode
        names = {0: "accepted", 1: "refused", 2: "usage error"}
        key = (group, names[code] if code in ok_codes else f"BAD exit {code}")
        tally[key] = tally.get(key, 0) + 1
        if code not in ok_codes:
            bad.append(f"{group}: {what}: {code}: {'' if p is None else p.stderr.strip()[-300:]}")
        return code

    with tempfile.TemporaryDirectory() as d:
        j = lambda *p: os.path.join(d, *p)  # noqa: E731
        w = j("bake")
        p = run("run", os.path.join(REPO, "samples", "tiny-bake.toml"), "--workdir", w, "-q", timeout=900)
        if p is None or p.returncode != 0:
            sys.exit(f"the tiny bake failed: {p and p.stderr}")
        env = j("env.npy")
        np.save(env, np.ones((6 * 8 * 8, 3), np.float32))
        m = np.random.default_rng(a.seed).random((300, 24), dtype=np.float32)
        np.save(j("m.npy"), m)
        run("convert", j("m.npy"), j("m.ltm"), "--chunk-size", "4KiB", "-q")
        kinds = {k: os.path.join(w, k + ".ltm") for k in ("rows", "cols", "cols4d", "final")}
        kinds["convert"] = j("m.ltm")
        originals = {}
        for k, path in kinds.items():
            out = j(f"orig_{k}.npy")
            run("convert", path, out, "-q")
            originals[k] = np.load(out)

        # 1. Mutants through every reader.
        for k, path in kinds.items():
            data = bytearray(open(path, "rb").read())
            for i in range(a.mutants):
                b = bytearray(data)
                how = rnd.choice(["flip", "truncate", "zero", "copy-frame"])
                if how == "flip":
                    for _ in range(rnd.randint(1, 4)):
                        b[rnd.randrange(len(b))] ^= 1 << rnd.randrange(8)
                elif how == "truncate":
                    del b[rnd.randrange(64, len(b)):]
                elif how == "zero":
                    s, n = rnd.randrange(len(b)), rnd.randint(1, 4096)
                    b[s:s + n] = bytes(len(b[s:s + n]))
                else:
                    frames = [o for o in range(64, len(b) - 64, 64) if b[o:o + 6] == b"LTMF\x01\x00"]
                    if len(frames) >= 2:
                        src, dst = rnd.sample(frames, 2)
                        b[dst:dst + 64] = b[src:src + 64]
                mp = j(f"mut_{k}.ltm")
                open(mp, "wb").write(bytes(b))
                what = f"{k} mutant {i} ({how})"
                record("mutants: verify", what, run("verify", mp))
                record("mutants: inspect", what, run("inspect", "--json", mp))
                out = j("mut.npy")
                if os.path.exists(out):
                    os.remove(out)
                pc = run("convert", mp, out, "-q")
                if record("mutants: convert", what, pc) == 0:
                    got = np.load(out)
                    if got.shape != originals[k].shape or not np.array_equal(got, originals[k]):
                        bad.append(f"mutants: convert: {what}: exit 0 with values other than the original's")
                        tally[("mutants: convert", "wrong data")] = tally.get(("mutants: convert", "wrong data"), 0) + 1
                if k == "final":
                    record("mutants: relight", what, run("relight", mp, "--env", env, "-o", j("mut_relit.npy"), "-q"))

        # 2. Special-file outputs.
        os.mkfifo(j("fifo"))
        os.mkdir(j("dir"))
        os.symlink("/dev/null", j("null"))
        write_hdr(j("sky.hdr"), 16, 8, (128, 128, 128, 129))
        for node in ("fifo", "dir", "null"):
            for ext in ("npy", "png", "exr"):
                target = j(f"{node}.{ext}")
                os.rename(j(node), target) if node != "null" else os.symlink("/dev/null", target)
                record("special outputs", f"relight -o {node}.{ext}",
                       run("relight", kinds["final"], "--env", env, "-o", target), ok_codes=(1,))
                if node == "null":
                    os.remove(target)
                else:
                    os.rename(target, j(node))
            target = j(f"{node}.npy")
            os.rename(j(node), target) if node != "null" else os.symlink("/dev/null", target)
            record("special outputs", f"convert -> {node}.npy", run("convert", kinds["final"], target), ok_codes=(1,))
            record("special outputs", f"convert env -> {node}.npy",
                   run("convert", j("sky.hdr"), target, "--cube-res", 8), ok_codes=(1,))
            os.remove(target) if node == "null" else os.rename(target, j(node))
        intact = stat.S_ISFIFO(os.stat(j("fifo")).st_mode) and os.path.isdir(j("dir")) and \
            stat.S_ISCHR(os.stat("/dev/null").st_mode)
        if not intact:
            bad.append("special outputs: a node was replaced")

        # 3. Extreme values.
        for name, rgbe in (("rgbe_255", (255, 255, 255, 255)), ("rgbe_255_red", (255, 0, 0, 255)),
                           ("rgbe_254", (200, 200, 200, 254))):
            path = j(name + ".hdr")
            write_hdr(path, 16, 8, rgbe)
            out = j(name + "_cube.npy")
            code = record("extreme values", name, run("convert", path, out, "--cube-res", 8))
            if code == 0:
                c = np.load(out)
                if not (np.isfinite(c).all() and (c >= 0).all()):
                    bad.append(f"extreme values: {name}: exit 0 with non-finite or negative texels")
                    tally[("extreme values", "wrong data")] = tally.get(("extreme values", "wrong data"), 0) + 1

        # 4. Hostile views of a factored bake.
        obj = j("octa.obj")
        with open(obj, "w") as f:
            f.write("v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1\n"
                    "f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6\n")
        with open(j("v.toml"), "w") as f:
            f.write(f'[output]\nmode = "vertex"\nobjects = ["o"]\n[sampling]\ncube_res = 8\nspp = 1\n'
                    f'[[material]]\nname = "g"\nalbedo = 0.3\nks = 0.5\nexponent = 8.0\n'
                    f'[[object]]\nname = "o"\ntype = "mesh"\nfile = "{obj}"\nmaterial = "g"\n')
        run("sample", j("v.toml"), "-o", j("g.ltm"), "--factor", 2, "-q", timeout=300)
        view = {"--eye": "0,-3,1", "--target": "0,0,0", "--up": "0,0,1", "--fov": "40", "--size": "8x8"}
        for change in ({"--eye": "0,0,0"}, {"--up": "0,0,0"}, {"--up": "0,3,-1"}, {"--eye": "1e30,0,0"},
                       {"--eye": "nan,0,0"}, {"--fov": "nan"}, {"--fov": "180"}, {"--fov": "0"},
                       {"--size": "16384x16384", "--mem-limit": "64MiB"}):
            args = sum(([k, v] for k, v in {**view, **change}.items()), [])
            record("hostile views", " ".join(f"{k} {v}" for k, v in change.items()),
                   run("relight", j("g.ltm"), "--env", env, *args, "-o", j("v.npy")), ok_codes=(1, 2))

    groups = sorted({g for g, _ in tally})
    print(f"{'group':24} outcomes")
    for g in groups:
        print(f"{g:24} " + ", ".join(f"{o}: {n}" for (gg, o), n in sorted(tally.items()) if gg == g))
    for b in bad:
        print("BAD", b)
    if a.json:
        with open(a.json, "w") as f:
            json.dump({"mutants": a.mutants, "seed": a.seed, "tally": {f"{g} / {o}": n for (g, o), n in tally.items()},
                       "bad": bad}, f, indent=1)
    sys.exit(1 if bad else 0)


def write_hdr(path, w, h, rgbe):
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode() + bytes(rgbe) * (w * h))


if __name__ == "__main__":
    main()
