"""CPCA beside the adaptive 4D wavelets at equal size on the bundled scene: stored bytes
against relit error (rel. L2 vs the exact relighting from raw.ltm) and relight time.

usage: cpca_relight.py LTBAKE DIR [--env sunset] [--terms 100]
  DIR holds raw.ltm, rows.ltm and cols.ltm of samples/medium.toml at R = 8: the demo bake
  with raw kept makes them, e.g. `ltbake run samples/medium-bake.toml --workdir DIR --until
  transpose` after adding "raw" to its keep list. Writes DIR/cpca_relight.csv and .png.
"""
import csv
import json
import os
import subprocess
import sys
import time

LTBAKE, DIR = sys.argv[1], sys.argv[2]
ENV = sys.argv[sys.argv.index("--env") + 1] if "--env" in sys.argv else "sunset"
TERMS = int(sys.argv[sys.argv.index("--terms") + 1]) if "--terms" in sys.argv else 100
ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
ENVDIR = subprocess.run(["bash", os.path.join(ROOT, "scripts/find_envmaps.sh")], capture_output=True,
                        text=True).stdout.strip()


def ltbake(*args):
    t0 = time.monotonic()
    p = subprocess.run([LTBAKE, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        sys.exit(f"ltbake {' '.join(map(str, args))}: exit {p.returncode}\n{p.stderr}")
    return p.stdout, time.monotonic() - t0


def stored_bytes(path):
    info = json.loads(ltbake("inspect", path, "--json", "--no-content")[0])
    return sum(a["chunks"]["stored_bytes"] for a in info["arrays"]), info["file_bytes"]


def relight(path):
    out, _ = ltbake("relight", path, "--env", os.path.join(ENVDIR, f"{ENV}.exr"), "--clamp", "--terms", TERMS,
                    "-o", os.path.join(DIR, "relit.npy"), "--reference", os.path.join(DIR, "raw.ltm"), "--json",
                    "--frames", 20)
    return json.loads(out)


rows = []
for keep in [0.005, 0.01, 0.02, 0.05]:
    c4 = os.path.join(DIR, f"cols4d_{keep}.ltm")
    fin = os.path.join(DIR, f"final_{keep}.ltm")
    _, t_ct = ltbake("column-transform", os.path.join(DIR, "cols.ltm"), "-o", c4, "--keep", keep, "--overwrite", "-q")
    _, t_q = ltbake("quantize", c4, "-o", fin, "--bits", 9, "--overwrite", "-q")
    size, fbytes = stored_bytes(fin)
    r = relight(fin)
    rows.append({"method": "4D wavelet", "params": f"keep={keep} bits=9", "compress_s": round(t_ct + t_q, 3),
                 "size_bytes": size, "file_bytes": fbytes, "relight_ms": r["frames"]["median_ms"],
                 "rel_l2": r["error"]["rel_l2"], "rel_l2_matrix_only": r["error_matrix_only"]["rel_l2"],
                 "psnr_db": r["error"]["psnr_db"]})
    print(rows[-1], flush=True)
for k, s in [(16, 2), (32, 4), (64, 6), (64, 8), (128, 8), (128, 16)]:
    out = os.path.join(DIR, f"cpca_{k}_{s}.ltm")
    j, t = ltbake("cpca", os.path.join(DIR, "rows.ltm"), "-o", out, "-k", k, "-s", s, "--overwrite", "--json",
                  "--progress", "never")
    j = json.loads(j)
    size, fbytes = stored_bytes(out)
    r = relight(out)
    rows.append({"method": "CPCA", "params": f"K={k} S={s}", "compress_s": round(t, 3), "size_bytes": size,
                 "file_bytes": fbytes, "relight_ms": r["frames"]["median_ms"], "rel_l2": r["error"]["rel_l2"],
                 "rel_l2_matrix_only": r["error_matrix_only"]["rel_l2"], "psnr_db": r["error"]["psnr_db"],
                 "cpca_relative_rms_error": j["relative_rms_error"], "iterations": j["iterations"]})
    print(rows[-1], flush=True)

keys = ["method", "params", "compress_s", "size_bytes", "file_bytes", "relight_ms", "rel_l2", "rel_l2_matrix_only",
        "psnr_db", "cpca_relative_rms_error", "iterations"]
with open(os.path.join(DIR, "cpca_relight.csv"), "w", newline="") as f:
    w = csv.DictWriter(f, keys, extrasaction="ignore")
    w.writeheader()
    for r in rows:
        w.writerow({"cpca_relative_rms_error": "", "iterations": "", **{k: r.get(k, "") for k in keys}})

import matplotlib  # noqa: E402
matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
fig, axes = plt.subplots(1, 2, figsize=(10, 4))
for m, marker in [("4D wavelet", "o"), ("CPCA", "s")]:
    pts = sorted((r["size_bytes"] / 2**20, r["rel_l2"], r["rel_l2_matrix_only"], r["relight_ms"]) for r in rows
                 if r["method"] == m)
    axes[0].plot([p[0] for p in pts], [p[2] for p in pts], marker=marker, label=f"{m}: matrix only")
    axes[0].plot([p[0] for p in pts], [p[1] for p in pts], marker=marker, linestyle="--", label=f"{m}: with {TERMS} terms")
    axes[1].plot([p[3] for p in pts], [p[2] for p in pts], marker=marker, label=m)
axes[0].set_xlabel("stored MiB")
axes[0].set_ylabel("relit rel. L2 error")
axes[0].set_yscale("log")
axes[0].legend(fontsize=7)
axes[0].set_title(f"medium (R=8, 256x256), {ENV}")
axes[1].set_xlabel("relight ms per frame (median)")
axes[1].set_ylabel("matrix-only rel. L2")
axes[1].set_yscale("log")
axes[1].legend(fontsize=7)
fig.tight_layout()
fig.savefig(os.path.join(DIR, "cpca_relight.png"), dpi=110)
print("wrote", os.path.join(DIR, "cpca_relight.csv"))
