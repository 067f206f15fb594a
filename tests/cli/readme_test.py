"""The README's demo bake is what a fresh run prints: runs `ltbake run samples/medium-bake.toml`
(the command README shows, in a work directory of its own) and checks every line of README's
shown output — the stage headers, the `wrote` and `kept` lines (paths relative to the
recipe's work directory, out/medium-bake/) and, of the summary table, each stage's action,
output, size and content_hash (wall time and peak RSS differ between runs). A README that
drifts from the code fails here.
    readme_test.py LTBAKE"""
import os
import re
import subprocess
import sys
import tempfile

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
from ltbtest import check, finish, run  # noqa: E402

REPO = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
COMMAND = "$ ltbake run samples/medium-bake.toml"

readme = open(os.path.join(REPO, "README.md"), encoding="utf-8").read()
start = readme.find(COMMAND + "\n")
check(start >= 0, f"README.md shows no '{COMMAND}' block")
shown = readme[start + len(COMMAND) + 1:readme.find("```", start)].splitlines() if start >= 0 else []
lines = [s for s in shown if s.startswith(("== ", "wrote ", "  kept "))]
rows = [s.split() for s in shown if re.match(r"^\S+\s+(run|skipped)\s", s)]
check(len(lines) >= 8 and len(rows) >= 6, f"README's demo block has {len(lines)} lines and {len(rows)} table rows")

os.environ["LTBAKE_ENVMAPS"] = subprocess.run(["bash", os.path.join(REPO, "scripts", "find_envmaps.sh")],
                                              capture_output=True, text=True, check=True).stdout.strip()
with tempfile.TemporaryDirectory() as d:
    work = os.path.join(d, "medium-bake")
    out = run("run", os.path.join(REPO, "samples", "medium-bake.toml"), "--workdir", work).stdout
    # A step line's ETA ("; about 2 s left in the bake") is a time like the table's: not compared.
    eta = re.compile(r"; about \S+ (s|min|h) left in the bake$")
    got = [eta.sub("", g) for g in out.replace(work + "/", "out/medium-bake/").splitlines()]
    lines = [eta.sub("", s) for s in lines]
    for s in lines:
        check(s in got, f"README line not in a fresh run's output: {s!r}")
    table = {r[0]: r for r in (g.split() for g in got) if len(r) >= 9 and r[1] in ("run", "skipped")}
    for r in rows:
        # stage action wall s peak MiB output size unit hash
        g = table.get(r[0])
        want, have = (r[1], *r[6:]), (g[1], *g[6:]) if g else None
        check(g is not None and want == have, f"README table row {' '.join(r)}: a fresh run has {g}")
finish()
