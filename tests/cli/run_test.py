"""`ltbake run`: recipes drive the stage graph like make, keyed on content and parameters.

- A bake of the tiny scene makes final.ltm; rerunning skips every stage; run.json holds each
  stage's command, log, wall time, peak RSS, output size and content_hash.
- Fused sample + row-transform (raw not kept) gives the same rows.ltm and final.ltm
  content_hash as the unfused bake that keeps raw.ltm.
- Changing one parameter redoes that stage and the stages whose input content changes, and
  nothing upstream.
- --dry-run changes nothing; --until stops early; --from needs its inputs; --force redoes.
- SIGINT/SIGTERM: the run exits 130/143, what was committed stays, a rerun resumes.
- A failing stage names the stage, the chunk and the command that re-runs just that stage.
- Bad recipes: each a clear error with exit 1 or 2.

usage: run_test.py PATH_TO_LTBAKE
"""
import json
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import LTBAKE, check, finish, run, run_report, write  # noqa: E402

REPO = os.path.abspath(os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", ".."))
TINY = os.path.join(REPO, "samples", "tiny.toml")


report = run_report


def actions(workdir, nodes):
    by = {s["node"]: s for s in report(workdir)["stages"]}
    return {n: by[n]["action"] for n in nodes if n in by}


def html_report(workdir):
    """run.html parsed by Python's own HTML parser (an independent reader): the timeline's
    bars (their <title>s), the text of every table cell, the images and their captions."""
    from html.parser import HTMLParser

    class Page(HTMLParser):
        def __init__(self):
            super().__init__()
            self.bars, self.bar_titles, self.cells, self.images, self.captions = [], [], [], [], []
            self.where = []

        def handle_starttag(self, tag, attrs):
            self.where.append(tag)
            if tag == "rect":
                self.bars.append(dict(attrs))
            if tag == "img":
                self.images.append(dict(attrs)["src"])
            if tag in ("td", "figcaption"):
                (self.cells if tag == "td" else self.captions).append("")

        def handle_endtag(self, tag):
            while self.where and self.where.pop() != tag:
                pass

        def handle_data(self, data):
            if "title" in self.where and "rect" in self.where:
                self.bar_titles.append(data.split(":")[0])
            if "td" in self.where:
                self.cells[-1] += data
            if "figcaption" in self.where:
                self.captions[-1] += data

    p = Page()
    p.feed(open(os.path.join(workdir, "run.html")).read())
    p.close()
    return {"bars": p.bars, "bar_titles": p.bar_titles, "cells": " ".join(p.cells), "images": p.images,
            "captions": p.captions}


def content_hash(path):
    return json.loads(run("inspect", "--json", path).stdout)["content_hash"]


BASE = f'''name = "t"
scene = "{TINY}"
[quantize]
bits = 9
'''
FRAME_HEADER_BYTES = 64  # docs/FORMAT.md "Chunk frames"
FUSED = ["sample+row-transform", "transpose", "column-transform", "quantize"]

with tempfile.TemporaryDirectory() as d:
    rec = write(os.path.join(d, "t.toml"), BASE)
    w = os.path.join(d, "w")

    # --- a whole bake, then a rerun that skips everything ---------------------------------
    p = run("run", rec, "--workdir", w)
    for f in ["rows.ltm", "cols.ltm", "cols4d.ltm", "final.ltm", "run.json"]:
        check(os.path.exists(os.path.join(w, f)), f"bake: {f} missing")
    check(not os.path.exists(os.path.join(w, "raw.ltm")), "fused bake wrote raw.ltm")
    check("content_hash" in p.stdout and "run report: " + os.path.join(w, "run.json") in p.stdout,
          f"bake: no summary table / report path:\n{p.stdout}")
    rep = report(w)
    check(rep["status"] == "ok" and rep["exit_code"] == 0, f"run.json status {rep.get('status')}")
    check(actions(w, FUSED) == {n: "run" for n in FUSED}, f"first bake actions {actions(w, FUSED)}")
    # Each step says where it is in the bake: "== NODE: ... [k/4]", k = 1, 2, 3, 4 in order; from
    # step 2 on (the matrix exists), how long the rest of the bake should take, which run.json
    # keeps as the step's eta_seconds.
    steps = [re.search(r"\[(\d+)/(\d+)\](; about \d+(\.\d)? (s|min|h) left in the bake)?$", l)
             for l in p.stdout.splitlines() if l.startswith("== ")]
    check([(int(m.group(1)), int(m.group(2))) if m else None for m in steps] == [(k, 4) for k in range(1, 5)],
          f"bake: step lines lack [k/4]:\n{p.stdout}")
    check([bool(m and m.group(3)) for m in steps] == [False, True, True, True],
          f"bake: steps 2-4 should say how long the rest takes, step 1 (sampling) not:\n{p.stdout}")
    etas = [s.get("eta_seconds") for s in rep["stages"]]
    # (Not necessarily shrinking: a step slower than the model raises the estimate of the rest.)
    check(etas[0] is None and all(e is not None and e > 0 for e in etas[1:]),
          f"run.json eta_seconds {etas}: none for sampling, then positive")
    for s in rep["stages"]:
        out = s["output"]
        check(s["wall_seconds"] > 0 and s["peak_rss_bytes"] > 1 << 20, f"{s['node']}: no wall time / peak RSS: {s}")
        check(out["bytes"] == os.path.getsize(out["path"]), f"{s['node']}: size in run.json != file size")
        check(out["content_hash"] == content_hash(out["path"]), f"{s['node']}: content_hash in run.json != inspect's")
        check(os.path.exists(s["log"]) and s["node"].split("+")[0] in open(s["log"]).read(),
              f"{s['node']}: log {s.get('log')} missing or empty")
        check(s["command"].startswith(LTBAKE) or "ltbake" in s["command"], f"{s['node']}: command {s['command']}")
    # run.html: the same report as a page; a step a timeline bar, every node in the table.
    page = html_report(w)
    check(len(page["bars"]) == len(rep["stages"]) and sorted(page["bar_titles"]) == sorted(s["node"] for s in rep["stages"]),
          f"run.html: timeline {page['bar_titles']} against run.json's steps")
    for s in rep["stages"]:
        check(s["node"] in page["cells"] and s["output"]["content_hash"] in page["cells"],
              f"run.html: step {s['node']} or its content_hash missing from the table")
    final_hash = content_hash(os.path.join(w, "final.ltm"))
    rows_hash = content_hash(os.path.join(w, "rows.ltm"))
    mtime = os.path.getmtime(os.path.join(w, "final.ltm"))

    # --json: stdout is run.json's report alone (the step lines go to stderr); with --dry-run, the plan.
    p = run("run", rec, "--workdir", w, "--json")
    j = json.loads(p.stdout)
    check(j == report(w) and "== quantize: skipped" in p.stderr, f"run --json: {p.stdout[:300]}\n{p.stderr}")
    j = json.loads(run("run", rec, "--workdir", w, "--json", "--dry-run").stdout)
    check([s["node"] for s in j["plan"]] == FUSED and all(s["action"] == "skip" for s in j["plan"]),
          f"run --dry-run --json: {j}")
    p = run("run", rec, "--workdir", w)
    check(actions(w, FUSED) == {n: "skip" for n in FUSED}, f"rerun should skip all: {actions(w, FUSED)}")
    check(p.stdout.count("skipped, up to date") == 4, f"rerun does not say what it skipped:\n{p.stdout}")
    check(os.path.getmtime(os.path.join(w, "final.ltm")) == mtime, "rerun touched final.ltm")

    # --- fused == unfused -------------------------------------------------------------------
    rec_raw = write(os.path.join(d, "raw.toml"),
                    BASE.replace('name = "t"', 'name = "raw"\nkeep = ["raw", "rows", "cols", "cols4d"]'))
    w_raw = os.path.join(d, "w_raw")
    run("run", rec_raw, "--workdir", w_raw)
    unfused = ["sample", "row-transform", "transpose", "column-transform", "quantize"]
    check(actions(w_raw, unfused) == {n: "run" for n in unfused}, f"unfused actions {actions(w_raw, unfused)}")
    check(os.path.exists(os.path.join(w_raw, "raw.ltm")), "keep raw: raw.ltm missing")
    check(content_hash(os.path.join(w_raw, "rows.ltm")) == rows_hash, "fused rows.ltm differs from unfused")
    check(content_hash(os.path.join(w_raw, "final.ltm")) == final_hash, "fused final.ltm differs from unfused")

    # --- one parameter changed: exactly what depends on it is redone ---------------------------
    def variant(name, text):
        return write(os.path.join(d, name + ".toml"), text)

    cases = [
        ("bits", BASE.replace("bits = 9", "bits = 8"), {"quantize"}),
        ("keep", BASE + '[column-transform]\nkeep = 0.1\n', {"column-transform", "quantize"}),
        # zstd changes how cols.ltm is stored, not its content: downstream stays up to date
        ("zstd", BASE + '[transpose]\nzstd = true\n', {"transpose"}),
        ("spp", BASE + '[sample]\nspp = 2\n', set(FUSED)),
    ]
    for label, text, expect in cases:
        run("run", variant(label, text), "--workdir", w)
        got = {n for n, a in actions(w, FUSED).items() if a != "skip"}
        check(got == expect, f"change {label}: redone {sorted(got)}, expected {sorted(expect)}")
        why = {s["node"]: s["reason"] for s in report(w)["stages"]}
        first = min(expect, key=FUSED.index)
        check("parameters changed" in why[first], f"change {label}: {first} gives no reason: {why[first]}")
        run("run", rec, "--workdir", w, "-q")  # back to the base recipe
    check(content_hash(os.path.join(w, "final.ltm")) == final_hash, "back to the base recipe: final.ltm differs")

    # --- --dry-run changes nothing ------------------------------------------------------------
    before = open(os.path.join(w, "run.json")).read()
    p = run("run", variant("bits7", BASE.replace("bits = 9", "bits = 7")), "--workdir", w, "--dry-run")
    check(re.search(r"quantize\s+redo\s+parameters changed: bits 9 -> 7", p.stdout) is not None,
          f"--dry-run plan does not say why quantize runs:\n{p.stdout}")
    check(re.search(r"transpose\s+skip\s+up to date", p.stdout) is not None, f"--dry-run plan:\n{p.stdout}")
    check(open(os.path.join(w, "run.json")).read() == before, "--dry-run changed run.json")

    # --- --force STAGE ----------------------------------------------------------------------
    run("run", rec, "--workdir", w, "--force", "quantize")
    check({n for n, a in actions(w, FUSED).items() if a != "skip"} == {"quantize"},
          f"--force quantize: {actions(w, FUSED)}")
    check(content_hash(os.path.join(w, "final.ltm")) == final_hash, "--force quantize changed final.ltm")

    # --- --until, then the rest -----------------------------------------------------------------
    w2 = os.path.join(d, "w2")
    run("run", rec, "--workdir", w2, "--until", "transpose")
    check(os.path.exists(os.path.join(w2, "cols.ltm")) and not os.path.exists(os.path.join(w2, "cols4d.ltm")),
          "--until transpose ran too much or too little")
    run("run", rec, "--workdir", w2)
    check(actions(w2, FUSED) == {"sample+row-transform": "skip", "transpose": "skip", "column-transform": "run",
                                 "quantize": "run"}, f"after --until: {actions(w2, FUSED)}")
    check(content_hash(os.path.join(w2, "final.ltm")) == final_hash, "--until then rest: final.ltm differs")

    # --- intermediates not kept are removed, and remade when needed again ------------------------
    w3 = os.path.join(d, "w3")
    rec_lean = variant("lean", BASE.replace('name = "t"', 'name = "lean"\nkeep = []'))
    run("run", rec_lean, "--workdir", w3)
    left = sorted(f for f in os.listdir(w3) if f.endswith(".ltm"))
    check(left == ["final.ltm"], f"keep = []: left {left}")
    p = run("run", rec_lean, "--workdir", w3)
    check("skipped, up to date (cols4d.ltm was not kept)" in p.stdout, f"keep = []: rerun:\n{p.stdout}")
    run("run", variant("lean8", BASE.replace('name = "t"', 'name = "lean"\nkeep = []').replace("bits = 9", "bits = 8")),
        "--workdir", w3)
    # quantize needs cols4d.ltm again, which needs cols.ltm, which needs rows.ltm: all remade
    check(all(a != "skip" for a in actions(w3, FUSED).values()) and len(actions(w3, FUSED)) == 4,
          f"keep = [], bits changed: the removed intermediates must be remade: {actions(w3, FUSED)}")
    check(sorted(f for f in os.listdir(w3) if f.endswith(".ltm")) == ["final.ltm"], "keep = []: leftovers")

    # --- cpca as a target: it reads rows.ltm beside the wavelet branch ------------------------
    rec_cpca = variant("cpca", BASE + '[cpca]\nclusters = 4\nbasis = 3\n')
    run("run", rec_cpca, "--workdir", w)
    check(actions(w, FUSED + ["cpca"]) == {**{n: "skip" for n in FUSED}, "cpca": "run"},
          f"cpca added: {actions(w, FUSED + ['cpca'])}")
    info = json.loads(run("inspect", "--json", os.path.join(w, "cpca.ltm")).stdout)
    check(info.get("cpca", {}).get("clusters") == 4, f"cpca.ltm metadata: {info.get('cpca')}")
    run("run", rec_cpca, "--workdir", w)
    check(actions(w, ["cpca"]) == {"cpca": "skip"}, "cpca rerun not skipped")

    # --- an inline [scene] table bakes the same matrix as the scene file ----------------------
    scene_text = open(TINY).read()
    inline = "\n".join(("[scene." + l[1:] if l.startswith("[") and not l.startswith("[[") else
                        "[[scene." + l[2:] if l.startswith("[[") else l) for l in scene_text.splitlines())
    rec_inline = variant("inline", 'name = "inline"\n' + inline + "\n[quantize]\nbits = 9\n")
    w5 = os.path.join(d, "w5")
    run("run", rec_inline, "--workdir", w5, "-q")
    check(os.path.exists(os.path.join(w5, "scene.toml")), "inline scene: scene.toml not written")
    check(content_hash(os.path.join(w5, "final.ltm")) == final_hash, "inline scene: final.ltm differs")
    p = run("run", rec_inline, "--workdir", w5)
    check(p.stdout.count("skipped, up to date") == 4, f"inline scene: rerun not skipped:\n{p.stdout}")

    # --- SIGTERM and SIGINT: exit 143/130, committed work kept, rerun resumes --------------------
    slow = write(os.path.join(d, "slow.toml"), BASE.replace('name = "t"', 'name = "slow"') +
                 "[sample]\ncube_res = 32\nspp = 32\n")
    for sig, code in [(signal.SIGTERM, 143), (signal.SIGINT, 130)]:
        ws = os.path.join(d, f"slow{code}")
        proc = subprocess.Popen([LTBAKE, "run", slow, "--workdir", ws, "--jobs", "1"], stdout=subprocess.PIPE,
                                stderr=subprocess.PIPE, text=True)
        line = proc.stdout.readline()
        check("sample+row-transform" in line, f"slow bake started with: {line!r}")
        # Signal once the stage has created its output (a condition, not a time).
        deadline = time.monotonic() + 60
        while not os.path.exists(os.path.join(ws, "rows.ltm")) and time.monotonic() < deadline:
            time.sleep(0.02)
        proc.send_signal(sig)
        out, err = proc.communicate(timeout=120)
        check(proc.returncode == code, f"{sig.name}: exit {proc.returncode}, expected {code}\n{out}{err}")
        check("rerun" in err, f"{sig.name}: no resume hint:\n{err}")
        # One message: the stage leaves the interruption to `run`, which names the resume.
        check(err.count("ltbake: error:") == 1, f"{sig.name}: the error is printed more than once:\n{err}")
        rows = os.path.join(ws, "rows.ltm")
        v = json.loads(run("verify", "--allow-incomplete", "--json", rows).stdout)[0]
        check(v["ok"], f"{sig.name}: rows.ltm does not verify after the interrupt: {v}")
        check(report(ws)["status"] == "interrupted", f"{sig.name}: run.json status {report(ws)['status']}")
        p = run("run", slow, "--workdir", ws)
        check(re.search(r"sample\+row-transform: resume \(interrupted: \d+ of \d+ chunks committed\)", p.stdout)
              is not None, f"{sig.name}: rerun does not resume:\n{p.stdout}")
    slow_hash = content_hash(os.path.join(d, "slow143", "final.ltm"))
    check(slow_hash == content_hash(os.path.join(d, "slow130", "final.ltm")), "interrupted bakes differ")

    # --- a failing stage names the stage, the chunk and the command to re-run it -----------------
    w4 = os.path.join(d, "w4")
    shutil.copytree(w, w4, ignore=shutil.ignore_patterns("run.json", "logs"))
    run("run", rec, "--workdir", w4, "-q")  # adopts the copied files (the stages find them made alike)
    rows = os.path.join(w4, "rows.ltm")
    frames = json.loads(run("inspect", "--json", "--chunks", rows).stdout)
    chunk = next(c for c in frames["chunk_list"] if c["array"] == "matrix" and c["encoding"] == "raw")
    with open(rows, "r+b") as f:
        f.seek(chunk["offset"] + FRAME_HEADER_BYTES + 100)
        b = f.read(1)
        f.seek(-1, 1)
        f.write(bytes([b[0] ^ 0x40]))
    p = run("run", rec, "--workdir", w4, "--force", "transpose", expect=1)
    check("stage transpose failed" in p.stderr and f"chunk {chunk['index']}" in p.stderr,
          f"failure does not name stage and chunk:\n{p.stderr}")
    m = re.search(r"re-run just this stage: (.*)", p.stderr)
    check(m is not None and " transpose " in m.group(1) and rows in m.group(1), f"no re-run command:\n{p.stderr}")
    check(report(w4)["status"] == "failed", "run.json does not record the failure")

    # --- bad recipes ------------------------------------------------------------------------------
    def bad(label, text, code, *needles, args=("--workdir", os.path.join(d, "wbad"))):
        r = write(os.path.join(d, "bad.toml"), text)
        p = run("run", r, *args, expect=code)
        for n in needles:
            check(n in p.stderr, f"bad recipe ({label}): message lacks {n!r}:\n{p.stderr}")

    bad("missing scene", 'scene = "nowhere.toml"\n', 1, os.path.join(d, "nowhere.toml"), "does not exist")
    bad("unknown top-level key", "colour = 3\n" + BASE, 2, '"colour" (line 1)', "the recipe")
    bad("unknown key in [quantize]", BASE + "colour = 3\n", 2, '"colour" (line 5)', "[quantize]")
    bad("unknown key in table", BASE + "[sample]\nspp = 4\nsp = 3\n", 2, '"sp" (line 7; did you mean "spp"?)', "[sample]")
    bad("cube_res", BASE + "[sample]\ncube_res = 12\n", 2, "bad.toml:6", "12", "not a power of two")
    bad("two budgets", BASE + "[column-transform]\nkeep = 0.1\nterms = 4\n", 2, "more than one of")
    bad("bad filter", BASE + '[row-transform]\nfilter = "db9"\n', 2, '"db9"', "haar")
    bad("keep over 100%", BASE + '[column-transform]\nkeep = "150%"\n', 2, '"keep"', '"150%"', "fraction")
    bad("budget unit", BASE + '[column-transform]\nbudget = "12Q"\n', 2, '"budget"', '"12Q"')
    # ... and "5%" is read as --keep reads it: the plan's column-transform gets --keep 0.05.
    pct = run("run", write(os.path.join(d, "pct.toml"), BASE + '[column-transform]\nkeep = "5%"\n'), "--workdir",
              os.path.join(d, "wpct"), "--dry-run")
    check("--keep 0.05" in pct.stdout + pct.stderr, f"keep = \"5%\": plan lacks --keep 0.05:\n{pct.stdout}")
    bad("relight without envs", BASE + "[relight]\nterms = 10\n", 2, "needs \"envs\"")
    # exposure is relight's --exposure (a multiplier, 0 automatic), which refuses negatives.
    bad("negative exposure", BASE + '[relight]\nenvs = ["a.exr"]\nexposure = -2.0\n', 2, '"exposure"', "-2",
        "outside [0, 64]")
    # [quantize]: error_ratio (one step, the default 1.1) or bits (per-column), not both;
    # scaling, dither and seed only with bits.
    bad("bits and error_ratio", BASE + "error_ratio = 1.2\n", 2, "error_ratio", "bits", "not both")
    bad("dither without bits", BASE.replace("bits = 9", "dither = false"), 2, "dither goes with bits")
    bad("error_ratio of 1", BASE.replace("bits = 9", "error_ratio = 1.0"), 2, '"error_ratio"')
    bad("target_error and budget", BASE + '[column-transform]\ntarget_error = 0.02\nbudget = "2%"\n', 2,
        "more than one of")
    for text, want in ((BASE + '[sample]\ntolerance = "1%"\nmax_levels = 3\n', "--tolerance 0.01 --max-levels 3"),
                       (BASE.replace("[quantize]\nbits = 9\n", ""), "--error-ratio 1.1"),
                       (BASE, "--budget 5%"),  # [column-transform] defaults to one 5% budget
                       (BASE + '[column-transform]\ntarget_error = "2%"\n', "--target-error 0.02"),
                       (BASE.replace("bits = 9", "error_ratio = 1.25"), "--error-ratio 1.25")):
        plan = run("run", write(os.path.join(d, "er.toml"), text), "--workdir", os.path.join(d, "wer"), "--dry-run")
        check(want in plan.stdout + plan.stderr, f"quantize plan lacks {want}:\n{plan.stdout}")
    # Every map's shape is read with the recipe (its header), before anything runs; env_layout
    # is relight's --env-layout. Radiance files with flat RGBE scanlines (1.0 everywhere).
    def hdr(name, w, h):
        with open(os.path.join(d, name), "wb") as f:
            f.write(b"#?RADIANCE\nFORMAT=32-bit_rle_rgbe\n\n-Y %d +X %d\n" % (h, w) + bytes([128, 128, 128, 129]) * (w * h))
        return os.path.join(d, name)
    probe, latlong = hdr("probe.hdr", 16, 16), hdr("ll.hdr", 32, 16)
    wmaps = os.path.join(d, "wmaps")
    bad("square map, no layout", BASE + f'[relight]\nenvs = ["{latlong}", "{probe}"]\n', 2, probe, "16x16",
        "--env-layout angular", 'env_layout = "..." in [relight]', args=("--workdir", wmaps))
    check(not os.path.exists(os.path.join(wmaps, "rows.ltm")), "a recipe with a bad map ran a stage")
    bad("lat-long read as a cross", BASE + f'[relight]\nenvs = ["{latlong}"]\nenv_layout = "hcross"\n', 2, latlong,
        "32x16 is not a horizontal cross")
    bad("max_levels without tolerance", BASE + "[sample]\nmax_levels = 3\n", 2, '"max_levels" goes with')
    bad("tolerance with sparse", BASE + '[sample]\nsparse = true\ntolerance = "1%"\n', 2, "does not yet combine")
    bad("env_layout choice", BASE + f'[relight]\nenvs = ["{probe}"]\nenv_layout = "mirrorball"\n', 2,
        '"env_layout" is "mirrorball"', "angular")
    np.save(os.path.join(d, "odd.npy"), np.ones((6 * 8 * 8 + 6, 3), np.float32))
    bad("npy not a cubemap", BASE + f'[relight]\nenvs = ["{os.path.join(d, "odd.npy")}"]\n', 2, "odd.npy",
        "is not a cubemap .npy", "(6R², 3)")
    with_relight = BASE.replace("[quantize]", 'targets = ["quantize", "relight"]\n[quantize]')
    plan = run("run", write(os.path.join(d, "probe.toml"), with_relight + f'[relight]\nenvs = ["{probe}"]\nenv_layout = "angular"\n'),
               "--workdir", wmaps, "--dry-run")
    check("--env-layout angular" in plan.stdout, f"env_layout = \"angular\": plan lacks --env-layout:\n{plan.stdout}")
    # run.html of a bake with relight steps: each relit image shown with its error.
    sky = os.path.join(d, "sky.npy")
    np.save(sky, np.random.default_rng(5).uniform(0.2, 1.5, (6 * 8 * 8, 3)).astype(np.float32))
    wrel = os.path.join(d, "wrel")
    run("run", write(os.path.join(d, "rel.toml"), with_relight + f'[relight]\nenvs = ["{sky}"]\nreference = true\n'),
        "--workdir", wrel, "-q")
    page, rrep = html_report(wrel), report(wrel)
    step = [s for s in rrep["stages"] if s["output"]["file"] == "relit-sky.png"]
    check(len(step) == 1 and page["images"] == ["relit-sky.png"] and os.path.exists(os.path.join(wrel, "relit-sky.png")),
          f"run.html: images {page['images']}")
    err = f"{step[0]['metrics']['error']['rel_l2']:.4f}" if step else "?"
    check(any("rel. L2 " + err in c for c in page["captions"]), f"run.html: caption lacks rel. L2 {err}: {page['captions']}")
    os.environ.pop("LTBAKE_NO_SUCH_VAR", None)
    bad("unset variable", BASE + '[relight]\nenvs = ["${LTBAKE_NO_SUCH_VAR}/a.exr"]\n', 2, "LTBAKE_NO_SUCH_VAR",
        "not set")
    bad("syntax", BASE + "[sample\n", 2, "bad.toml:5")
    bad("no workdir", BASE, 2, "no work directory", args=())
    bad("vertex scene", f'scene = "{os.path.join(REPO, "samples", "bunny-vertices.toml")}"\n', 2, "vertex rows",
        'targets = ["cpca"]')
    wbad = os.path.join(d, "wbad")
    bad("unknown stage", BASE, 2, '"colour-transform" is not a stage', args=("--workdir", wbad, "--until", "colour-transform"))
    bad("input missing", BASE, 1, "rows.ltm", "does not exist", args=("--workdir", wbad, "--from", "transpose"))
    # a work directory holding another recipe's bake
    other = write(os.path.join(d, "other.toml"), BASE.replace('name = "t"', 'name = "other"'))
    p = run("run", other, "--workdir", w, expect=1)
    check("holds the bake of another recipe" in p.stderr and '"t"' in p.stderr, f"other recipe:\n{p.stderr}")
    check(content_hash(os.path.join(w, "final.ltm")) == final_hash, "refused run changed the other bake")

finish()
