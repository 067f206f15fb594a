"""CLI golden tests: each tests/cli/golden/NAME.case holds a command line and an exit code;
NAME.out the expected stdout and stderr. Paths are normalised ({tmp}, {samples}).

usage: golden_test.py PATH_TO_LTBAKE [--regen]   (--regen rewrites the .out files)

Fixtures made fresh in {tmp} for every run:
  sample.ltm   samples/tiny-transport.npy converted with 256-byte chunks (one job: chunks in order)
  corrupt.ltm  sample.ltm with one payload byte of chunk 1 flipped
  newer.ltm    sample.ltm with its format major set to 2
  partial.ltm  sample.ltm cut after its third chunk (as a killed writer leaves it)
"""
import glob
import json
import os
import shlex
import subprocess
import sys
import tempfile

LTBAKE = os.path.abspath(sys.argv[1])
REGEN = "--regen" in sys.argv
HERE = os.path.dirname(os.path.abspath(__file__))
SAMPLES = os.path.normpath(os.path.join(HERE, "..", "..", "samples"))
failures = []
passed = 0


def make_fixtures(tmp):
    sample = os.path.join(tmp, "sample.ltm")
    subprocess.run([LTBAKE, "convert", os.path.join(SAMPLES, "tiny-transport.npy"), sample, "--chunk-size", "256", "--jobs", "1",
                    "-q"], check=True)
    chunks = json.loads(subprocess.run([LTBAKE, "inspect", sample, "--json", "--chunks"], check=True,
                                       capture_output=True, text=True).stdout)["chunk_list"]
    data = bytearray(open(sample, "rb").read())
    corrupt = bytearray(data)
    corrupt[chunks[1]["offset"] + 64 + 5] ^= 0x10  # inside chunk 1's payload
    open(os.path.join(tmp, "corrupt.ltm"), "wb").write(corrupt)
    newer = bytearray(data)
    newer[8] = 2  # format major (u16 at offset 8)
    open(os.path.join(tmp, "newer.ltm"), "wb").write(newer)
    open(os.path.join(tmp, "partial.ltm"), "wb").write(data[:chunks[3]["offset"] + 40])


with tempfile.TemporaryDirectory() as tmp:
    make_fixtures(tmp)
    for case in sorted(glob.glob(os.path.join(HERE, "golden", "*.case"))):
        name = os.path.basename(case)[:-5]
        spec = {}
        for line in open(case):
            if line.strip() and not line.startswith("#"):
                k, v = line.split(":", 1)
                spec[k.strip()] = v.strip()
        args = [a.replace("{tmp}", tmp).replace("{samples}", SAMPLES) for a in shlex.split(spec.get("args", ""))]
        p = subprocess.run([LTBAKE, *args], capture_output=True, text=True, timeout=60, cwd=tmp)
        norm = lambda s: s.replace(tmp, "{tmp}").replace(SAMPLES, "{samples}")
        got = f"exit: {p.returncode}\n--- stdout\n{norm(p.stdout)}--- stderr\n{norm(p.stderr)}"
        out = case[:-5] + ".out"
        if REGEN:
            open(out, "w").write(got)
        want = open(out).read() if os.path.exists(out) else "(no .out file; run with --regen)"
        if p.returncode != int(spec.get("exit", "0")):
            failures.append(f"{name}: exit {p.returncode}, the case expects {spec.get('exit')}")
        elif got != want:
            failures.append(f"{name}: output differs\n--- expected\n{want}\n--- got\n{got}")
        else:
            passed += 1

for f in failures:
    print(f)
print(f"{passed} passed, {len(failures)} failed")
sys.exit(1 if failures else 0)
