#!/usr/bin/python3
"""Where the lighting error of each changing-lighting method sits, band by band and frame by
frame (issue 40: "report the per-band error over time"; Overbeck 2006, ch. 6).

For each map, `relight --sequence SEQ --applied-lighting` writes every frame's applied
lighting L~ in the matrix's column basis for NWA 30, NWA 100, BI 30 and PBI 30; the same
with `--method nwa --terms all` gives the true lighting L in that basis (every term kept).
Bands as ltbake's PBI defines them (stages/relight/incremental.h): band 0 the scaling
function and the coarsest details, band b the details of side R/2^b. Per frame and band,
the selection's own measure (relight's area weighting, Ng et al. 2003):
sum_{j in b} area_j |L_j - L~_j| / sum_j area_j |L_j|, |.| the RGB magnitude of a
coefficient and area_j its wavelet's support in texels, so the bands add up to the frame's
whole error.

Run:  /usr/bin/python3 bench/pbi_bands.py [BUILD_DIR=build]
Knobs: LTB_PBI_MATRIX (default bench/out/pbi_unseen/final.ltm, from bash bench/pbi_unseen.sh),
       LTB_PBI_MAPS (space-separated; default bench/out/unseen_maps/{sun_sky,three_windows}.hdr),
       LTB_PBI_SEQUENCE (rotate:3.6:100,hold:25)
Writes bench/results/pbi_bands.{md,json,png}.
"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import ROOT, git_describe, machine, run  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
MATRIX = os.environ.get("LTB_PBI_MATRIX", os.path.join(ROOT, "bench", "out", "pbi_unseen", "final.ltm"))
MAPDIR = os.path.join(ROOT, "bench", "out", "unseen_maps")
MAPS = os.environ.get("LTB_PBI_MAPS", f"{MAPDIR}/sun_sky.hdr {MAPDIR}/three_windows.hdr").split()
SEQ = os.environ.get("LTB_PBI_SEQUENCE", "rotate:3.6:100,hold:25")
METHODS = [("nwa", 30), ("nwa", 100), ("bi", 30), ("pbi", 30)]
RESULTS = os.path.join(ROOT, "bench", "results")


def bands_of(cols):
    """Each column's band (stages/relight/incremental.cpp's rule), its support area in texels
    (stages/relight/relight.cpp's FaceSupportAreas) and the band count."""
    r = int(round((cols / 6) ** 0.5))
    p = np.arange(cols) % (r * r)
    m = np.maximum(p % r, p // r)
    level = np.floor(np.log2(np.maximum(m, 1))).astype(int)
    band = np.where(m <= 1, 0, level)
    area = np.where(m == 0, float(r * r), (r / 2.0 ** level) ** 2)
    return band, area, int(np.log2(r))


def applied(tmp, m, method, terms):
    pattern = os.path.join(tmp, f"{method}{terms}_%04d.npy")
    rep = json.loads(run(LTB, "relight", MATRIX, "--env", m, "--clamp", "--sequence", SEQ, "--method", method,
                         "--terms", terms, "-o", os.path.join(tmp, "img_%04d.npy"), "--applied-lighting", pattern,
                         "--json", "--progress", "never"))
    n = len(rep["frames"])
    got = np.stack([np.load(pattern % f).astype(np.float64) for f in range(n)])
    for f in range(n):
        os.remove(pattern % f)
    return got, rep


def main():
    res = {"sequence": SEQ, "matrix": MATRIX, "maps": {}}
    for m in MAPS:
        name = os.path.splitext(os.path.basename(m))[0]
        with tempfile.TemporaryDirectory() as tmp:
            truth, _ = applied(tmp, m, "nwa", "all")
            band, area, nb = bands_of(truth.shape[1])
            norm = (np.linalg.norm(truth, axis=2) * area).sum(1)
            res["maps"][name] = {}
            for method, terms in METHODS:
                got, rep = applied(tmp, m, method, terms)
                err = np.linalg.norm(got - truth, axis=2) * area
                per = np.stack([err[:, band == b].sum(1) for b in range(nb)], 1)
                res["maps"][name][f"{method}{terms}"] = {
                    "band_error": (per / norm[:, None]).tolist(),
                    "columns_touched": [fr["columns_touched"] for fr in rep["frames"]],
                    "band_terms": [[b["terms"] for b in fr["bands"]] for fr in rep["frames"]],
                    "band_resets": [[b["update"] == "reset" for b in fr["bands"]] for fr in rep["frames"]],
                }
                print(f"{name} {method}{terms}: mean per-band error while rotating "
                      + " ".join(f"{x:.4f}" for x in (per / norm[:, None])[:100].mean(0)), flush=True)
    res["bands"] = nb
    meta = {"machine": machine(), "commit": git_describe()}
    with open(os.path.join(RESULTS, "pbi_bands.json"), "w") as f:
        json.dump({"meta": meta, "results": res}, f)
    rotating = int(SEQ.split(",")[0].split(":")[2]) if SEQ.startswith("rotate:") else None
    lines = ["# The lighting error per band over time (bench/pbi_bands.py)", "",
             f"{meta['machine']}, commit {meta['commit']}. Matrix `{os.path.relpath(MATRIX, ROOT)}`, sequence "
             f"`{SEQ}`. Per frame and band b: the area-weighted L1 error of the applied lighting over the band's "
             "coefficients, sum_b area_j |L_j - L~_j|, over the lighting's sum_j area_j |L_j| (relight's term "
             "selection measure; the bands add up to the whole). Band 0: the scaling function and the "
             "coarsest details; band b: the details of side R/2^b. Means over the "
             f"rotation's {rotating} frames; per-band terms are the frame's budget spent in the band (PBI, BI), "
             "resets the share of frames a band was reset (PBI).", ""]
    for name, methods in res["maps"].items():
        lines += [f"## {name}", "", "| method | " + " | ".join(f"band {b}" for b in range(nb)) +
                  " | whole | terms per band | resets per band | columns touched |",
                  "|---|" + "---|" * (nb + 4)]
        for key, v in methods.items():
            e = np.array(v["band_error"])[:rotating]
            whole = e.sum(1).mean()
            terms = np.array(v["band_terms"])[:rotating].mean(0)
            resets = np.array(v["band_resets"])[:rotating].mean(0)
            lines.append(f"| {key} | " + " | ".join(f"{x:.4f}" for x in e.mean(0)) + f" | {whole:.4f} | " +
                         " ".join(f"{x:.1f}" for x in terms) + " | " + " ".join(f"{x:.2f}" for x in resets) +
                         f" | {np.mean(v['columns_touched'][:rotating]):.1f} |")
        lines.append("")
    try:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        # The map where PBI 30's error is largest (a sun sky's is tiny for every method).
        name = max(res["maps"], key=lambda n: np.array(res["maps"][n]["pbi30"]["band_error"]).sum(1).mean())
        fig, axes = plt.subplots(1, 2, figsize=(11, 4), sharey=True)
        for ax, key in zip(axes, ("pbi30", "nwa100")):
            e = np.array(res["maps"][name][key]["band_error"])
            for b in range(nb):
                ax.plot(e[:, b], label=f"band {b}")
            ax.set_title(f"{key}, {name}")
            ax.set_xlabel("frame")
            ax.set_yscale("log")
            ax.set_ylim(bottom=1e-5)
        axes[0].set_ylabel("band's area-weighted L1 error / the lighting's")
        axes[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(os.path.join(RESULTS, "pbi_bands.png"), dpi=100)
        lines.append("![per-band error over time](pbi_bands.png)")
    except ImportError:
        pass
    with open(os.path.join(RESULTS, "pbi_bands.md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
