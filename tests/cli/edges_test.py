"""Integrity at the edges (issue 36): what a hostile or unlucky user can do around the
container, each case a refusal with a clear message, never a replaced device, a stale resume,
an Embree abort or a half-written file.

1. Outputs written by rename (relight -o .npy/.png/.exr, convert .ltm -> .npy, convert
   env -> .npy) never replace a FIFO, a directory or a device: exit 1 naming the path and
   what it is, and the node is still what it was. A symbolic link to a regular file is
   followed (the file it names gets the output, the link stays); a dangling one is refused.
2. `convert m.npy m.ltm` after m.npy's values changed (same shape) refuses to resume the old
   file (naming the chunk and both values); --overwrite converts the new values.
4. A failed step's hint to resume the whole bake is the full command, --workdir included.
12. A view whose image buffers exceed --mem-limit is refused with the size that fits.
6. Views Embree cannot trace (eye = target, zero or parallel up, an eye at 1e30, fov nan) are
   refused by relight of a factored bake, and meshes beyond the traceable range by sample,
   in image and vertex mode: exit 1 with the value, never 134 (Embree's assertion).
14. `ltbake view` under load: every request gets a status (503 when busy), slow clients
    hold no worker and get 408.
13. `sample --sparse` of a scene with fewer than 64 dense rows works.
15. Recipes: a vertex scene through column-transform without depth = "none", a depth the
    image cannot take, and [triple] eye = target are refused before anything runs, naming
    the recipe's line.

usage: edges_test.py PATH_TO_LTBAKE
"""
import json
import os
import select
import signal
import socket
import stat
import subprocess
import struct
import sys
import tempfile
import threading

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest as t  # noqa: E402

W = H = 4
R = 2


def says(p, *parts, code=1, what=""):
    """p failed with `code` and its stderr holds every part; never an abort (134)."""
    t.check(p.returncode == code, f"{what}: exit {p.returncode}, expected {code}\n{p.stderr}")
    for part in parts:
        t.check(part in p.stderr, f"{what}: stderr lacks {part!r}:\n{p.stderr}")


def write_hdr(path, w, h, value_rgbe=(128, 128, 128, 129)):
    """A flat (not run-length coded) Radiance RGBE image, every pixel the same."""
    with open(path, "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n" + f"-Y {h} +X {w}\n".encode())
        f.write(bytes(value_rgbe) * (w * h))


def special_outputs(d, j):
    m = np.random.default_rng(3).random((W * H, 6 * R * R), dtype=np.float32)
    np.save(j("m.npy"), m)
    t.run("convert", j("m.npy"), j("m.ltm"), "--cube-res", R, "--image", f"{W}x{H}", "-q")
    env = np.ones((6 * R * R, 3), np.float32)
    np.save(j("env.npy"), env)
    write_hdr(j("sky.hdr"), 16, 8)

    fifo = j("pipe.out")
    os.mkfifo(fifo)
    os.mkdir(j("dir.out"))
    os.symlink("/dev/null", j("null.out"))
    os.symlink(j("absent.npy"), j("dangling.npy"))
    targets = [(fifo, "is a FIFO"), (j("dir.out"), "is a directory"),
               (j("null.out"), "which is a character device")]
    for ext in ("npy", "png", "exr"):
        for node, kind in targets:
            out = node + "." + ext
            if os.path.lexists(node) and not os.path.lexists(out):
                os.rename(node, out) if not os.path.islink(node) else os.symlink(os.readlink(node), out)
            p = t.run("relight", j("m.ltm"), "--env", j("env.npy"), "-o", out, expect=None)
            says(p, out, kind, what=f"relight -o {out}")
            os.rename(out, node) if not os.path.islink(out) else os.remove(out)
    for node, kind in targets:
        out = node + ".npy"
        os.rename(node, out) if not os.path.islink(node) else os.symlink(os.readlink(node), out)
        says(t.run("convert", j("m.ltm"), out, expect=None), out, kind, what=f"convert -> {out}")
        says(t.run("convert", j("sky.hdr"), out, "--cube-res", R, expect=None), out, kind,
             what=f"convert env -> {out}")
        if not os.path.islink(out):
            os.rename(out, node)
    t.check(stat.S_ISFIFO(os.stat(fifo).st_mode), "the FIFO was replaced")
    t.check(os.path.isdir(j("dir.out")), "the directory was replaced")
    t.check(stat.S_ISCHR(os.stat("/dev/null").st_mode), "/dev/null is no longer a device")
    t.check(not os.path.exists(fifo + ".lock") and not os.path.exists("/dev/null.lock"), "a lock file beside a node")
    says(t.run("relight", j("m.ltm"), "--env", j("env.npy"), "-o", j("dangling.npy"), expect=None),
         "dangling.npy", "does not exist", what="a dangling link")
    t.check(not os.path.exists(j("absent.npy")), "a dangling link's target was created")
    # A link to a regular file is followed: the file gets the image, the link stays.
    np.save(j("real.npy"), np.zeros(1, np.float32))
    os.symlink(j("real.npy"), j("link.npy"))
    t.run("relight", j("m.ltm"), "--env", j("env.npy"), "-o", j("link.npy"), "-q")
    t.check(os.path.islink(j("link.npy")), "the link was replaced by a file")
    got = np.load(j("real.npy"))
    want = (m.astype(np.float64) @ env.astype(np.float64))
    t.check(got.shape[0] == W * H and np.allclose(got.reshape(W * H, -1)[:, 0], want[:, 0], rtol=1e-5),
            f"the link's target does not hold the relit values: {got.shape}")


def changed_input(d, j):
    rng = np.random.default_rng(5)
    a = rng.random((300, 24), dtype=np.float32)
    np.save(j("c.npy"), a)
    t.run("convert", j("c.npy"), j("c.ltm"), "--chunk-size", "4KiB", "-q")
    b = a.copy()
    b[123, 7] += 1.0  # same shape, one value changed
    np.save(j("c.npy"), b)
    p = t.run("convert", j("c.npy"), j("c.ltm"), "--chunk-size", "4KiB", expect=None)
    says(p, "c.ltm", "row 123, column 7", "the input changed since", "--overwrite", what="changed .npy")
    t.run("convert", j("c.ltm"), j("back.npy"), "-q")
    t.check(np.array_equal(np.load(j("back.npy")), a), "the refused run changed the file")
    p = t.run("convert", j("c.npy"), j("c.ltm"), "--chunk-size", "4KiB", "--overwrite")
    t.check("started over" in p.stderr, f"--overwrite does not say it started over: {p.stderr}")
    t.run("convert", j("c.ltm"), j("back.npy"), "-q")
    t.check(np.array_equal(np.load(j("back.npy")), b), "--overwrite kept the old values")
    # Unchanged input: the rerun resumes (nothing to write) and says so.
    p = t.run("convert", j("c.npy"), j("c.ltm"), "--chunk-size", "4KiB")
    t.check("resumed" in p.stdout, f"an unchanged input was not resumed: {p.stdout}")


OCTA = """v 1 0 0\nv -1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nv 0 0 -1
f 1 3 5\nf 3 2 5\nf 2 4 5\nf 4 1 5\nf 3 1 6\nf 2 3 6\nf 4 2 6\nf 1 4 6
"""


def scene_text(mode, obj, scale=1.0, cube_res=R):
    out = 'objects = ["ball"]' if mode == "vertex" else \
        "[camera]\neye = [0.0, -4.0, 1.0]\ntarget = [0.0, 0.0, 0.0]\nup = [0.0, 0.0, 1.0]\nwidth = 8\nheight = 8"
    return f"""[output]
mode = "{mode}"
{out if mode == "vertex" else ""}
{"" if mode == "vertex" else out}
[sampling]
cube_res = {cube_res}
spp = 1
[[material]]
name = "shiny"
albedo = 0.3
ks = 0.5
exponent = 8.0
[[object]]
name = "ball"
type = "mesh"
file = "{obj}"
scale = {scale!r}
material = "shiny"
"""


def hostile_views(d, j):
    t.write(j("octa.obj"), OCTA)
    vs = t.write(j("v.toml"), scene_text("vertex", j("octa.obj")))
    t.run("sample", vs, "-o", j("g.ltm"), "--factor", 2, "-q")
    env = j("env.npy")
    ok_view = ["--eye", "0,-3,1", "--target", "0,0,0", "--up", "0,0,1", "--size", "8x8"]
    t.run("relight", j("g.ltm"), "--env", env, *ok_view, "-o", j("view.npy"), "-q")
    cases = [
        (["--eye", "0,0,0"], "equals target"),
        (["--up", "0,0,0"], "up is [0, 0, 0]"),
        (["--up", "0,3,-1"], "parallel to the view direction"),
        (["--eye", "1e30,0,0"], "eye [1e+30, 0, 0] is outside what ray tracing holds"),
        (["--fov", "nan"], "fov"),
    ]
    for change, part in cases:
        args = list(ok_view)
        for k in range(0, len(change), 2):
            i = args.index(change[k]) if change[k] in args else None
            if i is None:
                args += change[k:k + 2]
            else:
                args[i + 1] = change[k + 1]
        p = t.run("relight", j("g.ltm"), "--env", env, *args, "-o", j("bad.npy"), expect=None)
        t.check(p.returncode in (1, 2), f"relight {change}: exit {p.returncode}\n{p.stderr}")
        t.check(part in p.stderr, f"relight {change}: stderr lacks {part!r}:\n{p.stderr}")
        t.check(not os.path.exists(j("bad.npy")), f"relight {change}: wrote an image")
    # 12. The view's image buffers count against --mem-limit (16384² took 12 GiB under 64MiB).
    args = [a if a != "8x8" else "16384x16384" for a in ok_view]
    p = t.run("relight", j("g.ltm"), "--env", env, *args, "--mem-limit", "64MiB", "-o", j("big.npy"), expect=None)
    says(p, "--size 16384x16384", "over --mem-limit 64.0 MiB", "largest square view that fits is 1182x1182",
         what="a view over --mem-limit")
    # Meshes beyond what Embree traces: refused with the vertex, in both modes.
    for mode, scale in (("image", 1e25), ("vertex", 1e20)):
        sc = t.write(j(f"far_{mode}.toml"), scene_text(mode, j("octa.obj"), scale=scale))
        p = t.run("sample", sc, "-o", j(f"far_{mode}.ltm"), expect=None)
        says(p, f"far_{mode}.toml", "outside what ray tracing holds", what=f"{mode} mesh at {scale:g}")


def sparse_small(d, j):
    sc = t.write(j("small.toml"), scene_text("image", j("octa.obj"), cube_res=4).replace("width = 8\nheight = 8",
                                                                                        "width = 16\nheight = 16"))
    p = t.run("sample", sc, "-o", j("sp.ltm"), "--sparse", "-q", expect=None)
    t.check(p.returncode == 0, f"sparse on a 16x16 image: exit {p.returncode}\n{p.stderr}")
    t.check(".dense.ltm" not in p.stderr, f"sparse names an internal file: {p.stderr}")
    if p.returncode == 0:
        v = json.loads(t.run("verify", "--json", j("sp.ltm")).stdout)[0]
        t.check(v["ok"], f"the small sparse bake does not verify: {v}")


def recipes(d, j):
    vs = j("v.toml")
    rec = t.write(j("vdepth.toml"), f'name = "v"\nscene = "{vs}"\nworkdir = "{j("wv")}"\n'
                  '[sample]\nfactor = 2\n[column-transform]\nbudget = "5%"\n')
    p = t.run("run", rec, "--dry-run", expect=None)
    says(p, "vdepth.toml", 'depth = "none"', code=2, what="a factored vertex recipe without depth none")
    rec = t.write(j("vdepth2.toml"), f'name = "v"\nscene = "{vs}"\nworkdir = "{j("wv")}"\n'
                  '[sample]\nfactor = 2\n[column-transform]\ndepth = "adaptive"\n')
    says(t.run("run", rec, "--dry-run", expect=None), "vdepth2.toml:7", 'depth = "none"', code=2,
         what="line of depth")
    img = t.write(j("img.toml"), scene_text("image", j("octa.obj")))
    rec = t.write(j("deep.toml"), f'name = "i"\nscene = "{img}"\nworkdir = "{j("wi")}"\n'
                  '[column-transform]\ndepth = 99\n')
    says(t.run("run", rec, "--dry-run", expect=None), "deep.toml:5", "at most 3", code=2, what="depth 99")
    rec = t.write(j("tri.toml"), f'name = "tr"\nscene = "{img}"\nworkdir = "{j("wt")}"\n'
                  f'[triple]\nmaterials = ["lambert"]\nenvs = ["{j("sky.hdr")}"]\n'
                  'eye = [0.0, 0.0, 0.0]\ntarget = [0.0, 0.0, 0.0]\n')
    says(t.run("run", rec, "--dry-run", expect=None), "tri.toml:7", "equals target", code=2,
         what="[triple] eye = target")
    t.check(not os.path.exists(j("wt", "run.json")), "a refused recipe ran")


def resume_hint(d, j):
    img = j("img.toml")
    # A map whose header passes the recipe's shape check (32x16, lat-long) but whose pixels
    # stop after 16 of 512: the bake runs and its relight step fails.
    with open(j("broken.hdr"), "wb") as f:
        f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y 16 +X 32\n" + bytes([128, 128, 128, 129]) * 16)
    w = j("wh")
    rec = t.write(j("hint.toml"), f'name = "h"\nscene = "{img}"\ntargets = ["relight"]\n'
                  f'[relight]\nenvs = ["{j("broken.hdr")}"]\n')
    p = t.run("run", rec, "--workdir", w, "--mem-limit", "256MiB", expect=None)
    t.check(p.returncode == 1, f"a bake with a broken map: exit {p.returncode}\n{p.stderr}")
    want = f"ltbake run {rec} --workdir {w} --mem-limit 256MiB"
    t.check(want in p.stderr, f"the resume hint is not the full command {want!r}:\n{p.stderr}")


def http_get(port, target, timeout=60):
    """(status, body) of a GET, or (None, error text) when no HTTP answer came."""
    try:
        with socket.create_connection(("127.0.0.1", port), timeout=timeout) as c:
            c.sendall(f"GET {target} HTTP/1.1\r\nHost: x\r\n\r\n".encode())
            data = b""
            while True:
                b = c.recv(65536)
                if not b:
                    break
                data += b
        head = data.split(b"\r\n", 1)[0].split()
        return (int(head[1]) if len(head) > 1 else None), data
    except OSError as e:
        return None, str(e)


def view_under_load(d, j):
    """14. `ltbake view` answers every request under load: 200 at once each get a status
    (200, or 503 when its queue is full), and clients that send their request a byte at a time
    hold no worker (a normal request is answered while they dribble; they get 408)."""
    view = subprocess.Popen([t.LTBAKE, "view", j("m.ltm"), "--env", j("sky.hdr")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        url = view.stdout.readline().strip()
        port = int(url.rsplit(":", 1)[1].strip("/"))
        results = [None] * 200
        def one(i):
            results[i] = http_get(port, f"/frame.png?rotate={i}")[0]
        threads = [threading.Thread(target=one, args=(i,)) for i in range(200)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        codes = {c: results.count(c) for c in set(results)}
        t.check(set(codes) <= {200, 503} and codes.get(200, 0) > 0, f"200 concurrent requests: {codes}")
        # Slow clients: 20 connections sending a byte every 0.2 s (at most 300 bytes, 60 s).
        slow = []
        for _ in range(20):
            c = socket.create_connection(("127.0.0.1", port), timeout=120)
            c.sendall(b"GET /frame.png?rotate=1")
            slow.append(c)
        ended = [None] * len(slow)
        def dribble(k):
            c = slow[k]
            try:
                for _ in range(300):
                    c.sendall(b"0")
                    r, _, _ = select.select([c], [], [], 0.2)
                    if r:
                        ended[k] = c.recv(64).split(b"\r\n", 1)[0].decode(errors="replace")
                        return
                ended[k] = "still reading after 300 bytes"
            except OSError as e:
                ended[k] = f"closed: {e}"
        dribblers = [threading.Thread(target=dribble, args=(k,)) for k in range(len(slow))]
        for th in dribblers:
            th.start()
        code, body = http_get(port, "/stats", timeout=60)
        t.check(code == 200, f"a normal request among 20 slow clients: {code} {body[:200]!r}")
        t.check(all(e is None for e in ended), f"slow clients were answered before the normal one: {ended}")
        for th in dribblers:
            th.join()
        for c in slow:
            c.close()
        t.check(all(e is not None and " 408 " in e + " " for e in ended), f"slow clients did not get 408: {ended}")
        code, _ = http_get(port, "/frame.png?rotate=5%00abc")
        t.check(code == 400, f"rotate=5%00abc: {code}, expected 400")
    finally:
        view.send_signal(signal.SIGINT)
        view.wait(timeout=60)


def view_bright(d, j):
    """8. `ltbake view` under a map near float32's largest value (RGBE exponent 255) relights
    at 2^-k and scales back, as relight does: a frame, not an error."""
    write_hdr(j("e255.hdr"), 64, 32, (255, 255, 255, 255))
    # In the Haar basis (row-transform) at R = 8 the lighting's coefficients reach 8× a texel,
    # beyond float32 unscaled (the image was NaN); a transport of 2^-20 (each row sums to
    # ~2^-20·3R²) keeps the image within float32.
    dim = np.random.default_rng(5).random((W * H, 6 * 8 * 8), dtype=np.float32) * np.float32(2.0 ** -20)
    np.save(j("dim.npy"), dim)
    t.run("convert", j("dim.npy"), j("dim.ltm"), "--cube-res", 8, "--image", f"{W}x{H}", "-q")
    t.run("row-transform", j("dim.ltm"), "-o", j("dimw.ltm"), "-q")
    view = subprocess.Popen([t.LTBAKE, "view", j("dimw.ltm"), "--env", j("e255.hdr")], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
    try:
        url = view.stdout.readline().strip()
        port = int(url.rsplit(":", 1)[1].strip("/"))
        code, body = http_get(port, "/frame.png?rotate=3")
        t.check(code == 200 and b"\r\n\r\n\x89PNG" in body, f"view of an exponent-255 map: {code} {body[:200]!r}")
    finally:
        view.send_signal(signal.SIGINT)
        view.wait(timeout=60)


def main():
    with tempfile.TemporaryDirectory() as d:
        j = lambda *p: os.path.join(d, *p)  # noqa: E731
        special_outputs(d, j)
        changed_input(d, j)
        hostile_views(d, j)
        sparse_small(d, j)
        recipes(d, j)
        resume_hint(d, j)
        view_under_load(d, j)
        view_bright(d, j)
    t.finish()


if __name__ == "__main__":
    main()
