#!/usr/bin/python3
"""Figure 7 of Cheslack-Postava et al. 2007 for ltbake (bench/run_fig7.sh drives it).

  fig7.py error REF.npy TEST.npy [TEST2.npy ...] [--band-rows 1024]
      ||REF - TEST||_F / ||REF||_F for each TEST, as JSON on stdout. The .npy files are
      memory-mapped and read in bands of rows (float64 accumulation); each band's pages
      are dropped (madvise DONTNEED) once used, so the resident memory stays ~ a few bands.
  fig7.py line RUN_DIR
      one summary line of a finished run (ct.json, q.json, err.json, run.json, ct.time).
  fig7.py report --dir OUT --results RESULTS [--notes NOTES.md]
      bench/results/column_transform_fig7.{csv,png,md} from OUT/runs/*/.
"""
import argparse
import csv
import glob
import json
import math
import mmap
import os
import resource
import sys
import time

import numpy as np

MODES = ["none", "full", "adaptive", "adaptive_budget", "none_budget", "full_budget"]
LABELS = {
    "none": "2D (--depth none --terms N)",
    "full": "full 4D (--depth full --terms N)",
    "adaptive": "adaptive 4D (--depth adaptive --terms N)",
    "adaptive_budget": "adaptive 4D, RD budget (--depth adaptive --budget K)",
    "none_budget": "2D, global budget (--depth none --budget K) [extra]",
    "full_budget": "full 4D, global budget (--depth full --budget K) [extra]",
}
SHORT = {
    "none": "2D terms",
    "full": "full 4D terms",
    "adaptive": "adaptive terms",
    "adaptive_budget": "adaptive RD budget",
    "none_budget": "2D budget",
    "full_budget": "full 4D budget",
}
STYLE = {
    "none": dict(color="tab:blue", marker="s", ls="-"),
    "full": dict(color="tab:orange", marker="^", ls="-"),
    "adaptive": dict(color="tab:green", marker="o", ls="-"),
    "adaptive_budget": dict(color="tab:red", marker="D", ls="-"),
    "none_budget": dict(color="tab:blue", marker="s", ls="--", mfc="none"),
    "full_budget": dict(color="tab:orange", marker="^", ls="--", mfc="none"),
}
ERROR_LEVELS = [0.01, 0.02, 0.05, 0.1, 0.2, 0.5]


# ---------------------------------------------------------------------------- error
class Npy:
    """A read-only memory map of a 2-D C-order .npy file."""

    def __init__(self, path):
        self.path = path
        self.f = open(path, "rb")
        version = np.lib.format.read_magic(self.f)
        if version == (1, 0):
            shape, fortran, dtype = np.lib.format.read_array_header_1_0(self.f)
        else:
            shape, fortran, dtype = np.lib.format.read_array_header_2_0(self.f)
        if fortran or len(shape) != 2:
            raise SystemExit(f"{path}: need a 2-D C-order array, got shape {shape} fortran={fortran}")
        self.shape, self.dtype, self.offset = shape, dtype, self.f.tell()
        self.mm = mmap.mmap(self.f.fileno(), 0, access=mmap.ACCESS_READ)
        self.row_bytes = shape[1] * dtype.itemsize

    def band(self, r0, r1):
        return np.frombuffer(self.mm, dtype=self.dtype, count=(r1 - r0) * self.shape[1],
                             offset=self.offset + r0 * self.row_bytes).reshape(r1 - r0, self.shape[1])

    def drop(self, r0, r1):
        start = self.offset + r0 * self.row_bytes
        end = min(self.offset + r1 * self.row_bytes, len(self.mm))
        start -= start % mmap.PAGESIZE
        if hasattr(self.mm, "madvise") and end > start:
            self.mm.madvise(mmap.MADV_DONTNEED, start, end - start)


def cmd_error(a):
    t0 = time.time()
    ref = Npy(a.ref)
    tests = [Npy(p) for p in a.tests]
    for t in tests:
        if t.shape != ref.shape:
            raise SystemExit(f"{t.path}: shape {t.shape} != reference {ref.shape}")
    ref_sq = 0.0
    diff_sq = [0.0] * len(tests)
    rows = ref.shape[0]
    for r0 in range(0, rows, a.band_rows):
        r1 = min(rows, r0 + a.band_rows)
        x = ref.band(r0, r1).astype(np.float64).ravel()
        ref_sq += float(np.dot(x, x))
        for i, t in enumerate(tests):
            d = t.band(r0, r1).astype(np.float64).ravel()
            d -= x
            diff_sq[i] += float(np.dot(d, d))
            del d
            t.drop(r0, r1)
        del x
        ref.drop(r0, r1)
    out = {
        "reference": a.ref,
        "shape": list(ref.shape),
        "band_rows": a.band_rows,
        "ref_sq": ref_sq,
        "tests": {os.path.basename(t.path): {"diff_sq": diff_sq[i],
                                             "rel_rms_error": math.sqrt(diff_sq[i] / ref_sq) if ref_sq > 0 else None}
                  for i, t in enumerate(tests)},
        "seconds": time.time() - t0,
        "peak_rss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss,
    }
    json.dump(out, sys.stdout, indent=1)
    print()


# ---------------------------------------------------------------------------- runs
def load_run(d):
    run = json.load(open(os.path.join(d, "run.json")))
    ct = json.load(open(os.path.join(d, "ct.json")))
    q = json.load(open(os.path.join(d, "q.json")))
    err = json.load(open(os.path.join(d, "err.json")))
    e, m, u, s = open(os.path.join(d, "ct.time")).read().split()[-4:]
    rows, cols = ct["rows"], ct["cols"]
    r = {
        "mode": run["mode"],
        "terms_or_budget": int(run["value"]),
        "nonzeros": int(q["nonzeros_out"]),
        "nonzero_fraction": q["nonzeros_out"] / (rows * cols),
        "rel_rms_error_quantized": err["tests"]["final.npy"]["rel_rms_error"],
        "rel_rms_error_unquantized": ct["relative_rms_error"],
        "bytes_per_nonzero": q["bytes_per_nonzero"],
        "column_transform_seconds": float(run["wall_seconds"]),
        "depth_histogram": " ".join(str(v) for v in ct["depth_histogram"]),
        # extras
        "nonzeros_unquantized": int(ct["nonzeros"]),
        "nonzero_fraction_unquantized": ct["nonzeros"] / (rows * cols),
        "quantized_matrix_bytes": q.get("matrix_bytes"),
        "column_transform_peak_rss_kib": int(m),
        "column_transform_user_seconds": float(u),
        "column_transform_sys_seconds": float(s),
        "busy_before_pct": run.get("busy_before_pct"),
        "loadavg_before": run.get("loadavg"),
        "empty_columns": ct.get("empty_columns"),
        "lambda": ct.get("lambda"),
        "histogram_bytes": ct.get("histogram_bytes"),
        "rows": rows,
        "cols": cols,
        "extra": bool(run.get("extra", False)),
        "binary_sha256": run.get("binary_sha256"),
    }
    if "c4.npy" in err["tests"]:
        r["numpy_unquantized_check"] = err["tests"]["c4.npy"]["rel_rms_error"]
    return r


def cmd_line(a):
    r = load_run(a.dir)
    print(f"  {r['mode']:<16} {r['terms_or_budget']:>9}  ct {r['column_transform_seconds']:7.2f} s "
          f"(busy {r['busy_before_pct']}%)  nnz {r['nonzeros_unquantized']:>9} -> {r['nonzeros']:>9} "
          f"({100 * r['nonzero_fraction']:.3f}%)  err {r['rel_rms_error_unquantized']:.4f} -> "
          f"{r['rel_rms_error_quantized']:.4f}  {r['bytes_per_nonzero']:.2f} B/nz", flush=True)


# ---------------------------------------------------------------------------- analysis
def frontier(points):
    """Points (nz, err) sorted by nz, keeping only those with less error than every
    point with fewer nonzeros (the usable part of the curve)."""
    out, best = [], math.inf
    for nz, e in sorted(points):
        if e < best:
            out.append((nz, e))
            best = e
    return out


def nz_at_error(front, err):
    """nonzeros needed for error err, log-log interpolation; None outside the curve."""
    es = [e for _, e in front]
    if not front or err < min(es) or err > max(es):
        return None
    le = np.log(es)[::-1]
    ln = np.log([n for n, _ in front])[::-1]
    return float(math.exp(np.interp(math.log(err), le, ln)))


def err_at_nz(front, nz):
    ns = [n for n, _ in front]
    if not front or nz < min(ns) or nz > max(ns):
        return None
    return float(math.exp(np.interp(math.log(nz), np.log(ns), np.log([e for _, e in front]))))


def compare(ra, rb, nzkey, errkey):
    """Size ratio nz_A / nz_B at equal error. Returns dict with rows and notes."""
    fa = frontier([(r[nzkey], r[errkey]) for r in ra])
    fb = frontier([(r[nzkey], r[errkey]) for r in rb])
    if not fa or not fb:
        return {"rows": [], "note": "missing data"}
    ea = (min(e for _, e in fa), max(e for _, e in fa))
    eb = (min(e for _, e in fb), max(e for _, e in fb))
    lo, hi = max(ea[0], eb[0]), min(ea[1], eb[1])
    res = {"range_a": ea, "range_b": eb, "rows": [], "excluded_a": len(ra) - len(fa), "excluded_b": len(rb) - len(fb)}
    if lo > hi:
        # no overlap: bound from the curve ends
        if ea[0] > eb[1]:
            # A never gets as low as B's worst point: at A's best error, B needs <= its smallest nz
            nz_a = max(n for n, _ in fa)
            nz_b = min(n for n, _ in fb)
            res["bound"] = (">=", nz_a / nz_b, ea[0])
        else:
            nz_a = min(n for n, _ in fa)
            nz_b = max(n for n, _ in fb)
            res["bound"] = ("<=", nz_a / nz_b, eb[0])
        return res
    levels = [e for e in ERROR_LEVELS if lo <= e <= hi]
    if not levels:
        levels = sorted({lo, math.sqrt(lo * hi), hi})
    for e in levels:
        na, nb = nz_at_error(fa, e), nz_at_error(fb, e)
        res["rows"].append((e, na, nb, na / nb))
    res["overlap"] = (lo, hi)
    return res


def fmt_compare(title, res, name_a, name_b, unit="nonzeros"):
    lines = [f"**{title}**"]
    if "bound" in res:
        op, v, e = res["bound"]
        lines.append(f"- no overlap of the error ranges ({name_a}: {res['range_a'][0]:.4g}–{res['range_a'][1]:.4g}, "
                     f"{name_b}: {res['range_b'][0]:.4g}–{res['range_b'][1]:.4g}); from the curve ends, "
                     f"size ratio {name_a} : {name_b} {op} **{v:.3g}** at error {e:.4g}")
        return "\n".join(lines) + "\n"
    if not res["rows"]:
        return f"**{title}**: {res.get('note', 'no data')}\n"
    lines.append(f"- error ranges: {name_a} {res['range_a'][0]:.4g}–{res['range_a'][1]:.4g}, "
                 f"{name_b} {res['range_b'][0]:.4g}–{res['range_b'][1]:.4g}; overlap {res['overlap'][0]:.4g}–{res['overlap'][1]:.4g}"
                 + (f" (points left out as not on their curve's frontier: {name_a} {res['excluded_a']}, {name_b} {res['excluded_b']})"
                    if res['excluded_a'] or res['excluded_b'] else ""))
    lines.append("")
    lines.append(f"| rel. RMS error | {unit} {name_a} | {unit} {name_b} | ratio {name_a} : {name_b} |")
    lines.append("| ---: | ---: | ---: | ---: |")
    for e, na, nb, ratio in res["rows"]:
        lines.append(f"| {e:.4g} | {na:,.0f} | {nb:,.0f} | **{ratio:.3g}** |")
    return "\n".join(lines) + "\n"


def monotone_report(rs, nzkey, errkey):
    """(violations, duplicates): consecutive points (by nonzeros) where the error does not
    decrease although the nonzeros grow; pairs of runs that gave the same nonzeros."""
    pts = sorted((r[nzkey], r[errkey], r["terms_or_budget"]) for r in rs)
    bad, dup = [], []
    for a, b in zip(pts, pts[1:]):
        if b[0] == a[0]:
            dup.append((a[2], b[2]))
        elif b[1] >= a[1]:
            bad.append((a[2], b[2]))
    return bad, dup


# ---------------------------------------------------------------------------- report
def cmd_report(a):
    runs = []
    for d in sorted(glob.glob(os.path.join(a.dir, "runs", "*"))):
        if os.path.exists(os.path.join(d, "done")):
            runs.append(load_run(d))
    if not runs:
        raise SystemExit("no finished runs in " + a.dir)
    runs.sort(key=lambda r: (MODES.index(r["mode"]), r["terms_or_budget"]))
    by = {m: [r for r in runs if r["mode"] == m] for m in MODES}
    rows, cols = runs[0]["rows"], runs[0]["cols"]
    os.makedirs(a.results, exist_ok=True)
    base = os.path.join(a.results, a.name)

    # CSV
    fields = ["mode", "terms_or_budget", "nonzeros", "nonzero_fraction", "rel_rms_error_quantized",
              "rel_rms_error_unquantized", "bytes_per_nonzero", "column_transform_seconds", "depth_histogram",
              "nonzeros_unquantized", "nonzero_fraction_unquantized", "quantized_matrix_bytes",
              "column_transform_peak_rss_kib", "column_transform_user_seconds", "column_transform_sys_seconds",
              "busy_before_pct", "loadavg_before"]
    with open(base + ".csv", "w", newline="") as f:
        w = csv.DictWriter(f, fieldnames=fields, extrasaction="ignore")
        w.writeheader()
        for r in runs:
            w.writerow(r)

    # plot
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    fig, axes = plt.subplots(1, 3, figsize=(21, 6.5), sharey=True)
    for ax, nzkey, errkey, title, scale in [
        (axes[0], "nonzero_fraction", "rel_rms_error_quantized", "after quantize --bits 9 (final.ltm)", 100),
        (axes[1], "nonzero_fraction_unquantized", "rel_rms_error_unquantized", "column-transform output, before quantization", 100),
        (axes[2], "quantized_matrix_bytes", "rel_rms_error_quantized", "after quantize --bits 9: stored matrix bytes", 1e-6),
    ]:
        for m in MODES:
            rs = sorted(by[m], key=lambda r: r[nzkey])
            if not rs:
                continue
            ax.plot([scale * r[nzkey] for r in rs], [r[errkey] for r in rs], label=LABELS[m], ms=5, **STYLE[m])
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel(f"nonzeros, % of the matrix ({rows} × {cols})" if scale == 100
                      else "final.ltm matrix_bytes (sparse chunks, zstd where it pays), MB")
        ax.set_title(title, fontsize=10)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].set_ylabel("relative RMS error  ||T − T'||_F / ||T||_F")
    axes[1].legend(fontsize=8, loc="lower left")
    fig.suptitle("ltbake, medium scene (%s): sparsity vs error, cf. Cheslack-Postava et al. 2007 Fig. 7"
                 % ("256×256 image, R = %d" % int(round(math.sqrt(cols / 6)))), fontsize=11)
    fig.tight_layout()
    fig.savefig(base + ".png", dpi=110)

    # markdown
    machine = open(os.path.join(a.dir, "machine.txt")).read() if os.path.exists(os.path.join(a.dir, "machine.txt")) else ""
    stages = []
    if os.path.exists(os.path.join(a.dir, "stages.tsv")):
        stages = [l.rstrip("\n").split("\t") for l in open(os.path.join(a.dir, "stages.tsv")) if l.strip()]
    prov = {}
    for l in machine.splitlines():
        if l.startswith("---"):
            break
        k, _, v = l.partition(": ")
        prov[k] = v
    R = int(round(math.sqrt(cols / 6)))
    md = []
    md.append("# Figure 7 for ltbake: sparsity vs error of 2D, full 4D, adaptive 4D and RD-budget compression\n")
    rel = os.path.relpath(a.dir, os.path.dirname(os.path.abspath(a.results)))
    md.append(f"Generated by `bench/fig7.py report` from the run in `{rel}`. Plot: "
              f"[{a.name}.png]({a.name}.png); raw table: [{a.name}.csv]({a.name}.csv).\n")
    md.append("## How to reproduce\n")
    env = []
    if prov.get("cube_res", "16") != "16":
        env.append(f"LTB_FIG7_CUBE_RES={prov['cube_res']}")
    if prov.get("terms") and prov["terms"] != "16 32 64 128 256 512 1024 2048":
        env.append(f'LTB_FIG7_TERMS="{prov["terms"]}"')
    if prov.get("extras") == "0":
        env.append("LTB_FIG7_EXTRAS=0")
    ext_terms = " ".join(str(r["terms_or_budget"]) for r in by["none"] if r["extra"])
    ext_fr = " ".join(f"{r['terms_or_budget'] / (rows * cols):.3g}" for r in by["none_budget"] if r["extra"])
    if prov.get("extras") != "0":
        if ext_terms != "4096 8192 16384 32768":
            env.append(f'LTB_FIG7_NONE_EXTRA_TERMS="{ext_terms}"')
        if ext_fr != "0.01 0.02 0.05 0.1 0.2 0.4":
            env.append(f'LTB_FIG7_NONE_EXTRA_FRACTIONS="{ext_fr}"')
    total = sum(float(x) for n, x in stages if n in ("sweep-invocation", "total-this-invocation")) or None
    md.append("```\n" + " ".join(env + ["bash bench/run_fig7.sh build"])
              + (f"    # took {total / 60:.0f} min here" if total else "") + "\n```\n")
    md.append("(`bash bench/run_fig7.sh build` alone is the R = 16 sweep with the extras; `LTB_FIG7_EXTRAS=0` "
              "runs only the issue's four curves; the per-run results stay in the run directory, a rerun "
              "skips finished runs and rewrites the report.)\n")
    md.append("Pipeline: `ltbake sample samples/medium.toml -o raw.ltm --cube-res %d` → `row-transform --filter db2` → "
              "`transpose` → per run `column-transform cols.ltm -o c4.ltm --filter legall53 --depth D (--terms N | --budget K) "
              "--json --overwrite` → `quantize c4.ltm -o final.ltm --bits 9 --json --overwrite` (default `--scaling level`, "
              "dither, seed 1) → `convert final.ltm final.npy` (decodes to the row-transformed basis) → "
              "`fig7.py error rows.npy final.npy` (reference: `convert rows.ltm rows.npy`). The error is "
              "||T − T'||_F / ||T||_F over the whole %d × %d matrix in the db2 row-transformed basis; db2 is orthonormal, so "
              "this equals the error in the pixel basis. Budgets K are the `nonzeros` the adaptive `--terms N` runs kept "
              "(before quantization). *nonzeros* in the table is quantize's `nonzeros_out`; *nnz before q.* is "
              "column-transform's `nonzeros`.\n" % (R, rows, cols))
    md.append("## Setup and machine\n")
    md.append(f"- matrix: {rows} × {cols} (256×256 image rows, R = {R} cube map, {cols} lights), "
              f"{rows * cols:,} elements; all-zero columns: {runs[0].get('empty_columns')} (lights below the scene's horizon)")
    md.append(f"- date {prov.get('date', '?')}; git {prov.get('git', '?')}; ltbake binary sha256 {prov.get('binary_sha256', '?')[:16]}… "
              f"(a private copy of build/ltbake taken at the start)")
    if prov.get("git_dirty"):
        md.append(f"- uncommitted changes in the working tree at the start (another engineer's work in progress "
                  f"and this benchmark's own files): `{prov['git_dirty'][:300]}`")
    shas = sorted({r["binary_sha256"] for r in runs if r.get("binary_sha256")})
    if len(shas) > 1:
        md.append(f"- **the runs used {len(shas)} different binaries** (the sweep was resumed after a rebuild): "
                  + ", ".join(x[:16] for x in shas))
    if stages:
        md.append("- wall times: " + ", ".join(f"{n} {float(s):.1f} s" for n, s in stages)
                  + " (sweep-invocation: the whole script run, bake included)")
    ctsum = sum(r["column_transform_seconds"] for r in runs)
    md.append(f"- sum of column-transform wall times over the {len(runs)} runs: {ctsum / 60:.1f} min")
    busy = [r["busy_before_pct"] for r in runs if r["busy_before_pct"] is not None]
    if busy:
        md.append(f"- machine busy just before each column-transform (1 s sample, the script waits up to 5 s for < 25%): "
                  f"median {int(np.median(busy))}%, max {max(busy)}% — another engineer was building and testing on the "
                  f"same 2 vCPUs, so the wall times are noisy")
    md.append("")
    hw = machine[machine.index("--- lscpu"):] if "--- lscpu" in machine else machine
    md.append("```\n" + hw.rstrip() + "\n```\n")

    md.append("## Results\n")
    md.append("| mode | N or K | nnz before q. | nonzeros | % of matrix | rel. RMS error (quantized) | (unquantized) | bytes/nnz | column-transform s | depth histogram (d = 0…8) |")
    md.append("| --- | ---: | ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    for r in runs:
        md.append(f"| {SHORT[r['mode']]}{' (ext.)' if r['extra'] else ''} | {r['terms_or_budget']:,} | {r['nonzeros_unquantized']:,} | {r['nonzeros']:,} | "
                  f"{100 * r['nonzero_fraction']:.4f} | {r['rel_rms_error_quantized']:.5f} | {r['rel_rms_error_unquantized']:.5f} | "
                  f"{r['bytes_per_nonzero']:.3f} | {r['column_transform_seconds']:.2f} | {r['depth_histogram']} |")
    md.append("")

    # sanity checks
    md.append("## Sanity checks\n")
    for m in MODES:
        if not by[m]:
            continue
        bu, du = monotone_report(by[m], "nonzeros_unquantized", "rel_rms_error_unquantized")
        bq, _ = monotone_report(by[m], "nonzeros", "rel_rms_error_quantized")
        md.append(f"- {SHORT[m]}: error decreases with nonzeros — unquantized: "
                  + ("yes" if not bu else "**no** between " + ", ".join(f"{x}→{y}" for x, y in bu))
                  + "; quantized: " + ("yes" if not bq else "**no** between " + ", ".join(f"{x}→{y}" for x, y in bq))
                  + ("" if not du else "; identical outputs (same nonzeros) for K = "
                     + ", ".join(f"{x:,} and {y:,}" for x, y in du)))
    if not any("numpy_unquantized_check" in r for r in runs):
        md.append("- (no NumPy check of an unquantized output in this run: it is made at adaptive N = 256 only)")
    for r in runs:
        if "numpy_unquantized_check" in r:
            md.append(f"- unquantized output of {SHORT[r['mode']]} N = {r['terms_or_budget']} decoded with `convert` and "
                      f"measured in NumPy: {r['numpy_unquantized_check']:.9f}; column-transform reported "
                      f"{r['rel_rms_error_unquantized']:.9f} (difference {abs(r['numpy_unquantized_check'] - r['rel_rms_error_unquantized']):.1e})")
    qadd = [math.sqrt(max(0.0, r["rel_rms_error_quantized"] ** 2 - r["rel_rms_error_unquantized"] ** 2)) for r in runs]
    md.append(f"- quantization (9 bits, level scaling, dither) adds, in quadrature, a relative RMS error of "
              f"{min(qadd):.4f}–{max(qadd):.4f} (median {float(np.median(qadd)):.4f}) over all runs")
    md.append("")

    # equal-error ratios
    md.append("## Size at equal error\n")
    md.append("Each curve's log(nonzeros) interpolated linearly in log(error), on its frontier (points with more "
              "error than a point with fewer nonzeros are left out), over the error range both curves cover; "
              "ratio > 1 means the first needs more nonzeros.\n")
    pairs = [("none", "adaptive"), ("full", "adaptive"), ("adaptive", "adaptive_budget"),
             ("none_budget", "adaptive_budget"), ("full_budget", "adaptive_budget"), ("none_budget", "adaptive")]
    for label, nzkey, errkey in [("quantized (final.ltm, nonzeros = nonzeros_out)", "nonzeros", "rel_rms_error_quantized"),
                                 ("unquantized (column-transform output)", "nonzeros_unquantized", "rel_rms_error_unquantized"),
                                 ("quantized, stored bytes instead of nonzeros (final.ltm `matrix_bytes`)", "quantized_matrix_bytes",
                                  "rel_rms_error_quantized")]:
        md.append(f"### {label}\n")
        for pa, pb in pairs:
            if not by[pa] or not by[pb]:
                continue
            res = compare(by[pa], by[pb], nzkey, errkey)
            md.append(fmt_compare(f"{SHORT[pa]} : {SHORT[pb]}", res, SHORT[pa], SHORT[pb],
                                  "bytes" if nzkey == "quantized_matrix_bytes" else "nonzeros"))

    # equal nonzeros: RD budget vs terms
    md.append("## RD budget vs per-column terms at equal nonzeros\n")
    md.append("Budget K = the adaptive `--terms N` run's nonzeros; the budget is met from below (to one histogram bin), "
              "so the budget run has at most as many nonzeros.\n")
    md.append("| N | K | nnz terms | nnz budget | err terms (unq.) | err budget (unq.) | budget ≤ terms | "
              "nonzeros_out terms | nonzeros_out budget | err terms (q.) | err budget (q.) | budget ≤ terms (q.) |")
    md.append("| ---: | ---: | ---: | ---: | ---: | ---: | --- | ---: | ---: | ---: | ---: | --- |")
    bud = {r["terms_or_budget"]: r for r in by["adaptive_budget"]}
    for t in by["adaptive"]:
        b = bud.get(t["nonzeros_unquantized"])
        if not b:
            continue
        ok_u = b["rel_rms_error_unquantized"] <= t["rel_rms_error_unquantized"] and b["nonzeros_unquantized"] <= t["nonzeros_unquantized"]
        ok_q = b["rel_rms_error_quantized"] <= t["rel_rms_error_quantized"]
        md.append(f"| {t['terms_or_budget']} | {b['terms_or_budget']:,} | {t['nonzeros_unquantized']:,} | {b['nonzeros_unquantized']:,} | "
                  f"{t['rel_rms_error_unquantized']:.5f} | {b['rel_rms_error_unquantized']:.5f} | {'yes' if ok_u else '**NO**'} "
                  f"({t['rel_rms_error_unquantized'] / b['rel_rms_error_unquantized']:.2f}× less error) | "
                  f"{t['nonzeros']:,} | {b['nonzeros']:,} | {t['rel_rms_error_quantized']:.5f} | {b['rel_rms_error_quantized']:.5f} | "
                  f"{'yes' if ok_q else '**NO**'}{'' if b['nonzeros'] <= t['nonzeros'] else ' (budget has more nonzeros_out)'} |")
    md.append("")

    # adaptive vs none/full at equal terms
    md.append("## Adaptive vs 2D and full 4D at the same N (per-column terms)\n")
    md.append("| N | nnz 2D | err 2D (unq. / q.) | nnz full | err full (unq. / q.) | nnz adaptive | err adaptive (unq. / q.) | adaptive ≤ both (unq. / q.) |")
    md.append("| ---: | ---: | ---: | ---: | ---: | ---: | ---: | --- |")
    nd = {r["terms_or_budget"]: r for r in by["none"]}
    fd = {r["terms_or_budget"]: r for r in by["full"]}
    for t in by["adaptive"]:
        n, f_ = nd.get(t["terms_or_budget"]), fd.get(t["terms_or_budget"])
        if not n or not f_:
            continue
        okq = t["rel_rms_error_quantized"] <= min(n["rel_rms_error_quantized"], f_["rel_rms_error_quantized"])
        oku = t["rel_rms_error_unquantized"] <= min(n["rel_rms_error_unquantized"], f_["rel_rms_error_unquantized"])
        md.append(f"| {t['terms_or_budget']} | {n['nonzeros_unquantized']:,} | {n['rel_rms_error_unquantized']:.4f} / {n['rel_rms_error_quantized']:.4f} | "
                  f"{f_['nonzeros_unquantized']:,} | {f_['rel_rms_error_unquantized']:.4f} / {f_['rel_rms_error_quantized']:.4f} | "
                  f"{t['nonzeros_unquantized']:,} | {t['rel_rms_error_unquantized']:.4f} / {t['rel_rms_error_quantized']:.4f} | "
                  f"{'yes' if oku else 'no'} / {'yes' if okq else 'no'} |")
    md.append("")
    # full 4D inflation: nonzeros full vs adaptive at same N
    infl = [(t["terms_or_budget"], fd[t["terms_or_budget"]]["nonzeros_unquantized"] / t["nonzeros_unquantized"])
            for t in by["adaptive"] if t["terms_or_budget"] in fd]
    if infl:
        md.append("Full 4D keeps more terms than adaptive at the same N (columns that adaptive leaves as pixels are exact "
                  "with fewer terms): nonzeros full / adaptive = " + ", ".join(f"N={n}: {v:.3f}" for n, v in infl) + ".\n")

    if a.notes and os.path.exists(a.notes):
        md.append(open(a.notes).read().rstrip() + "\n")
    with open(base + ".md", "w") as f:
        f.write("\n".join(md))
    print(f"wrote {base}.csv, {base}.png, {base}.md ({len(runs)} runs)")


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="cmd", required=True)
    e = sub.add_parser("error")
    e.add_argument("ref")
    e.add_argument("tests", nargs="+")
    e.add_argument("--band-rows", type=int, default=1024)
    e.set_defaults(fn=cmd_error)
    l = sub.add_parser("line")
    l.add_argument("dir")
    l.set_defaults(fn=cmd_line)
    r = sub.add_parser("report")
    r.add_argument("--dir", required=True)
    r.add_argument("--results", required=True)
    r.add_argument("--notes")
    r.add_argument("--name", default="column_transform_fig7", help="base name of the outputs in --results")
    r.set_defaults(fn=cmd_report)
    a = ap.parse_args()
    a.fn(a)


if __name__ == "__main__":
    main()
