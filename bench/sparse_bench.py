#!/usr/bin/python3
"""Sparse precomputation (`ltbake sample --sparse`, Huang & Ramamoorthi 2010) against the full bake.

Issue "sparse precomputation", targets: at most 12% of the matrix entries traced, sampling
at least 5x faster (wall), relit images within 2% relative L2 of the full bake's, and
dense-first CPCA at least 8x faster than plain CPCA of the full bake at most 5% more error.

Per case (scene, bounces), in bench/out/sparse/CASE/:
 1. the full bake, `ltbake sample SCENE -o full.ltm --progress never -q --jobs 2`, and
 2. the sparse bake, the same with `--sparse`, alternately REPEATS times each (outputs and
    the sparse checkpoint `<out>.dense.ltm` deleted before each run), after one untimed
    warm-up run of each without -q whose text gives the full bake's rays and horizon skips
    and the sparse phases' wall seconds. Wall seconds (perf_counter around the child),
    CPU seconds and peak RSS of the child (os.wait4); medians with min-max;
 3. a second full bake with `--seed 2` (once): the Monte Carlo noise floor at the same spp;
 4. `ltbake inspect sparse.ltm --json`: traced fraction, entries, rays, rows and
    thread-seconds per phase (summed over rows, so they can exceed the wall time);
 5. row-transform (haar) of the three, relight under every bundled environment map
    (scripts/find_envmaps.sh) at each TERMS with --clamp; rel. L2 = |a - b| / |b| over all
    pixels and channels (b = full), rel. H1 = the same of the images' forward differences
    in x and y (image mode only; vertex mode reports L2, also per object, and no H1); for
    sparse vs full and for seed 2 vs full (the floor);
 6. first case only: `ltbake cpca -k 64 -s 16` of the full bake's rows (plain, the paper's
    baseline), of the sparse rows (dense-first, automatic on a sparse bake) and of the
    sparse rows with --no-dense-first: wall seconds, relative_rms_error, rows_streamed,
    seconds_dense/seconds_final, and relit rel. L2 at 200 terms against the full rows
    under two maps (city and forest when present);
 7. first case only (image mode): full, sparse and 10x |difference| under city.exr at the
    largest TERMS, tone-mapped with one exposure from the full image (its 99th percentile
    to 1, gamma 1/2.2): bench/results/sparse_CASE_{full,sparse,diff10,side_by_side}.png.

Cases (LTB_SPARSE_CASES, comma-separated; default all four):
  medium     samples/medium.toml, 256x256 image, bounces 0
  dragon     samples/dragon.toml, 128x128 image, bounces 0
  vertex     bench/sparse_scenes/dragon_grid.toml: the dragon (res3, 22,998 vertices) on a
             160x160-vertex ground grid (generated into bench/out/sparse/ by
             bench/sparse_scenes/ground_grid.py), 48,598 vertex rows, bounces 0
  vertex-b1  the same with --bounces 1

Run (from anywhere; BUILD_DIR defaults to build/):

    /usr/bin/python3 bench/sparse_bench.py [BUILD_DIR]
    LTB_SPARSE_NAME=smoke LTB_SPARSE_SCALE=0.25 LTB_SPARSE_CUBE_RES=16 LTB_SPARSE_REPEATS=1 \\
        /usr/bin/python3 bench/sparse_bench.py          # a ~3-minute check that it all works

Run the full scale on an otherwise idle machine (the header records the load average).

Environment knobs:
  LTB_SPARSE_CASES     cases to run (medium,dragon,vertex,vertex-b1)
  LTB_SPARSE_REPEATS   timed runs of each of full and sparse (3)
  LTB_SPARSE_SCALE     multiplies the image width and height (aspect kept) and the ground
                       grid's vertices a side (1.0); scaled scenes go to bench/out/sparse/scenes/
  LTB_SPARSE_CUBE_RES  R, passed as --cube-res to every bake (32)
  LTB_SPARSE_TERMS     relight --terms values (100,200)
  LTB_SPARSE_JOBS      sample --jobs (2)
  LTB_SPARSE_CPCA      0 skips step 6 (1)
  LTB_SPARSE_MAPS      comma-separated environment maps instead of scripts/find_envmaps.sh's
  LTB_SPARSE_CPCA_KS   CPCA clusters and basis size, "K,S" (64,16)
  LTB_SPARSE_WARMUP    0: no untimed warm-up runs; the first runs, which also give the ray
                       counts, are timed (1)
  LTB_SPARSE_CPCA_RUNS which CPCA runs (plain,dense-first,no-dense-first); the target needs the
                       first two, no-dense-first (the same passes on the sparse rows) is the slowest
  LTB_SPARSE_KEEP      1 keeps the case's .ltm files in bench/out/sparse/CASE/ (0: each raw
                       bake is deleted once row-transformed, the rest when the case is done;
                       the full-scale medium case peaks at ~6 GB of disk)
  LTB_SPARSE_NAME      results are bench/results/sparse_bench_NAME.{md,csv,json} and
                       sparse_CASE_NAME_*.png (default: sparse_bench.* and sparse_CASE_*.png)

Writes bench/results/sparse_bench[_NAME].md (tables, also printed), .csv (one row per
case x map x terms) and .json (every measurement, including each repetition), each
through a temporary name. A failing command is reported with its stderr; the other cases
still run and the script exits 1 at the end.

Runtime at full scale on the 2-vCPU VM: about an hour, extrapolated (not measured) from a
scale-0.25, R = 16 run (3 min) by rows x texels and from bench/results/cpca.md: medium ~4 min
of bakes and relights plus ~25 min of CPCA (plain ~10, dense-first ~5, no-dense-first ~10;
LTB_SPARSE_CPCA_RUNS=plain,dense-first saves the last), dragon ~2 min, vertex ~6 min,
vertex-b1 ~25 min (five full bakes with a bounce, ~4-5 min each: warm-up, 3 timed, seed 2).
"""
import csv
import datetime
import io
import json
import os
import re
import shlex
import shutil
import statistics
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import git_describe, machine  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
OUT = os.path.join(HERE, "out", "sparse")
RESULTS = os.path.join(HERE, "results")
sys.path.insert(0, os.path.join(HERE, "sparse_scenes"))
import ground_grid  # noqa: E402  (bench/sparse_scenes/ground_grid.py)

ALL_CASES = ["medium", "dragon", "vertex", "vertex-b1"]
CASES = [c.strip() for c in os.environ.get("LTB_SPARSE_CASES", ",".join(ALL_CASES)).split(",") if c.strip()]
REPEATS = int(os.environ.get("LTB_SPARSE_REPEATS", "3"))
SCALE = float(os.environ.get("LTB_SPARSE_SCALE", "1.0"))
CUBE_RES = int(os.environ.get("LTB_SPARSE_CUBE_RES", "32"))
TERMS = [int(t) for t in os.environ.get("LTB_SPARSE_TERMS", "100,200").split(",") if t.strip()]
JOBS = int(os.environ.get("LTB_SPARSE_JOBS", "2"))
DO_CPCA = os.environ.get("LTB_SPARSE_CPCA", "1") != "0"
CPCA_RUNS = {"plain": ("plain, full bake", "full_rows", []),
             "dense-first": ("dense-first, sparse bake", "sparse_rows", []),
             "no-dense-first": ("--no-dense-first, sparse bake", "sparse_rows", ["--no-dense-first"])}
CPCA_SELECTED = [r.strip() for r in os.environ.get("LTB_SPARSE_CPCA_RUNS", ",".join(CPCA_RUNS)).split(",") if r.strip()]
KEEP = os.environ.get("LTB_SPARSE_KEEP", "0") == "1"
NAME = os.environ.get("LTB_SPARSE_NAME", "")
TAG = "_" + NAME if NAME else ""
KNOBS = ["LTB_SPARSE_MAPS", "LTB_SPARSE_WARMUP", "LTB_SPARSE_CPCA_KS", "LTB_SPARSE_CASES", "LTB_SPARSE_REPEATS", "LTB_SPARSE_SCALE", "LTB_SPARSE_CUBE_RES", "LTB_SPARSE_TERMS",
         "LTB_SPARSE_JOBS", "LTB_SPARSE_CPCA", "LTB_SPARSE_CPCA_RUNS", "LTB_SPARSE_KEEP", "LTB_SPARSE_NAME"]

CPCA_K, CPCA_S = (int(v) for v in os.environ.get("LTB_SPARSE_CPCA_KS", "64,16").split(","))
CPCA_TERMS = 200
WARMUP = os.environ.get("LTB_SPARSE_WARMUP", "1") != "0"
GRID_N, GRID_SIZE = 160, 6.0  # the vertex scenes' ground: vertices a side, units a side
DRAGON_PLY = os.path.join(ROOT, "data", "meshes", "dragon_res3.ply")
TARGET_TRACED, TARGET_SPEEDUP, TARGET_L2 = 0.12, 5.0, 0.02
TARGET_CPCA_SPEEDUP, TARGET_CPCA_ERROR = 8.0, 1.05


# ---- running commands ---------------------------------------------------------------------

class CommandError(Exception):
    pass


class Run:
    """A finished child: its stdout, wall and CPU seconds, peak RSS."""

    def __init__(self, stdout, wall, cpu, rss_mib):
        self.stdout, self.wall, self.cpu, self.rss_mib = stdout, wall, cpu, rss_mib


def ltbake(*args):
    """Runs ltbake with ARGS; raises CommandError (with its stderr) unless it exits 0."""
    cmd = [LTB, *map(str, args)]
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        t0 = time.perf_counter()
        p = subprocess.Popen(cmd, stdout=out, stderr=err)
        _, status, ru = os.wait4(p.pid, 0)  # this child's own rusage
        wall = time.perf_counter() - t0
        p.returncode = os.waitstatus_to_exitcode(status)
        out.seek(0)
        err.seek(0)
        stdout, stderr = out.read().decode(errors="replace"), err.read().decode(errors="replace")
    if p.returncode != 0:
        raise CommandError(f"`{shlex.join(cmd)}` exited {p.returncode}\n--- stderr ---\n{stderr.rstrip()}"
                           + (f"\n--- stdout ---\n{stdout.rstrip()}" if stdout.strip() else ""))
    return Run(stdout, wall, ru.ru_utime + ru.ru_stime, ru.ru_maxrss / 1024)


def remove(*paths):
    for p in paths:
        if os.path.exists(p):
            os.remove(p)


def write_atomic(path, data):
    """Writes str or bytes to PATH through PATH.tmp, renamed when complete."""
    tmp = path + ".tmp"
    with open(tmp, "wb") as f:
        f.write(data.encode() if isinstance(data, str) else data)
    os.replace(tmp, path)


def log(msg):
    print(msg, flush=True)


# ---- scenes -------------------------------------------------------------------------------

def ply_vertices(path):
    with open(path, "rb") as f:
        for line in f:
            if line.startswith(b"element vertex"):
                return int(line.split()[2])
            if line.startswith(b"end_header"):
                break
    raise ValueError(f"{path}: no `element vertex` in the PLY header")


def absolute_mesh_paths(text, src_dir):
    """The scene text with every `file = "..."` made absolute (relative to SRC_DIR)."""
    return re.sub(r'^(\s*file\s*=\s*")([^"]+)(")',
                  lambda m: m.group(1) + os.path.normpath(os.path.join(src_dir, m.group(2))) + m.group(3),
                  text, flags=re.M)


def scaled_image_scene(src, case):
    """SRC itself at scale 1, else a copy in OUT/scenes/ with width and height scaled."""
    if SCALE == 1.0:
        return src
    with open(src) as f:
        text = f.read()
    w = int(re.search(r"^\s*width\s*=\s*(\d+)", text, re.M).group(1))
    h = int(re.search(r"^\s*height\s*=\s*(\d+)", text, re.M).group(1))
    w2 = max(8, round(w * SCALE))
    h2 = max(8, round(w2 * h / w))
    text = re.sub(r"^(\s*width\s*=\s*)\d+", rf"\g<1>{w2}", text, flags=re.M)
    text = re.sub(r"^(\s*height\s*=\s*)\d+", rf"\g<1>{h2}", text, flags=re.M)
    text = absolute_mesh_paths(text, os.path.dirname(os.path.abspath(src)))
    dst = os.path.join(OUT, "scenes", f"{case}_s{SCALE:g}.toml")
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    write_atomic(dst, f"# {os.path.relpath(src, ROOT)} at LTB_SPARSE_SCALE={SCALE:g}: {w2}x{h2} "
                      "(bench/sparse_bench.py)\n" + text)
    return dst


def vertex_scene():
    """bench/sparse_scenes/dragon_grid.toml and its ground grid (scaled: a copy in OUT/scenes/).
    Returns the scene path and the rows of each object, in row order."""
    src = os.path.join(HERE, "sparse_scenes", "dragon_grid.toml")
    n = max(2, round(GRID_N * SCALE))
    grid = os.path.join(OUT, "ground_grid.obj" if n == GRID_N else f"ground_grid_{n}.obj")
    ground_grid.write_grid(grid, n, GRID_SIZE)
    parts = [("dragon", ply_vertices(DRAGON_PLY)), ("ground", n * n)]  # objects = ["dragon", "ground"]
    if n == GRID_N:
        return src, parts
    with open(src) as f:
        text = absolute_mesh_paths(f.read(), os.path.dirname(src))
    default_grid = os.path.join(OUT, "ground_grid.obj")
    if default_grid not in text:
        raise ValueError(f"{src}: expected the ground grid at {default_grid}")
    text = text.replace(default_grid, grid)
    dst = os.path.join(OUT, "scenes", f"vertex_s{SCALE:g}.toml")
    os.makedirs(os.path.dirname(dst), exist_ok=True)
    write_atomic(dst, f"# bench/sparse_scenes/dragon_grid.toml with a {n}x{n} ground grid "
                      f"(LTB_SPARSE_SCALE={SCALE:g}, bench/sparse_bench.py)\n" + text)
    return dst, parts


def case_setup(case):
    """The case's scene file, extra sample flags, and the rows of each object (vertex mode)."""
    if case == "medium":
        return scaled_image_scene(os.path.join(ROOT, "samples", "medium.toml"), case), [], None
    if case == "dragon":
        return scaled_image_scene(os.path.join(ROOT, "samples", "dragon.toml"), case), [], None
    if case in ("vertex", "vertex-b1"):
        scene, parts = vertex_scene()
        return scene, (["--bounces", "1"] if case == "vertex-b1" else []), parts
    raise ValueError(f"unknown case {case!r} in LTB_SPARSE_CASES; known: {', '.join(ALL_CASES)}")


def envmaps():
    if os.environ.get("LTB_SPARSE_MAPS"):  # maps of one's own instead of Blender's
        return [os.path.abspath(m) for m in os.environ["LTB_SPARSE_MAPS"].split(",") if m.strip()]
    p = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True, text=True)
    if p.returncode != 0:
        raise CommandError(f"scripts/find_envmaps.sh exited {p.returncode}\n{p.stderr}")
    d = p.stdout.strip()
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".exr"))


def map_name(path):
    return os.path.splitext(os.path.basename(path))[0]


# ---- steps 1-4: the bakes -----------------------------------------------------------------

def parse_full_text(text):
    """Rays and horizon skips from the text of a full `sample` run."""
    rays = re.search(r"rays traced: (\d+) in ([0-9.eE+-]+) s", text)
    skipped = re.search(r"skipped: (\d+) \(row, texel\) pairs wholly below the horizon", text)
    seeing = re.search(r"rows that see geometry: (\d+)", text)
    if not (rays and skipped and seeing):
        raise CommandError("cannot parse the full sample's text (rays traced / skipped / rows that see "
                           "geometry):\n" + text)
    return {"rays": int(rays.group(1)), "trace_seconds": float(rays.group(2)),
            "skipped_pairs": int(skipped.group(1)), "rows_seeing": int(seeing.group(1))}


def parse_sparse_text(text):
    """The sparse run's own summary (percentages and per-phase wall seconds), or {}."""
    out = {}
    m = re.search(r"traced ([0-9.]+)% of the entries \(phase 1 ([0-9.]+)%, phase 2 ([0-9.]+)%\)", text)
    if m:
        out["traced_percent"] = [float(m.group(i)) for i in (1, 2, 3)]
    m = re.search(r"phase 1 (\d+) rays in ([0-9.]+) s, phase 2 (\d+) rays in ([0-9.]+) s", text)
    if m:
        out["phase_rays"] = [int(m.group(1)), int(m.group(3))]
        out["phase_wall_seconds"] = [float(m.group(2)), float(m.group(4))]
    m = re.search(r"sparse: .*", text)
    if m:
        out["line"] = m.group(0)
    return out


def bake(scene, flags, work):
    """Steps 1-4: warm-ups, alternating timed full/sparse runs, the seed-2 bake, inspect."""
    full, sparse, seed2 = (os.path.join(work, f) for f in ("full.ltm", "sparse.ltm", "full_seed2.ltm"))
    common = ["--progress", "never", "--jobs", JOBS, "--cube-res", CUBE_RES, *flags]

    def run_full(quiet=True):
        remove(full)
        return ltbake("sample", scene, "-o", full, *common, *(["-q"] if quiet else []))

    def run_sparse(quiet=True):
        remove(sparse, sparse + ".dense.ltm")
        return ltbake("sample", scene, "-o", sparse, "--sparse", *common, *(["-q"] if quiet else []))

    warm_full, warm_sparse = run_full(quiet=False), run_sparse(quiet=False)
    log(f"  {'warm-up' if WARMUP else 'run #1'}: full {warm_full.wall:.2f} s, sparse {warm_sparse.wall:.2f} s wall")
    res = {"full_text": parse_full_text(warm_full.stdout), "sparse_text": parse_sparse_text(warm_sparse.stdout),
           "full": [], "sparse": []}
    if not WARMUP:  # LTB_SPARSE_WARMUP=0: the first (verbose) runs are timed runs too
        for kind, r in (("full", warm_full), ("sparse", warm_sparse)):
            res[kind].append({"wall": r.wall, "cpu": r.cpu, "rss_mib": r.rss_mib})
    for i in range(REPEATS if WARMUP else REPEATS - 1):
        for kind, fn in (("full", run_full), ("sparse", run_sparse)):
            r = fn()
            res[kind].append({"wall": r.wall, "cpu": r.cpu, "rss_mib": r.rss_mib})
            log(f"  {kind} #{i + 1}: {r.wall:.2f} s wall, {r.cpu:.2f} s CPU, {r.rss_mib:.0f} MiB")
    remove(seed2)
    ltbake("sample", scene, "-o", seed2, "--seed", 2, *common, "-q")
    info = json.loads(ltbake("inspect", sparse, "--json", "--progress", "never").stdout)
    if not info.get("sparse"):
        raise CommandError(f"{sparse}: `inspect --json` has no sparse block")
    res["sparse_inspect"] = info["sparse"]
    res["basis_rows"] = info["basis"]["rows"]
    res["shape"] = info["shape"]
    return res


# ---- step 5: relit images -----------------------------------------------------------------

def row_transform(work, names):
    for x in names:
        rows = os.path.join(work, f"{x}_rows.ltm")
        remove(rows)
        ltbake("row-transform", os.path.join(work, f"{x}.ltm"), "-o", rows, "--filter", "haar",
               "--progress", "never", "-q")
        if not KEEP:
            remove(os.path.join(work, f"{x}.ltm"))


def relit(work, matrix, env, terms):
    """The relit image (rows x 3, float64) of WORK/MATRIX.ltm, cached in WORK/relit/."""
    out = os.path.join(work, "relit", f"{matrix}_{map_name(env)}_{terms}.npy")
    if not os.path.exists(out):
        os.makedirs(os.path.dirname(out), exist_ok=True)
        ltbake("relight", os.path.join(work, matrix + ".ltm"), "--env", env, "--terms", terms, "--clamp",
               "-o", out + ".tmp.npy", "--progress", "never", "-q")
        os.replace(out + ".tmp.npy", out)
    return np.load(out).astype(np.float64)


def rel_l2(a, b):
    nb = np.linalg.norm(b)
    return float(np.linalg.norm(a - b) / nb) if nb > 0 else float("nan")


def rel_h1(a, b, hw):
    """Relative L2 of the forward differences in x and y of two rows x 3 images of size HW."""
    if hw is None:
        return None
    h, w = hw
    a, b = a.reshape(h, w, 3), b.reshape(h, w, 3)
    ga = np.concatenate([np.diff(a, axis=0).ravel(), np.diff(a, axis=1).ravel()])
    gb = np.concatenate([np.diff(b, axis=0).ravel(), np.diff(b, axis=1).ravel()])
    return rel_l2(ga, gb)


def relit_errors(work, maps, hw, parts):
    """Per map and terms: rel. L2 (and H1, per-object L2) of sparse and of seed 2 against full."""
    out = []
    for env in maps:
        for terms in TERMS:
            ref = relit(work, "full_rows", env, terms)
            row = {"map": map_name(env), "terms": terms}
            for label, matrix in (("sparse", "sparse_rows"), ("floor", "full_seed2_rows")):
                img = relit(work, matrix, env, terms)
                if img.shape != ref.shape:
                    raise CommandError(f"{matrix} relit to {img.shape}, full_rows to {ref.shape}")
                row[f"l2_{label}"] = rel_l2(img, ref)
                row[f"h1_{label}"] = rel_h1(img, ref, hw)
                if parts:
                    r0 = 0
                    for name, n in parts:
                        row[f"l2_{label}_{name}"] = rel_l2(img[r0:r0 + n], ref[r0:r0 + n])
                        r0 += n
            out.append(row)
        log(f"  {map_name(env)}: " + ", ".join(
            f"{r['terms']} terms {r['l2_sparse']:.4f} (floor {r['l2_floor']:.4f})" for r in out[-len(TERMS):]))
    return out


# ---- step 6: CPCA -------------------------------------------------------------------------

def cpca(work, maps):
    """Plain CPCA of the full rows vs dense-first and --no-dense-first CPCA of the sparse rows."""
    cpca_maps = [m for m in maps if map_name(m) in ("city", "forest")] or maps[:2]
    runs = []
    for key in CPCA_SELECTED:
        label, src, extra = CPCA_RUNS[key]
        name = "cpca_" + key.replace("-", "_")
        out = os.path.join(work, name + ".ltm")
        remove(out)
        r = ltbake("cpca", os.path.join(work, src + ".ltm"), "-o", out, "-k", CPCA_K, "-s", CPCA_S, "--json",
                   "--progress", "never", *extra)
        rep = json.loads(r.stdout)
        errs = {map_name(m): rel_l2(relit(work, name, m, CPCA_TERMS), relit(work, "full_rows", m, CPCA_TERMS))
                for m in cpca_maps}
        runs.append({"key": key, "label": label, "input": src, "wall": r.wall, "cpu": r.cpu, "rss_mib": r.rss_mib,
                     "report": rep, "relit_l2": errs})
        log(f"  cpca {label}: {r.wall:.2f} s, relative_rms_error {rep['relative_rms_error']:.4f}, "
            f"relit {', '.join(f'{k} {v:.4f}' for k, v in errs.items())}")
    return runs


# ---- step 7: images -----------------------------------------------------------------------

def to_png(img, scale):
    v = np.clip(img * scale, 0.0, 1.0) ** (1 / 2.2)
    return (v * 255 + 0.5).astype(np.uint8)


def side_by_side(case, work, maps, hw):
    """Full, sparse and 10x |difference| PNGs and one combined image; returns their paths."""
    from PIL import Image, ImageDraw
    env = next((m for m in maps if map_name(m) == "city"), maps[0])
    terms = max(TERMS)
    h, w = hw
    full = relit(work, "full_rows", env, terms).reshape(h, w, 3)
    sparse = relit(work, "sparse_rows", env, terms).reshape(h, w, 3)
    p99 = float(np.percentile(full, 99))
    scale = 1.0 / p99 if p99 > 0 else 1.0 / max(float(full.max()), 1e-30)
    panels = {"full": to_png(full, scale), "sparse": to_png(sparse, scale),
              "diff10": to_png(np.abs(sparse - full), 10 * scale)}
    paths = {}
    for k, arr in panels.items():
        paths[k] = os.path.join(RESULTS, f"sparse_{case}{TAG}_{k}.png")
        buf = io.BytesIO()
        Image.fromarray(arr).save(buf, format="PNG")
        write_atomic(paths[k], buf.getvalue())
    zoom = max(1, -(-256 // w))  # small (scaled) images: nearest-neighbour up to >= 256 pixels wide
    zw, zh, label_h, gap = w * zoom, h * zoom, 16, 4
    combo = Image.new("RGB", (3 * zw + 2 * gap, zh + label_h), "white")
    draw = ImageDraw.Draw(combo)
    for i, (k, text) in enumerate((("full", "full"), ("sparse", "sparse"), ("diff10", "10x |sparse - full|"))):
        combo.paste(Image.fromarray(panels[k]).resize((zw, zh), Image.NEAREST), (i * (zw + gap), label_h))
        draw.text((i * (zw + gap) + 3, 2), text, fill="black")
    paths["side_by_side"] = os.path.join(RESULTS, f"sparse_{case}{TAG}_side_by_side.png")
    buf = io.BytesIO()
    combo.save(buf, format="PNG")
    write_atomic(paths["side_by_side"], buf.getvalue())
    return {"map": map_name(env), "terms": terms, "p99": p99, "files": paths}


# ---- one case -----------------------------------------------------------------------------

def run_case(case, maps, with_extras):
    log(f"== {case}")
    scene, flags, parts = case_setup(case)
    work = os.path.join(OUT, case)
    if os.path.isdir(work):
        shutil.rmtree(work)  # no stale relit images or outputs from an earlier run
    os.makedirs(work)
    t0 = time.perf_counter()
    res = {"case": case, "scene": os.path.relpath(scene, ROOT), "flags": flags}
    res.update(bake(scene, flags, work))
    br = res["basis_rows"]
    hw = (br["height"], br["width"]) if br.get("kind") == "image" else None
    if parts and sum(n for _, n in parts) != res["shape"][0]:
        log(f"  note: the objects' vertex counts {parts} do not add up to {res['shape'][0]} rows: no per-object errors")
        parts = None
    res["parts"] = parts
    row_transform(work, ["full", "sparse", "full_seed2"])
    res["errors"] = relit_errors(work, maps, hw, parts)
    if with_extras:  # a failure here keeps the case's measurements
        try:
            if DO_CPCA and CPCA_SELECTED:
                res["cpca"] = cpca(work, maps)
            if hw is not None:
                res["images"] = side_by_side(case, work, maps, hw)
            else:
                log("  side-by-side images: skipped (vertex mode has no image)")
        except (CommandError, OSError, ValueError, KeyError) as e:
            print(f"{case} (CPCA / images): FAILED\n{e}", file=sys.stderr, flush=True)
            res["extras_error"] = str(e)
    if not KEEP:
        for f in os.listdir(work):
            if f.endswith(".ltm"):
                os.remove(os.path.join(work, f))
    res["seconds"] = time.perf_counter() - t0
    return res


# ---- report -------------------------------------------------------------------------------

def med(runs, key):
    v = [r[key] for r in runs]
    return statistics.median(v), min(v), max(v)


def summarize(res):
    """Derived per-case figures: fractions, ratios, means over maps."""
    sp, ft = res["sparse_inspect"], res["full_text"]
    entries = sp["entries"]
    s = {"traced": sp["traced_fraction"],
         "traced_dense": sp["traced_entries"]["dense"] / entries if entries else float("nan"),
         "traced_sparse": sp["traced_entries"]["sparse"] / entries if entries else float("nan"),
         "full_traced": 1 - ft["skipped_pairs"] / entries if entries else float("nan"),
         "rays_sparse": sp["rays"]["dense"] + sp["rays"]["sparse"], "rays_full": ft["rays"]}
    for k in ("wall", "cpu", "rss_mib"):
        s[f"full_{k}"], s[f"sparse_{k}"] = med(res["full"], k), med(res["sparse"], k)
    s["speedup"] = s["full_wall"][0] / s["sparse_wall"][0]
    s["cpu_ratio"] = s["full_cpu"][0] / s["sparse_cpu"][0]
    s["by_terms"] = {}
    for t in TERMS:
        rows = [e for e in res["errors"] if e["terms"] == t]
        d = {k: statistics.mean(e[k] for e in rows) for k in ("l2_sparse", "l2_floor")}
        for k in ("h1_sparse", "h1_floor"):
            d[k] = statistics.mean(e[k] for e in rows) if rows[0][k] is not None else None
        worst = max(rows, key=lambda e: e["l2_sparse"])
        d["worst"] = (worst["map"], worst["l2_sparse"])
        for name, _ in res["parts"] or []:
            d[f"l2_sparse_{name}"] = statistics.mean(e[f"l2_sparse_{name}"] for e in rows)
            d[f"l2_floor_{name}"] = statistics.mean(e[f"l2_floor_{name}"] for e in rows)
        s["by_terms"][t] = d
    return s


def verdict(ok):
    return "**met**" if ok else "**missed**"


def fmt_range(m):
    return f"{m[0]:.2f} ({m[1]:.2f}–{m[2]:.2f})"


def h1_text(v):
    return "—" if v is None else f"{v:.4f}"


def case_section(res, s):
    sp, ft, st = res["sparse_inspect"], res["full_text"], res["sparse_text"]
    br = res["basis_rows"]
    size = (f"{br['width']}×{br['height']} image" if br.get("kind") == "image"
            else f"vertex mode ({', '.join(f'{n}: {k:,}' for n, k in res['parts'])})" if res["parts"]
            else "vertex mode")
    lines = [f"### {res['case']}: `{res['scene']}` {' '.join(res['flags'])}".rstrip(), "",
             f"{size}, {res['shape'][0]:,} rows ({ft['rows_seeing']:,} see geometry) × {res['shape'][1]:,} texels "
             f"(R = {CUBE_RES}); sparse: {sp['rows']['dense']:,} dense rows, {sp['rows']['sparse']:,} sparse rows "
             f"reconstructed, {sp['rows'].get('traced_in_full', 0):,} traced in full (fit residual over the limit), "
             f"{sp['parameters']['features']} features, radius {sp['parameters']['radius']:.4g}; fit residual median "
             f"{sp.get('residual', {}).get('median', float('nan')):.3f}, p90 "
             f"{sp.get('residual', {}).get('p90', float('nan')):.3f}. Case time {res['seconds']:.0f} s.", "",
             "| | full | sparse | sparse / full |", "|---|---|---|---|",
             f"| entries traced | {s['full_traced']:.1%} (the rest wholly below the horizon) | **{s['traced']:.2%}** "
             f"(phase 1 {s['traced_dense']:.2%}, phase 2 {s['traced_sparse']:.2%}) | {s['traced'] / s['full_traced']:.3f} |",
             f"| rays | {s['rays_full']:,} | {s['rays_sparse']:,} (phase 1 {sp['rays']['dense']:,}, "
             f"phase 2 {sp['rays']['sparse']:,}) | {s['rays_sparse'] / s['rays_full']:.3f} |",
             f"| wall s, median (min–max) of {REPEATS} | {fmt_range(s['full_wall'])} | {fmt_range(s['sparse_wall'])} "
             f"| **speed-up {s['speedup']:.2f}×** |",
             f"| CPU s, median (min–max) | {fmt_range(s['full_cpu'])} | {fmt_range(s['sparse_cpu'])} "
             f"| CPU ratio {s['cpu_ratio']:.2f}× |",
             f"| peak RSS MiB, median | {s['full_rss_mib'][0]:.0f} | {s['sparse_rss_mib'][0]:.0f} | |",
             "| seconds per phase | | wall (warm-up run's text): "
             + (" / ".join(f"{x:.2f}" for x in st["phase_wall_seconds"]) if "phase_wall_seconds" in st else "?")
             + f"; thread-seconds (inspect): {sp['seconds']['dense']:.2f} / {sp['seconds']['sparse']:.2f} | |"]
    if "traced_percent" in st and abs(st["traced_percent"][0] - 100 * s["traced"]) > 0.05:
        lines += ["", f"Note: `sample --sparse`'s own summary (warm-up run) says {st['traced_percent'][0]:.2f}% traced "
                  f"(phase 1 {st['traced_percent'][1]:.2f}%, phase 2 {st['traced_percent'][2]:.2f}%); the table "
                  "gives `inspect`'s count from the side tables."]
    lines += ["", "Relit images against the full bake (means over the maps; the floor is a second full bake with "
              "`--seed 2`):", "",
              "| terms | sparse: rel. L2 | worst map | sparse: rel. H1 | floor: rel. L2 | floor: rel. H1 |",
              "|---|---|---|---|---|---|"]
    for t, d in s["by_terms"].items():
        lines.append(f"| {t} | **{d['l2_sparse']:.4f}** | {d['worst'][0]} {d['worst'][1]:.4f} | {h1_text(d['h1_sparse'])} "
                     f"| {d['l2_floor']:.4f} | {h1_text(d['h1_floor'])} |")
    if br.get("kind") != "image":
        lines += ["", "(Vertex mode: no H1, the rows are not an image.)"]
    if res["parts"]:
        lines += ["", "Per object, mean rel. L2 over the maps (sparse / floor): " + "; ".join(
            f"{t} terms: " + ", ".join(f"{n} {d[f'l2_sparse_{n}']:.4f} / {d[f'l2_floor_{n}']:.4f}" for n, _ in res["parts"])
            for t, d in s["by_terms"].items()) + "."]
    head = "| map | " + " | ".join(f"L2 sparse {t} | L2 floor {t} | H1 sparse {t} | H1 floor {t}" for t in TERMS) + " |"
    lines += ["", "<details><summary>per map</summary>", "", head, "|---" * (1 + 4 * len(TERMS)) + "|"]
    for m in sorted({e["map"] for e in res["errors"]}):
        cells = []
        for t in TERMS:
            e = next(x for x in res["errors"] if x["map"] == m and x["terms"] == t)
            cells += [f"{e['l2_sparse']:.4f}", f"{e['l2_floor']:.4f}", h1_text(e["h1_sparse"]), h1_text(e["h1_floor"])]
        lines.append(f"| {m} | " + " | ".join(cells) + " |")
    lines += ["", "</details>", ""]
    d_last = s["by_terms"][max(TERMS)]
    lines += [f"Targets: traced ≤ {TARGET_TRACED:.0%}: {s['traced']:.2%} — {verdict(s['traced'] <= TARGET_TRACED)}; "
              f"≥ {TARGET_SPEEDUP:g}× faster (wall medians): {s['speedup']:.2f}× — {verdict(s['speedup'] >= TARGET_SPEEDUP)}; "
              f"relit rel. L2 ≤ {TARGET_L2:.0%}: " + ", ".join(
                  f"{d['l2_sparse']:.2%} at {t} terms" for t, d in s["by_terms"].items())
              + f" — {verdict(all(d['l2_sparse'] <= TARGET_L2 for d in s['by_terms'].values()))} "
              f"(floor {d_last['l2_floor']:.2%} at {max(TERMS)} terms).", ""]
    if "images" in res:
        im = res["images"]
        lines += [f"Images under {im['map']} at {im['terms']} terms (exposure: the full image's 99th percentile "
                  f"{im['p99']:.4g} → 1, gamma 1/2.2; the difference ×10 at that exposure): "
                  + ", ".join(f"[{k}]({os.path.basename(p)})" for k, p in im["files"].items()) + ".", "",
                  f"![full, sparse, 10× difference]({os.path.basename(im['files']['side_by_side'])})", ""]
    return lines


def cpca_section(res):
    runs = res["cpca"]
    by = {r["key"]: r for r in runs}
    plain = by.get("plain", runs[0])  # the ratios' reference
    maps = list(plain["relit_l2"])
    lines = [f"### CPCA ({res['case']}): K = {CPCA_K}, S = {CPCA_S}, relit at {CPCA_TERMS} terms against the full "
             "bake's rows", "",
             f"| run | input | wall s | speed-up vs {plain['key']} | CPU s | peak RSS MiB | relative_rms_error | × plain | rows_streamed "
             "| seconds_dense / final | " + " | ".join(f"relit L2 {m}" for m in maps) + " |",
             "|---" * (10 + len(maps)) + "|"]
    for r in runs:
        rep = r["report"]
        lines.append(f"| {r['label']} | {r['input']}.ltm | {r['wall']:.2f} | {plain['wall'] / r['wall']:.2f}× | "
                     f"{r['cpu']:.2f} | {r['rss_mib']:.0f} | {rep['relative_rms_error']:.4f} | "
                     f"{rep['relative_rms_error'] / plain['report']['relative_rms_error']:.3f}× | "
                     f"{rep['rows_streamed']:,} | {rep['seconds_dense']:.2f} / {rep['seconds_final']:.2f} | "
                     + " | ".join(f"{r['relit_l2'][m]:.4f}" for m in maps) + " |")
    lines += ["", "relative_rms_error is each run's error against its own input (the sparse rows for the sparse "
              "runs); the relit columns compare each with the full bake relit at the same terms. seconds_dense is "
              "the seeded start and growth levels (on the dense rows only with dense-first), seconds_final the "
              "passes after them.", ""]
    if "plain" in by and "dense-first" in by:
        df = by["dense-first"]
        speed = plain["wall"] / df["wall"]
        err = df["report"]["relative_rms_error"] / plain["report"]["relative_rms_error"]
        lines += [f"Target: dense-first ≥ {TARGET_CPCA_SPEEDUP:g}× faster than plain CPCA of the full bake: "
                  f"{speed:.2f}× — {verdict(speed >= TARGET_CPCA_SPEEDUP)}; at ≤ 5% more error: {err:.3f}× the "
                  f"relative_rms_error — {verdict(err <= TARGET_CPCA_ERROR)}.", ""]
    else:
        lines += ["Target not evaluated: it needs the plain and dense-first runs (LTB_SPARSE_CPCA_RUNS).", ""]
    return lines


def command_line():
    env = " ".join(f"{k}={shlex.quote(os.environ[k])}" for k in KNOBS if k in os.environ)
    return (env + " " if env else "") + "/usr/bin/python3 " + " ".join(
        shlex.quote(os.path.relpath(a, ROOT) if os.path.exists(a) else a) for a in sys.argv)


def report(results, failures, started, load):
    summaries = {r["case"]: summarize(r) for r in results}
    t_last = max(TERMS)
    lines = ["# Sparse precomputation vs the full bake (bench/sparse_bench.py)", "",
             f"Machine: {machine()}; load average at the start {load}. Date {started:%Y-%m-%d %H:%M}. "
             f"ltbake `{os.path.relpath(LTB, ROOT)}` at `{git_describe()}` (binary of "
             f"{datetime.datetime.fromtimestamp(os.path.getmtime(LTB)):%Y-%m-%d %H:%M}).", "",
             f"Command: `{command_line()}` — scale {SCALE:g}, R = {CUBE_RES}, {REPEATS} timed repetitions each "
             f"(alternating full, sparse; one untimed warm-up of each first), sample --jobs {JOBS}, relit at "
             f"{', '.join(map(str, TERMS))} terms under {len(results[0]['errors']) // len(TERMS) if results else 0} maps.",
             "", "## Summary", "",
             f"| case | traced | rays sparse / full | wall speed-up | CPU ratio | rel. L2 at {t_last} terms (worst map) "
             f"| floor | rel. H1 at {t_last} | floor H1 |", "|---|---|---|---|---|---|---|---|---|"]
    for r in results:
        s = summaries[r["case"]]
        d = s["by_terms"][t_last]
        lines.append(f"| {r['case']} | {s['traced']:.2%} | {s['rays_sparse'] / s['rays_full']:.3f} | "
                     f"{s['speedup']:.2f}× | {s['cpu_ratio']:.2f}× | {d['l2_sparse']:.4f} ({d['worst'][0]} "
                     f"{d['worst'][1]:.4f}) | {d['l2_floor']:.4f} | {h1_text(d['h1_sparse'])} | {h1_text(d['h1_floor'])} |")
    lines += ["", f"Targets: traced ≤ {TARGET_TRACED:.0%}, ≥ {TARGET_SPEEDUP:g}× faster, relit rel. L2 ≤ {TARGET_L2:.0%}, "
              f"dense-first CPCA ≥ {TARGET_CPCA_SPEEDUP:g}× faster at ≤ 5% more error.", "", "## Cases", ""]
    for r in results:
        lines += case_section(r, summaries[r["case"]])
    for r in results:
        if "cpca" in r:
            lines += ["## CPCA", ""] + cpca_section(r)
    failures = failures + [(r["case"] + " (CPCA / images)", r["extras_error"]) for r in results if "extras_error" in r]
    if failures:
        lines += ["## Failed", ""] + [f"- {c}: {msg.splitlines()[0]}" for c, msg in failures] + [""]
    md = "\n".join(lines) + "\n"

    buf = io.StringIO()
    w = csv.writer(buf)
    w.writerow(["case", "scene", "flags", "rows", "cube_res", "scale", "map", "terms", "rel_l2_sparse",
                "rel_h1_sparse", "rel_l2_floor", "rel_h1_floor", "traced_fraction", "traced_phase1",
                "traced_phase2", "rays_full", "rays_sparse", "wall_full_median", "wall_sparse_median",
                "speedup", "cpu_full_median", "cpu_sparse_median", "cpu_ratio"])
    for r in results:
        s = summaries[r["case"]]
        for e in r["errors"]:
            w.writerow([r["case"], r["scene"], " ".join(r["flags"]), r["shape"][0], CUBE_RES, SCALE, e["map"],
                        e["terms"], f"{e['l2_sparse']:.6g}", "" if e["h1_sparse"] is None else f"{e['h1_sparse']:.6g}",
                        f"{e['l2_floor']:.6g}", "" if e["h1_floor"] is None else f"{e['h1_floor']:.6g}",
                        f"{s['traced']:.6g}", f"{s['traced_dense']:.6g}", f"{s['traced_sparse']:.6g}",
                        s["rays_full"], s["rays_sparse"], f"{s['full_wall'][0]:.4f}", f"{s['sparse_wall'][0]:.4f}",
                        f"{s['speedup']:.4f}", f"{s['full_cpu'][0]:.4f}", f"{s['sparse_cpu'][0]:.4f}",
                        f"{s['cpu_ratio']:.4f}"])
    raw = {"machine": machine(), "date": started.isoformat(), "command": command_line(), "git": git_describe(),
           "scale": SCALE, "cube_res": CUBE_RES, "repeats": REPEATS, "terms": TERMS, "results": results,
           "failures": [{"case": c, "error": m} for c, m in failures]}
    os.makedirs(RESULTS, exist_ok=True)
    base = os.path.join(RESULTS, f"sparse_bench{TAG}")
    write_atomic(base + ".md", md)
    write_atomic(base + ".csv", buf.getvalue())
    write_atomic(base + ".json", json.dumps(raw, indent=1) + "\n")
    print("\n" + md)
    log(f"wrote {os.path.relpath(base, ROOT)}.{{md,csv,json}}")


def main():
    if not os.access(LTB, os.X_OK):
        sys.exit(f"{LTB}: not an executable; pass the build directory (default: build/)")
    for c in CASES:
        if c not in ALL_CASES:
            sys.exit(f"LTB_SPARSE_CASES: unknown case {c!r}; known: {', '.join(ALL_CASES)}")
    for r in CPCA_SELECTED:
        if r not in CPCA_RUNS:
            sys.exit(f"LTB_SPARSE_CPCA_RUNS: unknown run {r!r}; known: {', '.join(CPCA_RUNS)}")
    if REPEATS < 1 or not TERMS or SCALE <= 0:
        sys.exit("LTB_SPARSE_REPEATS must be >= 1, LTB_SPARSE_TERMS non-empty, LTB_SPARSE_SCALE > 0")
    started = datetime.datetime.now()
    with open("/proc/loadavg") as f:
        load = " ".join(f.read().split()[:3])
    t0 = time.perf_counter()
    maps = envmaps()
    os.makedirs(OUT, exist_ok=True)
    results, failures = [], []
    for i, case in enumerate(CASES):
        try:
            results.append(run_case(case, maps, with_extras=(i == 0)))
        except (CommandError, OSError, ValueError, KeyError) as e:
            print(f"{case}: FAILED\n{e}", file=sys.stderr, flush=True)
            failures.append((case, str(e)))
    if results:
        report(results, failures, started, load)
    log(f"total {time.perf_counter() - t0:.0f} s")
    if failures or any("extras_error" in r for r in results):
        sys.exit(1)


if __name__ == "__main__":
    main()
