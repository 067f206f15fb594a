"""`ltbake sample --sparse` (docs/SPARSE.md) through the CLI, against independent oracles:
the full bake of the same scene, NumPy, and the container's own guarantees.

1. Piecewise-constant visibility (a plane under a square occluder): with every row dense,
   the adaptive angular sampling traces a fraction of the texels and the matrix equals the
   full sample bit for bit (every texel near a shadow edge was traced).
2. Determinism across --jobs and --chunk-rows, a kill storm (phase 1 and phase 2) with
   resume: the same content_hash as an uninterrupted run.
3. Accuracy on the bundled tiny scene, direct and with one bounce: T·L of the sparse bake
   against the full bake (NumPy), within a bound set from the noise between two full bakes.
4. The side tables and `inspect --json`'s sparse block agree with each other (NumPy sums).
5. The fused row-transform equals row-transform of the sparse raw matrix; cpca on the sparse
   bake runs dense-first; a recipe with [sample] sparse = true bakes through quantize + cpca.
6. Bad parameters are refused naming the flag and the value.
7. --sparse auto: the pilot's record is consistent with its decision (the prediction's
   closed form), a full decision writes the full bake's matrix (content_hash of `sample`
   without --sparse) and a sparse one the --sparse bake's; a rerun keeps the recorded
   decision; a recipe's sparse = true runs --sparse auto. (The hidden --sparse-margin pins
   the decision, so no test depends on how fast the machine is.)

usage: sparse_test.py PATH_TO_LTBAKE
"""
import json
import os
import sys
import tempfile

import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import ltbtest as t  # noqa: E402

HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.join(HERE, "..", "..", "samples")
TINY = os.path.join(SAMPLES, "tiny.toml")


def info(path):
    return json.loads(t.run("inspect", path, "--json").stdout)


def matrix_hash(path):
    return info(path)["arrays"][0]["content_hash"]


def load(path, d, name):
    npy = os.path.join(d, name + ".npy")
    t.run("convert", path, npy, "-q")
    return np.load(npy).astype(np.float64)


def sample(scene, out, *args, expect=0):
    return t.run("sample", scene, "-o", out, "--progress", "never", "-q", *args, expect=expect)


OCCLUDER_SCENE = """
[output]
mode = "image"
[camera]
eye = [0.0, -2.2, 0.9]
target = [0.0, 0.6, 0.0]
up = [0.0, 0.0, 1.0]
fov = 30.0
width = 20
height = 16
[sampling]
cube_res = 16
spp = 4
[[material]]
name = "floor"
albedo = 0.8
[[object]]
name = "ground"
type = "plane"
size = [8.0, 8.0]
material = "floor"
[[object]]
name = "square"
type = "box"
size = [1.5, 1.5, 1.5]
center = [0.0, 0.4, 1.3]
material = "floor"
"""

with tempfile.TemporaryDirectory() as d:
    # 1. A plane under a square occluder, every row dense: exact, with far fewer texels traced.
    #    (A cube seen from below: no part of its silhouette is thinner than the grid's
    #    spacing, which the adaptive sampling could miss — docs/SPARSE.md.)
    occ = t.write(os.path.join(d, "occluder.toml"), OCCLUDER_SCENE)
    sample(occ, os.path.join(d, "occ_full.ltm"))
    sample(occ, os.path.join(d, "occ_dense.ltm"), "--sparse", "--dense-fraction", "1")
    t.check(matrix_hash(os.path.join(d, "occ_dense.ltm")) == matrix_hash(os.path.join(d, "occ_full.ltm")),
            "occluder: the all-dense sparse bake differs from the full bake")
    full = load(os.path.join(d, "occ_full.ltm"), d, "occ_full")
    t.check(full.max() > 0 and (full == 0).sum() > 0.2 * full.size, "occluder scene: expected lit and shadowed entries")
    sp = info(os.path.join(d, "occ_dense.ltm"))["sparse"]
    t.check(sp["rows"]["sparse"] == 0 and sp["rows"]["dense"] == int((full.sum(axis=1) > 0).sum()),
            f"occluder: all rows that see geometry are dense: {sp['rows']}")
    # The grid is a quarter of the texels above the horizon (half of the 6R²): ~1/8, plus the
    # shadow's edges: well under half.
    t.check(0.1 <= sp["traced_fraction"] <= 0.3, f"occluder: traced fraction {sp['traced_fraction']}")

    # 2. Determinism and resume on the tiny scene (image 32², R = 8).
    ref = os.path.join(d, "tiny_sparse.ltm")
    sample(TINY, ref, "--sparse", "--jobs", "1")
    h = matrix_hash(ref)
    kinds = {}
    for a in info(ref)["arrays"]:
        kinds[a["name"]] = a.get("content_hash")
    for args in (["--jobs", "2", "--chunk-rows", "7"], ["--jobs", "3", "--chunk-rows", "100"]):
        out = os.path.join(d, "tiny_sparse_" + args[1] + ".ltm")
        sample(TINY, out, "--sparse", *args)
        got = {a["name"]: a.get("content_hash") for a in info(out)["arrays"]}
        for name in kinds:
            if name != "sparse_seconds":  # wall time per row: the one array that differs
                t.check(got[name] == kinds[name], f"{args}: array {name} differs ({got[name]} vs {kinds[name]})")
    storm = os.path.join(d, "tiny_storm.ltm")
    t.kill_storm(["sample", TINY, "-o", storm, "--sparse", "--chunk-rows", "8", "--progress", "never", "-q"], storm,
                 kills=t.scaled(12, 4), max_delay=0.25, seed=3)
    sample(TINY, storm, "--sparse", "--chunk-rows", "8")
    t.check(matrix_hash(storm) == h, "kill storm + resume: content differs from an uninterrupted run")
    t.check(not os.path.exists(storm + ".dense.ltm"), "the phase-1 checkpoint is left behind after the output sealed")
    # A rerun of a finished output does nothing and keeps it.
    sample(TINY, storm, "--sparse", "--chunk-rows", "8")
    t.check(matrix_hash(storm) == h, "a rerun changed a finished output")

    # 3. Accuracy: T·L of the sparse bake against the full bake, direct and with one bounce.
    #    The bound: 1.5 × the difference between two full bakes (seeds 1 and 2) plus 1%.
    g = np.random.default_rng(4)
    for bounces in ("0", "1"):
        f1 = os.path.join(d, f"full_b{bounces}.ltm")
        f2 = os.path.join(d, f"full2_b{bounces}.ltm")
        s1 = os.path.join(d, f"sparse_b{bounces}.ltm")
        sample(TINY, f1, "--bounces", bounces)
        sample(TINY, f2, "--bounces", bounces, "--seed", "2")
        sample(TINY, s1, "--bounces", bounces, "--sparse")
        A = load(f1, d, "a")
        A2 = load(f2, d, "a2")
        S = load(s1, d, "s")
        t.check(S.shape == A.shape and np.all(S >= 0) and np.all(np.isfinite(S)), f"bounces {bounces}: sparse matrix")
        t.check(np.all(S[A.sum(axis=1) == 0] == 0), f"bounces {bounces}: rows without geometry must stay zero")
        lights = {"constant": np.ones(A.shape[1]), "random": g.random(A.shape[1])}
        sun = np.full(A.shape[1], 0.05)
        sun[g.integers(0, A.shape[1], 3)] = 40.0
        lights["suns"] = sun
        for name, L in lights.items():
            b = A @ L
            floor = np.linalg.norm(A2 @ L - b) / np.linalg.norm(b)
            err = np.linalg.norm(S @ L - b) / np.linalg.norm(b)
            print(f"bounces {bounces}, {name}: sparse {err:.4f}, two full bakes {floor:.4f}")
            t.check(err <= 1.5 * floor + 0.01, f"bounces {bounces}, {name}: relit error {err:.4f} > 1.5 × {floor:.4f} + 1%")

    # 4. Side tables against inspect's summary.
    meta = info(s1)
    sp = meta["sparse"]
    kind = t.side_table(s1, "sparse_kind")[:, 0]
    mask = t.side_table(s1, "mask")[:, 0]
    resid = t.side_table(s1, "sparse_residual")[:, 0]
    t.check(np.array_equal(kind > 0, mask > 0), "sparse_kind must be non-zero exactly where mask is")
    # Kind 1 with a residual: a row phase 2 traced in full (its fit failed), not a phase-1 row.
    dense = int(((kind == 1) & (resid == 0)).sum())
    in_full = int(((kind == 1) & (resid > 0)).sum())
    sparse_rows = int((kind == 2).sum())
    t.check(sp["rows"]["dense"] == dense and sp["rows"]["sparse"] == sparse_rows and
            sp["rows"]["traced_in_full"] == in_full, f"rows per kind: {sp['rows']} vs {dense}, {sparse_rows}, {in_full}")
    t.check(np.all(resid[kind == 2] <= 0.15), "a reconstructed row's residual above the limit")
    valid = int(mask.sum())
    t.check(abs(dense - 0.25 * valid) <= 1, f"dense rows {dense} for 25% of {valid}")
    cols = meta["shape"][1]
    frac = (sp["traced_entries"]["dense"] + sp["traced_entries"]["sparse"]) / (valid * cols)
    t.check(abs(frac - sp["traced_fraction"]) < 1e-12, f"traced fraction {sp['traced_fraction']} vs {frac}")
    t.check(0.05 < sp["traced_fraction"] < 0.5, f"traced fraction {sp['traced_fraction']}")
    t.check(sp["parameters"]["dense_fraction"] == 0.25 and sp["parameters"]["neighbours"] == 16,
            f"parameters {sp['parameters']}")

    # 5. Fused row-transform; cpca dense-first; a recipe.
    rows = os.path.join(d, "sparse_rows.ltm")
    t.run("row-transform", s1, "-o", rows, "--filter", "haar", "--progress", "never", "-q")
    fused = os.path.join(d, "sparse_fused.ltm")
    sample(TINY, fused, "--bounces", "1", "--sparse", "--row-transform", "haar")
    t.check(matrix_hash(fused) == matrix_hash(rows), "fused sparse sample + row-transform differs from the two stages")
    t.check("sparse" in info(rows), "row-transform must carry the sparse side tables")
    c = json.loads(t.run("cpca", rows, "-o", os.path.join(d, "cpca.ltm"), "-k", "4", "-s", "3", "--json",
                         "--progress", "never").stdout)
    t.check(c["dense_first"] and c["dense_rows"] == dense + in_full, f"cpca on a sparse bake should run dense-first: {c}")
    recipe = t.write(os.path.join(d, "bake.toml"), f"""
scene = "{TINY}"
workdir = "{os.path.join(d, 'work')}"
targets = ["quantize", "cpca"]
[sample]
sparse = "force"
dense_fraction = 0.3
[cpca]
clusters = 4
basis = 3
""")
    t.run("run", recipe, "--progress", "never", "-q")
    rep = t.run_report(os.path.join(d, "work"))
    for f in ("final.ltm", "cpca.ltm", "rows.ltm"):
        t.check(os.path.exists(os.path.join(d, "work", f)), f"recipe: {f} missing")
    t.check(info(os.path.join(d, "work", "rows.ltm"))["sparse"]["parameters"]["dense_fraction"] == 0.3,
            "recipe: dense_fraction did not reach the stage")
    bad = t.write(os.path.join(d, "bad.toml"), f'scene = "{TINY}"\nworkdir = "{d}/w2"\n[sample]\ndense_fraction = 0.3\n')
    p = t.run("run", bad, expect=2)
    t.check("sparse = true" in p.stderr and "bad.toml" in p.stderr, f"recipe key without sparse: {p.stderr}")

    # 7. --sparse auto.
    def summary(out, *args):
        return json.loads(t.run("sample", TINY, "-o", out, "--progress", "never", "--json", *args).stdout)

    plain = os.path.join(d, "auto_plain.ltm")
    sample(TINY, plain)
    for margin, want, same_as in (("0", "full", plain), ("1e9", "sparse", ref)):
        out = os.path.join(d, f"auto_{want}.ltm")
        j = summary(out, "--sparse", "auto", "--sparse-margin", margin, "--jobs", "1")
        a = j["sparse_auto"]
        t.check(a["decision"] == want and not a["resumed"], f"--sparse-margin {margin}: {a}")
        v, per = j["rows_with_geometry"], a["cpu_seconds_per_row"]
        dense = max(1, min(v, round(0.25 * v)))
        pred = a["predicted_cpu_seconds"]
        t.check(abs(pred["full"] - v * per["full"]) <= 1e-9 * pred["full"] + 1e-12, f"predicted full: {a}")
        t.check(abs(pred["sparse"] - (dense * per["dense"] + (v - dense) * per["sparse"])) <= 1e-9 * pred["sparse"] + 1e-12,
                f"predicted sparse: {a}")
        t.check(a["pilot_rows"] > 0 and min(per.values()) > 0, f"pilot: {a}")
        t.check((pred["sparse"] <= a["margin"] * pred["full"]) == (want == "sparse"), f"decision against the record: {a}")
        t.check(matrix_hash(out) == matrix_hash(same_as), f"--sparse auto ({want}): matrix differs from {same_as}")
        names = [x["name"] for x in info(out)["arrays"]]
        t.check(("sparse_kind" in names) == (want == "sparse"), f"{want}: arrays {names}")
        meta = info(out)["provenance"]["parameters"]["sparse_auto"]
        t.check(meta["decision"] == want and meta["reason"] == a["reason"], f"{want}: provenance {meta}")
        # A rerun follows the recorded decision whatever the pilot would say now.
        other = "1e9" if margin == "0" else "0"
        a2 = summary(out, "--sparse", "auto", "--sparse-margin", other, "--jobs", "1")["sparse_auto"]
        t.check(a2["decision"] == want and a2["resumed"], f"rerun: the recorded decision was not kept: {a2}")
        t.check(matrix_hash(out) == matrix_hash(same_as), f"rerun ({want}) changed the output")
    # Other sampling (a seed) with --overwrite: the pilot runs again.
    a3 = summary(os.path.join(d, "auto_full.ltm"), "--sparse", "auto", "--sparse-margin", "0", "--seed", "5", "--jobs", "1",
                 "--overwrite")["sparse_auto"]
    t.check(not a3["resumed"], f"--overwrite with another seed kept a stale decision: {a3}")
    p = sample(TINY, os.path.join(d, "bad.ltm"), "--sparse", "always", expect=2)
    t.check("--sparse always" in p.stderr and "auto or force" in p.stderr, f"--sparse always: {p.stderr}")
    for value, flag in (('"force"', "--sparse force"), ("true", "--sparse auto"), ('"auto"', "--sparse auto")):
        r = t.write(os.path.join(d, "auto.toml"), f'scene = "{TINY}"\nworkdir = "{d}/w3"\n[sample]\nsparse = {value}\n')
        p = t.run("run", r, "--dry-run", "--json")
        t.check(flag in p.stdout, f"recipe sparse = {value}: the plan does not pass {flag}")
    r = t.write(os.path.join(d, "auto.toml"), f'scene = "{TINY}"\nworkdir = "{d}/w3"\n[sample]\nsparse = "yes"\n')
    p = t.run("run", r, expect=2)
    t.check('"yes"' in p.stderr and "auto.toml" in p.stderr, f"recipe sparse = \"yes\": {p.stderr}")

    # 6. Bad parameters name the flag and the value.
    for args, flag in ((["--dense-fraction", "0"], "--dense-fraction 0"), (["--dense-fraction", "1.5"], "--dense-fraction 1.5"),
                       (["--radius", "0"], "--radius 0"), (["--radius", "-2"], "--radius -2"),
                       (["--features", "0"], "--features 0"), (["--features", "385"], "--features 385"),
                       (["--neighbours", "0"], "--neighbours 0"), (["--neighbours", "65"], "--neighbours 65"),
                       (["--l1-lambda", "1"], "--l1-lambda 1")):
        p = sample(TINY, os.path.join(d, "bad.ltm"), "--sparse", *args, expect=1)
        t.check(flag in p.stderr, f"{args}: message should name '{flag}': {p.stderr}")
        t.check(not os.path.exists(os.path.join(d, "bad.ltm")), f"{args}: an output was left behind")
    p = sample(TINY, os.path.join(d, "bad.ltm"), "--sparse", "--shard", "0", "--nshards", "2", expect=1)
    t.check("shard" in p.stderr, f"--sparse --shard: {p.stderr}")

t.finish()
