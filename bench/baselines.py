#!/usr/bin/python3
"""ltbake's compressed light transport against what a user would pick instead, in bytes
on disk at equal relit error, on scenes and maps no test or default was tuned on.

Per scene (bench/unseen_meshes.py: the Utah teapot, a scanned bust; R = 32, spp 4):
sample -> raw.ltm (the pixel-basis matrix T every method starts from) -> row-transform db2
-> transpose, then

- ltbake adaptive 4D: column-transform --budget B (adaptive depth, LeGall 5/3) -> quantize
  (the default, --error-ratio 1.1): final.ltm;
- ltbake 2D: the same with --depth none;
- zfp (Debian python3-zfpy) of T itself, in its 2D layout (pixels x lights) and a 4D one
  (H x W x 6R x R), fixed accuracy at max|T| * 2^-k and fixed precision, never fixed rate;
  reversible as the lossless point;
- JPEG 2000 (Debian OpenJPEG, opj_compress): every light's column as an H x W image, 16
  bits after one global scale (max|T|; T >= 0), tiled into one mosaic with one tile per
  light (`-t W,H`), over compression ratios (-r);
- zstd -3 of T's bytes (lossless floor).

Error: the relit image under each map with every lighting term (so only the matrix
differs), B' = T' L, against B = T L of the uncompressed raw matrix, rel. L2 over the
pixels that see geometry (raw.ltm's mask) and the three channels, averaged over the maps.
ltbake's files are relit by `ltbake relight --terms all --no-clamp-output`; the
baselines' decoded matrices by NumPy in float64. The maps: Blender's night, studio and
sunrise (blender-data), which no test uses, resampled by `ltbake convert --cube-res 32
--clamp`. Bytes at equal error are interpolated log-log along each curve (the lower
envelope of zfp's layouts and modes).

    /usr/bin/python3 bench/baselines.py [BUILD=build]

Environment: LTB_BASE_SCENES ("teapot:128 snowden:128"), LTB_BASE_MAPS (the three above),
LTB_BASE_DIR (bench/out/baselines), LTB_BASE_NAME (baselines). Writes
bench/results/NAME.md, .json and .png.
"""
import json
import math
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests", "cli"))
import benchlib  # noqa: E402
import ltbtest  # noqa: E402
import unseen_meshes  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(benchlib.ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
ltbtest.LTBAKE = LTB
SCENES = [s.split(":") for s in os.environ.get("LTB_BASE_SCENES", "teapot:128 snowden:128").split()]
OUT = os.path.abspath(os.environ.get("LTB_BASE_DIR", os.path.join(HERE, "out", "baselines")))
NAME = os.environ.get("LTB_BASE_NAME", "baselines")
R = 32
B4D = ["0.1%", "0.25%", "0.5%", "1%", "2%", "4%", "8%"]
B2D = ["0.5%", "1%", "2%", "4%", "8%", "16%"]
ZFP_K = list(range(1, 15))       # fixed accuracy: tolerance max|T| * 2^-k
ZFP_PREC = [6, 8, 10, 12, 14, 16, 20]
J2K_RATIOS = [500, 200, 100, 50, 25, 12, 6, 3]
TARGETS = [0.005, 0.01, 0.02, 0.05]


def ltb(*args):
    p = subprocess.run([LTB, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"ltbake {' '.join(map(str, args))}\n{p.stderr}")
    return p.stdout


def default_maps():
    d = subprocess.run(["bash", os.path.join(benchlib.ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True, check=True).stdout.strip()
    return [os.path.join(d, f"{n}.exr") for n in ("night", "studio", "sunrise")]


MAPS = os.environ.get("LTB_BASE_MAPS", "").split() or default_maps()


class Scene:
    """The raw matrix T, its mask, the lighting cubemaps and the reference images B = T L
    (make_scene builds one)."""

    def path(self, f):
        return os.path.join(self.dir, f)

    def error_of(self, images):
        """Mean over the maps of rel. L2 on the mask-1 rows."""
        errs = []
        for b, ref in zip(images, self.B):
            d = (b - ref)[self.mask]
            errs.append(math.sqrt((d ** 2).sum() / (ref[self.mask] ** 2).sum()))
        return float(np.mean(errs))

    def matrix_error(self, T2):
        T2 = T2.reshape(self.T.shape)
        return self.error_of([T2.astype(np.float64) @ L for L in self.L])


def ltbake_curves(s):
    out = {"ltbake adaptive 4D": [], "ltbake 2D": []}
    for label, flags, budgets in (("ltbake adaptive 4D", ["--depth", "adaptive"], B4D),
                                  ("ltbake 2D", ["--depth", "none"], B2D)):
        for b in budgets:
            ltb("column-transform", s.path("cols.ltm"), "-o", s.path("c4.ltm"), *flags, "--budget", b, "-q",
                "--overwrite")
            ltb("quantize", s.path("c4.ltm"), "-o", s.path("final.ltm"), "-q", "--overwrite")
            images = []
            for cube in s.maps:
                ltb("relight", s.path("final.ltm"), "--env", cube, "--terms", "all", "--no-clamp-output", "-o",
                    s.path("relit.npy"), "-q")
                images.append(np.load(s.path("relit.npy")).reshape(-1, 3).astype(np.float64))
            out[label].append({"setting": b, "bytes": os.path.getsize(s.path("final.ltm")), "error": s.error_of(images)})
            print(f"  {label} {b}: {out[label][-1]['bytes']} B, error {out[label][-1]['error']:.4%}", flush=True)
    os.remove(s.path("c4.ltm"))
    return out


def zfp_curves(s):
    import zfpy
    H = W = s.size
    layouts = {"2D": s.T, "4D": s.T.reshape(H, W, 6 * R, R)}
    top = float(np.abs(s.T).max())
    out = {}
    for lname, arr in layouts.items():
        arr = np.ascontiguousarray(arr)
        for mode, settings in (("accuracy", ZFP_K), ("precision", ZFP_PREC), ("reversible", [None])):
            key = f"zfp {lname} {mode}"
            out[key] = []
            for k in settings:
                kw = {"tolerance": top * 2.0 ** -k} if mode == "accuracy" else {"precision": k} if mode == "precision" \
                    else {}
                blob = zfpy.compress_numpy(arr, **kw)
                err = s.matrix_error(zfpy.decompress_numpy(blob))
                out[key].append({"setting": k, "bytes": len(blob), "error": err})
            print(f"  {key}: {[(p['bytes'], round(p['error'], 5)) for p in out[key]]}", flush=True)
    return out


def j2k_curves(s):
    """Two ways to put the matrix in JPEG 2000: one tile per light (each light's image coded
    on its own, the rate split evenly between tiles) and the same mosaic as one tile (one
    rate allocation for the whole matrix; the wavelet crosses the lights' borders)."""
    H = W = s.size
    T = s.T
    if T.min() < 0:
        raise SystemExit(f"{s.name}: T has negative entries ({T.min()}); the JPEG 2000 baseline assumes T >= 0")
    top = float(T.max())
    gc, gr = R, 6 * R  # tiles per mosaic row and column: light j at tile (j // R, j % R)
    q = np.round(T / top * 65535).astype("<u2")  # rows x lights
    mosaic = q.T.reshape(gr, gc, H, W).transpose(0, 2, 1, 3).reshape(gr * H, gc * W)
    mosaic.tofile(s.path("mosaic.rawl"))
    del q, mosaic
    out = {}
    for label, tiles in (("JPEG 2000, a tile per light", ["-t", f"{W},{H}"]), ("JPEG 2000, one mosaic", [])):
        out[label] = []
        for ratio in J2K_RATIOS:
            subprocess.run(["opj_compress", "-i", s.path("mosaic.rawl"), "-F", f"{gc * W},{gr * H},1,16,u", "-o",
                            s.path("m.j2k"), "-r", str(ratio), *tiles], check=True, capture_output=True)
            subprocess.run(["opj_decompress", "-i", s.path("m.j2k"), "-o", s.path("m.rawl")], check=True,
                           capture_output=True)
            dec = np.fromfile(s.path("m.rawl"), "<u2").reshape(gr, H, gc, W).transpose(0, 2, 1, 3).reshape(-1, H * W).T
            T2 = dec.astype(np.float64) / 65535 * top
            out[label].append({"setting": ratio, "bytes": os.path.getsize(s.path("m.j2k")) + 8,
                               "error": s.matrix_error(T2)})
            print(f"  {label} -r {ratio}: {out[label][-1]['bytes']} B, error {out[label][-1]['error']:.4%}", flush=True)
    for f in ("mosaic.rawl", "m.rawl", "m.j2k"):
        os.remove(s.path(f))
    return out


def zstd_floor(s):
    p = subprocess.run(["zstd", "-3", "-T2", "-q", "-c", s.path("raw.npy")], capture_output=True, check=True)
    return len(p.stdout)


def bytes_at(curve, target):
    """Bytes at relit error `target`, log-log between the two points around it (None outside)."""
    pts = sorted((p["error"], p["bytes"]) for p in curve if p["error"] > 0)
    best = None
    for (e0, b0), (e1, b1) in zip(pts, pts[1:]):
        if e0 <= target <= e1 and e1 > e0:
            t = (math.log(target) - math.log(e0)) / (math.log(e1) - math.log(e0))
            b = math.exp(math.log(b0) + t * (math.log(b1) - math.log(b0)))
            best = b if best is None else min(best, b)
    for e, b in pts:  # a point at or below the target with fewer bytes than the interpolation
        if e <= target and (best is None or b < best):
            best = b
    return best


def main():
    os.makedirs(OUT, exist_ok=True)
    results = []
    t0 = time.time()
    for name, size in SCENES:
        size = int(size)
        print(f"{name} {size}²", flush=True)
        s = make_scene(name, size)
        curves = {}
        curves.update(ltbake_curves(s))
        curves.update(zfp_curves(s))
        curves.update(j2k_curves(s))
        floor = zstd_floor(s)
        results.append({"scene": name, "size": size, "rows": int(s.T.shape[0]), "cols": int(s.T.shape[1]),
                        "raw_bytes": int(s.T.nbytes), "zstd_bytes": floor, "curves": curves})
        for f in ("raw.npy", "cols.ltm", "final.ltm", "relit.npy"):
            if os.path.exists(s.path(f)):
                os.remove(s.path(f))
    report(results, time.time() - t0)


def make_scene(name, size):
    """Bakes the scene (raw.ltm, then rows and cols for ltbake) and its reference images."""
    s = Scene()
    s.name, s.size = name, size
    s.dir = os.path.join(OUT, f"{name}{size}")
    os.makedirs(s.dir, exist_ok=True)
    scene = unseen_meshes.scenes(os.path.join(OUT, "scenes"), size)[name]
    w = s.path
    ltb("sample", scene, "-o", w("raw.ltm"), "--cube-res", R, "-q", "--overwrite")
    ltb("convert", w("raw.ltm"), w("raw.npy"), "-q", "--overwrite")
    ltb("row-transform", w("raw.ltm"), "-o", w("rows.ltm"), "--filter", "db2", "-q", "--overwrite")
    ltb("transpose", w("rows.ltm"), "-o", w("cols.ltm"), "-q", "--overwrite")
    os.remove(w("rows.ltm"))
    s.T = np.load(w("raw.npy"))
    s.mask = ltbtest.side_table(w("raw.ltm"), "mask")[:, 0] != 0
    s.maps, s.L = [], []
    for m in MAPS:
        cube = w(os.path.basename(m) + ".npy")
        ltb("convert", m, cube, "--cube-res", R, "--clamp", "-q", "--overwrite")
        s.maps.append(cube)
        s.L.append(np.load(cube).astype(np.float64))
    s.B = [s.T.astype(np.float64) @ L for L in s.L]
    return s


def report(results, seconds):
    res = os.path.join(HERE, "results")
    meta = {"machine": benchlib.machine(), "commit": benchlib.git_describe(), "maps": [os.path.basename(m) for m in MAPS],
            "minutes": seconds / 60}
    json.dump({**meta, "results": results}, open(os.path.join(res, NAME + ".json"), "w"), indent=1)
    L = ["# ltbake against zfp and JPEG 2000: bytes on disk at equal relit error, unseen scenes", "",
         f"`/usr/bin/python3 bench/baselines.py` ({seconds / 60:.1f} min); {meta['machine']}; commit {meta['commit']}.",
         f"Scenes: bench/unseen_meshes.py, R = 32, spp 4. Maps: {', '.join(meta['maps'])} (Blender's, unused by the "
         "tests). Error: relit rel. L2 with every lighting term against the uncompressed matrix, pixels that see "
         "geometry, mean over the maps. Bytes interpolated log-log at each error.", ""]
    for r in results:
        c = r["curves"]
        zfp = [p for k, v in c.items() if k.startswith("zfp") and "reversible" not in k for p in v]
        zfp_lossless = min(v[0]["bytes"] for k, v in c.items() if "reversible" in k)
        L += [f"## {r['scene']} {r['size']}² ({r['rows']} × {r['cols']}, raw f32 {r['raw_bytes']:,} B; zstd -3 "
              f"{r['zstd_bytes']:,} B; zfp reversible {zfp_lossless:,} B)", "",
              "| relit error | ltbake 4D | ltbake 2D | zfp (best layout, mode) | JPEG 2000 (best way) | 2D / 4D | zfp / 4D | "
              "JPEG 2000 / 4D |", "|---|---|---|---|---|---|---|---|"]
        j2k = [p for k, v in c.items() if k.startswith("JPEG") for p in v]
        for t in TARGETS:
            b4, b2 = bytes_at(c["ltbake adaptive 4D"], t), bytes_at(c["ltbake 2D"], t)
            bz, bj = bytes_at(zfp, t), bytes_at(j2k, t)
            f = lambda b: f"{b:,.0f}" if b else "–"  # noqa: E731
            q = lambda b: f"{b / b4:.2f}×" if b and b4 else "–"  # noqa: E731
            L.append(f"| {t:.1%} | {f(b4)} | {f(b2)} | {f(bz)} | {f(bj)} | {q(b2)} | {q(bz)} | {q(bj)} |")
        L += ["", "Every point (setting: bytes, error):", ""]
        for k, v in c.items():
            L.append(f"- {k}: " + "; ".join(f"{p['setting']}: {p['bytes']:,} B, {p['error']:.3%}" for p in v))
        L.append("")
    open(os.path.join(res, NAME + ".md"), "w").write("\n".join(L) + "\n")
    print("\n".join(L))
    plot(results, os.path.join(res, NAME + ".png"))


def plot(results, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, len(results), figsize=(6 * len(results), 4.5), squeeze=False)
    for ax, r in zip(axes[0], results):
        for k, v in r["curves"].items():
            if "reversible" in k:
                continue
            pts = sorted((p["bytes"], p["error"]) for p in v)
            ax.loglog([p[0] for p in pts], [p[1] for p in pts], "o-" if k.startswith("ltbake") else ".--", label=k,
                      lw=2 if k.startswith("ltbake") else 1)
        ax.set_title(f"{r['scene']} {r['size']}², R = 32")
        ax.set_xlabel("bytes on disk")
        ax.set_ylabel("relit rel. L2 (every lighting term)")
        ax.grid(True, which="both", alpha=0.3)
        ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


if __name__ == "__main__":
    main()
