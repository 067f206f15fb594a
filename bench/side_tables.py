#!/usr/bin/python3
"""What a final.ltm spends besides its matrix, on scenes no test or default was tuned on.

For each scene of bench/unseen_meshes.py (the Utah teapot and a scanned bust from npm, on
the medium scene's floor) at each size: sample (R = 32, spp 4) -> row-transform db2 ->
transpose, then column-transform (adaptive 4D budgets and 2D budgets) -> quantize (the
default, --error-ratio 1.1), and `inspect --json` of every final.ltm: matrix payload, side
tables (each by name) and container overhead (header, metadata, frame headers and
padding, index, trailer). Issue 39's targets: side tables + overhead <= 2% of any
final.ltm over 100 KB, and <= 8 KB at 128^2 pixels, R = 32.

    /usr/bin/python3 bench/side_tables.py [BUILD=build]

Environment: LTB_SIDE_SIZES ("128 256"), LTB_SIDE_SCENES ("teapot snowden"; at 256 only the
first), LTB_SIDE_4D ("0.25% 1% 4%"), LTB_SIDE_2D ("1% 4%"), LTB_SIDE_DIR
(bench/out/side_tables). Writes bench/results/side_tables.md and .json.
"""
import json
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
import benchlib  # noqa: E402
import unseen_meshes  # noqa: E402

BUILD = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else os.path.join(benchlib.ROOT, "build"))
LTB = os.path.join(BUILD, "ltbake")
SIZES = [int(s) for s in os.environ.get("LTB_SIDE_SIZES", "128 256").split()]
SCENES = os.environ.get("LTB_SIDE_SCENES", "teapot snowden").split()
B4D = os.environ.get("LTB_SIDE_4D", "0.25% 1% 4%").split()
B2D = os.environ.get("LTB_SIDE_2D", "1% 4%").split()
OUT = os.path.abspath(os.environ.get("LTB_SIDE_DIR", os.path.join(HERE, "out", "side_tables")))
R = 32


def ltb(*args):
    p = subprocess.run([LTB, *map(str, args)], capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"ltbake {' '.join(map(str, args))}\n{p.stderr}")
    return p.stdout


def main():
    os.makedirs(OUT, exist_ok=True)
    rows = []
    t0 = time.time()
    for size in SIZES:
        paths = unseen_meshes.scenes(OUT, size)
        for name in SCENES if size <= 128 else SCENES[:1]:
            w = lambda f: os.path.join(OUT, f"{name}{size}_{f}")  # noqa: E731
            ltb("sample", paths[name], "-o", w("raw.ltm"), "--cube-res", R, "-q", "--overwrite")
            ltb("row-transform", w("raw.ltm"), "-o", w("rows.ltm"), "--filter", "db2", "-q", "--overwrite")
            os.remove(w("raw.ltm"))
            ltb("transpose", w("rows.ltm"), "-o", w("cols.ltm"), "-q", "--overwrite")
            os.remove(w("rows.ltm"))
            for label, flags, budgets in (("adaptive 4D", ["--depth", "adaptive"], B4D),
                                          ("2D", ["--depth", "none"], B2D)):
                for b in budgets:
                    ltb("column-transform", w("cols.ltm"), "-o", w("c4.ltm"), *flags, "--budget", b, "-q", "--overwrite")
                    ltb("quantize", w("c4.ltm"), "-o", w("final.ltm"), "-q", "--overwrite")
                    info = json.loads(ltb("inspect", w("final.ltm"), "--json"))
                    od = info["on_disk"]
                    tables = {a["name"]: a["chunks"]["stored_bytes"] for a in info["arrays"][1:]}
                    rows.append({"scene": name, "size": size, "method": label, "budget": b,
                                 "total": od["total_bytes"], "matrix": od["matrix_bytes"],
                                 "side": od["side_table_bytes"], "overhead": od["overhead_bytes"],
                                 "tables": tables, "chunks": sum(a["chunks"]["expected"] for a in info["arrays"])})
                    r = rows[-1]
                    print(f"{name} {size}² {label} {b}: {r['total']} B, side {r['side']} + overhead {r['overhead']} "
                          f"({(r['side'] + r['overhead']) / r['total']:.2%})", flush=True)
            os.remove(w("cols.ltm"))
            os.remove(w("c4.ltm"))
    report(rows, time.time() - t0)


def report(rows, seconds):
    res = os.path.join(HERE, "results")
    json.dump({"machine": benchlib.machine(), "commit": benchlib.git_describe(), "rows": rows},
              open(os.path.join(res, "side_tables.json"), "w"), indent=1)
    lines = ["# Side tables and container overhead of final.ltm, on unseen scenes", "",
             f"`/usr/bin/python3 bench/side_tables.py` ({seconds / 60:.1f} min); {benchlib.machine()}; "
             f"commit {benchlib.git_describe()}. Scenes from bench/unseen_meshes.py (npm teapot, snowden), "
             "R = 32, db2 rows, LeGall 5/3 columns, quantize --error-ratio 1.1.", "",
             "Targets (issue 39): side + overhead ≤ 2% of any final.ltm over 100 KB; ≤ 8 KB at 128², R = 32.", "",
             "| scene | pixels | method | budget | final.ltm | matrix | side tables (by name) | overhead | chunks "
             "| side + overhead | share | target |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for r in rows:
        extra = r["side"] + r["overhead"]
        share = extra / r["total"]
        ok = []
        if r["total"] > 100e3:
            ok.append("≤ 2%: " + ("met" if share <= 0.02 else "**missed**"))
        if r["size"] == 128:
            ok.append("≤ 8 KB: " + ("met" if extra <= 8000 else "**missed**"))
        tables = ", ".join(f"{k} {v}" for k, v in r["tables"].items())
        lines.append(f"| {r['scene']} | {r['size']}² | {r['method']} | {r['budget']} | {r['total']:,} | {r['matrix']:,} "
                     f"| {r['side']:,} ({tables}) | {r['overhead']:,} | {r['chunks']} | {extra:,} | {share:.2%} "
                     f"| {'; '.join(ok)} |")
    open(os.path.join(res, "side_tables.md"), "w").write("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
