#!/usr/bin/python3
"""Changing lighting: NWA, BI and PBI (Overbeck 2006, Fig. 6.2) on the medium scene.

The medium scene at R = 32 (bench/pbi_bake.toml: 256x256 pixels, 6144 lights, adaptive 4D
final.ltm at a 5% budget, quantized; baked on the first run) is relit under each bundled
map (scripts/find_envmaps.sh) rotated 360 degrees over 100 frames, then held 25 frames
(`--sequence rotate:3.6:100,hold:25`), with NWA 30/60/100/200, BI 30 and PBI 30 terms a
frame. The reference is the same matrix under each frame's full lighting (every term), so
the errors are those of the lighting approximation alone. Per frame: rel. L2 and the
area-weighted (relative) L1 of the image, and the frame time (the lighting transform,
term selection, the Eq. 8 product and the image update; not the PNG write).

Targets (issue 19): PBI 30 at or below NWA 100 over the rotation; below 1% rel. L2 within
5 frames of the hold; frame time within 1.2x of NWA 30 (medians over all frames and maps).

    /usr/bin/python3 bench/pbi_sequences.py [BUILD_DIR=build]

Environment: LTB_PBI_MAPS (space-separated map paths; default every bundled map),
LTB_PBI_SEQUENCE (rotate:3.6:100,hold:25), LTB_PBI_MATRIX (a final.ltm to use instead of
the bake), LTB_PBI_CONFIGS ("nwa:30 nwa:60 nwa:100 nwa:200 bi:30 pbi:30"; NWA 30 and PBI 30
are needed for the targets), LTB_PBI_NAME (pbi_sequences), LTB_PBI_DESC (the matrix's description in the table), LTB_PBI_FROM_CSV=1 (no runs: the tables and the plot from
the last run's CSV). Writes bench/results/NAME.{md,csv,png}.
"""
import csv
import json
import os
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from benchlib import machine  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)
BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
SEQ = os.environ.get("LTB_PBI_SEQUENCE", "rotate:3.6:100,hold:25")
RESULTS = os.path.join(HERE, "results")
CONFIGS = [(c.split(":")[0], int(c.split(":")[1])) for c in
           os.environ.get("LTB_PBI_CONFIGS", "nwa:30 nwa:60 nwa:100 nwa:200 bi:30 pbi:30").split()]
NAME = os.environ.get("LTB_PBI_NAME", "pbi_sequences")
DESC = os.environ.get("LTB_PBI_DESC", "the medium scene, 256x256, R = 32")


def maps():
    if os.environ.get("LTB_PBI_MAPS"):
        return os.environ["LTB_PBI_MAPS"].split()
    d = subprocess.run(["bash", os.path.join(ROOT, "scripts", "find_envmaps.sh")], capture_output=True,
                       text=True).stdout.strip()
    return sorted(os.path.join(d, f) for f in os.listdir(d) if f.endswith(".exr"))


def matrix():
    if os.environ.get("LTB_PBI_MATRIX"):
        return os.environ["LTB_PBI_MATRIX"]
    final = os.path.join(HERE, "out", "pbi", "final.ltm")
    if not os.path.exists(final):
        subprocess.run([LTB, "run", os.path.join(HERE, "pbi_bake.toml")], check=True)
    return final


def median(v):
    v = sorted(v)
    return v[len(v) // 2] if v else float("nan")


def read_csv(path):
    with open(path) as f:
        return [[r["map"], r["method"], int(r["terms"]), int(r["frame"]), float(r["ms"]), float(r["rel_l2"]),
                 float(r["l1_area"]), float(r["lighting_rel_l2"])] for r in csv.DictReader(f)]


def main():
    mat = matrix()
    rot_frames = sum(int(s.split(":")[-1]) for s in SEQ.split(",") if s.startswith("rotate"))
    rows = []  # map, method, terms, frame, ms, rel_l2, l1_area, lighting_rel_l2
    if os.environ.get("LTB_PBI_FROM_CSV") == "1":  # only the tables and the plot, from the last run's CSV
        rows = read_csv(os.path.join(RESULTS, NAME + ".csv"))
    with tempfile.TemporaryDirectory() as tmp:
        for m in maps() if not rows else []:
            name = os.path.splitext(os.path.basename(m))[0]
            for method, terms in CONFIGS:
                r = subprocess.run([LTB, "relight", mat, "--env", m, "--clamp", "--sequence", SEQ, "--method", method,
                                    "--terms", str(terms), "--reference", mat, "-o",
                                    os.path.join(tmp, "f_%04d.npy"), "--json", "--progress", "never"],
                                   capture_output=True, text=True, check=True)
                rep = json.loads(r.stdout)
                for fr in rep["frames"]:
                    rows.append([name, method, terms, fr["frame"], fr["ms"], fr["rel_l2"], fr["l1_area"],
                                 fr["lighting_rel_l2"]])
                print(f"{name} {method}{terms}: mean rel. L2 {rep['summary']['mean_rel_l2']:.4f}, "
                      f"median {rep['summary']['median_ms']:.2f} ms", flush=True)
    os.makedirs(RESULTS, exist_ok=True)
    with open(os.path.join(RESULTS, NAME + ".csv") + ".tmp", "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["map", "method", "terms", "frame", "ms", "rel_l2", "l1_area", "lighting_rel_l2"])
        w.writerows(rows)
    os.replace(os.path.join(RESULTS, NAME + ".csv") + ".tmp", os.path.join(RESULTS, NAME + ".csv"))

    names = sorted({r[0] for r in rows})
    frames = max(r[3] for r in rows) + 1

    def sel(method, terms, map_name=None):
        return [r for r in rows if r[1] == method and r[2] == terms and (map_name is None or r[0] == map_name)]

    stats = {}
    for method, terms in CONFIGS:
        s = sel(method, terms)
        rot = [r[5] for r in s if r[3] < rot_frames]
        hold = [r[5] for r in s if r[3] >= rot_frames]
        # frames after the hold starts until rel. L2 < 1%, per map (the worst map counts)
        settle = []
        for n in names:
            per = sorted(sel(method, terms, n), key=lambda r: r[3])
            k = next((r[3] - rot_frames for r in per if r[3] >= rot_frames and r[5] < 0.01), None)
            settle.append(k)
        stats[(method, terms)] = {
            "rot_l2": sum(rot) / len(rot), "rot_l1": sum(r[6] for r in s if r[3] < rot_frames) / len(rot),
            "hold_l2": sum(hold) / len(hold) if hold else float("nan"),
            "last_l2": sum(r[5] for r in s if r[3] == frames - 1) / len(names),
            "settle": settle, "ms": median([r[4] for r in s])}
    base_ms = stats[("nwa", 30)]["ms"]
    pbi, nwa100 = stats[("pbi", 30)], stats[("nwa", 100)]
    worst_settle = None if None in pbi["settle"] else max(pbi["settle"])
    lines = [
        "# Changing lighting: NWA, BI and PBI (bench/pbi_sequences.py)",
        "",
        f"Machine: {machine()}. Matrix: `{os.path.relpath(mat, ROOT)}` ({DESC}). "
        f"Sequence `{SEQ}` under {len(names)} maps ({', '.join(names)}). Errors against the same matrix relit with "
        "every lighting term each frame (the lighting approximation alone); means over frames and maps; "
        "frame times are medians over every frame of every map (one run each, the machine otherwise idle).",
        "",
        "| method | terms | mean rel. L2, rotating | mean area-weighted L1, rotating | mean rel. L2, held | "
        "rel. L2, last frame | frames after the hold to < 1% (worst map) | median ms a frame | × NWA 30 |",
        "|---|---|---|---|---|---|---|---|---|",
    ]
    for method, terms in CONFIGS:
        s = stats[(method, terms)]
        settle = "never" if None in s["settle"] else str(max(s["settle"]))
        lines.append(f"| {method.upper()} | {terms} | {s['rot_l2']:.4f} | {s['rot_l1']:.4f} | {s['hold_l2']:.4f} | "
                     f"{s['last_l2']:.2e} | {settle} | {s['ms']:.2f} | {s['ms'] / base_ms:.2f} |")
    lines += [
        "",
        "Targets:",
        f"- PBI 30 at or below NWA 100 over the rotation: {pbi['rot_l2']:.4f} against {nwa100['rot_l2']:.4f} — "
        + ("**met**" if pbi["rot_l2"] <= nwa100["rot_l2"] else
           f"**missed** by {100 * (pbi['rot_l2'] / nwa100['rot_l2'] - 1):.0f}%")
        + " (" + ", ".join(f"{m.upper()} {t}: {stats[(m, t)]['rot_l2']:.4f}" for m, t in CONFIGS
                           if (m, t) != ("pbi", 30)) + ").",
        f"- Below 1% rel. L2 within 5 frames of the hold: worst map {worst_settle} frames — "
        + ("**met**" if worst_settle is not None and worst_settle <= 5 else "**missed**") + ".",
        f"- Frame time within 1.2x of NWA 30: {pbi['ms'] / base_ms:.2f}x — "
        + ("**met**" if pbi["ms"] <= 1.2 * base_ms else "**missed**") + ".",
    ]
    with open(os.path.join(RESULTS, NAME + ".md"), "w") as f:
        f.write("\n".join(lines) + "\n")
    print("\n".join(lines))

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 2, figsize=(12, 4.2))
    for method, terms in CONFIGS:
        mean = [sum(r[5] for r in sel(method, terms) if r[3] == k) / len(names) for k in range(frames)]
        mean_l1 = [sum(r[6] for r in sel(method, terms) if r[3] == k) / len(names) for k in range(frames)]
        style = "-" if method == "pbi" else ("--" if method == "bi" else ":")
        axes[0].plot(mean, style, label=f"{method.upper()} {terms}")
        axes[1].plot(mean_l1, style, label=f"{method.upper()} {terms}")
    for ax, what in zip(axes, ("rel. L2 of the image", "area-weighted rel. L1 of the image")):
        ax.axvline(rot_frames - 0.5, color="gray", lw=0.8)
        ax.set_yscale("log")
        ax.set_xlabel(f"frame ({SEQ})")
        ax.set_ylabel(what + f" (mean of {len(names)} maps)")
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"{DESC}: lighting approximations over {SEQ}")
    fig.tight_layout()
    fig.savefig(os.path.join(RESULTS, NAME + ".png"), dpi=110)


if __name__ == "__main__":
    main()
